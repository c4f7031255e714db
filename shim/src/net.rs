//! Connections to the sensor server, counted from the controller's end: request bytes sent
//! (climbsim holds time until it has read them all), response bytes received (a thread blocked
//! on a connection is let go when climbsim has written more than it took).

use core::ffi::{c_int, c_void};
use core::sync::atomic::Ordering;

use crate::abi::{Conn, Shared, call};
use crate::schedule::block::active;
use crate::schedule::park::note_call;
use crate::sys::{self, real};

const AF_INET: u16 = 2;

/// The sensor connection `fd` of this process is, if it is one.
pub(crate) fn conn_of(shared: &'static Shared, fd: c_int) -> Option<(usize, &'static Conn)> {
    if shared.header.sensor_port.load(Ordering::Relaxed) == 0 {
        return None;
    }
    let pid = crate::schedule::block::pid();
    shared.live_conns().iter().enumerate().find(|(_, c)| c.is_followed() && c.fd.load(Ordering::Relaxed) == fd && c.pid.load(Ordering::Relaxed) == pid)
}

#[repr(C)]
struct SockaddrIn {
    family: u16,
    port_be: u16,
    addr_be: u32,
    zero: [u8; 8],
}

unsafe extern "C" {
    fn getsockname(fd: c_int, addr: *mut SockaddrIn, len: *mut u32) -> c_int;
}

/// A connection to the sensor server starts: give it an entry.
fn follow_connection(shared: &'static Shared, fd: c_int, to: *const SockaddrIn) {
    // SAFETY: the caller's address, at least a sockaddr_in long (checked by the caller).
    let to = unsafe { &*to };
    let header = &shared.header;
    if to.family != AF_INET || u32::from(u16::from_be(to.port_be)) != header.sensor_port.load(Ordering::Relaxed) || to.addr_be != header.sensor_ip.load(Ordering::Relaxed) {
        return;
    }
    let mut local = SockaddrIn { family: 0, port_be: 0, addr_be: 0, zero: [0; 8] };
    let mut len = core::mem::size_of::<SockaddrIn>() as u32;
    let saved = sys::errno();
    // SAFETY: a valid buffer and length for the socket's own address.
    let rc = unsafe { getsockname(fd, &mut local, &mut len) };
    sys::set_errno(saved);
    if rc != 0 {
        return;
    }
    let port = u32::from(u16::from_be(local.port_be));
    forget(shared, fd);
    for (index, conn) in shared.conns.iter().enumerate() {
        if conn.client_port.load(Ordering::Relaxed) != 0 {
            continue;
        }
        // Scans stop at the high-water mark: it is raised before the entry is taken.
        shared.header.conns_high.fetch_max(index as u32 + 1, Ordering::AcqRel);
        if conn.client_port.compare_exchange(0, u32::MAX, Ordering::AcqRel, Ordering::Relaxed).is_ok() {
            conn.no_waiters();
            conn.sent.store(0, Ordering::Relaxed);
            conn.read.store(0, Ordering::Relaxed);
            conn.resp_written.store(0, Ordering::Relaxed);
            conn.resp_taken.store(0, Ordering::Relaxed);
            conn.pid.store(crate::schedule::block::pid(), Ordering::Relaxed);
            conn.fd.store(fd, Ordering::Relaxed);
            conn.client_port.store(port, Ordering::Release);
            return;
        }
    }
    crate::schedule::block::refuse(crate::abi::refused::CONNS);
}

/// The descriptor is closed (or reused): its connection is no longer followed.
pub(crate) fn forget(shared: &'static Shared, fd: c_int) {
    if let Some((_, conn)) = conn_of(shared, fd) {
        conn.client_port.store(0, Ordering::Release);
    }
}

/// Process `pid` is ending: its connections are no longer followed (it may not have closed
/// them; left taken, they would be scanned for the rest of the run).
pub(crate) fn forget_process(shared: &'static Shared, pid: i32) {
    for conn in shared.live_conns().iter().filter(|c| c.is_followed() && c.pid.load(Ordering::Relaxed) == pid) {
        conn.client_port.store(0, Ordering::Release);
    }
}

/// `sent` request bytes went out on `fd`.
pub(crate) fn count_sent(fd: c_int, sent: isize) {
    if sent <= 0 {
        return;
    }
    if let Some(shared) = active()
        && let Some((_, conn)) = conn_of(shared, fd)
    {
        note_call(shared, call::NET);
        conn.sent.fetch_add(sent as u64, Ordering::AcqRel);
    }
}

/// A receive on `fd` returned `received` (0: the end of the stream).
pub(crate) fn count_received(fd: c_int, received: isize) {
    if received < 0 {
        return;
    }
    if let Some(shared) = active()
        && let Some((_, conn)) = conn_of(shared, fd)
    {
        note_call(shared, call::NET);
        conn.resp_taken.fetch_add(if received == 0 { 1 } else { received as u64 }, Ordering::AcqRel);
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn connect(fd: c_int, addr: *const c_void, len: u32) -> c_int {
    let next = real!(connect: fn(c_int, *const c_void, u32) -> c_int);
    // SAFETY: passing the caller's arguments through.
    let result = unsafe { next(fd, addr, len) };
    const EINPROGRESS: c_int = 115;
    if let Some(shared) = active()
        && (result == 0 || sys::errno() == EINPROGRESS)
        && !addr.is_null()
        && len as usize >= core::mem::size_of::<SockaddrIn>()
    {
        follow_connection(shared, fd, addr.cast());
    }
    result
}
