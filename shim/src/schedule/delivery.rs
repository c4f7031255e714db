//! Signals climbsim fired for a thread (a timer's, or one another followed thread sent), sent
//! by the thread to itself in its own turn, so that each arrives at a point of its run that
//! does not depend on the host (see `signals/`, which arms the timers and follows the waits).

use core::ffi::{c_int, c_long};
use core::sync::atomic::Ordering;

use crate::abi::{SigTimer, Slot, timer_kind, timer_state};
use crate::native;
use crate::sys::{self, nr};

/// The signals whose default action is to do nothing.
const IGNORED_BY_DEFAULT: [c_int; 4] = [17, 18, 23, 28];
const SI_TIMER: c_int = -2;
const SI_USER: c_int = 0;
const SI_TKILL: c_int = -6;
/// The most a POSIX timer's overrun counts (Linux's DELAYTIMER_MAX, INT_MAX).
const DELAYTIMER_MAX: u32 = i32::MAX as u32;
/// The timer ids handed out: timer i of the block is `TIMER_ID_BASE + i`. Non-negative, as
/// glibc needs them, and far from the small numbers a kernel gives.
pub(crate) const TIMER_ID_BASE: i64 = 0x2000_0000;

thread_local! {
    /// The last signal [`take_due`] found to interrupt this thread's wait (0: none since asked).
    static INTERRUPTED_BY: core::cell::Cell<c_int> = const { core::cell::Cell::new(0) };
}

/// The signal that last interrupted this thread's wait, if one did since the last asking: a
/// wait that Linux restarts after a handler with SA_RESTART asks which handler ran.
pub(crate) fn interrupted_by() -> Option<c_int> {
    Some(INTERRUPTED_BY.with(|last| last.replace(0))).filter(|&signo| signo != 0)
}

/// Signals climbsim fired for this thread (`Slot::signals_due`), sent to itself now; whether
/// one of them interrupts the wait it was let go from.
pub(crate) fn take_due(slot: &Slot) -> bool {
    if slot.signals_due.swap(0, Ordering::AcqRel) == 0 {
        return false;
    }
    let Some(shared) = crate::schedule::block::shared() else { return false };
    let (pid, tid) = (crate::schedule::block::pid(), sys::gettid());
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
        let bit = 1u64 << (signo - 1);
        let (blocked, waiting) = (slot.sig_blocked.load(Ordering::Relaxed), slot.sig_waiting.load(Ordering::Relaxed));
        // A POSIX timer whose last signal is still pending (nobody has taken it yet): the kernel
        // queues no second one, it counts the expirations as the timer's overrun
        // (`timer_getoverrun`, up to DELAYTIMER_MAX). (Pending is asked of the signal's number:
        // the same signal pending from elsewhere counts as this timer's.)
        let posix = timer.kind.load(Ordering::Relaxed) == timer_kind::POSIX;
        if posix && timer.queued.load(Ordering::Relaxed) != 0 {
            if sys::pending_signals() & bit != 0 {
                let _ = timer.overrun.fetch_update(Ordering::AcqRel, Ordering::Relaxed, |overrun| Some(overrun.saturating_add(expirations).min(DELAYTIMER_MAX)));
                continue;
            }
            timer.queued.store(0, Ordering::Relaxed);
        }
        let overrun = expirations - 1;
        timer.overrun.store(overrun, Ordering::Relaxed);
        if posix {
            timer.queued.store(1, Ordering::Relaxed);
        }
        // Blocked here and waited for by no one: pending on the process, as the kernel keeps
        // it, for whichever thread unblocks it or waits for it later.
        let whole_process = blocked & bit != 0 && waiting & bit == 0 && timer.tid.load(Ordering::Relaxed) == 0;
        send(timer, index, signo, overrun, (pid, tid), whole_process);
        let this_one = waiting & bit != 0 || (blocked & bit == 0 && !ignored(signo));
        if this_one {
            INTERRUPTED_BY.with(|last| last.set(signo));
        }
        interrupts |= this_one;
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
        // As the kernel marks it: a signal sent to a thread (tgkill, tkill) SI_TKILL, to a
        // process (kill) SI_USER. (glibc's cancellation handler takes SIGCANCEL only with
        // SI_TKILL: a canceled thread in a condition wait waited on.)
        info[2] = if timer.tid.load(Ordering::Relaxed) != 0 { SI_TKILL } else { SI_USER };
        info[4] = value as u32 as i32;
        info[5] = (value >> 32) as u32 as i32;
        timer.state.store(timer_state::FREE, Ordering::Release);
    } else {
        info[2] = SI_TIMER;
        info[4] = (TIMER_ID_BASE + index as i64) as i32;
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
pub(crate) fn ignored(signo: c_int) -> bool {
    match crate::handlers::kernel_action(signo).0 {
        0 => IGNORED_BY_DEFAULT.contains(&signo),
        1 => true,
        _ => false,
    }
}
