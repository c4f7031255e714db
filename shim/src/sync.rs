//! Threads, and threads waiting on one another (condition variables, semaphores, joins).
//!
//! A new thread gets a slot reserved by its creator before it exists, so that no simulated time
//! passes while it starts. A thread that waits for another counts as blocked: its real wait is
//! cut into 200 µs slices of wall time, between which it looks whether climbsim let it go (its
//! timeout came, in simulated time). The thread that wakes it marks it running *before* the
//! wake-up, so that time cannot move between the two. Programs' timeouts are in their clocks'
//! simulated time; the slices use the kernel's monotonic clock.

use core::ffi::{c_int, c_void};
use core::sync::atomic::Ordering;

use crate::abi::{NEVER, Shared, call, release, state, waits};
use crate::sys::{self, clockid_t, real, timespec};
use crate::time::{sim_now, sim_time_of, to_ns};
use crate::{active, my_slot, note_call, notify_scheduler, pid, reset_computation};

/// One slice of a real wait (wall time).
const SLICE_NS: u64 = 200_000;
const ETIMEDOUT: c_int = 110;

fn real_deadline_after(ns: u64) -> timespec {
    crate::time::from_ns(crate::time::real_monotonic_ns().saturating_add(ns))
}

/// Wait for `addr` (a condition variable, a semaphore, a thread) until simulated `deadline`
/// ([`NEVER`]: none), one `slice` at a time (`slice(d)` waits for real until the monotonic
/// `d`, returning 0 when woken, ETIMEDOUT at `d`, or another error). Returns what the wait
/// returns: 0 when woken, ETIMEDOUT at the deadline.
fn peer_wait(shared: &Shared, addr: usize, deadline: u64, slice: &mut dyn FnMut(&timespec) -> c_int) -> c_int {
    peer_wait_for(shared, addr, deadline, false, slice)
}

/// [`peer_wait`]; with `spurious`, a slice that ends without a wake-up returns 0 (a spurious
/// wake-up, which condition variables allow): between slices the waiter holds the mutex, and a
/// waker that signals after unlocking could signal then, which must not be lost. The caller
/// checks its condition and waits again.
fn peer_wait_for(shared: &Shared, addr: usize, deadline: u64, spurious: bool, slice: &mut dyn FnMut(&timespec) -> c_int) -> c_int {
    note_call(shared, call::PEER);
    let Some(slot) = my_slot() else {
        return slice_until(shared, deadline, slice);
    };
    if deadline <= sim_now(shared) {
        // A zero timeout: one look, no block.
        let rc = slice(&real_deadline_after(0));
        return if rc == 0 { 0 } else { ETIMEDOUT };
    }
    let publish = || {
        slot.deadline_ns.store(deadline, Ordering::Relaxed);
        slot.waits.store(waits::PEER, Ordering::Relaxed);
        slot.conn_mask.store(addr as u64, Ordering::Relaxed);
        slot.release.store(0, Ordering::Relaxed);
        slot.state.store(state::BLOCKED, Ordering::Release);
        notify_scheduler(shared);
    };
    shared.header.peer_waiters.fetch_add(1, Ordering::AcqRel);
    publish();
    let result = loop {
        if slot.state.load(Ordering::Acquire) == state::RUNNING {
            match slot.release.load(Ordering::Acquire) {
                release::DEADLINE => break ETIMEDOUT,
                release::ENDING => break slice_until(shared, deadline, slice),
                // Marked running by a thread about to wake it: take the wake-up (or, if it
                // went to another waiter, wait on).
                _ => {
                    let rc = slice(&real_deadline_after(SLICE_NS));
                    if rc != ETIMEDOUT || spurious {
                        break if rc == ETIMEDOUT { 0 } else { rc };
                    }
                    publish();
                    continue;
                }
            }
        }
        let rc = slice(&real_deadline_after(SLICE_NS));
        if rc != ETIMEDOUT || spurious {
            slot.state.store(state::RUNNING, Ordering::Release);
            break if rc == ETIMEDOUT { 0 } else { rc };
        }
        if active().is_none() {
            slot.state.store(state::RUNNING, Ordering::Release);
            break slice_until(shared, deadline, slice);
        }
    };
    slot.waits.store(0, Ordering::Relaxed);
    shared.header.peer_waiters.fetch_sub(1, Ordering::AcqRel);
    reset_computation(shared);
    result
}

/// After the run's end (or for a thread without a slot): slices until woken or the deadline.
fn slice_until(shared: &Shared, deadline: u64, slice: &mut dyn FnMut(&timespec) -> c_int) -> c_int {
    loop {
        let rc = slice(&real_deadline_after(SLICE_NS));
        if rc != ETIMEDOUT {
            return rc;
        }
        if deadline != NEVER && sim_now(shared) >= deadline {
            return ETIMEDOUT;
        }
    }
}

