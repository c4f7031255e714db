//! The physical robot: a rapier3d world with terrain, rocker suspension, wheels and magnet shafts
//! driven by the emulated servos, and magnetic adhesion.

mod lockstep;
pub mod terrain;
pub mod world;

pub use world::{AdhesionSample, RobotWorld, StartPose, WorldConfig, WorldError};
pub use lockstep::{Lockstep, ReplyError, SimError};
