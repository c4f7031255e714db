//! epoll, which Python's asyncio (its default selector) and most event loops wait in. The
//! descriptors an epoll instance watches live in the kernel, so the shim keeps its own copy of
//! each process's registrations (from epoll_ctl) to tell what a wait is for; the wait itself is
//! the poll family's (wait.rs).

use core::ffi::{c_int, c_void};
use core::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, AtomicU64, Ordering};

use crate::abi::call;
use crate::schedule::block::{active, shared};
use crate::sys::{real, timespec};
use crate::time::from_ns;
use crate::wait::{EpollCall, Interest, ms_timeout, wait, wall_ms};

/// Registrations followed at once (all epoll instances of a process together).
const ENTRIES: usize = crate::abi::EPOLL_ENTRIES;

struct Entry {
    /// The epoll instance; -1: free.
    epfd: AtomicI32,
    fd: AtomicI32,
    events: AtomicU32,
    /// The registration's user data, which is all a reported event carries.
    data: AtomicU64,
    /// For an edge-triggered registration of the port: how far into the port's stream bytes
    /// were visible when it was last reported readable (see `port_edge`).
    edge_at: AtomicU64,
    /// For an edge-triggered registration of the port: a writable edge is due.
    writable_edge: AtomicBool,
}

#[allow(clippy::declare_interior_mutable_const)]
const FREE: Entry = Entry { epfd: AtomicI32::new(-1), fd: AtomicI32::new(-1), events: AtomicU32::new(0), data: AtomicU64::new(0), edge_at: AtomicU64::new(0), writable_edge: AtomicBool::new(false) };
static ENTRIES_TABLE: [Entry; ENTRIES] = [FREE; ENTRIES];
/// An epoll instance of this process was registered in another (see `add_nested_timers`): only
/// then do waits look for the timers of nested instances.
static NESTED: AtomicBool = AtomicBool::new(false);

const EPOLL_CTL_ADD: c_int = 1;
const EPOLL_CTL_DEL: c_int = 2;
const EPOLL_CTL_MOD: c_int = 3;
const EPOLLIN: u32 = 0x1;
const EPOLLPRI: u32 = 0x2;
const EPOLLOUT: u32 = 0x4;
const EPOLLRDNORM: u32 = 0x40;
const EPOLLWRNORM: u32 = 0x100;
const EPOLLET: u32 = 1 << 31;

/// struct epoll_event: packed on x86-64 (4 + 8 bytes), padded elsewhere (4 + 4 + 8).
#[cfg(target_arch = "x86_64")]
const EVENT: (usize, usize) = (12, 4);
#[cfg(not(target_arch = "x86_64"))]
const EVENT: (usize, usize) = (16, 8);

fn event_data(event: *const u8) -> u64 {
    // SAFETY: one struct epoll_event of the caller's.
    unsafe { event.add(EVENT.1).cast::<u64>().read_unaligned() }
}

fn find(epfd: c_int, fd: c_int) -> Option<&'static Entry> {
    ENTRIES_TABLE.iter().find(|e| e.epfd.load(Ordering::Relaxed) == epfd && e.fd.load(Ordering::Relaxed) == fd)
}

