//! climbsim: a hardware-in-the-loop simulator for a magnetic wall-climbing welding robot.
//!
//! Layers import only downwards: [`protocol`] (sans-IO codec) → [`device`] (control table and
//! servo model per firmware profile) → [`bus`] (routing, multi-reply ordering, wire timing) →
//! [`transport`] (pty, TCP, in-memory). See `docs/architecture.md` for the architecture.

pub mod bus;
pub mod control;
pub mod device;
pub mod embedded;
pub mod fault;
pub mod metrics;
pub mod overrides;
pub mod parts;
pub mod proc_stat;
pub mod protocol;
pub mod real_bus;
pub mod report;
pub mod rng;
pub mod robot;
pub mod runner;
pub mod scenario;
pub mod sensor_server;
pub mod sim;
pub mod source_location;
pub mod transcript;
pub mod transport;
pub mod virtual_time;
