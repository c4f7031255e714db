//! The physical robot: a rapier3d world with terrain, rocker suspension, wheels and magnet shafts
//! driven by the emulated servos, and magnetic adhesion.

pub mod camera;
pub mod detector;
pub mod lidar;
pub mod line;
mod lockstep;
pub mod obstacles;
pub mod terrain;
mod terrain_contacts;
pub mod world;

pub use camera::{Frame, LineCamera, LineCameraSettings};
pub use detector::{DetectorSettings, LineDetector, LineMeasurement};
pub use line::{LineProjection, Surface, WeldLine};
pub use lockstep::{Lockstep, ReplyError, SimError};
pub use world::{
    AdhesionSample, CAMERA_FRAME, PartFrame, PartShape, PartShapeKind, RobotWorld, SolverSettings, StartPose, SurfaceFrame, TerrainMesh, WorldConfig, WorldError, magnet_frame, wheel_frame,
};