fn record(epfd: c_int, op: c_int, fd: c_int, event: *const c_void) {
    // struct epoll_event is packed on x86-64: its first 4 bytes are the events.
    // SAFETY: the caller's event, when the operation takes one.
    let events = if event.is_null() { 0 } else { unsafe { event.cast::<u32>().read_unaligned() } };
    let data = if event.is_null() { 0 } else { event_data(event.cast()) };
    match op {
        EPOLL_CTL_ADD | EPOLL_CTL_MOD => {
            // The descriptor added is an instance with registrations, or the instance added to
            // is watched by another.
            if ENTRIES_TABLE.iter().any(|e| e.epfd.load(Ordering::Relaxed) == fd || e.fd.load(Ordering::Relaxed) == epfd) {
                NESTED.store(true, Ordering::Relaxed);
            }
            if let Some(entry) = find(epfd, fd) {
                entry.events.store(events, Ordering::Relaxed);
                entry.data.store(data, Ordering::Relaxed);
                entry.edge_at.store(0, Ordering::Relaxed);
                entry.writable_edge.store(true, Ordering::Relaxed);
                return;
            }
            match ENTRIES_TABLE.iter().find(|e| e.epfd.compare_exchange(-1, epfd, Ordering::AcqRel, Ordering::Relaxed).is_ok()) {
                Some(entry) => {
                    entry.fd.store(fd, Ordering::Relaxed);
                    entry.events.store(events, Ordering::Relaxed);
                    entry.data.store(data, Ordering::Relaxed);
                    entry.edge_at.store(0, Ordering::Relaxed);
                    entry.writable_edge.store(true, Ordering::Relaxed);
                }
                None => crate::schedule::block::refuse(crate::abi::refused::EPOLL),
            }
        }
        EPOLL_CTL_DEL => {
            if let Some(entry) = find(epfd, fd) {
                entry.fd.store(-1, Ordering::Relaxed);
                entry.events.store(0, Ordering::Relaxed);
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
fn interest(call: EpollCall) -> Interest {
    let epfd = call.epfd;
    let mut interest = Interest::default();
    interest.epoll = Some(call);
    let Some(shared) = shared() else { return interest };
    let mut any = false;
    for entry in &ENTRIES_TABLE {
        if entry.epfd.load(Ordering::Acquire) != epfd {
            continue;
        }
        any = true;
        let events = entry.events.load(Ordering::Relaxed);
        let (fd, read) = (entry.fd.load(Ordering::Relaxed), events & (EPOLLIN | EPOLLPRI) != 0);
        interest.add(shared, fd, read, events & EPOLLOUT != 0);
        if read && NESTED.load(Ordering::Relaxed) {
            add_nested_timers(shared, &mut interest, fd, 1);
        }
    }
    if !any {
        // Registrations made before the shim followed this process (or too many): unknown.
        interest.add_other();
    }
    interest
}

/// If `fd` is an epoll instance itself (watched by another, `depth` deep), the timerfds it
/// watches, however deep, are waited on too: their expiries are simulated time, and a timer
/// shown expired makes the instances that watch it readable in the kernel. (The instance is
/// otherwise the kernel's to say: `Interest::add` counted it as such.) Linux nests at most 5.
fn add_nested_timers(shared: &'static crate::abi::Shared, interest: &mut Interest, fd: c_int, depth: u32) {
    const DEEPEST: u32 = 5;
    if depth > DEEPEST {
        return;
    }
    for entry in ENTRIES_TABLE.iter().filter(|e| e.epfd.load(Ordering::Acquire) == fd) {
        let (inner, events) = (entry.fd.load(Ordering::Relaxed), entry.events.load(Ordering::Relaxed));
        // (An entry being filled in or freed by another thread: not yet, or no longer, there.)
        if inner < 0 || events & (EPOLLIN | EPOLLPRI) == 0 {
            continue;
        }
        if crate::timerfd::timer_of(inner).is_some() {
            interest.add(shared, inner, true, false);
        } else {
            add_nested_timers(shared, interest, inner, depth + 1);
        }
    }
}

/// The wait's first `first` events were taken at a look; add what is ready now (with the port
/// masked as ever), an event for a registration already reported merged into it. The total.
fn collect_more(shared: &crate::abi::Shared, call: EpollCall, first: c_int, port_fd: Option<c_int>) -> c_int {
    let next = real!(epoll_wait: fn(c_int, *mut c_void, c_int, c_int) -> c_int);
    let room = call.max - first;
    if room <= 0 {
        return first;
    }
    let base = call.events.cast::<u8>();
    // SAFETY: within the caller's array of `max` events.
    let tail = unsafe { base.add(first as usize * EVENT.0) };
    let saved = crate::sys::errno();
    // SAFETY: the caller's epoll instance and the free part of its array; no wait.
    let more = mask_events(shared, call.epfd, tail.cast(), room, unsafe { next(call.epfd, tail.cast(), room, 0) }, port_fd);
    crate::sys::set_errno(saved);
    let mut total = first as usize;
    for index in 0..more.max(0) as usize {
        // SAFETY: the kernel filled `more` events after the first ones.
        let event = unsafe { tail.add(index * EVENT.0) };
        let data = event_data(event);
        // SAFETY: as above; the flags are the event's first 4 bytes.
        let flags = unsafe { event.cast::<u32>().read_unaligned() };
        // SAFETY: each within the first events of the caller's array.
        let same = (0..first as usize).map(|i| unsafe { base.add(i * EVENT.0) }).find(|&e| event_data(e) == data);
        match same {
            // SAFETY: one of the first events.
            Some(earlier) => unsafe { earlier.cast::<u32>().write_unaligned(earlier.cast::<u32>().read_unaligned() | flags) },
            None => {
                // SAFETY: both within the array; `total` <= `first + index`.
                unsafe { core::ptr::copy(event, base.add(total * EVENT.0), EVENT.0) };
                total += 1;
            }
        }
    }
    total as c_int
}

/// The events an epoll wait reported (`ready` of them, in an array of `room`), without the
/// port's readiness where nothing visible is there to read (held.rs): an event for the port's
/// registration loses EPOLLIN, and is dropped if nothing else is left in it. An edge-triggered
/// registration of the port gets its edges from the shim alone (`port_edge`).
fn mask_events(shared: &crate::abi::Shared, epfd: c_int, events: *mut c_void, room: c_int, ready: c_int, port_fd: Option<c_int>) -> c_int {
    let Some(entry) = port_fd.filter(|_| ready >= 0).and_then(|fd| find(epfd, fd)) else { return ready };
    let port_data = entry.data.load(Ordering::Relaxed);
    let edges = edge_triggered(entry);
    let base = events.cast::<u8>();
    let mut kept = 0;
    let mut port_event = None;
    for index in 0..ready as usize {
        // SAFETY: the kernel filled `ready` events of the caller's array.
        let event = unsafe { base.add(index * EVENT.0) };
        // SAFETY: as above.
        let mut flags = unsafe { event.cast::<u32>().read_unaligned() };
        if event_data(event) == port_data {
            let hidden = if edges { EPOLLIN | EPOLLRDNORM | EPOLLOUT | EPOLLWRNORM } else { EPOLLIN | EPOLLRDNORM };
            if edges || crate::schedule::held::hide(shared, flags & (EPOLLIN | EPOLLRDNORM) != 0) {
                flags &= !hidden;
                // SAFETY: as above.
                unsafe { event.cast::<u32>().write_unaligned(flags) };
                if flags == 0 {
                    continue;
                }
            }
            port_event = Some(kept);
        }
        if kept != index {
            // SAFETY: both within the reported events; `kept` < `index`.
            unsafe { core::ptr::copy(event, base.add(kept * EVENT.0), EVENT.0) };
        }
        kept += 1;
    }
    let added = if edges { port_edge(shared, entry) } else { 0 };
    if added != 0 {
        let at = match port_event {
            Some(at) => Some(at),
            None if kept < room as usize => {
                kept += 1;
                Some(kept - 1)
            }
            None => None,
        };
        if let Some(at) = at {
            // SAFETY: within the caller's array (`at` < `room`); packed on x86-64.
            unsafe {
                let event = base.add(at * EVENT.0);
                let flags = if Some(at) == port_event { event.cast::<u32>().read_unaligned() } else { 0 };
                event.cast::<u32>().write_unaligned(flags | added);
                event.add(EVENT.1).cast::<u64>().write_unaligned(port_data);
            }
        }
    }
    kept as c_int
}

/// An edge-triggered registration of the port (Go's netpoller registers every descriptor so).
/// The kernel's edges for it come whenever the host moves bytes: it reports the port readable
/// once, when climbsim writes a reply ahead of its time (and not again when the bytes become
/// visible), and writable whenever climbsim has drained what the controller wrote, at no
/// simulated instant. So the shim gives the registration its edges itself, and takes them:
/// readable whenever more bytes have become visible since it last said so and some are unread;
/// writable once after it is registered, and again after a write to the port found it full.
/// The events due now (0: none).
fn port_edge(shared: &crate::abi::Shared, entry: &Entry) -> u32 {
    let (events, visible) = edges_due(shared, entry);
    if events & EPOLLIN != 0 {
        entry.edge_at.store(visible, Ordering::Relaxed);
    }
    if events & EPOLLOUT != 0 {
        entry.writable_edge.store(false, Ordering::Relaxed);
    }
    events
}

/// The edges due now to an edge-triggered registration of the port (see `port_edge`), not
/// taken, and how far into the port's stream bytes are visible.
fn edges_due(shared: &crate::abi::Shared, entry: &Entry) -> (u32, u64) {
    let stream = crate::schedule::held::stream_now(shared);
    let wanted = entry.events.load(Ordering::Relaxed);
    let readable = wanted & EPOLLIN != 0 && stream.visible > entry.edge_at.load(Ordering::Relaxed) && stream.unread() > 0;
    let writable = wanted & EPOLLOUT != 0 && entry.writable_edge.load(Ordering::Relaxed);
    ((if readable { EPOLLIN } else { 0 }) | (if writable { EPOLLOUT } else { 0 }), stream.visible)
}

fn edge_triggered(entry: &Entry) -> bool {
    entry.events.load(Ordering::Relaxed) & EPOLLET != 0
}

/// A write to the port found it full (EAGAIN): its edge-triggered registrations are told when
/// it is writable again (at once: climbsim drains the port at every instant).
pub(crate) fn port_was_full(shared: &crate::abi::Shared) {
    for entry in &ENTRIES_TABLE {
        let fd = entry.fd.load(Ordering::Relaxed);
        if entry.epfd.load(Ordering::Acquire) >= 0 && edge_triggered(entry) && crate::wait::is_port(shared, fd) {
            entry.writable_edge.store(true, Ordering::Relaxed);
        }
    }
}

/// The edge-triggered registration of the port in `epfd`'s, if any: where it has seen the
/// port's stream to (its waits are for bytes past there; see `port_edge`).
fn port_edges(epfd: c_int, port_fd: Option<c_int>) -> Option<&'static AtomicU64> {
    let entry = port_fd.and_then(|fd| find(epfd, fd))?;
    edge_triggered(entry).then_some(&entry.edge_at)
}

/// The wall-clock timeout of the kernel wait for an epoll wait: none when the shim has an edge
/// of the port's to report (the kernel would not report it).
fn kernel_timeout(shared: &crate::abi::Shared, epfd: c_int, port_fd: Option<c_int>, wall: Option<u64>) -> Option<u64> {
    let edge_due = port_fd.and_then(|fd| find(epfd, fd)).is_some_and(|entry| edge_triggered(entry) && edges_due(shared, entry).0 != 0);
    if edge_due { Some(0) } else { wall }
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

/// One epoll wait on simulated time, the cancellation point it is, with the signal mask
/// `sigmask` asks for (null: the program's): `real(wall)` is the kernel's wait with a wall-clock
/// timeout (None: none), after the shim's own for an edge of the port it has to report.
fn wait_on_epoll(shared: &'static crate::abi::Shared, epfd: c_int, events: *mut c_void, max: c_int, timeout: Option<u64>, sigmask: *const c_void, real: &mut dyn FnMut(Option<u64>) -> c_int) -> c_int {
    let interest = interest(EpollCall { epfd, events, max, collect_more });
    let port_fd = interest.port_fd;
    crate::wait::as_cancellation_point(|| {
        // (Inside: a cancellation acted on unwinds past no guard.)
        let _seen = crate::schedule::park::PortSeen::watch(port_edges(epfd, port_fd));
        crate::wait::with_wait_mask(sigmask, || {
            wait(shared, call::POLL, &interest, timeout, &mut |wall| mask_events(shared, epfd, events, max, real(kernel_timeout(shared, epfd, port_fd, wall)), port_fd))
        })
    })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn epoll_wait(epfd: c_int, events: *mut c_void, max: c_int, timeout_ms: c_int) -> c_int {
    let next = real!(epoll_wait: fn(c_int, *mut c_void, c_int, c_int) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(epfd, events, max, timeout_ms) };
    };
    // SAFETY: the caller's arguments, with our timeout.
    wait_on_epoll(shared, epfd, events, max, ms_timeout(timeout_ms), core::ptr::null(), &mut |wall| unsafe { next(epfd, events, max, wall_ms(wall)) })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn epoll_pwait(epfd: c_int, events: *mut c_void, max: c_int, timeout_ms: c_int, sigmask: *const c_void) -> c_int {
    let next = real!(epoll_pwait: fn(c_int, *mut c_void, c_int, c_int, *const c_void) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(epfd, events, max, timeout_ms, sigmask) };
    };
    // SAFETY: the caller's arguments, with our timeout.
    wait_on_epoll(shared, epfd, events, max, ms_timeout(timeout_ms), sigmask, &mut |wall| unsafe { next(epfd, events, max, wall_ms(wall), sigmask) })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn epoll_pwait2(epfd: c_int, events: *mut c_void, max: c_int, timeout: *const timespec, sigmask: *const c_void) -> c_int {
    let next = real!(epoll_pwait2: fn(c_int, *mut c_void, c_int, *const timespec, *const c_void) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(epfd, events, max, timeout, sigmask) };
    };
    // A timeout the program cannot have meant: Linux's EFAULT or EINVAL, at once.
    let asked = match crate::sys::program_timespec(timeout) {
        Ok(asked) => asked,
        Err(errno) => return crate::wait::refused(errno),
    };
    wait_on_epoll(shared, epfd, events, max, asked, sigmask, &mut |wall| {
        let limit = wall.map(from_ns);
        let limit_ptr = limit.as_ref().map_or(core::ptr::null(), |t| t as *const timespec);
        // SAFETY: the caller's arguments, with our timeout.
        unsafe { next(epfd, events, max, limit_ptr, sigmask) }
    })
}
