//! Waiting for a child process. The kernel wakes the parent; meanwhile it counts as blocked, so
//! that the child (a followed process itself) can run on. A child that ends makes its waiting
//! parent ready before it goes, so that time does not move between the child's end and the
//! parent's return.

use core::ffi::{c_int, c_void};
use core::sync::atomic::Ordering;

use crate::abi::{NEVER, Parked, Shared, Wait, call, state};
use crate::schedule::block::{active, notify_scheduler};
use crate::schedule::park::{charge, note_call};
use crate::schedule::slot::my_slot;
use crate::sys::real;

const WNOHANG: c_int = 1;

/// Run the real wait `wait` for `child` (-1: any) as a blocked thread. The real call is the
/// shim's own (a trap of it goes to the kernel, with the program's signal mask).
fn blocked_in_wait<T>(options: c_int, child: i64, wait: impl FnOnce() -> T) -> T {
    let wait = || {
        let _own = crate::sys::OwnCalls::enter();
        wait()
    };
    let Some(shared) = active() else { return wait() };
    note_call(shared, call::WAIT_CHILD);
    let slot = my_slot();
    // A child that has said it ends is waited for as a call that returns at once: the kernel is
    // through with its exit within microseconds, and time must not move meanwhile. (Parked, the
    // parent of a vfork child whose exec failed would see time move: the kernel lets that
    // parent go as the child ends, before its waitpid can be woken by it.)
    if options & WNOHANG != 0 || slot.is_none() || (child > 0 && said_it_ends(shared, child as i32)) {
        charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
        return wait();
    }
    let slot = slot.expect("checked above");
    crate::schedule::park::publish_state(slot, Parked::Blocked, NEVER, Wait::Child(child));
    notify_scheduler(shared);
    let result = wait();
    slot.wait_over();
    crate::schedule::turn::resume_after_kernel_wake(shared, slot);
    result
}

/// The status a wait reported for a child (`wait`'s `status`): if the child was killed by
/// SIGSYS, the run fails saying so. A statically linked program inherits the run's filter but
/// not the shim that answers it, so its first followed call kills it; its parent may well
/// carry on as if nothing had happened, and the run passed.
fn check_ended(pid: c_int, status: *const c_int) {
    const SIGSYS: c_int = 31;
    if pid > 0
        && !status.is_null()
        && let Some(status) = crate::sys::read_from_program(status)
        && status & 0x7f == SIGSYS
    {
        crate::schedule::block::refuse(crate::abi::refused::KILLED_BY_SIGSYS);
    }
}

/// [`check_ended`] for `waitid`'s answer (`siginfo_t`: si_code CLD_KILLED or CLD_DUMPED, and
/// the signal in si_status).
fn check_ended_info(rc: c_int, info: *const c_void) {
    const CLD_KILLED: i32 = 2;
    const CLD_DUMPED: i32 = 3;
    if rc == 0
        && !info.is_null()
        && let Some(words) = crate::sys::read_from_program(info.cast::<[i32; 7]>())
        && words[4] != 0
        && (words[2] == CLD_KILLED || words[2] == CLD_DUMPED)
    {
        // (si_pid is 0 when WNOHANG found no child.)
        let status = words[6];
        check_ended(words[4], &status);
    }
}

/// Child `pid` of this process has said that it ends: every slot of it is marked exited.
fn said_it_ends(shared: &Shared, pid: i32) -> bool {
    let me = crate::sys::getpid();
    let mut its = shared.live_slots().iter().filter(|s| s.pid.load(Ordering::Relaxed) == pid && s.parent.load(Ordering::Relaxed) == me && s.state() != state::FREE).peekable();
    its.peek().is_some() && its.all(|s| s.state() == state::EXITED)
}

/// This process is ending: a parent waiting for it runs again from now.
pub(crate) fn wake_waiting_parent(shared: &Shared, pid: i32, parent: i32) {
    for slot in shared.live_slots() {
        // The state first (Acquire): the wait read after it is the one its park published.
        if slot.pid.load(Ordering::Relaxed) != parent || slot.state() != state::BLOCKED {
            continue;
        }
        let Wait::Child(awaited) = slot.wait() else { continue };
        if awaited <= 0 || awaited == i64::from(pid) {
            slot.make_ready(None);
        }
    }
}

/// A trapped `wait4` or `waitid` (`number`, with the kernel's arguments `a`) whose real call is
/// `real`: the kernel's return, a negative errno on failure.
pub(crate) fn trapped_wait(number: i64, a: [i64; 6], real: impl FnOnce() -> core::ffi::c_long) -> core::ffi::c_long {
    const P_PID: i64 = 1;
    let (options, child) = if number == crate::sys::nr::WAITID { (a[3] as c_int, if a[0] == P_PID { a[1] } else { -1 }) } else { (a[2] as c_int, i64::from(a[0] as c_int)) };
    let rc = blocked_in_wait(options, child, real);
    if number == crate::sys::nr::WAITID {
        check_ended_info(rc as c_int, a[2] as *const c_void);
    } else {
        check_ended(rc as c_int, a[1] as *const c_int);
    }
    rc
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn waitpid(pid: c_int, status: *mut c_int, options: c_int) -> c_int {
    let next = real!(waitpid: fn(c_int, *mut c_int, c_int) -> c_int);
    // SAFETY: passing the caller's arguments through.
    let ended = blocked_in_wait(options, i64::from(pid), || unsafe { next(pid, status, options) });
    check_ended(ended, status);
    ended
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn wait4(pid: c_int, status: *mut c_int, options: c_int, usage: *mut c_void) -> c_int {
    let next = real!(wait4: fn(c_int, *mut c_int, c_int, *mut c_void) -> c_int);
    // SAFETY: passing the caller's arguments through.
    let ended = blocked_in_wait(options, i64::from(pid), || unsafe { next(pid, status, options, usage) });
    check_ended(ended, status);
    ended
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn wait(status: *mut c_int) -> c_int {
    let next = real!(wait: fn(*mut c_int) -> c_int);
    // SAFETY: passing the caller's argument through.
    let ended = blocked_in_wait(0, -1, || unsafe { next(status) });
    check_ended(ended, status);
    ended
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn waitid(kind: c_int, id: u32, info: *mut c_void, options: c_int) -> c_int {
    let next = real!(waitid: fn(c_int, u32, *mut c_void, c_int) -> c_int);
    const P_PID: c_int = 1;
    let child = if kind == P_PID { i64::from(id) } else { -1 };
    // SAFETY: passing the caller's arguments through.
    let rc = blocked_in_wait(options, child, || unsafe { next(kind, id, info, options) });
    check_ended_info(rc, info);
    rc
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn wait3(status: *mut c_int, options: c_int, usage: *mut c_void) -> c_int {
    let next = real!(wait3: fn(*mut c_int, c_int, *mut c_void) -> c_int);
    // SAFETY: passing the caller's arguments through.
    let ended = blocked_in_wait(options, -1, || unsafe { next(status, options, usage) });
    check_ended(ended, status);
    ended
}
