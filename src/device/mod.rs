//! One emulated servo: a control table built from a firmware profile, and a servo model that turns
//! goals into shaft torque and shaft state back into Present registers. Pure: time comes in as an
//! argument, nothing here reads a clock.

mod control_table;
mod error;
pub mod profile;

pub use control_table::{ControlTable, StagedWrite, WriteContext};
pub use error::DeviceError;
pub use profile::{FirmwareProfile, ProfileError};
