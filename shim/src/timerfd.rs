//! timerfd on simulated time. The program gets a real timerfd (so that it can poll it, put it
//! in epoll and close it), but its expiry is kept here, in simulated time, and the real timer is
//! never armed until that time has come: then it is set to fire at once, so that the kernel
//! shows the descriptor readable, and a read returns the simulated expirations.

use core::ffi::{c_int, c_void};
use core::sync::atomic::{AtomicBool, AtomicI32, AtomicPtr, AtomicU64, Ordering};

use crate::abi::{NEVER, Parked, Shared, Wait, release};
use crate::schedule::block::active;
use crate::schedule::park::{charge, note_call, park};
use crate::sys::{real, timespec};
use crate::time::{clock_at, from_ns, sim_now, sim_time_of, to_ns};

/// A followed timer, by its descriptor's number: no table of a fixed size, so a process may
/// have as many as it may have descriptors. Zeroed memory is a free entry.
pub(crate) struct Timer {
    /// The descriptor is a followed timerfd.
    followed: AtomicBool,
    clock: AtomicI32,
    /// Simulated time of the next expiry ([`NEVER`]: disarmed).
    expiry: AtomicU64,
    interval: AtomicU64,
    /// The real timer has been set to fire for an expiry that has come.
    shown: AtomicBool,
}

/// Descriptors a chunk of the table covers (32 KiB of this process's memory, mapped when a
/// timerfd first gets a number in its range).
const CHUNK: usize = 1024;
/// The chunks: descriptors below [`crate::abi::TIMERFD_DESCRIPTORS`].
const CHUNKS: usize = crate::abi::TIMERFD_DESCRIPTORS / CHUNK;
static TABLE: [AtomicPtr<Timer>; CHUNKS] = [const { AtomicPtr::new(core::ptr::null_mut()) }; CHUNKS];

/// The entry of descriptor `fd` (its chunk mapped if `map` and not yet there).
fn entry(fd: c_int, map: bool) -> Option<&'static Timer> {
    let fd = usize::try_from(fd).ok()?;
    let chunk = TABLE.get(fd / CHUNK)?;
    let mut entries = chunk.load(Ordering::Acquire);
    if entries.is_null() {
        if !map {
            return None;
        }
        entries = map_chunk(chunk)?;
    }
    // SAFETY: a mapped chunk of CHUNK entries, never unmapped; the index is below CHUNK.
    Some(unsafe { &*entries.add(fd % CHUNK) })
}

/// Map a zeroed chunk of entries into `chunk` (or take the one another thread mapped first).
fn map_chunk(chunk: &AtomicPtr<Timer>) -> Option<*mut Timer> {
    let bytes = CHUNK * core::mem::size_of::<Timer>();
    let mapped = crate::sys::fresh_pages(bytes)?;
    match chunk.compare_exchange(core::ptr::null_mut(), mapped.cast(), Ordering::AcqRel, Ordering::Acquire) {
        Ok(_) => Some(mapped.cast()),
        Err(theirs) => {
            crate::sys::release_pages(mapped, bytes);
            Some(theirs)
        }
    }
}

#[repr(C)]
pub(crate) struct Itimerspec {
    interval: timespec,
    value: timespec,
}

const TFD_TIMER_ABSTIME: c_int = 1;
const EAGAIN: c_int = 11;
const F_GETFL: c_int = 3;
const O_NONBLOCK: c_int = 0o4000;

unsafe extern "C" {
    fn fcntl(fd: c_int, command: c_int, ...) -> c_int;
}

/// The followed timer on `fd`.
pub(crate) fn timer_of(fd: c_int) -> Option<&'static Timer> {
    entry(fd, false).filter(|timer| timer.followed.load(Ordering::Acquire))
}

/// The descriptor is closed: its timer is no longer followed.
pub(crate) fn forget(fd: c_int) {
    if let Some(timer) = timer_of(fd) {
        timer.followed.store(false, Ordering::Release);
    }
}

/// When the timer on `fd` expires next (simulated ns; [`NEVER`]: disarmed, or none).
pub(crate) fn expiry(fd: c_int) -> u64 {
    timer_of(fd).map_or(NEVER, |timer| timer.expiry.load(Ordering::Acquire))
}