/// A thread is about to wake waiters on `addr`: they run from now (before the wake-up lands).
fn wake_peers(addr: usize) {
    let Some(shared) = active() else { return };
    if shared.header.peer_waiters.load(Ordering::Acquire) == 0 {
        return;
    }
    let me = pid();
    for slot in &shared.slots {
        if slot.state.load(Ordering::Acquire) == state::BLOCKED
            && slot.waits.load(Ordering::Relaxed) == waits::PEER
            && slot.conn_mask.load(Ordering::Relaxed) == addr as u64
            && slot.pid.load(Ordering::Relaxed) == me
        {
            let _ = slot.state.compare_exchange(state::BLOCKED, state::RUNNING, Ordering::AcqRel, Ordering::Relaxed);
        }
    }
}

/// The simulated deadline of an absolute `abstime` on `clock`.
fn deadline_of(shared: &Shared, clock: clockid_t, abstime: *const timespec) -> u64 {
    if abstime.is_null() {
        return NEVER;
    }
    // SAFETY: the caller's timespec.
    sim_time_of(shared, clock, to_ns(unsafe { &*abstime })).unwrap_or(0)
}

/// pthread_cond_timedwait's clock is the condition variable's (REALTIME unless set): the
/// simulated clocks are 55 years apart, so the deadline itself says which.
fn cond_clock(abstime: *const timespec) -> clockid_t {
    // SAFETY: the caller's timespec (null checked).
    if !abstime.is_null() && unsafe { (*abstime).tv_sec } > 1_000_000_000 { sys::CLOCK_REALTIME } else { sys::CLOCK_MONOTONIC }
}

type CondClockwait = unsafe extern "C" fn(*mut c_void, *mut c_void, clockid_t, *const timespec) -> c_int;

