//! Signals on simulated time: the process's ITIMER_REAL (`alarm`, `setitimer`, `getitimer`),
//! POSIX timers on the simulated clocks (`timer_create` and kin), and the waits for a signal
//! (`pause`, `sigsuspend`, `sigtimedwait`). All of them trapped system calls (`seccomp.rs`).
//!
//! A timer lives in the block (`abi::SigTimer`). climbsim fires it at its instant, with every
//! controller thread parked: it picks the thread that takes the signal and lets it go
//! (`release::SIGNAL`). That thread sends the signal to itself ([`take_due`]), so that it
//! arrives in the thread's own turn, at a point of its run that does not depend on the host:
//! inside the trap handler every other signal waits until the handler returns, so the
//! program's handler runs right after the interrupted call returns EINTR, as on a kernel. A
//! wait that the signal does not interrupt (it is blocked and not waited for, or ignored) goes
//! on.

use core::cell::Cell;
use core::ffi::{c_int, c_long};
use core::sync::atomic::Ordering;

use crate::abi::{NEVER, SIG_TIMERS, Shared, SigTimer, Slot, call, release, state, timer_kind, timer_state, waits};
use crate::native;
use crate::now::{from_ns, sim_now, to_ns};
use crate::sys::{self, nr, timespec, timeval};

const SIGALRM: c_int = 14;
const SIGSYS_BIT: u64 = 1 << 30;
/// The signals whose default action is to do nothing.
const IGNORED_BY_DEFAULT: [c_int; 4] = [17, 18, 23, 28];
const SI_TIMER: c_int = -2;
const SIGEV_SIGNAL: c_int = 0;
const SIGEV_NONE: c_int = 1;
const SIGEV_THREAD_ID: c_int = 4;
const ITIMER_REAL: i64 = 0;
const SIG_BLOCK: c_long = 0;
const EINTR: c_long = 4;
const EAGAIN: c_long = 11;
const EINVAL: c_long = 22;
/// The timer ids handed out: timer i of the block is `ID_BASE + i`. Non-negative, as glibc
/// needs them, and far from the small numbers a kernel gives.
const ID_BASE: i64 = 0x2000_0000;
/// "Not in the trap handler" (a real mask never holds SIGSYS, so never all ones).
const NO_MASK: u64 = u64::MAX;

thread_local! {
    /// Inside the trap handler: the program's signal mask, which the kernel saved (the
    /// handler's own blocks everything).
    static TRAP_MASK: Cell<u64> = const { Cell::new(NO_MASK) };
}

/// The trap handler starts with the program's mask `mask`; what to give [`left_trap`].
pub(crate) fn entered_trap(mask: u64) -> u64 {
    TRAP_MASK.with(|m| m.replace(mask))
}

pub(crate) fn left_trap(before: u64) {
    TRAP_MASK.with(|m| m.set(before));
}

/// The program changed its mask (a trapped sigprocmask): climbsim sees it in the slot.
pub(crate) fn mask_changed(mask: u64) {
    TRAP_MASK.with(|m| m.set(mask));
    if let Some(slot) = crate::claimed_slot() {
        slot.sig_blocked.store(mask, Ordering::Relaxed);
    }
}

/// The program's signal mask for this thread now.
pub(crate) fn program_mask() -> u64 {
    let trapped = TRAP_MASK.with(Cell::get);
    if trapped != NO_MASK {
        return trapped;
    }
    let mut mask = 0u64;
    native::call4(nr::RT_SIGPROCMASK, SIG_BLOCK, 0, &mut mask as *mut u64 as c_long, 8);
    mask
}

/// A thread that claims a slot: its signal state starts afresh.
pub(crate) fn slot_claimed(slot: &Slot) {
    slot.signals_due.store(0, Ordering::Relaxed);
    slot.sig_waiting.store(0, Ordering::Relaxed);
    slot.sig_blocked.store(program_mask(), Ordering::Relaxed);
}

