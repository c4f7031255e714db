//! climbsim: a hardware-in-the-loop simulator for a magnetic wall-climbing welding robot.
//!
//! Layers import only downwards: [`protocol`] (sans-IO codec) → [`device`] (control table and
//! servo model per firmware profile) → [`bus`] (routing, multi-reply ordering, wire timing) →
//! [`transport`] (pty, TCP, in-memory). See `docs/architecture.md` for the architecture.

pub mod protocol;
pub mod embedded;
pub mod source_location;
pub mod overrides;
pub mod parts;
pub mod rng;
pub mod proc_stat;
pub mod device;
pub mod fault;
pub mod bus;
pub mod robot;
pub mod scenario;
pub mod sim;
pub mod control;
pub mod sensor_server;
pub mod transcript;
pub mod real_bus;
pub mod virtual_time;
pub mod transport;
pub mod metrics;
pub mod report;
pub mod runner;
