//! New programs. A process about to exec (often a vfork child, which shares its parent's memory
//! and thread-locals, so only the shared block is touched here) reserves a slot for its task
//! first: its parent may block in waitpid at once, and time must not move before the new
//! program has loaded the shim and claimed the slot. posix_spawn reserves one for the child it
//! will make.

use core::ffi::{c_char, c_int, c_void};
use core::sync::atomic::Ordering;

use crate::abi::{Shared, Slot, state};
use crate::native;
use crate::schedule::block::shared;
use crate::sys::{self, real};

/// Reserve a free slot for task `tid` of a program to come (`tid` 0: a child of `parent`
/// whose id is not known yet).
fn reserve(tid: i32, parent: i32) -> Option<&'static Slot> {
    let shared = shared()?;
    if shared.header.mode.load(Ordering::Acquire) != crate::abi::mode::VIRTUAL {
        return None;
    }
    // The task may hold a slot already (a followed process that execs): it keeps it.
    if tid != 0 && shared.live_slots().iter().any(|s| s.tid.load(Ordering::Relaxed) == tid && matches!(s.state(), state::RUNNING | state::RESERVED)) {
        return None;
    }
    // A child of posix_spawn (whose exec glibc makes inside, where only the trap sees it) finds
    // the slot its parent reserved for it before the clone: it is this task's, not a second one.
    if tid != 0 {
        let parent = sys::getppid();
        if let Some(ours) = shared.live_slots().iter().find(|s| s.state() == state::RESERVED && s.tid.load(Ordering::Relaxed) == 0 && s.pid.load(Ordering::Relaxed) == parent) {
            ours.tid.store(tid, Ordering::Release);
            return None;
        }
    }
    let (_, slot) = crate::schedule::slot::take_free_slot(shared, Slot::reserve_unused)?;
    slot.pid.store(if tid == 0 { parent } else { tid }, Ordering::Relaxed);
    // The program to come is a child of `parent` (fork, posix_spawn), or of this process's
    // parent (an exec: the same process).
    slot.parent.store(if tid == 0 { parent } else { sys::getppid() }, Ordering::Relaxed);
    slot.tid.store(tid, Ordering::Release);
    Some(slot)
}

/// An exec failed: the reservation goes.
fn unreserve(slot: Option<&'static Slot>) {
    if let Some(slot) = slot
        && slot.unreserve()
        && let Some(shared) = shared()
    {
        crate::schedule::block::notify_scheduler(shared);
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
        // An exec from a thread other than the main one: the kernel gives the thread the
        // process's id as it execs, and the new program's main thread takes on its slot under
        // that id (see `slot::exit_earlier_image`), in its turn, as a single-threaded process's
        // exec does.
        let pid = sys::getpid();
        let taken_on = shared().filter(|_| tid != pid).and_then(|shared| shared.live_slots().iter().find(|s| s.tid.load(Ordering::Relaxed) == tid && s.state() == state::RUNNING));
        if let Some(slot) = taken_on {
            slot.tid.store(pid, Ordering::Release);
        }
        let result = run();
        // Still here: the exec failed.
        if let Some(slot) = taken_on {
            slot.tid.store(tid, Ordering::Release);
        }
        unreserve(reserved);
        return result;
    }
    let Some(shared) = shared() else { return run() };
    // An exec made inside another of this task's (libc's execve, whose own call traps): the
    // outer one has said it all.
    if shared.live_slots().iter().any(|s| s.tid.load(Ordering::Relaxed) == tid && s.state() == state::EXITED && s.exec_marker_fd.load(Ordering::Acquire) > 0) {
        return run();
    }
    // The new program will not delete its earlier image's timers itself (see `init`). (Should
    // the exec fail, they are gone: an edge left as it is.)
    crate::signals::delete_posix_timers_of(sys::getpid());
    let mine = shared.live_slots().iter().find(|s| s.tid.load(Ordering::Relaxed) == tid && matches!(s.state(), state::RUNNING | state::RESERVED));
    let marker = crate::marker::exec_marker();
    // Exited, and no longer this process's: a parent waiting for it waits on the real world.
    // A task without a slot (a vfork child, which runs on its parent's) takes one to say so.
    let leaving = match mine {
        Some(slot) => Some((slot, slot.state(), slot.pid.swap(0, Ordering::AcqRel))),
        None if marker > 0 => slot_of_its_own(shared, tid, 0, 0).map(|slot| (slot, state::FREE, 0)),
        None => None,
    };
    if let Some((slot, _, _)) = leaving {
        say_left(shared, slot, marker.max(0));
    }
    let result = run();
    // Still here: the exec failed.
    if let Some((slot, state_before, pid_before)) = leaving {
        // Before the marker closes: climbsim, seeing it closed, must not take this for the
        // exec's end (see `Slot::exec_marker_fd`).
        slot.exec_marker_fd.store(0, Ordering::Release);
        if state_before == state::FREE {
            slot.tid.store(0, Ordering::Relaxed);
        }
        slot.pid.store(pid_before, Ordering::Relaxed);
        slot.exec_failed(state_before);
    }
    if marker > 0 {
        native::call1(sys::nr::CLOSE, marker.into());
    }
    result
}

