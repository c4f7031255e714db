//! The shim's own signal handlers and the program's view of them. SIGSYS (every trapped system
//! call, seccomp.rs) and, in a Go program, SIGSEGV (its `rdtsc`, tsc.rs) stay the shim's:
//! - nobody replaces them: the program's wish is remembered and reported back to it by
//!   sigaction, and a fault that is not the shim's goes to the handler the program wished for;
//! - they stay deliverable: a trapped call (or an `rdtsc`) while its signal is blocked would be
//!   fatal, so the program's signal masks (sigprocmask, sigaction's masks) never include them.

use core::cell::Cell;
use core::ffi::{c_int, c_long, c_void};
use core::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use crate::native;
use crate::sys::{self, nr};

pub(crate) const SIGSYS: c_int = 31;
pub(crate) const SIGSYS_BIT: u64 = 1 << (SIGSYS - 1);
pub(crate) const SIGSEGV: c_int = 11;
const SIGSEGV_BIT: u64 = 1 << (SIGSEGV - 1);
pub(crate) const SIG_SETMASK: i64 = 2;
const EINVAL: c_long = 22;
const SA_SIGINFO: u64 = 4;
const SIG_DFL: usize = 0;
const SIG_IGN: usize = 1;

/// Offsets into the x86_64 `ucontext_t` the kernel passes: the general registers, and the
/// signal mask restored when the handler returns.
#[cfg(target_arch = "x86_64")]
pub(crate) mod context {
    pub const GREGS: usize = 40;
    pub const SIGMASK: usize = 296;
    pub const R8: usize = 0;
    pub const R9: usize = 1;
    pub const R10: usize = 2;
    pub const RDI: usize = 8;
    pub const RSI: usize = 9;
    pub const RDX: usize = 12;
    pub const RAX: usize = 13;
    pub const RCX: usize = 14;
    pub const RSP: usize = 15;
    pub const RIP: usize = 16;
}

/// struct sigaction as the kernel takes it (rt_sigaction, x86_64).
#[repr(C)]
#[derive(Clone, Copy)]
struct KernelSigaction {
    handler: usize,
    flags: u64,
    restorer: usize,
    mask: u64,
}

/// The program's own wish for one of the shim's signals (a `KernelSigaction`'s handler, flags,
/// restorer, mask).
struct Wish([AtomicUsize; 4]);

impl Wish {
    const fn new() -> Self {
        Wish([AtomicUsize::new(0), AtomicUsize::new(0), AtomicUsize::new(0), AtomicUsize::new(0)])
    }

    fn load(&self) -> KernelSigaction {
        let [handler, flags, restorer, mask] = &self.0;
        KernelSigaction { handler: handler.load(Ordering::Relaxed), flags: flags.load(Ordering::Relaxed) as u64, restorer: restorer.load(Ordering::Relaxed), mask: mask.load(Ordering::Relaxed) as u64 }
    }

    fn store(&self, wanted: KernelSigaction) {
        for (slot, value) in self.0.iter().zip([wanted.handler, wanted.flags as usize, wanted.restorer, wanted.mask as usize]) {
            slot.store(value, Ordering::Relaxed);
        }
    }
}

static PROGRAM_SIGSYS: Wish = Wish::new();
static PROGRAM_SIGSEGV: Wish = Wish::new();
static PROGRAM_GIVE_WAY: Wish = Wish::new();
/// Set once the shim's SIGSEGV handler is installed (`keep_sigsegv`).
static SIGSEGV_KEPT: AtomicBool = AtomicBool::new(false);
/// Set once the shim's handler of climbsim's request to give way is installed (`keep_give_way`).
static GIVE_WAY_KEPT: AtomicBool = AtomicBool::new(false);
const GIVE_WAY_BIT: u64 = 1 << (crate::abi::GIVE_WAY_SIGNAL - 1);

/// The program's wish for `signal`, if the shim keeps that signal.
fn wish_for(signal: c_int) -> Option<&'static Wish> {
    match signal {
        SIGSYS => Some(&PROGRAM_SIGSYS),
        SIGSEGV if SIGSEGV_KEPT.load(Ordering::Relaxed) => Some(&PROGRAM_SIGSEGV),
        crate::abi::GIVE_WAY_SIGNAL if GIVE_WAY_KEPT.load(Ordering::Relaxed) => Some(&PROGRAM_GIVE_WAY),
        _ => None,
    }
}