fn cond_slices(cond: *mut c_void, mutex: *mut c_void) -> impl FnMut(&timespec) -> c_int {
    let clockwait: CondClockwait = real!(pthread_cond_clockwait: fn(*mut c_void, *mut c_void, clockid_t, *const timespec) -> c_int);
    // SAFETY: the caller's condition variable and mutex, which it holds.
    move |until: &timespec| unsafe { clockwait(cond, mutex, sys::CLOCK_MONOTONIC, until) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_cond_wait(cond: *mut c_void, mutex: *mut c_void) -> c_int {
    let Some(shared) = active() else {
        let next = real!(pthread_cond_wait: fn(*mut c_void, *mut c_void) -> c_int);
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(cond, mutex) };
    };
    peer_wait_for(shared, cond as usize, NEVER, true, &mut cond_slices(cond, mutex))
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_cond_timedwait(cond: *mut c_void, mutex: *mut c_void, abstime: *const timespec) -> c_int {
    let Some(shared) = active() else {
        let next = real!(pthread_cond_timedwait: fn(*mut c_void, *mut c_void, *const timespec) -> c_int);
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(cond, mutex, abstime) };
    };
    let deadline = deadline_of(shared, cond_clock(abstime), abstime);
    peer_wait_for(shared, cond as usize, deadline, true, &mut cond_slices(cond, mutex))
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_cond_clockwait(cond: *mut c_void, mutex: *mut c_void, clock: clockid_t, abstime: *const timespec) -> c_int {
    let Some(shared) = active() else {
        let next: CondClockwait = real!(pthread_cond_clockwait: fn(*mut c_void, *mut c_void, clockid_t, *const timespec) -> c_int);
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(cond, mutex, clock, abstime) };
    };
    let deadline = deadline_of(shared, clock, abstime);
    peer_wait_for(shared, cond as usize, deadline, true, &mut cond_slices(cond, mutex))
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_cond_signal(cond: *mut c_void) -> c_int {
    wake_peers(cond as usize);
    let next = real!(pthread_cond_signal: fn(*mut c_void) -> c_int);
    // SAFETY: passing the caller's argument through.
    unsafe { next(cond) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_cond_broadcast(cond: *mut c_void) -> c_int {
    wake_peers(cond as usize);
    let next = real!(pthread_cond_broadcast: fn(*mut c_void) -> c_int);
    // SAFETY: passing the caller's argument through.
    unsafe { next(cond) }
}

/// A semaphore wait: taken at once if it can be, else a peer wait (errno-style results).
fn sem_wait_until(sem: *mut c_void, deadline_of_call: impl FnOnce(&'static Shared) -> u64) -> c_int {
    let trywait = real!(sem_trywait: fn(*mut c_void) -> c_int);
    let clockwait = real!(sem_clockwait: fn(*mut c_void, clockid_t, *const timespec) -> c_int);
    let Some(shared) = active() else { return -2 };
    // SAFETY: the caller's semaphore.
    if unsafe { trywait(sem) } == 0 {
        return 0;
    }
    let deadline = deadline_of_call(shared);
    let mut slice = |until: &timespec| {
        // SAFETY: the caller's semaphore.
        if unsafe { clockwait(sem, sys::CLOCK_MONOTONIC, until) } == 0 { 0 } else { sys::errno() }
    };
    match peer_wait(shared, sem as usize, deadline, &mut slice) {
        0 => 0,
        error => {
            sys::set_errno(error);
            -1
        }
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn sem_wait(sem: *mut c_void) -> c_int {
    match sem_wait_until(sem, |_| NEVER) {
        -2 => {
            let next = real!(sem_wait: fn(*mut c_void) -> c_int);
            // SAFETY: passing the caller's argument through.
            unsafe { next(sem) }
        }
        rc => rc,
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn sem_timedwait(sem: *mut c_void, abstime: *const timespec) -> c_int {
    match sem_wait_until(sem, |shared| deadline_of(shared, sys::CLOCK_REALTIME, abstime)) {
        -2 => {
            let next = real!(sem_timedwait: fn(*mut c_void, *const timespec) -> c_int);
            // SAFETY: passing the caller's arguments through.
            unsafe { next(sem, abstime) }
        }
        rc => rc,
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn sem_clockwait(sem: *mut c_void, clock: clockid_t, abstime: *const timespec) -> c_int {
    match sem_wait_until(sem, |shared| deadline_of(shared, clock, abstime)) {
        -2 => {
            let next = real!(sem_clockwait: fn(*mut c_void, clockid_t, *const timespec) -> c_int);
            // SAFETY: passing the caller's arguments through.
            unsafe { next(sem, clock, abstime) }
        }
        rc => rc,
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn sem_post(sem: *mut c_void) -> c_int {
    wake_peers(sem as usize);
    let next = real!(sem_post: fn(*mut c_void) -> c_int);
    // SAFETY: passing the caller's argument through.
    unsafe { next(sem) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_join(thread: usize, result: *mut *mut c_void) -> c_int {
    let Some(shared) = active() else {
        let next = real!(pthread_join: fn(usize, *mut *mut c_void) -> c_int);
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(thread, result) };
    };
    let clockjoin = real!(pthread_clockjoin_np: fn(usize, *mut *mut c_void, clockid_t, *const timespec) -> c_int);
    // SAFETY: the caller's thread and result pointer.
    let mut slice = |until: &timespec| unsafe { clockjoin(thread, result, sys::CLOCK_MONOTONIC, until) };
    peer_wait(shared, thread, NEVER, &mut slice)
}

/// What a new thread needs to claim the slot its creator reserved.
struct Start {
    slot: usize,
    routine: unsafe extern "C" fn(*mut c_void) -> *mut c_void,
    arg: *mut c_void,
}

unsafe extern "C" fn trampoline(start: *mut c_void) -> *mut c_void {
    // SAFETY: the Box pthread_create leaked for this thread.
    let start = unsafe { Box::from_raw(start.cast::<Start>()) };
    crate::claim_reserved(start.slot);
    // SAFETY: the program's own start routine and argument.
    unsafe { (start.routine)(start.arg) }
}

unsafe extern "C" {
    fn pthread_self() -> usize;
}

/// The thread is ending: whoever joins it runs from now.
pub(crate) fn thread_ending() {
    // SAFETY: pthread_self has no preconditions.
    wake_peers(unsafe { pthread_self() });
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_create(thread: *mut usize, attr: *const c_void, routine: unsafe extern "C" fn(*mut c_void) -> *mut c_void, arg: *mut c_void) -> c_int {
    let next = real!(pthread_create: fn(*mut usize, *const c_void, unsafe extern "C" fn(*mut c_void) -> *mut c_void, *mut c_void) -> c_int);
    let Some(slot) = active().and_then(|_| crate::reserve_thread_slot()) else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(thread, attr, routine, arg) };
    };
    let start = Box::into_raw(Box::new(Start { slot, routine, arg }));
    // SAFETY: our trampoline, with the start it frees.
    let rc = unsafe { next(thread, attr, trampoline, start.cast()) };
    if rc != 0 {
        // SAFETY: not handed to any thread.
        drop(unsafe { Box::from_raw(start) });
        crate::unreserve_slot(slot);
    }
    rc
}
