//! epoll, which Python's asyncio (its default selector) and most event loops wait in. The
//! descriptors an epoll instance watches live in the kernel, so the shim keeps its own copy of
//! each process's registrations (from epoll_ctl) to tell what a wait is for; the wait itself is
//! the poll family's (wait.rs).

use core::ffi::{c_int, c_void};
use core::sync::atomic::{AtomicI32, AtomicU32, Ordering};

use crate::abi::call;
use crate::sys::{real, timespec};
use crate::time::{from_ns, to_ns};
use crate::wait::{Interest, ms_timeout, wait, wall_ms};
use crate::{active, shared};

/// Registrations followed at once (all epoll instances of a process together).
const ENTRIES: usize = 512;

struct Entry {
    /// The epoll instance; -1: free.
    epfd: AtomicI32,
    fd: AtomicI32,
    events: AtomicU32,
}

#[allow(clippy::declare_interior_mutable_const)]
const FREE: Entry = Entry { epfd: AtomicI32::new(-1), fd: AtomicI32::new(-1), events: AtomicU32::new(0) };
static ENTRIES_TABLE: [Entry; ENTRIES] = [FREE; ENTRIES];

const EPOLL_CTL_ADD: c_int = 1;
const EPOLL_CTL_DEL: c_int = 2;
const EPOLL_CTL_MOD: c_int = 3;
const EPOLLIN: u32 = 0x1;
const EPOLLPRI: u32 = 0x2;
const EPOLLOUT: u32 = 0x4;

fn find(epfd: c_int, fd: c_int) -> Option<&'static Entry> {
    ENTRIES_TABLE.iter().find(|e| e.epfd.load(Ordering::Relaxed) == epfd && e.fd.load(Ordering::Relaxed) == fd)
}

fn record(epfd: c_int, op: c_int, fd: c_int, event: *const c_void) {
    // struct epoll_event is packed on x86-64: its first 4 bytes are the events.
    // SAFETY: the caller's event, when the operation takes one.
    let events = if event.is_null() { 0 } else { unsafe { event.cast::<u32>().read_unaligned() } };
    match op {
        EPOLL_CTL_ADD | EPOLL_CTL_MOD => {
            if let Some(entry) = find(epfd, fd) {
                entry.events.store(events, Ordering::Relaxed);
                return;
            }
            if let Some(entry) = ENTRIES_TABLE.iter().find(|e| e.epfd.compare_exchange(-1, epfd, Ordering::AcqRel, Ordering::Relaxed).is_ok()) {
                entry.fd.store(fd, Ordering::Relaxed);
                entry.events.store(events, Ordering::Relaxed);
            }
        }
        EPOLL_CTL_DEL => {
            if let Some(entry) = find(epfd, fd) {
                entry.fd.store(-1, Ordering::Relaxed);
                entry.epfd.store(-1, Ordering::Release);
            }
        }
        _ => {}
    }
}

/// A closed descriptor leaves every epoll instance (and an epoll instance closed forgets all).
pub(crate) fn forget(fd: c_int) {
    for entry in &ENTRIES_TABLE {
        if entry.fd.load(Ordering::Relaxed) == fd || entry.epfd.load(Ordering::Relaxed) == fd {
            entry.fd.store(-1, Ordering::Relaxed);
            entry.epfd.store(-1, Ordering::Release);
        }
    }
}

/// What a wait on `epfd` waits on. (After fork the child's table is its own copy of its
/// parent's, and stays right: it inherits the instances.)
fn interest(epfd: c_int) -> Interest {
    let mut interest = Interest::default();
    let Some(shared) = shared() else { return interest };
    let mut any = false;
    for entry in &ENTRIES_TABLE {
        if entry.epfd.load(Ordering::Acquire) != epfd {
            continue;
        }
        any = true;
        let events = entry.events.load(Ordering::Relaxed);
        interest.add(shared, entry.fd.load(Ordering::Relaxed), events & (EPOLLIN | EPOLLPRI) != 0, events & EPOLLOUT != 0);
    }
    if !any {
        // Registrations made before the shim followed this process (or too many): unknown.
        interest.add_other();
    }
    interest
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn epoll_ctl(epfd: c_int, op: c_int, fd: c_int, event: *mut c_void) -> c_int {
    let next = real!(epoll_ctl: fn(c_int, c_int, c_int, *mut c_void) -> c_int);
    // SAFETY: passing the caller's arguments through.
    let rc = unsafe { next(epfd, op, fd, event) };
    if rc == 0 && shared().is_some() {
        record(epfd, op, fd, event);
    }
    rc
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn epoll_wait(epfd: c_int, events: *mut c_void, max: c_int, timeout_ms: c_int) -> c_int {
    let next = real!(epoll_wait: fn(c_int, *mut c_void, c_int, c_int) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(epfd, events, max, timeout_ms) };
    };
    // SAFETY: the caller's arguments, with our timeout.
    wait(shared, call::POLL, interest(epfd), ms_timeout(timeout_ms), &mut |wall| unsafe { next(epfd, events, max, wall_ms(wall)) })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn epoll_pwait(epfd: c_int, events: *mut c_void, max: c_int, timeout_ms: c_int, sigmask: *const c_void) -> c_int {
    let next = real!(epoll_pwait: fn(c_int, *mut c_void, c_int, c_int, *const c_void) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(epfd, events, max, timeout_ms, sigmask) };
    };
    // SAFETY: the caller's arguments, with our timeout.
    wait(shared, call::POLL, interest(epfd), ms_timeout(timeout_ms), &mut |wall| unsafe { next(epfd, events, max, wall_ms(wall), sigmask) })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn epoll_pwait2(epfd: c_int, events: *mut c_void, max: c_int, timeout: *const timespec, sigmask: *const c_void) -> c_int {
    let next = real!(epoll_pwait2: fn(c_int, *mut c_void, c_int, *const timespec, *const c_void) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(epfd, events, max, timeout, sigmask) };
    };
    // SAFETY: the caller's timespec, if any.
    let asked = (!timeout.is_null()).then(|| to_ns(unsafe { &*timeout }));
    wait(shared, call::POLL, interest(epfd), asked, &mut |wall| {
        let limit = wall.map(from_ns);
        let limit_ptr = limit.as_ref().map_or(core::ptr::null(), |t| t as *const timespec);
        // SAFETY: the caller's arguments, with our timeout.
        unsafe { next(epfd, events, max, limit_ptr, sigmask) }
    })
}
