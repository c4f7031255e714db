//! An exec's marker: a descriptor (a memfd named `abi::EXEC_MARKER_NAME`) that a task exec'ing
//! a program on the wall clock leaves open, and that the new program's shim closes as it starts
//! (`Slot::exec_marker_fd`): climbsim, and a thread looking for a free slot, wait until it is
//! gone, once the kernel has released what the exec closed.

use core::ffi::c_int;
use core::sync::atomic::Ordering;

use crate::abi::Slot;
use crate::native;
use crate::sys;

/// A descriptor that marks an exec leaving the followed world, for climbsim to watch in
/// /proc (`/proc/TID/fd/N` names [`abi::EXEC_MARKER_NAME`]): a memfd at a set number that the
/// exec does not close; the new program's shim closes it at start (see
/// [`close_inherited_exec_marker`]), in user space, once the exec is over. Only then are the
/// descriptors the exec closed released: the kernel puts their last close off until the task
/// returns to user space, milliseconds after it took them out of the table. Among them the pipe
/// through which Python's `subprocess` and others learn that the exec succeeded, whose end a
/// parent waits for. Without the marker climbsim moved simulated time on while the host ran the
/// exec, by as much as the host took (0.1 s on average, up to 0.57 s, for a forked child's exec
/// beside a Python controller). -1: none could be made at its number.
pub(crate) fn exec_marker() -> c_int {
    let Some(place) = exec_marker_place() else { return -1 };
    let memfd = native::call2(sys::nr::MEMFD_CREATE, crate::abi::EXEC_MARKER_NAME.as_ptr() as i64, 0);
    if memfd < 0 {
        return -1;
    }
    let moved = native::call3(sys::nr::FCNTL, memfd, F_DUPFD, place.into());
    native::call1(sys::nr::CLOSE, memfd);
    if moved == i64::from(place) {
        return place;
    }
    if moved >= 0 {
        native::call1(sys::nr::CLOSE, moved);
    }
    -1
}

/// The number an exec's marker takes: high, so that the program's own descriptors leave it
/// free, without growing the descriptor table the new program inherits past 1024 entries.
fn exec_marker_place() -> Option<c_int> {
    let mut limit = [0u64; 2];
    if native::call4(sys::nr::PRLIMIT64, 0, RLIMIT_NOFILE, 0, limit.as_mut_ptr() as i64) < 0 || limit[0] < 2 {
        return None;
    }
    Some((limit[0] - 1).min(EXEC_MARKER_AT_MOST) as c_int)
}

/// In a program that a followed one exec'd without the shim's clock: close the marker of that
/// exec (see [`exec_marker`]), which tells climbsim that the exec is over.
pub(crate) fn close_inherited_exec_marker() {
    if let Some(place) = exec_marker_place()
        && names_marker(None, place)
    {
        native::call1(sys::nr::CLOSE, place.into());
    }
}

/// Whether the exec that `slot`'s marker stands for is over (or none is under way): the
/// marker is gone from its task's descriptors (see [`exec_marker`]). Until then the slot is not
/// taken again: climbsim watches it.
pub(crate) fn exec_over(slot: &Slot) -> bool {
    let (fd, tid) = (slot.exec_marker_fd.load(Ordering::Acquire), slot.tid.load(Ordering::Relaxed));
    fd <= 0 || tid <= 0 || !names_marker(Some(tid), fd)
}

/// Whether descriptor `fd` of task `tid` (None: this one) is an exec's marker.
fn names_marker(tid: Option<i32>, fd: c_int) -> bool {
    // (This may be a vfork child: no heap.)
    let path = sys::fd_path(tid, fd);
    let mut link = [0u8; 64];
    let read = native::call4(sys::nr::READLINKAT, sys::AT_FDCWD, path.as_ptr() as i64, link.as_mut_ptr() as i64, link.len() as i64);
    read > 0 && crate::abi::is_exec_marker_link(&link[..read as usize])
}

const F_DUPFD: i64 = 0;
const RLIMIT_NOFILE: i64 = 7;
const EXEC_MARKER_AT_MOST: u64 = 1023;
