//! A running thread that climbsim asks to give way: it has computed for a quantum of its CPU
//! time without a followed call (a spin on a flag, a lock-free queue polled), and climbsim's
//! scheduler sent it [`abi::GIVE_WAY_SIGNAL`] (src/virtual_time/preempt.rs measures). Its
//! handler parks the thread by the one rule, `Shared::give_way`, in the thread's own turn.
//!
//! Only where a park is safe: not in the shim's own code (a park there could take the turn
//! while the thread holds something of the shim's, or is half-way through its own park), nor
//! in a system call the shim makes for it. Asked there, it does nothing: either it makes a call
//! (and the question is stale), or climbsim asks again after another quantum.

use core::ffi::{c_int, c_void};
use core::sync::atomic::{AtomicU64, Ordering};

use crate::abi::{self, GiveWay, Parked, Shared, Slot, Wait};
use crate::schedule::block::active;
use crate::schedule::now::sim_now;
use crate::schedule::park::{park, take_computation};
use crate::schedule::slot::claimed_slot;
use crate::{handlers, native, sys};

/// Install the handler (once the block is mapped, in every followed process). What the
/// handler needs that is not async-signal-safe to find is found here: where the shim's code
/// lies, and libc's clock (resolved with dlsym at its first use), which a park reads.
#[cfg(target_arch = "x86_64")]
pub(crate) fn install() -> Result<(), &'static [u8]> {
    let text = crate::program::shim_text().ok_or(b"cannot find the shim's own code in its program headers".as_slice())?;
    SHIM_TEXT[0].store(text.0, Ordering::Relaxed);
    SHIM_TEXT[1].store(text.1, Ordering::Relaxed);
    let _ = crate::schedule::now::real_monotonic_ns();
    handlers::keep_give_way(on_give_way as *const () as usize)
}

/// The shim's own text (start, end).
static SHIM_TEXT: [AtomicU64; 2] = [AtomicU64::new(0), AtomicU64::new(0)];

fn in_shim_text(address: u64) -> bool {
    let (start, end) = (SHIM_TEXT[0].load(Ordering::Relaxed), SHIM_TEXT[1].load(Ordering::Relaxed));
    let page = native::PAGE_ADDRESS as u64;
    (start..end).contains(&address) || (page..page + native::PAGE_BYTES as u64).contains(&address)
}

#[cfg(target_arch = "x86_64")]
unsafe extern "C" fn on_give_way(signal: c_int, info: *mut c_void, context: *mut c_void) {
    let shared = active();
    if !shared.is_some_and(|shared| sent_by_climbsim(shared, info)) {
        // SAFETY: the kernel's arguments of this signal.
        unsafe { handlers::forward_sent(signal, info, context) };
        return;
    }
    // SAFETY: the kernel's ucontext for this signal, x86_64 layout.
    let rip = unsafe { *context.cast::<u8>().add(handlers::context::GREGS).cast::<u64>().add(handlers::context::RIP) };
    let Some(shared) = shared else { return };
    if sys::in_shim() || in_shim_text(rip) {
        return;
    }
    let saved_errno = native::errno();
    {
        let _own = sys::OwnCalls::enter();
        give_way(shared);
    }
    native::set_errno(saved_errno);
}

/// Whether the signal came from climbsim's tgkill (not the program's own raise, nor a kill
/// from elsewhere, which go where the program wished).
#[cfg(target_arch = "x86_64")]
fn sent_by_climbsim(shared: &Shared, info: *mut c_void) -> bool {
    const SI_TKILL: c_int = -6;
    // SAFETY: the kernel's siginfo: si_signo, si_errno, si_code, padding, then the sender's pid.
    let (code, pid) = unsafe { (*info.cast::<c_int>().add(2), *info.cast::<c_int>().add(4)) };
    code == SI_TKILL && pid == shared.header.climbsim_pid.load(Ordering::Relaxed)
}

/// Give way as `Shared::give_way` says, if this thread still has its turn and made no call
/// since it was asked.
fn give_way(shared: &Shared) {
    let Some(slot) = claimed_slot() else { return };
    if slot.handing.load(Ordering::Acquire) != 0 {
        return;
    }
    let now = sim_now(shared);
    // (Running on, its computation under --controller-cpu is charged at its next call.)
    let until = match shared.give_way(slot, now) {
        GiveWay::Stale | GiveWay::KeepOn => return,
        GiveWay::ToReady => now,
        GiveWay::Until(until) => until,
    };
    // With --controller-cpu its computation costs its CPU time × F, as at its next call: it is
    // ready again once that is over (the threads ready or due before then run first).
    let until = match take_computation(shared) {
        0 => until,
        ns => now.saturating_add(ns),
    };
    count_giving_way(shared, slot);
    park(shared, Parked::Yielded, until, Wait::Turn);
}

/// The thread gives way now: climbsim's question is answered, and measured again from here.
fn count_giving_way(shared: &Shared, slot: &Slot) {
    slot.give_way_asked.store(0, Ordering::Relaxed);
    slot.gave_way.fetch_add(1, Ordering::Release);
    shared.header.turns.gave_way.fetch_add(1, Ordering::Relaxed);
}

#[cfg(not(target_arch = "x86_64"))]
pub(crate) fn install() -> Result<(), &'static [u8]> {
    Ok(())
}

/// SIGWINCH, whose default action is to ignore it (see `abi::GIVE_WAY_SIGNAL`).
const _: () = assert!(abi::GIVE_WAY_SIGNAL == 28);
