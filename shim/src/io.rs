//! Writes to the servo port, counted: climbsim holds simulated time until it has read (and so
//! time-stamped) every byte the controller wrote, since the kernel hands them over a little later.

use core::ffi::c_int;
use core::sync::atomic::Ordering;

use crate::abi::call;
use crate::sys::{iovec, real};
use crate::wait::is_port;
use crate::{active, charge, note_call};

fn count_written(fd: c_int, written: isize) {
    if written <= 0 {
        return;
    }
    let Some(shared) = active() else { return };
    crate::net::count_sent(fd, written);
    if is_port(shared, fd) {
        note_call(shared, call::WRITE);
        shared.header.port_tx_total.fetch_add(written as u64, Ordering::AcqRel);
        charge(shared, shared.header.syscall_ns.load(Ordering::Relaxed));
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn write(fd: c_int, buf: *const u8, count: usize) -> isize {
    let next = real!(write: fn(c_int, *const u8, usize) -> isize);
    // SAFETY: passing the caller's arguments through.
    let written = unsafe { next(fd, buf, count) };
    count_written(fd, written);
    written
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn writev(fd: c_int, iov: *const iovec, count: c_int) -> isize {
    let next = real!(writev: fn(c_int, *const iovec, c_int) -> isize);
    // SAFETY: passing the caller's arguments through.
    let written = unsafe { next(fd, iov, count) };
    count_written(fd, written);
    written
}