/// The signals the program may never block.
pub(crate) fn kept_signals() -> u64 {
    SIGSYS_BIT | if SIGSEGV_KEPT.load(Ordering::Relaxed) { SIGSEGV_BIT } else { 0 } | if GIVE_WAY_KEPT.load(Ordering::Relaxed) { GIVE_WAY_BIT } else { 0 }
}

/// The shim's SIGSEGV handler (tsc.rs's), kept from here on as SIGSYS's is.
#[cfg(target_arch = "x86_64")]
pub(crate) fn keep_sigsegv(handler: usize) -> Result<(), &'static [u8]> {
    install_own_handler(SIGSEGV, handler).map_err(|_| b"cannot install the SIGSEGV handler for rdtsc".as_slice())?;
    SIGSEGV_KEPT.store(true, Ordering::Relaxed);
    Ok(())
}

/// The handler of climbsim's request to give way (give_way.rs's), kept from here on as SIGSYS's
/// is.
#[cfg(target_arch = "x86_64")]
pub(crate) fn keep_give_way(handler: usize) -> Result<(), &'static [u8]> {
    // What a library's constructor may have set before the shim's: the program's first wish.
    let mut before = KernelSigaction { handler: SIG_DFL, flags: 0, restorer: 0, mask: 0 };
    if native::call4(nr::RT_SIGACTION, crate::abi::GIVE_WAY_SIGNAL as c_long, 0, &mut before as *mut KernelSigaction as c_long, 8) == 0 {
        PROGRAM_GIVE_WAY.store(before);
    }
    install_own_handler(crate::abi::GIVE_WAY_SIGNAL, handler).map_err(|_| b"cannot install the handler that lets climbsim preempt a computing thread".as_slice())?;
    GIVE_WAY_KEPT.store(true, Ordering::Relaxed);
    Ok(())
}

/// The SIGSYS handler.
///
/// The kernel's rt_sigaction from the page, not libc's: after an exec the inherited filter
/// traps sigaction, and there is no handler yet to take the trap. While the handler runs every
/// other signal waits: a wake-up or a wait in a signal handler that interrupted the shim's own
/// queue work would meet its lock. SIGSYS itself stays deliverable (NODEFER), so that what the
/// handler calls may trap again.
#[cfg(target_arch = "x86_64")]
pub(crate) fn install_sigsys(handler: usize) -> Result<(), &'static [u8]> {
    install_own_handler(SIGSYS, handler).map_err(|_| b"cannot install the SIGSYS handler".as_slice())
}

/// One of the shim's handlers (SA_SIGINFO), with every signal but the shim's own blocked while it
/// runs. SA_RESTART: a request to give way that lands in a system call the shim does not follow
/// restarts it where the kernel restarts calls after a handled signal (a read, a write); one
/// it never restarts (a sleep, poll, connect) returns EINTR, as after any signal (climbsim asks
/// only a thread that computed for a quantum since its last followed call). A trap or a fault
/// interrupts no call.
///
/// A Go program's own calls trap on a goroutine's stack, which may have 2 KiB left and which the
/// handler's frames must not overrun: there the handlers run on the signal stack Go gives each
/// of its threads (32 KiB). Elsewhere on the thread's own stack, as a C program's handlers do
/// (Rust's std sets a small signal stack of its own for its overflow report).
#[cfg(target_arch = "x86_64")]
fn install_own_handler(signal: c_int, handler: usize) -> Result<(), ()> {
    const SA_RESTORER: u64 = 0x0400_0000;
    const SA_NODEFER: u64 = 0x4000_0000;
    const SA_ONSTACK: u64 = 0x0800_0000;
    const SA_RESTART: u64 = 0x1000_0000;
    let on_stack = if crate::program::go_text().is_some() { SA_ONSTACK } else { 0 };
    let action =
        KernelSigaction { handler, flags: SA_SIGINFO | SA_NODEFER | SA_RESTART | SA_RESTORER | on_stack, restorer: native::PAGE_ADDRESS + native::RESTORER_OFFSET, mask: !(SIGSYS_BIT | SIGSEGV_BIT) };
    match native::call4(nr::RT_SIGACTION, signal as c_long, &action as *const KernelSigaction as c_long, 0, 8) {
        0 => Ok(()),
        _ => Err(()),
    }
}

