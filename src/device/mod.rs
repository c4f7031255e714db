//! One emulated servo: a control table built from a firmware profile, and a servo model that turns
//! goals into shaft torque and shaft state back into Present registers. Pure: time comes in as an
//! argument, nothing here reads a clock.

mod control_table;
mod error;
mod keys;
mod motor;
mod plant;
pub mod profile;
mod servo;
pub mod shaft;

pub use control_table::{ControlTable, StagedWrite, WriteContext, decode as decode_item};
pub use error::DeviceError;
pub use plant::{BenchPlant, Plant, StillPlant};
pub use profile::{FirmwareProfile, ProfileError};
pub use servo::{Addressing, AfterReply, Outcome, Request, Servo};
pub use shaft::{BenchLoad, ShaftDrive, ShaftLoad, ShaftState};
