//! Reads and writes: the servo port's, receives (a sensor connection's are counted, net.rs),
//! and a blocking read of anything else, which waits on simulated time first
//! (`wait::await_readable`). The servo port's writes are counted: climbsim holds simulated time
//! until it has read (and so time-stamped) every byte the controller wrote, since the kernel
//! hands them over a little later. A read that finds nothing waits on simulated time: a blocking one as the
//! terminal's VMIN and VTIME say, a non-blocking one (the C++ SDK's loop) as a spin. Reads, the
//! FIONREAD ioctl and tcflush see only the reply bytes visible now (held.rs).

use core::ffi::{c_int, c_void};
use core::sync::atomic::Ordering;

use crate::abi::{Shared, Wait, call, release};
use crate::schedule::block::active;
use crate::schedule::held::{stream_now, took};
use crate::schedule::park::park_blocked;
use crate::schedule::park::{charge, note_call};
use crate::sys::{iovec, real};
use crate::time::sim_now;
use crate::wait::{await_readable, is_port};

/// The block, if `fd` is the servo port while virtual time runs: one `fstat` a write, for both
/// the ring and the count.
fn port_of(fd: c_int) -> Option<&'static Shared> {
    active().filter(|shared| is_port(shared, fd))
}

/// A write the kernel made (`port`: to the servo port, see [`port_of`]) is counted.
fn count_written(fd: c_int, written: isize, port: Option<&'static Shared>) {
    if written <= 0 {
        let errno = crate::sys::errno();
        if written < 0 && errno == crate::sys::EAGAIN {
            if let Some(shared) = port {
                crate::epoll::port_was_full(shared);
            }
            crate::sys::set_errno(errno);
        }
        return;
    }
    crate::net::count_sent(fd, written);
    if let Some(shared) = port {
        note_call(shared, call::WRITE);
        shared.header.port.tx_total.fetch_add(written as u64, Ordering::AcqRel);
        charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn write(fd: c_int, buf: *const u8, count: usize) -> isize {
    // One fstat says both whether this is the port and whether it is a pipe or a socket.
    let shared = active();
    let stat = shared.and_then(|_| crate::sys::file_stat(fd));
    let port = shared.filter(|shared| crate::wait::is_port_device(shared, stat.and_then(crate::sys::FileStat::char_device)));
    if let Some(written) = port.and_then(|shared| crate::port_ring::write(shared, fd, &[iovec { iov_base: buf.cast_mut().cast(), iov_len: count }])) {
        return written;
    }
    let next = real!(write: fn(c_int, *const u8, usize) -> isize);
    if port.is_none()
        && let Some(shared) = shared
        && let Some(kind) = stat.and_then(crate::sys::FileStat::pipe_or_socket)
    {
        let written = crate::room::write_with_room(shared, fd, kind, count, |done, kind| {
            let rest = iovec { iov_base: buf.wrapping_add(done).cast_mut().cast(), iov_len: count - done };
            let rc = crate::native::call6(crate::sys::nr::PWRITEV2, fd as core::ffi::c_long, &rest as *const iovec as core::ffi::c_long, 1, -1, 0, RWF_NOWAIT) as isize;
            // A pipe opened by name (a FIFO, /proc/self/fd/N) takes no RWF_NOWAIT: written
            // through a non-blocking description of its own. (Anything else that refuses it is
            // written as it is: write_with_room gives up.)
            if rc == -(crate::sys::EOPNOTSUPP as isize) && kind.pipe {
                return crate::sys::write_pipe_without_waiting(fd, buf.wrapping_add(done), count - done).unwrap_or(rc);
            }
            rc
        });
        if let Some(written) = written {
            count_written(fd, written, port);
            return written;
        }
    }
    // SAFETY: passing the caller's arguments through.
    let written = unsafe { next(fd, buf, count) };
    count_written(fd, written, port);
    written
}

/// pwritev2's flag: fail with EAGAIN rather than wait (pipes and sockets honour it).
const RWF_NOWAIT: core::ffi::c_long = 8;

#[unsafe(no_mangle)]
pub unsafe extern "C" fn writev(fd: c_int, iov: *const iovec, count: c_int) -> isize {
    let port = port_of(fd);
    if let Some(shared) = port
        && !iov.is_null()
        && (1..=IOV_MAX).contains(&count)
    {
        // SAFETY: writev's contract: `count` valid iovecs at `iov`.
        let parts = unsafe { core::slice::from_raw_parts(iov, count as usize) };
        if let Some(written) = crate::port_ring::write(shared, fd, parts) {
            return written;
        }
    }
    let next = real!(writev: fn(c_int, *const iovec, c_int) -> isize);
    // SAFETY: passing the caller's arguments through.
    let written = unsafe { next(fd, iov, count) };
    count_written(fd, written, port);
    written
}

/// The most iovecs a writev takes (UIO_MAXIOV); past it the kernel answers EINVAL.
const IOV_MAX: c_int = 1024;
/// Also TIOCINQ.
const FIONREAD: u64 = 0x541B;
const TCGETS: u64 = 0x5401;
const TCFLSH: u64 = 0x540B;
const TCIFLUSH: c_int = 0;
const TCOFLUSH: c_int = 1;
const TCIOFLUSH: c_int = 2;
/// struct termios: c_cc starts after four flags and c_line; VTIME and VMIN are its 5th and 6th.
const C_CC: usize = 17;
const VTIME: usize = 5;
const VMIN: usize = 6;

/// libc's ioctl (the shim's own `ioctl` below hides what is held).
fn real_ioctl(fd: c_int, request: u64, arg: *mut c_void) -> c_int {
    let next = real!(ioctl: fn(c_int, u64, *mut c_void) -> c_int);
    // SAFETY: the request's own argument, as the caller (or the shim) passed it.
    unsafe { next(fd, request, arg) }
}

/// Bytes a read of the port may return now: what the kernel has, less what is not visible yet.
fn readable(shared: &Shared, fd: c_int) -> usize {
    let mut available: c_int = 0;
    // FIONREAD writes one int.
    let kernel = if real_ioctl(fd, FIONREAD, (&mut available as *mut c_int).cast()) == 0 { available.max(0) as usize } else { 0 };
    let stream = stream_now(shared);
    if stream.hidden() > 0 { kernel.min(stream.unread() as usize) } else { kernel }
}

/// What a read of the port does when nothing is there yet.
enum PortRead {
    /// Read for real now, at most this many bytes (all there are: the kernel does not block).
    Now(usize),
    /// Return this without asking the kernel (0: nothing came before VTIME ran out).
    Return(isize),
}

/// The terminal's VMIN and VTIME (None: not a terminal).
fn vmin_vtime(fd: c_int) -> Option<(u8, u8)> {
    let mut termios = [0u8; 64];
    // TCGETS fills a struct termios (60 bytes on Linux).
    (real_ioctl(fd, TCGETS, termios.as_mut_ptr().cast()) == 0).then(|| (termios[C_CC + VMIN], termios[C_CC + VTIME]))
}

/// What a non-blocking read of an empty terminal returns: 0 with VMIN = VTIME = 0 (the kernel
/// checks that before O_NONBLOCK; the C++ SDK adds the result to its count unchecked), else
/// -1 with EAGAIN.
fn empty_nonblocking_read(fd: c_int) -> isize {
    if vmin_vtime(fd) == Some((0, 0)) {
        return 0;
    }
    crate::sys::set_errno(crate::sys::EAGAIN);
    -1
}

/// Wait on simulated time until a read of the port can go to the kernel without blocking.
fn wait_for_port_bytes(shared: &'static crate::abi::Shared, fd: c_int, len: usize) -> PortRead {
    let Some((vmin, vtime)) = vmin_vtime(fd) else { return PortRead::Now(len) };
    let deadline = if vmin == 0 && vtime > 0 { sim_now(shared).saturating_add(u64::from(vtime) * 100_000_000) } else { crate::abi::NEVER };
    loop {
        let available = readable(shared, fd);
        if available > 0 {
            return PortRead::Now(len.min(available));
        }
        if vmin == 0 && vtime == 0 {
            // A read that never waits: a spin, as a non-blocking one.
            spun_on_empty_port(shared);
            let available = readable(shared, fd);
            return if available > 0 { PortRead::Now(len.min(available)) } else { PortRead::Return(0) };
        }
        match park_blocked(shared, deadline, Wait::Data { port: true, conns: false }) {
            // A signal's handler has run (the thread sent it to itself): the read goes on, as
            // with SA_RESTART.
            release::DATA | release::SIGNAL => {}
            release::ENDING => return PortRead::Now(len),
            _ => return PortRead::Return(0),
        }
    }
}

/// A non-blocking read of the port found nothing: a spin, as a zero-timeout poll of it.
fn spun_on_empty_port(shared: &'static crate::abi::Shared) {
    crate::schedule::park::spin_on_port(shared, sim_now(shared));
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn read(fd: c_int, buf: *mut c_void, len: usize) -> isize {
    let next = real!(read: fn(c_int, *mut c_void, usize) -> isize);
    if let Some(result) = crate::timerfd::read(fd, buf, len) {
        return result;
    }
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(fd, buf, len) };
    };
    if len == 0 || !crate::wait::is_port(shared, fd) {
        if len > 0
            && let Err(errno) = await_readable(shared, fd)
        {
            return crate::wait::refused(errno) as isize;
        }
        // SAFETY: passing the caller's arguments through.
        let received = unsafe { next(fd, buf, len) };
        crate::net::count_received(fd, received);
        return received;
    }
    note_call(shared, call::READ);
    // SAFETY: fcntl F_GETFL on the caller's descriptor.
    let blocking = unsafe { crate::sys::fcntl(fd, crate::sys::F_GETFL) } & crate::sys::O_NONBLOCK == 0;
    if !blocking {
        let stream = stream_now(shared);
        if stream.looks_empty() {
            // Only bytes not due yet: the read finds nothing, and says so as the kernel would.
            spun_on_empty_port(shared);
            return empty_nonblocking_read(fd);
        }
        let limit = if stream.hidden() > 0 { len.min(stream.unread() as usize) } else { len };
        // SAFETY: the caller's buffer, at most its length.
        let received = unsafe { next(fd, buf, limit) };
        if received <= 0 {
            let errno = crate::sys::errno();
            spun_on_empty_port(shared);
            crate::sys::set_errno(errno);
        }
        took(shared, received);
        return received;
    }
    match wait_for_port_bytes(shared, fd, len) {
        PortRead::Now(bytes) => {
            // SAFETY: the caller's buffer, at most its length.
            let received = unsafe { next(fd, buf, bytes) };
            took(shared, received);
            received
        }
        PortRead::Return(value) => value,
    }
}

/// FIONREAD (TIOCINQ) counts only the visible bytes of the port; TCFLSH is tcflush's.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ioctl(fd: c_int, request: u64, arg: *mut c_void) -> c_int {
    if request != FIONREAD && request != TCFLSH {
        return real_ioctl(fd, request, arg);
    }
    let Some(shared) = active().filter(|shared| is_port(shared, fd)) else { return real_ioctl(fd, request, arg) };
    if request == TCFLSH {
        return flush_port(shared, fd, arg as usize as c_int);
    }
    let rc = real_ioctl(fd, request, arg);
    let stream = stream_now(shared);
    if rc == 0 && !arg.is_null() && stream.hidden() > 0 {
        let count = arg.cast::<c_int>();
        // SAFETY: FIONREAD's argument is the caller's int, which the kernel just wrote.
        unsafe { *count = (*count).min(stream.unread().min(i32::MAX as u64) as c_int) };
    }
    rc
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn tcflush(fd: c_int, queue: c_int) -> c_int {
    match active().filter(|shared| is_port(shared, fd)) {
        Some(shared) => flush_port(shared, fd, queue),
        None => real_ioctl(fd, TCFLSH, queue as usize as *mut c_void),
    }
}

/// tcflush of the port: what arrived is discarded, what is still on its way (held) is not.
fn flush_port(shared: &'static Shared, fd: c_int, queue: c_int) -> c_int {
    note_call(shared, call::READ);
    let stream = stream_now(shared);
    let input = queue == TCIFLUSH || queue == TCIOFLUSH;
    if !input || stream.hidden() == 0 {
        let rc = real_ioctl(fd, TCFLSH, queue as usize as *mut c_void);
        if rc == 0 && input {
            // Everything written has been discarded.
            shared.header.port.rx_taken.fetch_max(stream.written, Ordering::AcqRel);
        }
        return rc;
    }
    let read = real!(read: fn(c_int, *mut c_void, usize) -> isize);
    let mut scratch = [0u8; 256];
    let mut left = stream.unread() as usize;
    while left > 0 {
        // SAFETY: our own buffer; the bytes are in the kernel's queue, so this does not block.
        let got = unsafe { read(fd, scratch.as_mut_ptr().cast(), left.min(scratch.len())) };
        if got <= 0 {
            break;
        }
        took(shared, got);
        left -= got as usize;
    }
    if queue == TCIOFLUSH {
        return real_ioctl(fd, TCFLSH, TCOFLUSH as usize as *mut c_void);
    }
    0
}

/// A closed descriptor is no longer a sensor connection, a timer, nor in any epoll instance.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn close(fd: c_int) -> c_int {
    // A vfork child shares its parent's memory: what it closes is still open in the parent.
    let vfork_child = crate::schedule::block::pid() != crate::sys::getpid();
    if let Some(shared) = crate::schedule::block::shared().filter(|_| !vfork_child) {
        crate::net::forget(shared, fd);
        crate::epoll::forget(fd);
        crate::timerfd::forget(fd);
    }
    let next = real!(close: fn(c_int) -> c_int);
    // SAFETY: passing the caller's argument through.
    unsafe { next(fd) }
}