/// A fault the shim does not answer goes where the program asked: its handler, called as the
/// kernel would have called it (the context it changes is the one the kernel resumes from); or,
/// by default, the kernel's action (the faulting instruction runs again without the shim's
/// handler, and the kernel ends the process as it would have).
///
/// # Safety
/// The kernel's arguments of a signal being handled.
#[cfg(target_arch = "x86_64")]
pub(crate) unsafe fn forward_to_program(signal: c_int, info: *mut c_void, context: *mut c_void) {
    let Some(wish) = wish_for(signal) else { return };
    let wanted = wish.load();
    match wanted.handler {
        SIG_DFL | SIG_IGN => put_back_default(signal),
        handler if wanted.flags & SA_SIGINFO != 0 => {
            // SAFETY: the program's own three-argument handler.
            let handler = unsafe { core::mem::transmute::<usize, unsafe extern "C" fn(c_int, *mut c_void, *mut c_void)>(handler) };
            // SAFETY: the kernel's arguments, as the kernel would have passed them.
            unsafe { handler(signal, info, context) };
        }
        handler => {
            // SAFETY: the program's own one-argument handler.
            let handler = unsafe { core::mem::transmute::<usize, unsafe extern "C" fn(c_int)>(handler) };
            // SAFETY: as the kernel would have called it.
            unsafe { handler(signal) };
        }
    }
}

/// A signal the shim handles for its own ends that was sent (`kill`, `raise`, another process),
/// not raised by a fault or the filter: the program's, as if the shim were not there. Ignored
/// if the program ignores it; its handler if it has one; by default the kernel's action, for
/// which the default is put back and the signal sent again (it ends the process, as it would
/// have).
///
/// # Safety
/// The kernel's arguments of a signal being handled.
#[cfg(target_arch = "x86_64")]
pub(crate) unsafe fn forward_sent(signal: c_int, info: *mut c_void, context: *mut c_void) {
    let Some(wish) = wish_for(signal) else { return };
    match wish.load().handler {
        SIG_IGN => {}
        // Its default action is to ignore it: nothing to do (and the shim's handler stays).
        SIG_DFL if signal == crate::abi::GIVE_WAY_SIGNAL => {}
        SIG_DFL => take_default_action(signal),
        // SAFETY: the kernel's arguments, for the program's handler.
        _ => unsafe { forward_to_program(signal, info, context) },
    }
}

/// The kernel's default action for `signal` from here on, in place of the shim's handler.
fn put_back_default(signal: c_int) {
    let default = KernelSigaction { handler: SIG_DFL, flags: 0, restorer: 0, mask: 0 };
    native::call4(nr::RT_SIGACTION, signal as c_long, &default as *const KernelSigaction as c_long, 0, 8);
}

/// The default action put back and the signal sent again to this thread: it is taken as the
/// handler returns (it ends the process, as it would have).
fn take_default_action(signal: c_int) {
    put_back_default(signal);
    native::call3(nr::TGKILL, sys::getpid() as c_long, sys::gettid() as c_long, signal as c_long);
}

/// A trap of a seccomp filter of the program's own (RET_TRAP): the program's handler, or, as
/// the kernel forces such a SIGSYS on a program that ignores it, its default action (the
/// process ends).
///
/// # Safety
/// The kernel's arguments of a signal being handled.
#[cfg(target_arch = "x86_64")]
pub(crate) unsafe fn forward_forced(signal: c_int, info: *mut c_void, context: *mut c_void) {
    let Some(wish) = wish_for(signal) else { return };
    match wish.load().handler {
        SIG_IGN | SIG_DFL => take_default_action(signal),
        // SAFETY: the kernel's arguments, for the program's handler.
        _ => unsafe { forward_to_program(signal, info, context) },
    }
}

/// Whether the program's handler for `signal` restarts the calls it interrupts (SA_RESTART);
/// a signal without a handler of the program's interrupts nothing it could restart.
pub(crate) fn restarts(signal: c_int) -> bool {
    const SA_RESTART: u64 = 0x1000_0000;
    let flags = wish_for(signal).map_or_else(|| kernel_action(signal).1, |wish| wish.load().flags);
    flags & SA_RESTART != 0
}

/// The handler and flags the kernel holds for `signal` now (for one the shim keeps, the
/// shim's own).
pub(crate) fn kernel_action(signal: c_int) -> (usize, u64) {
    let mut action = KernelSigaction { handler: SIG_DFL, flags: 0, restorer: 0, mask: 0 };
    native::call4(nr::RT_SIGACTION, signal as c_long, 0, &mut action as *mut KernelSigaction as c_long, 8);
    (action.handler, action.flags)
}