/// The timer on `fd` has expired by now: make its descriptor readable for real (the kernel's
/// timer fires at once), so that a poll of it sees what simulated time says. Whether it had to.
pub(crate) fn show_if_expired(shared: &Shared, fd: c_int) -> bool {
    let Some(timer) = timer_of(fd) else { return false };
    if timer.expiry.load(Ordering::Acquire) > sim_now(shared) || timer.shown.swap(true, Ordering::AcqRel) {
        return false;
    }
    let settime = real!(timerfd_settime: fn(c_int, c_int, *const Itimerspec, *mut Itimerspec) -> c_int);
    let now = Itimerspec { interval: timespec { tv_sec: 0, tv_nsec: 0 }, value: timespec { tv_sec: 0, tv_nsec: 1 } };
    // SAFETY: the program's own timerfd, a valid itimerspec, no old value wanted.
    unsafe { settime(fd, 0, &now, core::ptr::null_mut()) };
    true
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn timerfd_create(clock: c_int, flags: c_int) -> c_int {
    let next = real!(timerfd_create: fn(c_int, c_int) -> c_int);
    // SAFETY: passing the caller's arguments through.
    let fd = unsafe { next(clock, flags) };
    if fd >= 0
        && let Some(shared) = active()
        && clock_at(shared, clock, 0).is_some()
    {
        // A number the kernel just gave out: no other thread holds it.
        match entry(fd, true) {
            Some(timer) => {
                timer.clock.store(clock, Ordering::Relaxed);
                timer.expiry.store(NEVER, Ordering::Relaxed);
                timer.interval.store(0, Ordering::Relaxed);
                timer.shown.store(false, Ordering::Relaxed);
                timer.followed.store(true, Ordering::Release);
            }
            None => crate::schedule::block::refuse(crate::abi::refused::TIMERFDS),
        }
    }
    fd
}

fn remaining(shared: &Shared, timer: &Timer) -> Itimerspec {
    let (expiry, interval) = (timer.expiry.load(Ordering::Acquire), timer.interval.load(Ordering::Relaxed));
    let left = if expiry == NEVER { 0 } else { expiry.saturating_sub(sim_now(shared)).max(1) };
    Itimerspec { interval: from_ns(interval), value: from_ns(left) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn timerfd_settime(fd: c_int, flags: c_int, new: *const Itimerspec, old: *mut Itimerspec) -> c_int {
    let next = real!(timerfd_settime: fn(c_int, c_int, *const Itimerspec, *mut Itimerspec) -> c_int);
    let (Some(shared), Some(timer)) = (active(), timer_of(fd)) else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(fd, flags, new, old) };
    };
    if new.is_null() {
        // SAFETY: the kernel reports the bad address.
        return unsafe { next(fd, flags, new, old) };
    }
    note_call(shared, crate::abi::call::SLEEP);
    if !old.is_null() {
        // SAFETY: the caller's itimerspec.
        unsafe { old.write(remaining(shared, timer)) };
    }
    // The real timer stays disarmed (and any shown expiry is taken back) until simulated time
    // says otherwise.
    let disarmed = Itimerspec { interval: timespec { tv_sec: 0, tv_nsec: 0 }, value: timespec { tv_sec: 0, tv_nsec: 0 } };
    // SAFETY: the program's own timerfd.
    unsafe { next(fd, 0, &disarmed, core::ptr::null_mut()) };
    // SAFETY: the caller's itimerspec (not null).
    let new = unsafe { &*new };
    let value = to_ns(&new.value);
    let clock = timer.clock.load(Ordering::Relaxed);
    let expiry = if value == 0 {
        NEVER
    } else if flags & TFD_TIMER_ABSTIME != 0 {
        sim_time_of(shared, clock, value).unwrap_or(0)
    } else {
        sim_now(shared).saturating_add(value)
    };
    timer.interval.store(to_ns(&new.interval), Ordering::Relaxed);
    timer.shown.store(false, Ordering::Relaxed);
    timer.expiry.store(expiry, Ordering::Release);
    charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
    0
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn timerfd_gettime(fd: c_int, current: *mut Itimerspec) -> c_int {
    let (Some(shared), Some(timer)) = (active(), timer_of(fd)) else {
        let next = real!(timerfd_gettime: fn(c_int, *mut Itimerspec) -> c_int);
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(fd, current) };
    };
    if !current.is_null() {
        // SAFETY: the caller's itimerspec.
        unsafe { current.write(remaining(shared, timer)) };
    }
    0
}

/// A read of a followed timer: `None` if `fd` is not one. Waits (on simulated time) for the
/// expiry if the descriptor blocks; returns the expirations since the last read, as 8 bytes.
pub(crate) fn read(fd: c_int, buf: *mut c_void, len: usize) -> Option<isize> {
    let shared = active()?;
    let timer = timer_of(fd)?;
    note_call(shared, crate::abi::call::READ);
    if len < 8 {
        crate::sys::set_errno(22);
        return Some(-1);
    }
    loop {
        let (expiry, now) = (timer.expiry.load(Ordering::Acquire), sim_now(shared));
        if expiry <= now {
            let interval = timer.interval.load(Ordering::Relaxed);
            let count = 1 + (now - expiry).checked_div(interval).unwrap_or(0);
            timer.expiry.store(if interval == 0 { NEVER } else { expiry + count * interval }, Ordering::Release);
            // Take back what the kernel's timer showed (its count is not the simulated one).
            if timer.shown.swap(false, Ordering::AcqRel) {
                let mut drained = 0u64;
                let real_read = real!(read: fn(c_int, *mut c_void, usize) -> isize);
                // SAFETY: an 8-byte read of the program's own timerfd into our buffer.
                unsafe { real_read(fd, (&mut drained as *mut u64).cast(), 8) };
            }
            // SAFETY: the caller's buffer, at least 8 bytes.
            unsafe { buf.cast::<u64>().write_unaligned(count) };
            return Some(8);
        }
        // SAFETY: fcntl F_GETFL on the program's descriptor.
        if unsafe { fcntl(fd, F_GETFL) } & O_NONBLOCK != 0 {
            crate::sys::set_errno(EAGAIN);
            charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
            return Some(-1);
        }
        if park(shared, Parked::Blocked, expiry, Wait::Time) == release::ENDING {
            let real_read = real!(read: fn(c_int, *mut c_void, usize) -> isize);
            // SAFETY: passing the caller's arguments through.
            return Some(unsafe { real_read(fd, buf, len) });
        }
    }
}
