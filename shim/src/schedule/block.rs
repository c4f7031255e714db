//! The shared block as this process sees it: mapped at start (`init`), the process's id, and
//! whether virtual time still holds (the run goes on and climbsim is there). Below everything
//! that follows a thread: it tells climbsim (`notify_scheduler`) and refuses what cannot be
//! followed, but knows nothing of slots or turns.

use core::ffi::{c_char, c_int};
use core::sync::atomic::{AtomicBool, AtomicPtr, AtomicU64, Ordering};

use crate::abi::{self, Shared, mode};
use crate::sys::{self, real};

/// The block, once mapped.
static SHARED: AtomicPtr<Shared> = AtomicPtr::new(core::ptr::null_mut());
/// Set once climbsim is found gone: the process goes on as after the run's end.
pub(crate) static ORPHANED: AtomicBool = AtomicBool::new(false);
/// The wall clock (CLOCK_MONOTONIC) when climbsim was found gone.
static ORPHANED_AT: AtomicU64 = AtomicU64::new(0);

pub(crate) use sys::{note_pid, noted_pid as pid};

/// The block if virtual time is on (the run has not ended, climbsim is there).
pub(crate) fn active() -> Option<&'static Shared> {
    let shared = shared()?;
    (shared.header.mode.load(Ordering::Acquire) == mode::VIRTUAL && !ORPHANED.load(Ordering::Relaxed)).then_some(shared)
}

/// climbsim's process has gone without ending the run (killed): nobody will let parked
/// threads go, so they stop waiting for it.
pub(crate) fn climbsim_gone(shared: &Shared) -> bool {
    let pid = shared.header.climbsim_pid.load(Ordering::Relaxed);
    let gone = pid > 0 && !sys::process_lives(pid);
    if gone && !ORPHANED.swap(true, Ordering::AcqRel) {
        // Clocks go on from here at the wall clock's rate, as after a run's end.
        ORPHANED_AT.store(sys::real_monotonic_ns(), Ordering::Relaxed);
    }
    gone
}

/// Whether climbsim was found gone, and when (wall clock).
pub(crate) fn orphaned_at() -> Option<u64> {
    ORPHANED.load(Ordering::Relaxed).then(|| ORPHANED_AT.load(Ordering::Relaxed))
}

/// The block, whatever its mode.
pub(crate) fn shared() -> Option<&'static Shared> {
    let pointer = SHARED.load(Ordering::Acquire);
    // SAFETY: set once to a mapping of the whole block that is never unmapped.
    (!pointer.is_null()).then(|| unsafe { &*pointer })
}

/// Tell climbsim's scheduler that a thread parked, yielded, ended or was refused: it decides.
pub(crate) fn notify_scheduler(shared: &Shared) {
    shared.header.turns.sched_word.fetch_add(1, Ordering::AcqRel);
    sys::futex_wake(&shared.header.turns.sched_word);
}

/// Something the controller did cannot be followed (`abi::refused`: a table had no room, an
/// io_uring): the run fails naming it.
pub(crate) fn refuse(which: u32) {
    if let Some(shared) = shared() {
        shared.header.refused.fetch_or(which, Ordering::AcqRel);
        notify_scheduler(shared);
    }
}

/// Map the block at `path` (what `CLIMBSIM_VT` names), checking that it is this shim's version.
pub(crate) fn map(path: *const c_char) -> Result<(), &'static [u8]> {
    const O_RDWR: c_int = 2;
    const O_CLOEXEC: c_int = 0o2000000;
    const PROT_READ_WRITE: c_int = 3;
    const MAP_SHARED: c_int = 1;
    // SAFETY: a NUL-terminated path from the environment.
    let fd = unsafe { sys::open(path, O_RDWR | O_CLOEXEC) };
    if fd < 0 {
        return Err(b"cannot open the block CLIMBSIM_VT names");
    }
    // SAFETY: mapping the file's first SHARED_BYTES, which climbsim sized so.
    let mapped = unsafe { sys::mmap(core::ptr::null_mut(), abi::SHARED_BYTES, PROT_READ_WRITE, MAP_SHARED, fd, 0) };
    let close = real!(close: fn(c_int) -> c_int);
    // SAFETY: closing our own descriptor; the mapping stays.
    unsafe { close(fd) };
    if mapped as isize == -1 {
        return Err(b"cannot map the block CLIMBSIM_VT names");
    }
    let block = mapped.cast::<Shared>();
    // SAFETY: the mapping holds a whole block.
    let header = unsafe { &(*block).header };
    if header.magic.load(Ordering::Acquire) != abi::MAGIC || header.abi.load(Ordering::Acquire) != abi::ABI {
        return Err(b"CLIMBSIM_VT names a block of another climbsim version");
    }
    SHARED.store(block, Ordering::Release);
    Ok(())
}
