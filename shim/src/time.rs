//! Clocks and sleeps on simulated time.
//!
//! Every clock id that tells the time of day or time since boot reads the block's `now_ns` plus
//! an offset (REALTIME and TAI from the run's epoch, the monotonic family from a fixed base);
//! the CPU-time clocks and dynamic (negative) ids stay the kernel's.

use core::ffi::{c_int, c_uint, c_void};
use core::sync::atomic::Ordering;

use crate::abi::{Parked, Shared, Wait, call, release};
use crate::schedule::block::{active, shared};
pub(crate) use crate::schedule::now::{clock_at, from_ns, real_monotonic_ns, sim_now, sim_time_of, to_ns};
use crate::schedule::park::{charge, note_call, park};
use crate::sys::{self, clockid_t, real, time_t, timespec, timeval};

/// A clock read: charged, then answered from the block (when the shim answers this clock).
pub(crate) fn read_clock(clock: clockid_t) -> Option<u64> {
    if let Some(shared) = active() {
        note_call(shared, call::CLOCK);
        charge(shared, shared.header.clock.clock_read_ns.load(Ordering::Relaxed));
    }
    let shared = shared()?;
    clock_at(shared, clock, sim_now(shared))
}

/// `clock_gettime` answered into the caller's `ts` if the shim answers `clock`: the one answer
/// of the interposer, the trapped system call and the patched vDSO alike.
pub(crate) fn answer_clock_gettime(clock: clockid_t, ts: *mut timespec) -> Option<c_int> {
    if ts.is_null() {
        return None;
    }
    let ns = read_clock(clock)?;
    // SAFETY: the caller's timespec.
    unsafe { *ts = from_ns(ns) };
    Some(0)
}

/// `gettimeofday` answered into the caller's `tv` (the kernel's time zone into `tz`, obsolete:
/// zeros unless settimeofday set it), as [`answer_clock_gettime`]: 0, or the kernel's -errno
/// for the time zone.
pub(crate) fn answer_gettimeofday(tv: *mut timeval, tz: *mut c_void) -> Option<c_int> {
    if tv.is_null() {
        return None;
    }
    let ns = read_clock(sys::CLOCK_REALTIME)?;
    // SAFETY: the caller's timeval.
    unsafe { *tv = timeval { tv_sec: (ns / 1_000_000_000) as time_t, tv_usec: ((ns % 1_000_000_000) / 1000) as i64 } };
    Some(if tz.is_null() { 0 } else { crate::native::call2(sys::nr::GETTIMEOFDAY, 0, tz as core::ffi::c_long) as c_int })
}

