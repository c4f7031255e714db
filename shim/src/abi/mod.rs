//! The shared-memory block between climbsim and the shim in each controller process, compiled
//! into both (climbsim includes this folder by path), so that the two always agree; the ABI
//! number guards against a shim file left over from another climbsim.
//!
//! - `layout.rs`: what the block holds, field by field, and who writes each.
//! - `protocol.rs`: a followed thread's states and the transitions between them, the only
//!   code that changes a slot's state, with its table.

mod layout;
pub mod protocol;

pub use layout::*;
pub use protocol::{GiveWay, Parked, Wait, state};