/// A trapped call of this module's families, on simulated time; None: the kernel's (the run
/// is over, a clock or timer climbsim does not follow), with the program's own mask.
pub(crate) fn trapped(number: i64, a: [i64; 6], program_mask: u64) -> Option<c_long> {
    let shared = crate::active()?;
    match number {
        nr::ALARM => Some(alarm(shared, a[0] as u32)),
        nr::SETITIMER if a[0] == ITIMER_REAL => Some(setitimer(shared, a[1] as *const [timeval; 2], a[2] as *mut [timeval; 2])),
        nr::GETITIMER if a[0] == ITIMER_REAL => Some(getitimer(shared, a[1] as *mut [timeval; 2])),
        nr::TIMER_CREATE => timer_create(shared, a[0] as c_int, a[1] as *const SigEvent, a[2] as *mut c_int),
        nr::TIMER_SETTIME => posix_timer(shared, a[0]).map(|t| timer_settime(shared, t, a[1] as c_int, a[2] as *const [timespec; 2], a[3] as *mut [timespec; 2])),
        nr::TIMER_GETTIME => posix_timer(shared, a[0]).map(|t| timer_gettime(shared, t, a[1] as *mut [timespec; 2])),
        nr::TIMER_GETOVERRUN => posix_timer(shared, a[0]).map(|t| c_long::from(t.overrun.load(Ordering::Relaxed))),
        nr::TIMER_DELETE => posix_timer(shared, a[0]).map(|t| {
            t.state.store(timer_state::FREE, Ordering::Release);
            0
        }),
        nr::KILL if a[0] > 0 => send_followed(shared, a[0] as i32, 0, a[1] as c_int),
        nr::TGKILL if a[0] > 0 => send_followed(shared, a[0] as i32, a[1] as i32, a[2] as c_int),
        nr::TKILL => pid_of_thread(shared, a[0] as i32).and_then(|pid| send_followed(shared, pid, a[0] as i32, a[1] as c_int)),
        nr::PAUSE => pause(shared),
        nr::RT_SIGSUSPEND => sigsuspend(shared, a[0] as *const u64, a[1], program_mask),
        nr::RT_SIGTIMEDWAIT => sigtimedwait(shared, a[0] as *const u64, a[1], a[2] as *const timespec, a[3]),
        _ => None,
    }
}

/// struct sigevent (x86_64): the value, the signal, how to notify, and SIGEV_THREAD_ID's thread.
#[repr(C)]
struct SigEvent {
    value: u64,
    signo: c_int,
    notify: c_int,
    tid: c_int,
}

fn charged_call(shared: &Shared, what: u32) {
    crate::note_call(shared, what);
    crate::charge(shared, shared.header.syscall_ns.load(Ordering::Relaxed));
}

/// Take a free timer (or one whose process has gone), busy for its process to fill in.
fn take_timer(shared: &Shared) -> Option<(usize, &SigTimer)> {
    for (index, timer) in shared.sig_timers.iter().enumerate() {
        let held = timer.state.load(Ordering::Acquire);
        let gone = held != timer_state::FREE && held != timer_state::BUSY && !process_lives(timer.pid.load(Ordering::Relaxed));
        if (held == timer_state::FREE || gone) && timer.state.compare_exchange(held, timer_state::BUSY, Ordering::AcqRel, Ordering::Relaxed).is_ok() {
            shared.header.sig_timers_high.fetch_max(index as u32 + 1, Ordering::AcqRel);
            timer.fired.store(0, Ordering::Relaxed);
            timer.overrun.store(0, Ordering::Relaxed);
            timer.deliver_tid.store(0, Ordering::Relaxed);
            timer.deadline_ns.store(NEVER, Ordering::Relaxed);
            timer.interval_ns.store(0, Ordering::Relaxed);
            timer.pid.store(crate::pid(), Ordering::Relaxed);
            return Some((index, timer));
        }
    }
    crate::refuse(crate::abi::refused::SIG_TIMERS);
    None
}

fn process_lives(pid: i32) -> bool {
    const ESRCH: c_long = 3;
    pid > 0 && native::call2(nr::KILL, pid as c_long, 0) != -ESRCH
}

/// This process's ITIMER_REAL, if it has one (`create`: made if not).
fn itimer(shared: &Shared, create: bool) -> Option<&SigTimer> {
    let pid = crate::pid();
    let found = shared.live_sig_timers().iter().find(|t| {
        t.pid.load(Ordering::Relaxed) == pid && t.kind.load(Ordering::Relaxed) == timer_kind::ITIMER_REAL && t.state.load(Ordering::Acquire) != timer_state::FREE
    });
    if found.is_some() || !create {
        return found;
    }
    let (_, timer) = take_timer(shared)?;
    timer.kind.store(timer_kind::ITIMER_REAL, Ordering::Relaxed);
    timer.tid.store(0, Ordering::Relaxed);
    timer.signo.store(SIGALRM as u32, Ordering::Relaxed);
    timer.clock.store(sys::CLOCK_MONOTONIC, Ordering::Relaxed);
    timer.value.store(0, Ordering::Relaxed);
    timer.state.store(timer_state::DISARMED, Ordering::Release);
    Some(timer)
}

