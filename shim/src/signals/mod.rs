//! Signals on simulated time: the process's ITIMER_REAL and POSIX timers (`timers.rs`), the
//! waits for a signal (`waits.rs`), and here the dispatch of the trapped calls, the program's
//! masks, and the delivery, including the signals one followed thread sends another (`kill`
//! and kin).
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

use crate::abi::{NEVER, Shared, SigTimer, Slot, call, release, state, timer_kind, timer_state};
use crate::native;
use crate::sys::{self, nr};

mod timers;
mod waits;

pub(crate) use timers::delete_posix_timers_of;

const ITIMER_REAL: i64 = 0;
/// The signals whose default action is to do nothing.
const IGNORED_BY_DEFAULT: [c_int; 4] = [17, 18, 23, 28];
const SI_TIMER: c_int = -2;
const SIG_BLOCK: c_long = 0;
const EINTR: c_long = 4;
const EAGAIN: c_long = 11;
const EINVAL: c_long = 22;
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
        nr::ALARM => Some(timers::alarm(shared, a[0] as u32)),
        nr::SETITIMER if a[0] == ITIMER_REAL => Some(timers::setitimer(shared, a[1] as *const [sys::timeval; 2], a[2] as *mut [sys::timeval; 2])),
        nr::GETITIMER if a[0] == ITIMER_REAL => Some(timers::getitimer(shared, a[1] as *mut [sys::timeval; 2])),
        nr::TIMER_CREATE => timers::timer_create(shared, a[0] as c_int, a[1] as *const timers::SigEvent, a[2] as *mut c_int),
        nr::TIMER_SETTIME => timers::posix_timer(shared, a[0]).map(|t| timers::timer_settime(shared, t, a[1] as c_int, a[2] as *const [sys::timespec; 2], a[3] as *mut [sys::timespec; 2])),
        nr::TIMER_GETTIME => timers::posix_timer(shared, a[0]).map(|t| timers::timer_gettime(shared, t, a[1] as *mut [sys::timespec; 2])),
        nr::TIMER_GETOVERRUN => timers::posix_timer(shared, a[0]).map(|t| c_long::from(t.overrun.load(Ordering::Relaxed))),
        nr::TIMER_DELETE => timers::posix_timer(shared, a[0]).map(|t| {
            t.state.store(timer_state::FREE, Ordering::Release);
            0
        }),
        nr::KILL if a[0] > 0 => send_followed(shared, a[0] as i32, 0, a[1] as c_int),
        nr::TGKILL if a[0] > 0 => send_followed(shared, a[0] as i32, a[1] as i32, a[2] as c_int),
        nr::TKILL => pid_of_thread(shared, a[0] as i32).and_then(|pid| send_followed(shared, pid, a[0] as i32, a[1] as c_int)),
        nr::PAUSE => waits::pause(shared),
        nr::RT_SIGSUSPEND => waits::sigsuspend(shared, a[0] as *const u64, a[1], program_mask),
        nr::RT_SIGTIMEDWAIT => waits::sigtimedwait(shared, a[0] as *const u64, a[1], a[2] as *const sys::timespec, a[3]),
        _ => None,
    }
}

fn charged_call(shared: &Shared, what: u32) {
    crate::note_call(shared, what);
    crate::charge(shared, shared.header.syscall_ns.load(Ordering::Relaxed));
}

/// Take a free timer (or one whose process has gone), busy for its process to fill in.
fn take_timer(shared: &Shared) -> Option<(usize, &SigTimer)> {
    for (index, timer) in shared.sig_timers.iter().enumerate() {
        let held = timer.state.load(Ordering::Acquire);
        let gone = held != timer_state::FREE && held != timer_state::BUSY && !sys::process_lives(timer.pid.load(Ordering::Relaxed));
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

/// The signals whose sending goes to the kernel as it is: 0 (a check that the target lives),
/// and those nobody can catch or block (SIGKILL, SIGSTOP) or that resume a stopped one
/// (SIGCONT).
const SENT_AS_THEY_ARE: [c_int; 4] = [0, 9, 18, 19];

/// The process a followed thread `tid` belongs to.
fn pid_of_thread(shared: &Shared, tid: i32) -> Option<i32> {
    shared.live_slots().iter().find(|s| s.tid.load(Ordering::Relaxed) == tid && !matches!(s.state(), state::FREE | state::EXITED)).map(|s| s.pid.load(Ordering::Relaxed))
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
    if !taker.in_waitpid() && taker.make_ready(Some(release::SIGNAL)) {
        crate::notify_scheduler(shared);
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

/// Send the entry's signal: ITIMER_REAL's as the kernel sends SIGALRM; a POSIX timer's with
/// SI_TIMER, its id, overrun and value (glibc's SIGEV_THREAD helper needs them); a followed
/// thread's `kill` with SI_USER and the sender's pid and uid (the entry is then freed).
fn send(timer: &SigTimer, index: usize, signo: c_int, overrun: u32, (pid, tid): (i32, i32), whole_process: bool) {
    let (pid, tid, signo) = (pid as c_long, tid as c_long, signo as c_long);
    let kind = timer.kind.load(Ordering::Relaxed);
    if kind == timer_kind::ITIMER_REAL {
        if whole_process {
            native::call2(nr::KILL, pid, signo);
        } else {
            native::call3(nr::TGKILL, pid, tid, signo);
        }
        return;
    }
    // siginfo_t (128 bytes): signo, errno, code, then (at byte 16) the sender's pid and uid, or
    // the timer's id, overrun and value.
    let value = timer.value.load(Ordering::Relaxed);
    let mut info = [0i32; 32];
    info[0] = signo as i32;
    if kind == timer_kind::SENT {
        info[4] = value as u32 as i32;
        info[5] = (value >> 32) as u32 as i32;
        timer.state.store(timer_state::FREE, Ordering::Release);
    } else {
        info[2] = SI_TIMER;
        info[4] = (timers::ID_BASE + index as i64) as i32;
        info[5] = overrun.min(i32::MAX as u32) as i32;
        info[6] = value as u32 as i32;
        info[7] = (value >> 32) as u32 as i32;
    }
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
