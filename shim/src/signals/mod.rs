//! Signals on simulated time: the process's ITIMER_REAL and POSIX timers (`timers.rs`), the
//! waits for a signal (`waits.rs`), and here the dispatch of the trapped calls, the program's
//! masks, and the delivery, including the signals one followed thread sends another (`kill`
//! and kin).
//!
//! A timer lives in the block (`abi::SigTimer`). climbsim fires it at its instant, with every
//! controller thread parked: it picks the thread that takes the signal and lets it go
//! (`release::SIGNAL`). That thread sends the signal to itself (`delivery::take_due`), so that it
//! arrives in the thread's own turn, at a point of its run that does not depend on the host:
//! inside the trap handler every other signal waits until the handler returns, so the
//! program's handler runs right after the interrupted call returns EINTR, as on a kernel. A
//! wait that the signal does not interrupt (it is blocked and not waited for, or ignored) goes
//! on.

use core::ffi::{c_int, c_long};
use core::sync::atomic::Ordering;

use crate::abi::{NEVER, Shared, SigTimer, call, release, timer_kind, timer_state};
use crate::native;
use crate::schedule::block::active;
use crate::sys::{self, nr, real};

mod timers;
mod waits;

pub(crate) use timers::delete_posix_timers_of;
pub(crate) use waits::WaitMask;

const ITIMER_REAL: i64 = 0;
const EINTR: c_long = 4;
const EAGAIN: c_long = 11;
const EINVAL: c_long = 22;
/// The program changed its mask (a trapped sigprocmask): climbsim sees it in the slot.
pub(crate) fn mask_changed(mask: u64) {
    crate::handlers::set_trap_mask(mask);
    if let Some(slot) = crate::schedule::slot::claimed_slot() {
        slot.sig_blocked.store(mask, Ordering::Relaxed);
    }
}

/// A trapped call of this module's families, on simulated time; None: the kernel's (the run
/// is over, a clock or timer climbsim does not follow), with the program's own mask.
pub(crate) fn trapped(number: i64, a: [i64; 6], program_mask: u64) -> Option<c_long> {
    let shared = active()?;
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
    crate::schedule::park::note_call(shared, what);
    crate::schedule::park::charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
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
            timer.queued.store(0, Ordering::Relaxed);
            timer.deliver_tid.store(0, Ordering::Relaxed);
            timer.deadline_ns.store(NEVER, Ordering::Relaxed);
            timer.interval_ns.store(0, Ordering::Relaxed);
            timer.pid.store(crate::schedule::block::pid(), Ordering::Relaxed);
            return Some((index, timer));
        }
    }
    crate::schedule::block::refuse(crate::abi::refused::SIG_TIMERS);
    None
}

/// pthread_cancel: glibc marks the thread canceled, and sends it SIGCANCEL only while it is in
/// an asynchronous cancellation window (a blocking call made through glibc, such as a
/// condition wait's futex). A thread that waits where the shim waits instead of glibc (a
/// sleep, a poll) is in none, and slept on to its deadline: it is sent SIGCANCEL as a followed
/// thread's signal, which ends its wait at this instant, and the wait acts on the
/// cancellation as it returns (`handlers::cancellation_point`).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_cancel(thread: usize) -> c_int {
    let next = real!(pthread_cancel: fn(usize) -> c_int);
    // SAFETY: passing the caller's argument through.
    let rc = unsafe { next(thread) };
    if rc == 0
        && let Some(shared) = active()
    {
        let me = crate::schedule::block::pid();
        // Still blocked (glibc sent nothing: a signal it sent has made it ready), in one of the
        // shim's waits that are cancellation points (its last followed call: a sleep or a wait
        // of the poll family), not in one that is none (a lock's futex, a semaphore's).
        let in_cancellation_point = |s: &crate::abi::Slot| matches!(s.last_call.load(Ordering::Relaxed), call::SLEEP | call::POLL | call::SELECT);
        let waiting = shared
            .live_slots()
            .iter()
            .find(|s| s.thread.load(Ordering::Relaxed) == thread as u64 && s.pid.load(Ordering::Relaxed) == me && s.state() == crate::abi::state::BLOCKED && in_cancellation_point(s));
        if let Some(target) = waiting {
            let _ = send_followed(shared, me, target.tid.load(Ordering::Relaxed), sys::SIGCANCEL);
        }
    }
    rc
}

/// The signals whose sending goes to the kernel as it is: 0 (a check that the target lives),
/// and those nobody can catch or block (SIGKILL, SIGSTOP) or that resume a stopped one
/// (SIGCONT).
const SENT_AS_THEY_ARE: [c_int; 4] = [0, 9, 18, 19];

/// The process a followed thread `tid` belongs to.
fn pid_of_thread(shared: &Shared, tid: i32) -> Option<i32> {
    shared.live_slots().iter().find(|s| s.tid.load(Ordering::Relaxed) == tid && s.is_live()).map(|s| s.pid.load(Ordering::Relaxed))
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
    let sender = (crate::schedule::block::pid() as u32 as u64) | (native::call0(nr::GETUID) as u32 as u64) << 32;
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
        crate::schedule::block::notify_scheduler(shared);
    }
    Some(0)
}