/// Change a timer climbsim may be firing: taken busy meanwhile (climbsim only fires while
/// every thread is parked, so this waits only on another thread of the process).
fn change(timer: &SigTimer, f: impl FnOnce(&SigTimer) -> bool) {
    loop {
        let held = timer.state.load(Ordering::Acquire);
        if held == timer_state::FREE {
            return;
        }
        if held != timer_state::BUSY && timer.state.compare_exchange(held, timer_state::BUSY, Ordering::AcqRel, Ordering::Relaxed).is_ok() {
            let armed = f(timer);
            timer.state.store(if armed { timer_state::ARMED } else { timer_state::DISARMED }, Ordering::Release);
            return;
        }
        core::hint::spin_loop();
    }
}

/// What is left of a timer at `now` (0: disarmed), and its period.
fn remaining(timer: Option<&SigTimer>, now: u64) -> (u64, u64) {
    let Some(timer) = timer else { return (0, 0) };
    let interval = timer.interval_ns.load(Ordering::Relaxed);
    if timer.state.load(Ordering::Acquire) != timer_state::ARMED {
        return (0, interval);
    }
    // An expiration due now that climbsim has not fired yet still counts as 1 ns to go.
    (timer.deadline_ns.load(Ordering::Relaxed).saturating_sub(now).max(1), interval)
}

/// Arm (`value` ns from `now`, then every `interval` ns) or disarm (`value` 0).
fn arm(timer: &SigTimer, now: u64, value: u64, interval: u64) {
    change(timer, |t| {
        t.deadline_ns.store(if value == 0 { NEVER } else { now.saturating_add(value) }, Ordering::Relaxed);
        t.interval_ns.store(interval, Ordering::Relaxed);
        value != 0
    });
}

fn alarm(shared: &Shared, seconds: u32) -> c_long {
    charged_call(shared, call::TIMER);
    let now = sim_now(shared);
    let Some(timer) = itimer(shared, seconds != 0) else { return 0 };
    let (left, _) = remaining(Some(timer), now);
    arm(timer, now, u64::from(seconds) * 1_000_000_000, 0);
    // Whole seconds, rounded up, as the kernel answers (an alarm due at all is at least 1).
    left.div_ceil(1_000_000_000) as c_long
}

fn timeval_ns(tv: &timeval) -> Option<u64> {
    (tv.tv_sec >= 0 && (0..1_000_000).contains(&tv.tv_usec)).then(|| tv.tv_sec as u64 * 1_000_000_000 + tv.tv_usec as u64 * 1000)
}

fn ns_timeval(ns: u64) -> timeval {
    // The kernel rounds a remainder up to the next microsecond (never 0 while armed).
    let micros = ns.div_ceil(1000);
    timeval { tv_sec: (micros / 1_000_000) as sys::time_t, tv_usec: (micros % 1_000_000) as c_long }
}

/// getitimer's and setitimer's old value: `[interval, value]`.
fn write_itimer(old: *mut [timeval; 2], (left, interval): (u64, u64)) {
    if !old.is_null() {
        // SAFETY: the caller's struct itimerval.
        unsafe { *old = [ns_timeval(interval), ns_timeval(left)] };
    }
}

fn setitimer(shared: &Shared, new: *const [timeval; 2], old: *mut [timeval; 2]) -> c_long {
    charged_call(shared, call::TIMER);
    let now = sim_now(shared);
    let wanted = if new.is_null() {
        None
    } else {
        // SAFETY: the caller's struct itimerval.
        let [interval, value] = unsafe { &*new };
        match (timeval_ns(interval), timeval_ns(value)) {
            (Some(interval), Some(value)) => Some((value, interval)),
            _ => return -EINVAL,
        }
    };
    let timer = itimer(shared, wanted.is_some_and(|(value, _)| value != 0));
    write_itimer(old, remaining(timer, now));
    if let (Some(timer), Some((value, interval))) = (timer, wanted) {
        arm(timer, now, value, interval);
    }
    0
}