/// `time` answered (and written to `out`, if given), as [`answer_clock_gettime`].
pub(crate) fn answer_time(out: *mut time_t) -> Option<time_t> {
    let seconds = (read_clock(sys::CLOCK_REALTIME)? / 1_000_000_000) as time_t;
    if !out.is_null() {
        // SAFETY: the caller's time_t.
        unsafe { *out = seconds };
    }
    Some(seconds)
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn clock_gettime(clock: clockid_t, ts: *mut timespec) -> c_int {
    if let Some(answer) = answer_clock_gettime(clock, ts) {
        return answer;
    }
    let next = real!(clock_gettime: fn(clockid_t, *mut timespec) -> c_int);
    // SAFETY: passing the caller's arguments through.
    unsafe { next(clock, ts) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn gettimeofday(tv: *mut timeval, tz: *mut c_void) -> c_int {
    match answer_gettimeofday(tv, tz) {
        Some(0) => return 0,
        Some(error) => {
            sys::set_errno(-error);
            return -1;
        }
        None => {}
    }
    let next = real!(gettimeofday: fn(*mut timeval, *mut c_void) -> c_int);
    // SAFETY: passing the caller's arguments through.
    unsafe { next(tv, tz) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn time(out: *mut time_t) -> time_t {
    if let Some(seconds) = answer_time(out) {
        return seconds;
    }
    let next = real!(time: fn(*mut time_t) -> time_t);
    // SAFETY: passing the caller's argument through.
    unsafe { next(out) }
}

/// `times` (trapped: glibc's is the system call): the kernel's CPU times into `buffer`, and
/// the clock ticks since boot on simulated time (CLOCK_BOOTTIME at the kernel's USER_HZ).
pub(crate) fn answer_times(buffer: *mut c_void) -> Option<core::ffi::c_long> {
    const TICK_NS: u64 = 1_000_000_000 / 100;
    let ns = read_clock(sys::CLOCK_BOOTTIME)?;
    let kernel = crate::native::call1(sys::nr::TIMES, buffer as core::ffi::c_long);
    // A buffer the kernel could not write: its EFAULT.
    Some(if kernel < 0 && kernel > -4096 { kernel } else { (ns / TICK_NS) as core::ffi::c_long })
}

/// Sleep until simulated time `deadline`: blocked until climbsim's clock gets there. After the
/// run's end, the rest is slept on the wall clock. What was left if a signal interrupted it.
pub(crate) fn sleep_until(shared: &Shared, deadline: u64) -> Option<u64> {
    note_call(shared, call::SLEEP);
    if deadline <= sim_now(shared) {
        charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
        return None;
    }
    match park(shared, Parked::Blocked, deadline, Wait::Time) {
        release::ENDING => {
            real_sleep_ns(deadline.saturating_sub(sim_now(shared)));
        }
        release::SIGNAL => return Some(deadline.saturating_sub(sim_now(shared))),
        _ => {}
    }
    None
}

/// [`sleep_until`] for a libc sleep the shim stands in for, a cancellation point (see
/// `handlers::cancellation_point`): a cancellation asked before acts at once; one asked while it
/// sleeps (`signals::pthread_cancel` sends SIGCANCEL, which ends the sleep) acts as it ends,
/// or, with the thread's cancellation off, the sleep goes on, as natively (where glibc sends
/// nothing then). A raw system call's sleep, in the trap handler, is no cancellation point
/// (`cancellation_point` does nothing there): it sleeps on, as natively, where glibc sends no
/// SIGCANCEL to a thread outside its own wrappers.
fn sleep_until_cancellable(shared: &Shared, deadline: u64) -> Option<u64> {
    crate::handlers::cancellation_point();
    loop {
        let left = sleep_until(shared, deadline)?;
        if crate::schedule::delivery::interrupted_by() != Some(sys::SIGCANCEL) {
            return Some(left);
        }
        crate::handlers::cancellation_point();
    }
}

/// Sleep `ns` of wall time: the error number (0, or EINTR for a signal).
pub(crate) fn real_sleep_ns(ns: u64) -> c_int {
    // glibc's clock_nanosleep is the system call, which would trap: this sleep is the shim's
    // own, on the wall clock.
    let _own = crate::sys::OwnCalls::enter();
    let clock_nanosleep = real!(clock_nanosleep: fn(clockid_t, c_int, *const timespec, *mut timespec) -> c_int);
    // SAFETY: a valid relative timespec; the remainder is not wanted.
    unsafe { clock_nanosleep(sys::CLOCK_MONOTONIC, 0, &from_ns(ns), core::ptr::null_mut()) }
}

/// clock_nanosleep on simulated time, for the interposer and the trap alike: the error number
/// (0 for done), or None where the kernel's clock answers (a CPU-time clock, or no run).
/// Interrupted by a signal: EINTR, and what was left of a relative sleep in `remain`.
///
/// After the run's end (or with climbsim gone) the clocks the shim answers still read simulated
/// time, going on at the wall's rate, so an absolute deadline a program took from one is
/// simulated too: given to the kernel as it is, it lies in the past (the monotonic family) or
/// years off (the time of day), and a clean-up's `time.sleep` (CPython sleeps to a deadline)
/// returned at once. What is left of it is slept on the wall clock instead; a relative sleep
/// then goes to the kernel as it is.
pub(crate) fn clock_nanosleep_virtual(clock: clockid_t, flags: c_int, request: *const timespec, remain: *mut timespec) -> Option<c_int> {
    let shared = shared()?;
    let running = active().is_some();
    let absolute = flags & sys::TIMER_ABSTIME != 0;
    // Clocks the shim answers that Linux cannot sleep on: their reads only.
    if matches!(clock, sys::CLOCK_MONOTONIC_RAW | sys::CLOCK_REALTIME_COARSE | sys::CLOCK_MONOTONIC_COARSE) {
        return Some(sys::EOPNOTSUPP);
    }
    if clock_at(shared, clock, 0).is_none() || (!running && !absolute) {
        return None;
    }
    // Linux's order after the clock: the request's memory (EFAULT), then its value (EINVAL).
    let asked = match sys::program_timespec(request) {
        Ok(Some(asked)) => asked,
        Ok(None) => return Some(sys::EFAULT),
        Err(error) => return Some(error),
    };
    let deadline = if absolute { sim_time_of(shared, clock, asked).unwrap_or(0) } else { sim_now(shared).saturating_add(asked) };
    if !running {
        // The caller's sleep was absolute: it has no remainder to report.
        return Some(real_sleep_ns(deadline.saturating_sub(sim_now(shared))));
    }
    let Some(left) = sleep_until_cancellable(shared, deadline) else { return Some(0) };
    if !absolute && !remain.is_null() {
        // SAFETY: the caller's timespec.
        unsafe { *remain = from_ns(left) };
    }
    Some(sys::EINTR)
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn clock_nanosleep(clock: clockid_t, flags: c_int, request: *const timespec, remain: *mut timespec) -> c_int {
    if let Some(error) = clock_nanosleep_virtual(clock, flags, request, remain) {
        return error;
    }
    let next = real!(clock_nanosleep: fn(clockid_t, c_int, *const timespec, *mut timespec) -> c_int);
    // SAFETY: passing the caller's arguments through.
    unsafe { next(clock, flags, request, remain) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn nanosleep(request: *const timespec, remain: *mut timespec) -> c_int {
    match clock_nanosleep_virtual(sys::CLOCK_MONOTONIC, 0, request, remain) {
        Some(0) => return 0,
        Some(error) => {
            sys::set_errno(error);
            return -1;
        }
        None => {}
    }
    let next = real!(nanosleep: fn(*const timespec, *mut timespec) -> c_int);
    // SAFETY: passing the caller's arguments through.
    unsafe { next(request, remain) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn usleep(micros: c_uint) -> c_int {
    if let Some(shared) = active() {
        if sleep_until_cancellable(shared, sim_now(shared).saturating_add(u64::from(micros) * 1000)).is_some() {
            sys::set_errno(sys::EINTR);
            return -1;
        }
        return 0;
    }
    let next = real!(usleep: fn(c_uint) -> c_int);
    // SAFETY: passing the caller's argument through.
    unsafe { next(micros) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn sleep(seconds: c_uint) -> c_uint {
    if let Some(shared) = active() {
        // Interrupted: the whole seconds left, as glibc's sleep answers (the kernel's
        // remainder's seconds, the nanoseconds dropped: 9 for 9.98 s), errno left EINTR.
        let Some(left) = sleep_until_cancellable(shared, sim_now(shared).saturating_add(u64::from(seconds) * 1_000_000_000)) else { return 0 };
        sys::set_errno(sys::EINTR);
        return (left / 1_000_000_000) as c_uint;
    }
    let next = real!(sleep: fn(c_uint) -> c_uint);
    // SAFETY: passing the caller's argument through.
    unsafe { next(seconds) }
}