/// A free slot for task `tid` of process `pid`, child of `parent` (both 0: no longer a followed
/// process's), which has none of its own (a vfork child runs on its parent's), to say that it
/// leaves.
fn slot_of_its_own(shared: &Shared, tid: i32, pid: i32, parent: i32) -> Option<&Slot> {
    let (_, slot) = crate::schedule::slot::take_free_slot(shared, Slot::reserve_unused)?;
    slot.parent.store(parent, Ordering::Relaxed);
    slot.pid.store(pid, Ordering::Relaxed);
    slot.tid.store(tid, Ordering::Relaxed);
    Some(slot)
}

/// `slot`'s task has left the followed world, now (an exec's `marker`, 0: none): climbsim waits
/// until it is gone, or its exec over, before it asks the waiters on the real world to look.
fn say_left(shared: &Shared, slot: &Slot, marker: c_int) {
    slot.exec_marker_fd.store(marker, Ordering::Relaxed);
    slot.exited_ns.store(crate::schedule::now::sim_now(shared), Ordering::Relaxed);
    slot.exit();
    crate::schedule::block::notify_scheduler(shared);
}

/// A vfork child ends (`_exit`, after an exec that failed): its parent, which the kernel lets
/// go as the child lets go of its memory, may wait for the end of a pipe the child still holds
/// (Python's `subprocess` reads why the exec failed until then), which the kernel releases only
/// as the child becomes a zombie. The child says it is going away in a slot of its own, and
/// climbsim waits until it has gone; so does its parent's waitpid for it (see `children.rs`).
pub(crate) fn vfork_child_exits() {
    if let Some(shared) = crate::schedule::block::active()
        && let Some(slot) = slot_of_its_own(shared, sys::gettid(), sys::getpid(), sys::getppid())
    {
        say_left(shared, slot, 0);
    }
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
    let reserved = reserve(0, crate::schedule::block::pid());
    // SAFETY: libc's fork; in the child the atfork handler claims the reserved slot.
    let child = unsafe { next() };
    match reserved {
        Some(slot) if child > 0 => known_child(slot, child),
        Some(_) if child == 0 => {}
        other => unreserve(other),
    }
    child
}

/// The child a slot was reserved for is `child`: its task, and its process (until then the
/// parent's, by which a child that looks before this finds it). The task first: a child that
/// looks in between finds the slot by it. climbsim looks the task up as /proc/PID/task/TID,
/// and with the parent's pid it found no such task: it judged the child gone and its slot
/// exited, and the child ran unfollowed (seen under load: a shell's `$(…)` let time move while
/// the shell waited for the output).
fn known_child(slot: &Slot, child: c_int) {
    slot.tid.store(child, Ordering::Release);
    slot.pid.store(child, Ordering::Release);
}

type SpawnFn = unsafe extern "C" fn(*mut c_int, *const c_char, *const c_void, *const c_void, *const *const c_char, *const *const c_char) -> c_int;