/// Receives: from the sensor server (counted, net.rs), or from anything else that may block.
const MSG_DONTWAIT: c_int = 0x40;

/// A receive that may block waits on simulated time first (see `io::await_readable`); `Err`:
/// it is not to be made, and fails with that errno (the socket's receive timeout passed first,
/// or a signal's handler ran), as Linux's does.
fn before_receive(fd: c_int, flags: c_int) -> Result<(), c_int> {
    match active() {
        Some(shared) if flags & MSG_DONTWAIT == 0 => await_readable(shared, fd),
        _ => Ok(()),
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn recv(fd: c_int, buf: *mut c_void, len: usize, flags: c_int) -> isize {
    let next = real!(recv: fn(c_int, *mut c_void, usize, c_int) -> isize);
    if let Err(errno) = before_receive(fd, flags) {
        return crate::wait::refused(errno) as isize;
    }
    // SAFETY: passing the caller's arguments through.
    let received = unsafe { next(fd, buf, len, flags) };
    if flags & 2 == 0 {
        // Not MSG_PEEK: the bytes are taken.
        crate::net::count_received(fd, received);
    }
    received
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn recvfrom(fd: c_int, buf: *mut c_void, len: usize, flags: c_int, addr: *mut c_void, addr_len: *mut u32) -> isize {
    let next = real!(recvfrom: fn(c_int, *mut c_void, usize, c_int, *mut c_void, *mut u32) -> isize);
    if let Err(errno) = before_receive(fd, flags) {
        return crate::wait::refused(errno) as isize;
    }
    // SAFETY: passing the caller's arguments through.
    let received = unsafe { next(fd, buf, len, flags, addr, addr_len) };
    if flags & 2 == 0 {
        crate::net::count_received(fd, received);
    }
    received
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn recvmsg(fd: c_int, message: *mut c_void, flags: c_int) -> isize {
    let next = real!(recvmsg: fn(c_int, *mut c_void, c_int) -> isize);
    if let Err(errno) = before_receive(fd, flags) {
        return crate::wait::refused(errno) as isize;
    }
    // SAFETY: passing the caller's arguments through.
    let received = unsafe { next(fd, message, flags) };
    if flags & 2 == 0 {
        crate::net::count_received(fd, received);
    }
    received
}
