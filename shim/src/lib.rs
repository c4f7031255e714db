//! climbsim's preload for `--clock virtual`: it puts an unchanged controller process (every
//! thread, every child that keeps `LD_PRELOAD`) on the simulation's clock.
//!
//! - Clock reads answer from the shared block (`abi/`), no system call.
//! - Sleeps and waits publish "blocked until T, waiting on the port / a sensor connection" and
//!   sleep on a futex until climbsim releases them: at T, or when their data is there.
//! - Every other intercepted call costs a small charge of simulated time, so that a loop that
//!   only spins still moves time (Shadow's `model_unblocked_syscall_latency`); a zero-timeout
//!   poll of an empty port jumps to the next reply byte due.
//!
//! Dormant (every call goes straight to libc) unless `CLIMBSIM_VT` names a block. The model and
//! what is intercepted: docs/virtual-time.md.
//!
//! Rules for this code: never call anything that is itself intercepted (std's time, sleep, I/O)
//! except through `real!`; no allocation; thread-locals are `const`-initialised plain cells.

#![allow(clippy::missing_safety_doc)]

pub mod abi;
mod children;
mod epoll;
mod futex;
mod give_way;
mod growing;
mod handlers;
mod io;
#[cfg(target_arch = "x86_64")]
mod ipc;
mod maps;
mod marker;
mod native;
mod net;
mod port_ring;
mod program;
mod room;
mod schedule;
mod seccomp;
#[cfg(target_arch = "x86_64")]
mod signals;
/// Signals are followed with the system calls, on x86_64 only.
#[cfg(not(target_arch = "x86_64"))]
mod signals {
    pub(crate) fn delete_posix_timers_of(_: i32) {}
    /// The waits of the pselect family keep the program's mask while they wait.
    pub(crate) struct WaitMask;
    impl WaitMask {
        pub(crate) fn enter(_: *const core::ffi::c_void) -> Result<Self, core::ffi::c_int> {
            Ok(WaitMask)
        }
        pub(crate) fn leave(self, rc: core::ffi::c_int) -> core::ffi::c_int {
            rc
        }
    }
}
mod spawn;
mod sync;
mod sys;
mod time;
mod timerfd;
#[cfg(target_arch = "x86_64")]
mod tsc;
/// rdtsc is answered on x86_64 only.
#[cfg(not(target_arch = "x86_64"))]
mod tsc {
    pub(crate) fn around_exec(_: bool) {}
}
#[cfg(target_arch = "x86_64")]
mod vdso;
mod wait;

use core::ffi::{c_char, c_int, c_void};
use core::sync::atomic::Ordering;

use abi::state;
use sys::real;

/// Map the block named by `CLIMBSIM_VT`. Runs before `main` in every process that preloads the
/// shim, with the arguments glibc's loader gives every `.init_array` entry.
extern "C" fn init(_argc: c_int, _argv: *const *const c_char, envp: *const *const c_char) {
    // SAFETY: getenv with a NUL-terminated name; the result is a C string or null.
    let path = unsafe { sys::getenv(c"CLIMBSIM_VT".as_ptr()) };
    if path.is_null() {
        // Dormant; but a program exec'd by a followed one that dropped CLIMBSIM_VT (to run on
        // the wall clock) inherits the seccomp filter, and its trapped calls need the handler.
        if seccomp::inherited() {
            // First: climbsim holds time until the exec that started this program is over.
            marker::close_inherited_exec_marker();
            let _ = program::inspect(envp, false);
            spawn::remember_shim_environment();
            if let Err(why) = seccomp::install_passthrough() {
                say_failure(why, b"");
            }
        }
        return;
    }
    schedule::block::note_pid();
    if let Err(why) = schedule::block::map(path) {
        say_failure(why, b"; the controller runs on the wall clock, which climbsim will report");
        return;
    }
    // SAFETY: registering plain C callbacks.
    unsafe {
        let mut key = 0u32;
        if sys::pthread_key_create(&mut key, Some(thread_exited)) == 0 {
            schedule::slot::set_exit_key(key);
        }
        sys::__register_atfork(None, None, Some(forked_child), core::ptr::null_mut());
        sys::__cxa_atexit(process_exiting, core::ptr::null_mut(), core::ptr::null_mut());
    }
    // A new program (after an exec) has no POSIX timers: those its earlier image made go.
    signals::delete_posix_timers_of(sys::getpid());
    spawn::resolve_exec_functions();
    spawn::remember_shim_environment();
    if let Some(vdso) = program::inspect(envp, true) {
        patch_vdso(&vdso);
    }
    if let Err(why) = seccomp::install() {
        say_failure(why, b"; only calls through libc's symbols are followed");
    }
    if let Err(why) = give_way::install() {
        say_failure(why, b"; a thread that computes without a followed call keeps its turn");
    }
    #[cfg(target_arch = "x86_64")]
    if let Err(why) = tsc::install() {
        say_failure(why, b"; the time-stamp counter is the host's");
    }
    // The main thread is followed from the start: before its first call it is already running.
    schedule::slot::exit_earlier_image();
    schedule::slot::my_slot();
}

