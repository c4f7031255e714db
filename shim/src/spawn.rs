//! New programs. A process about to exec (often a vfork child, which shares its parent's memory
//! and thread-locals, so only the shared block is touched here) reserves a slot for its task
//! first: its parent may block in waitpid at once, and time must not move before the new
//! program has loaded the shim and claimed the slot. posix_spawn reserves one for the child it
//! will make.

use core::ffi::{c_char, c_int, c_void};
use core::sync::atomic::Ordering;

use crate::abi::{Slot, state};
use crate::sys::{self, real};
use crate::shared;

/// Reserve a free slot for task `tid` of a program to come (`tid` 0: a child of `parent`
/// whose id is not known yet).
fn reserve(tid: i32, parent: i32) -> Option<&'static Slot> {
    let shared = shared()?;
    if shared.header.mode.load(Ordering::Acquire) != crate::abi::mode::VIRTUAL {
        return None;
    }
    // The task may hold a slot already (a followed process that execs): it keeps it.
    if tid != 0 && shared.slots.iter().any(|s| s.tid.load(Ordering::Relaxed) == tid && matches!(s.state.load(Ordering::Acquire), state::RUNNING | state::RESERVED)) {
        return None;
    }
    for slot in shared.slots.iter().skip(1) {
        if crate::take_unused(slot, state::RESERVED) {
            slot.pid.store(if tid == 0 { parent } else { tid }, Ordering::Relaxed);
            // The program to come is a child of `parent` (fork, posix_spawn), or of this
            // process's parent (an exec: the same process).
            slot.parent.store(if tid == 0 { parent } else { sys::getppid() }, Ordering::Relaxed);
            slot.tid.store(tid, Ordering::Release);
            return Some(slot);
        }
    }
    None
}

/// An exec failed: the reservation goes.
fn unreserve(slot: Option<&'static Slot>) {
    if let Some(slot) = slot
        && slot.state.compare_exchange(state::RESERVED, state::FREE, Ordering::AcqRel, Ordering::Relaxed).is_ok()
        && let Some(shared) = shared()
    {
        crate::notify_scheduler(shared);
    }
}

/// The environment the new program gets still names the block: it will load the shim.
fn carries_shim(envp: *const *const c_char) -> bool {
    let mut entry = envp;
    if entry.is_null() {
        return false;
    }
    const NAME: &[u8] = b"CLIMBSIM_VT=";
    // SAFETY: a NULL-terminated array of NUL-terminated strings (the exec's own argument).
    unsafe {
        while !(*entry).is_null() {
            let text = *entry;
            if (0..NAME.len()).all(|i| *text.add(i) as u8 == NAME[i]) {
                return true;
            }
            entry = entry.add(1);
        }
    }
    false
}

unsafe extern "C" {
    static environ: *const *const c_char;
}

/// Run an exec. A program that will load the shim gets a slot before it starts; one that will
/// not (its environment drops the block) leaves the followed world with this task, which
/// otherwise would count as running for ever.
fn exec_with(envp: *const *const c_char, run: impl FnOnce() -> c_int) -> c_int {
    let tid = sys::gettid();
    if carries_shim(envp) {
        let reserved = reserve(tid, 0);
        let result = run();
        unreserve(reserved);
        return result;
    }
    let Some(shared) = shared() else { return run() };
    let mine = shared.slots.iter().find(|s| s.tid.load(Ordering::Relaxed) == tid && matches!(s.state.load(Ordering::Acquire), state::RUNNING | state::RESERVED));
    let before = mine.map(|s| s.state.swap(state::EXITED, Ordering::AcqRel));
    crate::notify_scheduler(shared);
    let result = run();
    if let (Some(slot), Some(before)) = (mine, before) {
        slot.state.store(before, Ordering::Release);
    }
    result
}

type ExecveFn = unsafe extern "C" fn(*const c_char, *const *const c_char, *const *const c_char) -> c_int;
type ExecvFn = unsafe extern "C" fn(*const c_char, *const *const c_char) -> c_int;
type FexecveFn = unsafe extern "C" fn(c_int, *const *const c_char, *const *const c_char) -> c_int;

