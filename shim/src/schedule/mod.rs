//! A followed thread's side of climbsim's schedule, in one place: everything that reads or
//! changes where a thread stands against climbsim's scheduler, below every call that follows a
//! thread (sleeps, waits, reads, futexes, spawns), which park, charge and read the time through
//! it only. From the bottom up:
//!
//! - `block`: the shared block as this process maps it; whether virtual time still holds;
//!   telling climbsim (`notify_scheduler`), refusing what cannot be followed.
//! - `now`: simulated time as the shim reads it, and the spins' limit on the host's clock.
//! - `held`: the port's replies written ahead of their instants, hidden until then.
//! - `turn`: a thread's turn, waited for and handed on (`HandOn`, which asks the rule of the
//!   turn, `abi::Shared::who_decides`).
//! - `slot`: a thread's slot, claimed, reserved, started in its turn, exited.
//! - `delivery`: the signals climbsim fired for a thread, sent by the thread to itself.
//! - `park`: charges and parks, and the looks at what the kernel wakes.
//!
//! A slot's state itself is changed only through `abi/protocol.rs`'s transitions.

pub(crate) mod block;
#[cfg(target_arch = "x86_64")]
pub(crate) mod delivery;
/// Signals are followed with the system calls, on x86_64 only.
#[cfg(not(target_arch = "x86_64"))]
pub(crate) mod delivery {
    pub(crate) fn take_due(_: &crate::abi::Slot) -> bool {
        false
    }
    pub(crate) fn interrupted_by() -> Option<core::ffi::c_int> {
        None
    }
}
pub(crate) mod held;
pub(crate) mod now;
pub(crate) mod park;
pub(crate) mod slot;
pub(crate) mod turn;