fn getitimer(shared: &Shared, current: *mut [timeval; 2]) -> c_long {
    charged_call(shared, call::TIMER);
    write_itimer(current, remaining(itimer(shared, false), sim_now(shared)));
    0
}

fn timer_create(shared: &Shared, clock: c_int, event: *const SigEvent, id: *mut c_int) -> Option<c_long> {
    // CPU-time clocks stay the kernel's.
    crate::time::clock_at(shared, clock, 0)?;
    charged_call(shared, call::TIMER);
    let (value, signo, notify, tid) = if event.is_null() {
        (None, SIGALRM, SIGEV_SIGNAL, 0)
    } else {
        // SAFETY: the caller's struct sigevent.
        let event = unsafe { &*event };
        (Some(event.value), event.signo, event.notify, event.tid)
    };
    let signo = match notify {
        SIGEV_NONE => 0,
        SIGEV_SIGNAL | SIGEV_THREAD_ID if (1..=64).contains(&signo) => signo,
        _ => return Some(-EINVAL),
    };
    let Some((index, timer)) = take_timer(shared) else { return Some(-EAGAIN) };
    let timer_id = ID_BASE + index as i64;
    timer.kind.store(timer_kind::POSIX, Ordering::Relaxed);
    timer.tid.store(if notify == SIGEV_THREAD_ID { tid } else { 0 }, Ordering::Relaxed);
    timer.signo.store(signo as u32, Ordering::Relaxed);
    timer.clock.store(clock, Ordering::Relaxed);
    // Without a sigevent the signal carries the timer's id.
    timer.value.store(value.unwrap_or(timer_id as u64), Ordering::Relaxed);
    timer.state.store(timer_state::DISARMED, Ordering::Release);
    // SAFETY: the caller's timer id.
    unsafe { *id = timer_id as c_int };
    Some(0)
}

/// The process's POSIX timer of id `id`; None if it is not one of the shim's (the kernel's, on
/// a CPU-time clock).
fn posix_timer(shared: &Shared, id: i64) -> Option<&SigTimer> {
    let index = usize::try_from(id.checked_sub(ID_BASE)?).ok().filter(|&i| i < SIG_TIMERS)?;
    let timer = &shared.sig_timers[index];
    let ours = timer.pid.load(Ordering::Relaxed) == crate::pid() && timer.kind.load(Ordering::Relaxed) == timer_kind::POSIX && timer.state.load(Ordering::Acquire) != timer_state::FREE;
    ours.then(|| {
        charged_call(shared, call::TIMER);
        timer
    })
}

fn timespec_ns(ts: &timespec) -> Option<u64> {
    (ts.tv_sec >= 0 && (0..1_000_000_000).contains(&ts.tv_nsec)).then(|| to_ns(ts))
}

fn write_itimerspec(out: *mut [timespec; 2], (left, interval): (u64, u64)) {
    if !out.is_null() {
        // SAFETY: the caller's struct itimerspec.
        unsafe { *out = [from_ns(interval), from_ns(left)] };
    }
}

fn timer_settime(shared: &Shared, timer: &SigTimer, flags: c_int, new: *const [timespec; 2], old: *mut [timespec; 2]) -> c_long {
    if new.is_null() {
        return -EINVAL;
    }
    // SAFETY: the caller's struct itimerspec.
    let [interval, value] = unsafe { &*new };
    let (Some(interval), Some(value)) = (timespec_ns(interval), timespec_ns(value)) else { return -EINVAL };
    let now = sim_now(shared);
    write_itimerspec(old, remaining(Some(timer), now));
    let value = if flags & sys::TIMER_ABSTIME != 0 && value != 0 {
        // An instant on the timer's clock; one already past expires at once.
        let at = crate::time::sim_time_of(shared, timer.clock.load(Ordering::Relaxed), value).unwrap_or(0);
        at.saturating_sub(now).max(1)
    } else {
        value
    };
    arm(timer, now, value, interval);
    0
}

fn timer_gettime(shared: &Shared, timer: &SigTimer, out: *mut [timespec; 2]) -> c_long {
    write_itimerspec(out, remaining(Some(timer), sim_now(shared)));
    0
}

