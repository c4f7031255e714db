//! A Go program's time-stamp counter, answered from simulated time.
//!
//! Go seeds each thread's random generator from `rdtsc` (`runtime.mcommoninit`), and the
//! generator picks the processor an idle thread steals a goroutine from and a `select`'s case:
//! with the host's counter, each run of a Go controller scheduled its goroutines differently
//! and its time series differed (by tenths of a millisecond over 2 s). So, as Shadow does, the
//! instruction faults (`PR_SET_TSC`, `PR_TSC_SIGSEGV`) and the fault is answered here: a 1 GHz
//! counter that reads the simulated monotonic clock. (The other half of Go's seed, the
//! kernel's 16 random bytes, `program.rs` makes the same in every run.)
//!
//! The program's own SIGSEGV handler (Go's, which turns a nil dereference into a panic) gets
//! every other fault, with the kernel's siginfo and context, as if the kernel had called it.
//! Only Go programs are so treated: a fault costs microseconds, and the flag survives an exec
//! (it is lifted for the exec, and set again should the exec fail).

use core::ffi::{c_int, c_long, c_void};
use core::sync::atomic::{AtomicBool, Ordering};

use crate::native;
use crate::sys::nr;

const PR_SET_TSC: c_long = 26;
const PR_TSC_ENABLE: c_long = 1;
const PR_TSC_SIGSEGV: c_long = 2;

static TRAPPED: AtomicBool = AtomicBool::new(false);

/// Whether this process's `rdtsc` faults into the shim.
fn trapped() -> bool {
    TRAPPED.load(Ordering::Relaxed)
}

/// Make `rdtsc` fault into the shim (a Go program only); from the constructor, single-threaded,
/// so every thread the program creates inherits it.
#[cfg(target_arch = "x86_64")]
pub(crate) fn install() -> Result<(), &'static [u8]> {
    if crate::program::go_text().is_none() {
        return Ok(());
    }
    crate::handlers::keep_sigsegv(on_sigsegv as *const () as usize)?;
    if native::call2(nr::PRCTL, PR_SET_TSC, PR_TSC_SIGSEGV) != 0 {
        return Err(b"the kernel cannot make rdtsc fault (PR_SET_TSC)");
    }
    TRAPPED.store(true, Ordering::Relaxed);
    crate::sys::host_clocks_by_syscall();
    Ok(())
}

/// Around an exec: the counter readable for the new program (`true`), or faulting again after
/// an exec that failed (`false`).
pub(crate) fn around_exec(before: bool) {
    if trapped() {
        native::call2(nr::PRCTL, PR_SET_TSC, if before { PR_TSC_ENABLE } else { PR_TSC_SIGSEGV });
    }
}

/// The counter: the simulated monotonic clock in nanoseconds (the host's, when no run is on).
fn counter() -> u64 {
    match crate::schedule::block::active() {
        Some(shared) => crate::schedule::now::clock_at(shared, crate::sys::CLOCK_MONOTONIC, crate::schedule::now::sim_now(shared)).unwrap_or(0),
        None => crate::schedule::now::real_monotonic_ns(),
    }
}

#[cfg(target_arch = "x86_64")]
unsafe extern "C" fn on_sigsegv(signal: c_int, info: *mut c_void, context: *mut c_void) {
    use crate::handlers::context as regs;
    // A general-protection fault (rdtsc with the flag set) comes as SI_KERNEL.
    const SI_KERNEL: c_int = 0x80;
    // SAFETY: the kernel's siginfo: si_code is its third int.
    let code = unsafe { *info.cast::<c_int>().add(2) };
    // SAFETY: the kernel's ucontext for this signal, x86_64 layout.
    let gregs = unsafe { context.cast::<u8>().add(regs::GREGS).cast::<i64>() };
    if code == SI_KERNEL {
        // SAFETY: the saved instruction pointer, and the instruction there (a fault on it means
        // it is mapped and executable, so readable).
        let rip = unsafe { *gregs.add(regs::RIP) } as *const u8;
        // Each byte is read only once the ones before it say the instruction goes on to it (0f
        // opens a two-byte opcode, 0f 01 a three-byte one): a faulting instruction is mapped
        // whole, the byte after it need not be.
        // SAFETY: the first byte of the faulting instruction, then bytes within it.
        let byte = |at: usize| unsafe { *rip.add(at) };
        let length = match byte(0) {
            0x0f => match byte(1) {
                0x31 => Some(2),
                0x01 if byte(2) == 0xf9 => Some(3),
                _ => None,
            },
            _ => None,
        };
        if let Some(length) = length {
            let saved_errno = native::errno();
            let ticks = counter();
            // SAFETY: writing saved registers within the ucontext: edx:eax the counter, ecx
            // (rdtscp's processor id) 0, and on past the instruction.
            unsafe {
                *gregs.add(regs::RAX) = (ticks & 0xffff_ffff) as i64;
                *gregs.add(regs::RDX) = (ticks >> 32) as i64;
                if length == 3 {
                    *gregs.add(regs::RCX) = 0;
                }
                *gregs.add(regs::RIP) += length;
            }
            native::set_errno(saved_errno);
            return;
        }
    }
    // SAFETY: the kernel's arguments for this signal, passed on.
    unsafe { crate::handlers::forward_to_program(signal, info, context) };
}