fn real_execve() -> ExecveFn {
    real!(execve: fn(*const c_char, *const *const c_char, *const *const c_char) -> c_int)
}
fn real_execv() -> ExecvFn {
    real!(execv: fn(*const c_char, *const *const c_char) -> c_int)
}
fn real_execvp() -> ExecvFn {
    real!(execvp: fn(*const c_char, *const *const c_char) -> c_int)
}
fn real_execvpe() -> ExecveFn {
    real!(execvpe: fn(*const c_char, *const *const c_char, *const *const c_char) -> c_int)
}
fn real_fexecve() -> FexecveFn {
    real!(fexecve: fn(c_int, *const *const c_char, *const *const c_char) -> c_int)
}

/// Look libc's exec functions up now: in a vfork child (Python's subprocess) a first lookup
/// would take the loader's lock, which a thread of the parent may hold.
pub(crate) fn resolve_exec_functions() {
    let _ = (real_execve(), real_execv(), real_execvp(), real_execvpe(), real_fexecve());
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn execve(path: *const c_char, argv: *const *const c_char, envp: *const *const c_char) -> c_int {
    let next = real_execve();
    // SAFETY: passing the caller's arguments through.
    exec_with(envp, || unsafe { next(path, argv, envp) })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn execv(path: *const c_char, argv: *const *const c_char) -> c_int {
    let next = real_execv();
    // SAFETY: passing the caller's arguments through.
    // SAFETY: `environ` is libc's, valid for the process.
    exec_with(unsafe { environ }, || unsafe { next(path, argv) })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn execvp(file: *const c_char, argv: *const *const c_char) -> c_int {
    let next = real_execvp();
    // SAFETY: passing the caller's arguments through.
    // SAFETY: as above.
    exec_with(unsafe { environ }, || unsafe { next(file, argv) })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn execvpe(file: *const c_char, argv: *const *const c_char, envp: *const *const c_char) -> c_int {
    let next = real_execvpe();
    // SAFETY: passing the caller's arguments through.
    exec_with(envp, || unsafe { next(file, argv, envp) })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn fexecve(fd: c_int, argv: *const *const c_char, envp: *const *const c_char) -> c_int {
    let next = real_fexecve();
    // SAFETY: passing the caller's arguments through.
    exec_with(envp, || unsafe { next(fd, argv, envp) })
}

/// fork: the child gets a slot reserved by its parent before it exists, so that a parent
/// that goes straight into waitpid cannot let time move before the child runs.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fork() -> c_int {
    let next = real!(fork: fn() -> c_int);
    let reserved = reserve(0, crate::pid());
    // SAFETY: libc's fork; in the child the atfork handler claims the reserved slot.
    let child = unsafe { next() };
    match reserved {
        Some(slot) if child > 0 => slot.tid.store(child, Ordering::Release),
        Some(_) if child == 0 => {}
        other => unreserve(other),
    }
    child
}

type SpawnFn = unsafe extern "C" fn(*mut c_int, *const c_char, *const c_void, *const c_void, *const *const c_char, *const *const c_char) -> c_int;

fn spawn_with(pid: *mut c_int, run: impl FnOnce() -> c_int) -> c_int {
    let reserved = reserve(0, sys::getpid());
    let result = run();
    match reserved {
        // SAFETY: posix_spawn wrote the child's pid where the caller asked, if it asked.
        Some(slot) if result == 0 && !pid.is_null() => slot.tid.store(unsafe { *pid }, Ordering::Release),
        other => unreserve(other),
    }
    result
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn posix_spawn(pid: *mut c_int, path: *const c_char, actions: *const c_void, attr: *const c_void, argv: *const *const c_char, envp: *const *const c_char) -> c_int {
    let next = real!(posix_spawn: fn(*mut c_int, *const c_char, *const c_void, *const c_void, *const *const c_char, *const *const c_char) -> c_int);
    let next: SpawnFn = next;
    // SAFETY: passing the caller's arguments through.
    spawn_with(pid, || unsafe { next(pid, path, actions, attr, argv, envp) })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn posix_spawnp(pid: *mut c_int, file: *const c_char, actions: *const c_void, attr: *const c_void, argv: *const *const c_char, envp: *const *const c_char) -> c_int {
    let next = real!(posix_spawnp: fn(*mut c_int, *const c_char, *const c_void, *const c_void, *const *const c_char, *const *const c_char) -> c_int);
    // SAFETY: passing the caller's arguments through.
    spawn_with(pid, || unsafe { next(pid, file, actions, attr, argv, envp) })
}