/// The signals whose sending goes to the kernel as it is: 0 (a check that the target lives),
/// and those nobody can catch or block (SIGKILL, SIGSTOP) or that resume a stopped one
/// (SIGCONT).
const SENT_AS_THEY_ARE: [c_int; 4] = [0, 9, 18, 19];

/// The process a followed thread `tid` belongs to.
fn pid_of_thread(shared: &Shared, tid: i32) -> Option<i32> {
    shared.live_slots().iter().find(|s| s.tid.load(Ordering::Relaxed) == tid && !matches!(s.state.load(Ordering::Acquire), state::FREE | state::EXITED)).map(|s| s.pid.load(Ordering::Relaxed))
}

/// `kill`, `tgkill` or `tkill` of a followed process or thread (`tid` 0: the process) by
/// another followed thread: the signal waits in the block for the thread that takes it, which
/// is let go and sends it to itself in its turn, once the sender parks (a kernel would deliver
/// it whenever the host scheduled the two). None: sent by the kernel as it is (the target is
/// not followed, is this very thread, or the signal is one of `SENT_AS_THEY_ARE`).
fn send_followed(shared: &Shared, pid: i32, tid: i32, signo: c_int) -> Option<c_long> {
    if !(1..=64).contains(&signo) || SENT_AS_THEY_ARE.contains(&signo) {
        return None;
    }
    let taker = shared.signal_taker(pid, tid, signo as u32)?;
    let taker_tid = taker.tid.load(Ordering::Relaxed);
    if taker_tid == sys::gettid() {
        return None;
    }
    charged_call(shared, call::TIMER);
    let (_, sent) = take_timer(shared)?;
    let sender = (crate::pid() as u32 as u64) | (native::call0(nr::GETUID) as u32 as u64) << 32;
    sent.kind.store(timer_kind::SENT, Ordering::Relaxed);
    sent.pid.store(pid, Ordering::Relaxed);
    sent.tid.store(tid, Ordering::Relaxed);
    sent.signo.store(signo as u32, Ordering::Relaxed);
    sent.value.store(sender, Ordering::Relaxed);
    sent.deliver_tid.store(taker_tid, Ordering::Relaxed);
    sent.fired.store(1, Ordering::Relaxed);
    sent.state.store(timer_state::DISARMED, Ordering::Release);
    taker.signals_due.fetch_add(1, Ordering::AcqRel);
    // Parked where the shim waits: ready, with the signal for its reason (a thread in the
    // kernel's waitpid takes it when it parks next).
    if taker.waits.load(Ordering::Relaxed) & waits::CHILD == 0 {
        taker.release.store(release::SIGNAL, Ordering::Release);
        for parked in [state::BLOCKED, state::YIELDED] {
            if taker.state.compare_exchange(parked, state::READY, Ordering::AcqRel, Ordering::Relaxed).is_ok() {
                crate::notify_scheduler(shared);
                break;
            }
        }
    }
    Some(0)
}

/// Signals climbsim fired for this thread (`Slot::signals_due`), sent to itself now; whether
/// one of them interrupts the wait it was let go from.
pub(crate) fn take_due(slot: &Slot) -> bool {
    if slot.signals_due.swap(0, Ordering::AcqRel) == 0 {
        return false;
    }
    let Some(shared) = crate::shared() else { return false };
    let (pid, tid) = (crate::pid(), sys::gettid());
    let mut interrupts = false;
    for (index, timer) in shared.live_sig_timers().iter().enumerate() {
        if timer.pid.load(Ordering::Relaxed) != pid || timer.deliver_tid.load(Ordering::Relaxed) != tid {
            continue;
        }
        let expirations = timer.fired.swap(0, Ordering::AcqRel);
        let signo = timer.signo.load(Ordering::Relaxed) as c_int;
        if expirations == 0 || !(1..=64).contains(&signo) {
            continue;
        }
        let overrun = expirations - 1;
        timer.overrun.store(overrun, Ordering::Relaxed);
        let bit = 1u64 << (signo - 1);
        let (blocked, waiting) = (slot.sig_blocked.load(Ordering::Relaxed), slot.sig_waiting.load(Ordering::Relaxed));
        // Blocked here and waited for by no one: pending on the process, as the kernel keeps
        // it, for whichever thread unblocks it or waits for it later.
        let whole_process = blocked & bit != 0 && waiting & bit == 0 && timer.tid.load(Ordering::Relaxed) == 0;
        send(timer, index, signo, overrun, (pid, tid), whole_process);
        interrupts |= waiting & bit != 0 || (blocked & bit == 0 && !ignored(signo));
    }
    interrupts
}

