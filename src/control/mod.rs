//! The built-in reference controllers (seed report §4–5): a linear line follower, a PID
//! wheel-speed controller with optional normal compensation, the seed's wall transition, an
//! occupancy-grid planner for relocation between welds, and the bus client they share.
//!
//! They are ordinary Dynamixel clients: every read and write is a real Protocol 2.0 packet
//! through the codec and the bus ([`BusLink`]), as an external controller's would be, only
//! without a pty in between so that a run is deterministic and faster than real time.

mod client;
mod line_follower;
mod pid;
pub mod planner;
mod reference;
mod relocation;
mod transition;

pub use client::{BusLink, ControlError, ServoClient};
pub use line_follower::LineFollowerGains;
pub use pid::{Pid, PidGains};
pub use reference::{ControlSample, LineError, ReferenceConfig, ReferenceController, Senses};
pub use relocation::{Leg, Pose2, Relocation, RelocationConfig, RelocationDecision, WeldTask};
pub use transition::{Phase, WallSighting, WallTransition, WallTransitionConfig};