/// The vDSO's clocks patched to the shim's, or the vDSO hidden (`program.rs`).
#[cfg(target_arch = "x86_64")]
fn patch_vdso(vdso: &program::VdsoEntry) {
    if let Err(why) = vdso::patch(vdso.image) {
        vdso.hide();
        say_failure(why, b"; it is hidden, and a runtime that reads it itself traps every clock read");
    }
}

/// Elsewhere the vDSO is hidden: such a runtime's clock reads trap.
#[cfg(not(target_arch = "x86_64"))]
fn patch_vdso(vdso: &program::VdsoEntry) {
    vdso.hide();
}

/// A line on stderr: what the shim could not do at start (`why`), and what follows from it.
fn say_failure(why: &[u8], so: &[u8]) {
    sys::say(b"climbsim shim: ");
    sys::say(why);
    sys::say(so);
    sys::say(b"\n");
}

#[used]
#[unsafe(link_section = ".init_array")]
static INIT: extern "C" fn(c_int, *const *const c_char, *const *const c_char) = init;

unsafe extern "C" fn thread_exited(_: *mut c_void) {
    sync::thread_ending();
    futex::robust_list_ends();
    if let Some(slot) = schedule::slot::claimed_slot() {
        schedule::slot::exit_slot(slot);
        schedule::slot::forget_ended_slot();
    }
}

/// The process is ending (exit or return from main): every thread of it stops with it.
unsafe extern "C" fn process_exiting(_: *mut c_void) {
    let Some(shared) = schedule::block::shared() else { return };
    let pid = sys::getpid();
    futex::robust_lists_of_process_end(pid);
    net::forget_process(shared, pid);
    children::wake_waiting_parent(shared, pid, sys::getppid());
    // This thread's own slot last: until then it runs, so climbsim decides nothing on a
    // process half marked (it would move time to the deadline of a thread not yet marked).
    let own = schedule::slot::my_slot();
    for slot in shared.live_slots() {
        if slot.pid.load(Ordering::Relaxed) == pid && slot.state() != state::FREE && !own.is_some_and(|own| core::ptr::eq(own, slot)) {
            schedule::slot::exit_slot(slot);
        }
    }
    if let Some(own) = own {
        schedule::slot::exit_slot(own);
    }
}

/// `_exit` (and C's `_Exit`): the process ends without its atexit handlers, so it says first
/// that its threads are gone. Otherwise climbsim finds out only from `/proc` (every 50 ms), and
/// each such child cost its parent's waitpid that much wall time.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn _exit(status: c_int) -> ! {
    leaving_without_atexit();
    let next = real!(_exit: fn(c_int) -> !);
    // SAFETY: libc's _exit with the caller's status.
    unsafe { next(status) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn _Exit(status: c_int) -> ! {
    leaving_without_atexit();
    let next = real!(_Exit: fn(c_int) -> !);
    // SAFETY: libc's _Exit with the caller's status.
    unsafe { next(status) }
}

fn leaving_without_atexit() {
    // A vfork child shares its parent's memory (this thread's slot is its parent's): its
    // parent goes on as the kernel resumes it; the child says it goes in a slot of its own.
    if schedule::block::pid() == sys::getpid() {
        // SAFETY: the same callback atexit would have run.
        unsafe { process_exiting(core::ptr::null_mut()) };
    } else {
        spawn::vfork_child_exits();
    }
}

/// A forked child is a new process: its threads claim slots of their own. It starts in its
/// turn, as a new thread does: its parent runs on until it parks, so that what the two do
/// (print to one log, say) does not interleave as the host scheduled them.
unsafe extern "C" fn forked_child() {
    schedule::block::note_pid();
    schedule::slot::forget_slot();
    schedule::turn::forget_charges();
    // Its slot, claimed now, waits for its turn there.
    schedule::slot::my_slot();
}