/// Send the timer's signal: ITIMER_REAL's as the kernel sends SIGALRM, a POSIX timer's with
/// SI_TIMER, its id, overrun and value (glibc's SIGEV_THREAD helper needs them).
fn send(timer: &SigTimer, index: usize, signo: c_int, overrun: u32, (pid, tid): (i32, i32), whole_process: bool) {
    let (pid, tid, signo) = (pid as c_long, tid as c_long, signo as c_long);
    let kind = timer.kind.load(Ordering::Relaxed);
    if kind == timer_kind::SENT {
        // siginfo_t of a kill: SI_USER, the sender's pid and uid.
        let sender = timer.value.load(Ordering::Relaxed);
        let mut info = [0i32; 32];
        info[0] = signo as i32;
        info[4] = sender as u32 as i32;
        info[5] = (sender >> 32) as u32 as i32;
        timer.state.store(timer_state::FREE, Ordering::Release);
        let info = info.as_ptr() as c_long;
        if whole_process {
            native::call3(nr::RT_SIGQUEUEINFO, pid, signo, info);
        } else {
            native::call4(nr::RT_TGSIGQUEUEINFO, pid, tid, signo, info);
        }
        return;
    }
    if kind == timer_kind::ITIMER_REAL {
        if whole_process {
            native::call2(nr::KILL, pid, signo);
        } else {
            native::call3(nr::TGKILL, pid, tid, signo);
        }
        return;
    }
    // siginfo_t (128 bytes): signo, errno, code, then the timer's id, overrun and value.
    let mut info = [0i32; 32];
    info[0] = signo as i32;
    info[2] = SI_TIMER;
    info[4] = (ID_BASE + index as i64) as i32;
    info[5] = overrun.min(i32::MAX as u32) as i32;
    let value = timer.value.load(Ordering::Relaxed);
    info[6] = value as u32 as i32;
    info[7] = (value >> 32) as u32 as i32;
    let info = info.as_ptr() as c_long;
    if whole_process {
        native::call3(nr::RT_SIGQUEUEINFO, pid, signo, info);
    } else {
        native::call4(nr::RT_TGSIGQUEUEINFO, pid, tid, signo, info);
    }
}

/// Whether `signo` is discarded on arrival (SIG_IGN, or a default action of nothing).
fn ignored(signo: c_int) -> bool {
    let mut action = [0usize; 4];
    native::call4(nr::RT_SIGACTION, signo as c_long, 0, action.as_mut_ptr() as c_long, 8);
    match action[0] {
        0 => IGNORED_BY_DEFAULT.contains(&signo),
        1 => true,
        _ => false,
    }
}

/// Wait until a signal ends this wait, or `deadline`; why it ended (`release::SIGNAL`: a
/// signal is pending for it). Signals come two ways: climbsim lets this thread go for a timer's
/// or a followed thread's signal (which it then sends itself), and the kernel raises others (a
/// child's SIGCHLD, a `kill` from a process climbsim does not follow), which wait pending while
/// the trap handler blocks them. For those it waits as a thread on a pipe does: looking at what
/// is pending (`ends`) whenever climbsim asks, and every millisecond of wall time.
fn wait_for_signal(shared: &Shared, deadline: u64, ends: impl Fn(u64) -> bool) -> u32 {
    const SLICE_NS: u64 = 1_000_000;
    let Some(slot) = crate::my_slot() else { return release::ENDING };
    let publish = || crate::publish_waiting_on_kernel(shared, slot, deadline, waits::OTHER, 0);
    publish();
    loop {
        if slot.state.load(Ordering::Acquire) == state::RUNNING {
            let why = slot.release.load(Ordering::Acquire);
            if why == release::SIGNAL && !take_due(slot) {
                publish();
                continue;
            }
            if why == release::DEADLINE && sim_now(shared) < deadline {
                publish();
                continue;
            }
            return why;
        }
        if crate::active().is_none() {
            slot.state.store(state::RUNNING, Ordering::Release);
            return release::ENDING;
        }
        if crate::look_at_kernel(shared, slot, SLICE_NS, || ends(pending()).then_some(())).is_some() {
            // Raised by the kernel: this thread runs again in its turn.
            crate::resume_after_kernel_wake(shared, slot);
            return release::SIGNAL;
        }
    }
}

