//! The timers: the process's ITIMER_REAL (`alarm`, `setitimer`, `getitimer`) and POSIX timers
//! on the simulated clocks (`timer_create` and kin), kept in the block for climbsim to fire.

use core::ffi::{c_int, c_long};
use core::sync::atomic::Ordering;

use crate::abi::{NEVER, SIG_TIMERS, Shared, SigTimer, call, timer_kind, timer_state};
use crate::schedule::now::{clock_at, from_ns, sim_now, sim_time_of};
use crate::sys::{self, timespec, timespec_ns, timeval, timeval_ns};

use super::{EAGAIN, EINVAL, charged_call, take_timer};

const SIGALRM: c_int = 14;
const SIGEV_SIGNAL: c_int = 0;
const SIGEV_NONE: c_int = 1;
const SIGEV_THREAD_ID: c_int = 4;
/// The timer ids handed out (see `delivery::TIMER_ID_BASE`).
use crate::schedule::delivery::TIMER_ID_BASE as ID_BASE;

/// struct sigevent (x86_64): the value, the signal, how to notify, and SIGEV_THREAD_ID's thread.
#[repr(C)]
pub(super) struct SigEvent {
    value: u64,
    signo: c_int,
    notify: c_int,
    tid: c_int,
}

/// This process's ITIMER_REAL, if it has one (`create`: made if not).
fn itimer(shared: &Shared, create: bool) -> Option<&SigTimer> {
    let pid = crate::schedule::block::pid();
    let found = shared
        .live_sig_timers()
        .iter()
        .find(|t| t.pid.load(Ordering::Relaxed) == pid && t.kind.load(Ordering::Relaxed) == timer_kind::ITIMER_REAL && t.state.load(Ordering::Acquire) != timer_state::FREE);
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

/// Arm (`value` ns from `now`, then every `interval` ns) or disarm (`value` 0, which clears the
/// interval too, as Linux does for both kinds of timer).
fn arm(timer: &SigTimer, now: u64, value: u64, interval: u64) {
    change(timer, |t| {
        t.deadline_ns.store(if value == 0 { NEVER } else { now.saturating_add(value) }, Ordering::Relaxed);
        t.interval_ns.store(if value == 0 { 0 } else { interval }, Ordering::Relaxed);
        value != 0
    });
}

pub(super) fn alarm(shared: &Shared, seconds: u32) -> c_long {
    charged_call(shared, call::TIMER);
    let now = sim_now(shared);
    let Some(timer) = itimer(shared, seconds != 0) else { return 0 };
    let (left, _) = remaining(Some(timer), now);
    arm(timer, now, u64::from(seconds) * 1_000_000_000, 0);
    // Whole seconds, rounded up, as the kernel answers (an alarm due at all is at least 1).
    left.div_ceil(1_000_000_000) as c_long
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

pub(super) fn setitimer(shared: &Shared, new: *const [timeval; 2], old: *mut [timeval; 2]) -> c_long {
    charged_call(shared, call::TIMER);
    let now = sim_now(shared);
    // A null new value disarms the timer (Linux's "misfeature", kept for old programs).
    let new = if new.is_null() { Some([timeval { tv_sec: 0, tv_usec: 0 }; 2]) } else { sys::read_from_program(new) };
    let Some([interval, value]) = new else { return -c_long::from(sys::EFAULT) };
    let wanted = match (timeval_ns(&interval), timeval_ns(&value)) {
        (Some(interval), Some(value)) => Some((value, interval)),
        _ => return -EINVAL,
    };
    let timer = itimer(shared, wanted.is_some_and(|(value, _)| value != 0));
    write_itimer(old, remaining(timer, now));
    if let (Some(timer), Some((value, interval))) = (timer, wanted) {
        arm(timer, now, value, interval);
    }
    0
}

pub(super) fn getitimer(shared: &Shared, current: *mut [timeval; 2]) -> c_long {
    charged_call(shared, call::TIMER);
    write_itimer(current, remaining(itimer(shared, false), sim_now(shared)));
    0
}

pub(super) fn timer_create(shared: &Shared, clock: c_int, event: *const SigEvent, id: *mut c_int) -> Option<c_long> {
    // CPU-time clocks stay the kernel's.
    clock_at(shared, clock, 0)?;
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
pub(super) fn posix_timer(shared: &Shared, id: i64) -> Option<&SigTimer> {
    let index = usize::try_from(id.checked_sub(ID_BASE)?).ok().filter(|&i| i < SIG_TIMERS)?;
    let timer = &shared.sig_timers[index];
    let ours =
        timer.pid.load(Ordering::Relaxed) == crate::schedule::block::pid() && timer.kind.load(Ordering::Relaxed) == timer_kind::POSIX && timer.state.load(Ordering::Acquire) != timer_state::FREE;
    ours.then(|| {
        charged_call(shared, call::TIMER);
        timer
    })
}

fn write_itimerspec(out: *mut [timespec; 2], (left, interval): (u64, u64)) {
    if !out.is_null() {
        // SAFETY: the caller's struct itimerspec.
        unsafe { *out = [from_ns(interval), from_ns(left)] };
    }
}

pub(super) fn timer_settime(shared: &Shared, timer: &SigTimer, flags: c_int, new: *const [timespec; 2], old: *mut [timespec; 2]) -> c_long {
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
        let at = sim_time_of(shared, timer.clock.load(Ordering::Relaxed), value).unwrap_or(0);
        at.saturating_sub(now).max(1)
    } else {
        value
    };
    arm(timer, now, value, interval);
    0
}

pub(super) fn timer_gettime(shared: &Shared, timer: &SigTimer, out: *mut [timespec; 2]) -> c_long {
    write_itimerspec(out, remaining(Some(timer), sim_now(shared)));
    0
}

/// A new program in process `pid` (after an exec, which the kernel makes delete the process's
/// POSIX timers; its ITIMER_REAL goes on, as the kernel's does): the timers its earlier image
/// made go. Called by the new program itself, or before an exec that leaves the followed world
/// (never from a vfork child, which shares the memory of its parent but not its timers: it
/// passes its own pid, which no timer holds).
pub(crate) fn delete_posix_timers_of(pid: i32) {
    let Some(shared) = crate::schedule::block::shared() else { return };
    for timer in shared.live_sig_timers() {
        if timer.pid.load(Ordering::Relaxed) == pid && timer.kind.load(Ordering::Relaxed) == timer_kind::POSIX {
            // An expiry fired for the earlier image is not sent to the new one.
            timer.fired.store(0, Ordering::Relaxed);
            timer.state.store(timer_state::FREE, Ordering::Release);
        }
    }
}