/// rt_sigprocmask inside the SIGSYS handler: the mask in force after the call is the one the
/// kernel restores from the ucontext when the handler returns, so that is the one changed
/// (never with the shim's signals in it).
pub(crate) fn sigprocmask(a: [i64; 6], current: &mut u64) -> c_long {
    const SIG_BLOCK: i64 = 0;
    const SIG_UNBLOCK: i64 = 1;
    let (how, set, old, size) = (a[0], a[1] as *const u64, a[2] as *mut u64, a[3]);
    if size != 8 {
        return -EINVAL;
    }
    let before = *current;
    if !set.is_null() {
        // SAFETY: the caller's sigset (8 bytes, as size says).
        let set = unsafe { *set };
        let after = match how {
            SIG_BLOCK => before | set,
            SIG_UNBLOCK => before & !set,
            SIG_SETMASK => set,
            _ => return -EINVAL,
        };
        // SIGKILL and SIGSTOP cannot be blocked either (the kernel drops them silently).
        *current = after & !(kept_signals() | 1 << 8 | 1 << 18);
    }
    if !old.is_null() {
        // SAFETY: the caller's sigset.
        unsafe { *old = before };
    }
    0
}

/// rt_sigaction: the shim's signals stay the shim's; other handlers run with them deliverable.
pub(crate) fn sigaction_call(a: [i64; 6]) -> c_long {
    let (signal, action, old, size) = (a[0] as c_int, a[1] as *const KernelSigaction, a[2] as *mut KernelSigaction, a[3]);
    if size != 8 {
        return -EINVAL;
    }
    if let Some(wish) = wish_for(signal) {
        let previous = wish.load();
        if !action.is_null() {
            // SAFETY: the caller's sigaction.
            wish.store(unsafe { *action });
        }
        if !old.is_null() {
            // SAFETY: the caller's sigaction.
            unsafe { *old = previous };
        }
        return 0;
    }
    if action.is_null() {
        return native::call6(nr::RT_SIGACTION, a[0], a[1], a[2], a[3], a[4], a[5]);
    }
    // SAFETY: the caller's sigaction.
    let mut cleaned = unsafe { *action };
    cleaned.mask &= !kept_signals();
    native::call4(nr::RT_SIGACTION, signal as c_long, &cleaned as *const KernelSigaction as c_long, old as c_long, size)
}

const SIG_BLOCK: c_long = 0;
/// "Not in the trap handler" (a real mask never holds SIGSYS, so never all ones).
const NO_MASK: u64 = u64::MAX;

thread_local! {
    /// Inside the trap handler: the program's signal mask, which the kernel saved (the
    /// handler's own blocks everything).
    static TRAP_MASK: Cell<u64> = const { Cell::new(NO_MASK) };
}

/// The trap handler starts with the program's mask `mask`; what to give [`left_trap`].
pub(crate) fn entered_trap(mask: u64) -> u64 {
    TRAP_MASK.with(|m| m.replace(mask))
}

pub(crate) fn left_trap(before: u64) {
    TRAP_MASK.with(|m| m.set(before));
}

/// A cancellation point (pthreads(7)), for the shim's own waits that replace glibc's: a
/// deferred cancellation of this thread, asked before the call or while it waited (which ended
/// the wait: see `signals::pthread_cancel`), is acted on here, as glibc acts on it in its own:
/// the thread's stack is unwound from here. Not inside the trap handler (a raw system call is
/// no cancellation point, and an unwinding out of a signal handler would leave its mask, which
/// blocks every signal, on the thread), where the shim's own calls of its interposers end.
pub(crate) fn cancellation_point() {
    if TRAP_MASK.with(Cell::get) == NO_MASK {
        // SAFETY: pthread_testcancel has no preconditions.
        unsafe { sys::pthread_testcancel() }
    }
}

/// The program changed its mask (a trapped sigprocmask), inside the trap handler.
pub(crate) fn set_trap_mask(mask: u64) {
    TRAP_MASK.with(|m| m.set(mask));
}

/// The program's signal mask for this thread now.
pub(crate) fn program_mask() -> u64 {
    let trapped = TRAP_MASK.with(Cell::get);
    if trapped != NO_MASK {
        return trapped;
    }
    let mut mask = 0u64;
    native::call4(nr::RT_SIGPROCMASK, SIG_BLOCK, 0, &mut mask as *mut u64 as c_long, 8);
    mask
}