fn pause(shared: &Shared) -> Option<c_long> {
    crate::note_call(shared, call::SIGNAL_WAIT);
    let program_mask = program_mask();
    match wait_for_signal(shared, NEVER, |pending| pending & !program_mask != 0) {
        release::SIGNAL => Some(-EINTR),
        _ => None,
    }
}

/// Signals pending for this thread or its process.
fn pending() -> u64 {
    let mut set = 0u64;
    native::call2(nr::RT_SIGPENDING, &mut set as *mut u64 as c_long, 8);
    set
}

fn sigsuspend(shared: &Shared, mask: *const u64, size: i64, program_mask: u64) -> Option<c_long> {
    if mask.is_null() || size != 8 {
        return Some(-EINVAL);
    }
    crate::note_call(shared, call::SIGNAL_WAIT);
    // SAFETY: the caller's sigset (8 bytes, as size says).
    let suspended = unsafe { *mask } & !SIGSYS_BIT;
    let slot = crate::my_slot();
    if let Some(slot) = slot {
        slot.sig_blocked.store(suspended, Ordering::Relaxed);
    }
    let why = if pending() & !suspended != 0 { release::SIGNAL } else { wait_for_signal(shared, NEVER, |pending| pending & !suspended != 0) };
    if let Some(slot) = slot {
        slot.sig_blocked.store(program_mask, Ordering::Relaxed);
    }
    if why != release::SIGNAL {
        return None;
    }
    // The signal is pending and the suspended mask lets it through: the kernel's own
    // sigsuspend runs its handler with that mask, puts the program's back and returns EINTR
    // at once.
    let suspended = suspended as c_long;
    Some(native::call2(nr::RT_SIGSUSPEND, &suspended as *const c_long as c_long, 8))
}

fn sigtimedwait(shared: &Shared, set: *const u64, info: i64, timeout: *const timespec, size: i64) -> Option<c_long> {
    if set.is_null() || size != 8 {
        return Some(-EINVAL);
    }
    crate::note_call(shared, call::SIGNAL_WAIT);
    // SAFETY: the caller's sigset.
    let set_bits = unsafe { *set };
    let zero = timespec { tv_sec: 0, tv_nsec: 0 };
    let take = || native::call4(nr::RT_SIGTIMEDWAIT, set as c_long, info as c_long, &zero as *const timespec as c_long, 8);
    let taken = take();
    if taken != -EAGAIN {
        return Some(taken);
    }
    let deadline = if timeout.is_null() {
        NEVER
    } else {
        // SAFETY: the caller's timespec.
        let Some(ns) = timespec_ns(unsafe { &*timeout }) else { return Some(-EINVAL) };
        if ns == 0 {
            crate::charge(shared, shared.header.syscall_ns.load(Ordering::Relaxed));
            return Some(-EAGAIN);
        }
        sim_now(shared).saturating_add(ns)
    };
    let Some(slot) = crate::my_slot() else { return None };
    slot.sig_waiting.store(set_bits, Ordering::Relaxed);
    let why = wait_for_signal(shared, deadline, |pending| pending & set_bits != 0);
    slot.sig_waiting.store(0, Ordering::Relaxed);
    match why {
        // One of the set, or another signal whose handler runs when this call returns.
        release::SIGNAL => Some(match take() {
            taken if taken > 0 => taken,
            _ => -EINTR,
        }),
        release::DEADLINE => Some(-EAGAIN),
        _ => None,
    }
}

/// An exec deletes the process's POSIX timers (its ITIMER_REAL goes on, as the kernel's does).
pub(crate) fn exec_deletes_posix_timers() {
    let Some(shared) = crate::shared() else { return };
    let pid = crate::pid();
    for timer in shared.live_sig_timers() {
        if timer.pid.load(Ordering::Relaxed) == pid && timer.kind.load(Ordering::Relaxed) == timer_kind::POSIX {
            timer.state.store(timer_state::FREE, Ordering::Release);
        }
    }
}