fn spawn_with(pid: *mut c_int, run: impl FnOnce() -> c_int) -> c_int {
    let reserved = reserve(0, sys::getpid());
    let result = run();
    match reserved {
        // SAFETY: posix_spawn wrote the child's pid where the caller asked, if it asked.
        Some(slot) if result == 0 && !pid.is_null() => known_child(slot, unsafe { *pid }),
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

/// This process's own `LD_PRELOAD=…` entry, as its environment held it at the start (the string
/// stays where it is even if the program unsets it).
static PRELOAD_ENTRY: core::sync::atomic::AtomicPtr<c_char> = core::sync::atomic::AtomicPtr::new(core::ptr::null_mut());

const PRELOAD: &[u8] = b"LD_PRELOAD=";

/// Whether the C string `text` starts with `prefix`.
fn starts_with(text: *const c_char, prefix: &[u8]) -> bool {
    // SAFETY: a NUL-terminated string; the comparison stops at its NUL (which no prefix holds).
    (0..prefix.len()).all(|i| unsafe { *text.add(i) } as u8 == prefix[i])
}

fn c_len(text: *const c_char) -> usize {
    let mut len = 0;
    // SAFETY: a NUL-terminated string.
    while unsafe { *text.add(len) } != 0 {
        len += 1;
    }
    len
}

/// Whether the C string `haystack` contains the bytes `needle`.
fn contains(haystack: *const c_char, needle: &[u8]) -> bool {
    let len = c_len(haystack);
    // SAFETY: `len` bytes of a NUL-terminated string.
    let bytes = unsafe { core::slice::from_raw_parts(haystack.cast::<u8>(), len) };
    !needle.is_empty() && bytes.windows(needle.len()).any(|w| w == needle)
}

/// Remember this process's shim entries (from the constructor).
pub(crate) fn remember_shim_environment() {
    // SAFETY: libc's environment at start-up, a NULL-terminated array of C strings.
    let mut entry = unsafe { environ };
    if entry.is_null() {
        return;
    }
    // SAFETY: as above.
    unsafe {
        while !(*entry).is_null() {
            if starts_with(*entry, PRELOAD) {
                PRELOAD_ENTRY.store((*entry).cast_mut(), Ordering::Relaxed);
            }
            entry = entry.add(1);
        }
    }
}

/// `envp` with the shim in it: under the filter a program without the shim would die at its
/// first followed call (the filter outlives the exec), so an environment that dropped
/// `LD_PRELOAD` (or the shim from it) gets it back. One that dropped `CLIMBSIM_VT` keeps it
/// dropped: its program runs on the wall clock as asked, its shim only passing the trapped calls
/// through. The new array lives in fresh pages (never the heap: this may be a vfork child); the
/// exec replaces them.
fn with_shim(envp: *const *const c_char) -> *const *const c_char {
    let preload = PRELOAD_ENTRY.load(Ordering::Relaxed);
    if preload.is_null() {
        return envp;
    }
    // SAFETY: our own entry, a C string.
    let shim_value = unsafe { core::slice::from_raw_parts(preload.cast::<u8>().add(PRELOAD.len()), c_len(preload) - PRELOAD.len()) };
    let mut count = 0;
    let mut their_preload = core::ptr::null::<c_char>();
    if !envp.is_null() {
        // SAFETY: the exec's environment, a NULL-terminated array of C strings.
        unsafe {
            while !(*envp.add(count)).is_null() {
                let text = *envp.add(count);
                if starts_with(text, PRELOAD) {
                    their_preload = text;
                }
                count += 1;
            }
        }
    }
    let preload_ok = !their_preload.is_null() && contains(their_preload, shim_value);
    if preload_ok {
        return envp;
    }
    // The new LD_PRELOAD: ours, then theirs if they had one.
    let theirs_len = if their_preload.is_null() { 0 } else { c_len(their_preload) - PRELOAD.len() };
    let string_bytes = PRELOAD.len() + shim_value.len() + 1 + theirs_len + 1;
    let array_bytes = (count + 2) * core::mem::size_of::<*const c_char>();
    let Some(memory) = sys::fresh_pages(array_bytes + string_bytes) else { return envp };
    let array = memory.cast::<*const c_char>();
    // SAFETY: `memory` holds array_bytes + string_bytes writable bytes; the sources are C strings.
    unsafe {
        let combined = memory.add(array_bytes);
        let mut at = 0;
        for part in [PRELOAD, shim_value] {
            core::ptr::copy_nonoverlapping(part.as_ptr(), combined.add(at), part.len());
            at += part.len();
        }
        if theirs_len > 0 {
            *combined.add(at) = b':';
            core::ptr::copy_nonoverlapping(their_preload.cast::<u8>().add(PRELOAD.len()), combined.add(at + 1), theirs_len);
            at += 1 + theirs_len;
        }
        *combined.add(at) = 0;
        let mut out = 0;
        *array.add(out) = combined.cast::<c_char>();
        out += 1;
        for i in 0..count {
            let text = *envp.add(i);
            if !starts_with(text, PRELOAD) {
                *array.add(out) = text;
                out += 1;
            }
        }
        *array.add(out) = core::ptr::null();
    }
    array.cast_const()
}

/// An exec trapped by the filter (execve, or execveat with `at` = (dirfd, flags)): with the shim
/// in its environment, and a slot for the program to come; what the system call returns.
pub(crate) fn exec_trapped(path: usize, argv: usize, envp: usize, at: Option<(i64, i64)>) -> i64 {
    let envp = with_shim(envp as *const *const c_char);
    let mut result = 0;
    crate::tsc::around_exec(true);
    exec_with(envp, || {
        result = match at {
            Some((dirfd, flags)) => crate::native::call6(sys::nr::EXECVEAT, dirfd, path as i64, argv as i64, envp as i64, flags, 0),
            None => crate::native::call3(sys::nr::EXECVE, path as i64, argv as i64, envp as i64),
        };
        if result < 0 { -1 } else { 0 }
    });
    crate::tsc::around_exec(false);
    result
}
