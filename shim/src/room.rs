//! Writes that wait for room: a blocking `write`, `send` or `sendto` to a pipe or a socket that
//! has none is made a part at a time without ever waiting in the kernel, and between the parts
//! the thread waits on simulated time for room (`wait::await_writable`). The send symbols live
//! here; a sensor connection's sends are counted (net.rs).

use core::ffi::{c_int, c_void};
use core::sync::atomic::Ordering;

use crate::abi::Shared;
use crate::net::count_sent;
use crate::schedule::block::active;
use crate::sys::{self, real};

/// A blocking write of `total` bytes to `fd`, a pipe or a socket (`kind`), made without ever
/// waiting in the kernel: `write_part(done, kind)` writes what is left after `done` bytes
/// without waiting (the kernel's convention: bytes written, or a negative errno; `kind`: a pipe
/// or a socket, and its inode), and while the kernel
/// has no room the thread waits on simulated time for some (`wait::await_writable`). Blocked in
/// the kernel's write, the writer would look running to climbsim, and a reader that sleeps on
/// simulated time before it reads would never get there (the run failed after 2 s). Linux's
/// answers: everything written, or what was written before an error or a signal's handler (if
/// nothing was, the error, or EINTR). None: not a blocking pipe or socket; the caller writes as
/// it is.
pub(crate) fn write_with_room(shared: &'static Shared, fd: c_int, kind: sys::PipeOrSocket, total: usize, mut write_part: impl FnMut(usize, sys::PipeOrSocket) -> isize) -> Option<isize> {
    // Waits on the kernel's word that there is room which then finds none, in a row, before the
    // write is left to the kernel (a descriptor whose poll and write disagree).
    const EMPTY_LOOKS_AT_MOST: u32 = 1000;
    // (The pipe climbsim copies the controller's output from is drained in real time, by
    // climbsim: a write to it that waits does so in the kernel, and simulated time holds.)
    let output = shared.header.output_pipe.load(Ordering::Relaxed);
    if kind.inode == output || total == 0 || !sys::blocking(fd) {
        return None;
    }
    let (mut done, mut empty_looks) = (0usize, 0u32);
    loop {
        let rc = write_part(done, kind);
        if rc >= 0 {
            done += rc as usize;
            if done >= total || rc == 0 {
                return Some(done as isize);
            }
            empty_looks = 0;
            continue;
        }
        let errno = (-rc) as c_int;
        if errno != crate::sys::EAGAIN || empty_looks >= EMPTY_LOOKS_AT_MOST {
            if done > 0 {
                return Some(done as isize);
            }
            // (Nothing written: a descriptor that cannot be written without waiting, or whose
            // poll and write disagree, is written as it is.)
            if errno == crate::sys::EAGAIN || errno == crate::sys::EOPNOTSUPP {
                return None;
            }
            crate::sys::set_errno(errno);
            return Some(-1);
        }
        empty_looks += 1;
        if let Err(errno) = crate::wait::await_writable(shared, fd) {
            // A signal's handler ran, or the socket's send timeout passed: what was written,
            // or EINTR (EAGAIN).
            if done > 0 {
                return Some(done as isize);
            }
            crate::sys::set_errno(errno);
            return Some(-1);
        }
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn send(fd: c_int, buf: *const c_void, len: usize, flags: c_int) -> isize {
    let next = real!(send: fn(c_int, *const c_void, usize, c_int) -> isize);
    // SAFETY: passing the caller's arguments through.
    let sent = sent_with_room(fd, len, flags, |done, flags| unsafe { next(fd, buf.cast::<u8>().wrapping_add(done).cast(), len - done, flags) });
    count_sent(fd, sent);
    sent
}

/// MSG_DONTWAIT: this send does not wait.
const MSG_DONTWAIT: c_int = 0x40;

/// A send of `len` bytes that may wait for room: made a part at a time without waiting, the
/// thread waiting on simulated time for room between the parts (see [`write_with_room`]).
/// `send_part(done, flags)` sends what is left after `done` bytes with `flags`.
fn sent_with_room(fd: c_int, len: usize, flags: c_int, mut send_part: impl FnMut(usize, c_int) -> isize) -> isize {
    if let Some(shared) = active()
        && flags & MSG_DONTWAIT == 0
        && let Some(kind) = sys::pipe_or_socket(fd)
        && let Some(sent) = write_with_room(shared, fd, kind, len, |done, _| {
            let sent = send_part(done, flags | MSG_DONTWAIT);
            if sent < 0 { -(sys::errno() as isize) } else { sent }
        })
    {
        return sent;
    }
    send_part(0, flags)
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn sendto(fd: c_int, buf: *const c_void, len: usize, flags: c_int, addr: *const c_void, addr_len: u32) -> isize {
    let next = real!(sendto: fn(c_int, *const c_void, usize, c_int, *const c_void, u32) -> isize);
    // SAFETY: passing the caller's arguments through.
    let sent = sent_with_room(fd, len, flags, |done, flags| unsafe { next(fd, buf.cast::<u8>().wrapping_add(done).cast(), len - done, flags, addr, addr_len) });
    count_sent(fd, sent);
    sent
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn sendmsg(fd: c_int, message: *const c_void, flags: c_int) -> isize {
    let next = real!(sendmsg: fn(c_int, *const c_void, c_int) -> isize);
    // SAFETY: passing the caller's arguments through.
    let sent = unsafe { next(fd, message, flags) };
    count_sent(fd, sent);
    sent
}
