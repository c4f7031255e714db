//! The robot in a rapier3d world: three body sections with a rocker and four wheels on revolute
//! joints, four magnet shafts turning about the axles, all driven by the eight emulated servos;
//! magnetic adhesion found by a ray (or the seed's sphere cast) per wheel, on a terrain collider.
//!
//! Frame (right-handed): x forward, y up, z to the robot's right, so positive yaw (about +y)
//! turns the nose left. One physics step is one servo firmware tick: before
//! the step each wheel servo's [`ShaftDrive`] becomes its joint's motor and each magnet servo's
//! drives its shaft; after it the angles and rates flow back through [`Servo::sense`]. The same
//! device code serves the bench and the world.

use std::num::NonZeroUsize;
use std::time::Duration;

use rapier3d::prelude::*;
use thiserror::Error;

use crate::device::{BenchLoad, Plant, Servo, ShaftDrive};
use crate::robot::{Climber, RobotDescription, ServoRole, WheelPosition};

use super::obstacles::{ObstacleError, ObstacleSpec};
use super::terrain::TerrainGeometry;

/// Collision groups: the robot's colliders touch only the terrain, never each other.
const TERRAIN_GROUP: Group = Group::GROUP_1;
const ROBOT_GROUP: Group = Group::GROUP_2;

/// Membership and filter of the robot's colliders and of its surface queries: robot, sees terrain.
fn robot_groups() -> InteractionGroups {
    InteractionGroups::new(ROBOT_GROUP, TERRAIN_GROUP, InteractionTestMode::And)
}
/// Gain of the velocity motor that emulates dry friction on a coasting joint (N·m·s/rad); the
/// motor's force limit is the friction torque itself.
const FRICTION_MOTOR_GAIN: f32 = 1.0e3;
/// Natural frequency of wheel-on-terrain contact springs (rapier's default is 60 Hz).
const STATIC_CONTACT_HZ: f32 = 240.0;

#[derive(Debug, Error)]
pub enum WorldError {
    #[error("robot description has no servo for the {role:?} of wheel {wheel:?}")]
    MissingServo { role: ServoRole, wheel: WheelPosition },
    #[error(transparent)]
    Robot(#[from] crate::robot::RobotError),
    #[error("obstacles[{index}]: {source}")]
    Obstacle { index: usize, source: ObstacleError },
}

/// Where the robot starts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StartPose {
    /// Wheel-contact point of the robot's centre (x, z); y is found on the terrain.
    pub x_m: f32,
    pub z_m: f32,
    pub yaw_deg: f32,
    /// Height of the wheel bottoms above the terrain at the start.
    pub clearance_m: f32,
    /// A start on a given plane of the surface (a wall, say) instead of on the ground below
    /// (x, z): the robot's centre at `point`, its up along `normal`, its nose along `forward`
    /// (in the plane); `x_m`, `z_m` and `yaw_deg` are then not used.
    pub on_surface: Option<SurfaceFrame>,
}

/// A point of the surface, its outward normal and a direction in it (see [`StartPose`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceFrame {
    pub point: Vector,
    pub normal: Vector,
    pub forward: Vector,
}

impl Default for StartPose {
    fn default() -> Self {
        Self { x_m: 0.0, z_m: 0.0, yaw_deg: 0.0, clearance_m: 0.002, on_surface: None }
    }
}

/// What a world is built from.
#[derive(Debug, Clone)]
pub struct WorldConfig {
    pub gravity: Vector,
    pub terrain: TerrainGeometry,
    pub start: StartPose,
    /// Tread-on-terrain friction (the wheel friction of the robot description if `None`).
    pub friction: Option<f32>,
    /// Magnets on (adhesion applied) or off.
    pub magnets_on: bool,
    /// Extra mass on the middle section (kg).
    pub payload_kg: f32,
    /// How hard rapier's solver works per step.
    pub solver: SolverSettings,
    /// Boxes and cylinders standing on the terrain.
    pub obstacles: Vec<ObstacleSpec>,
}

impl WorldConfig {
    /// A world on `terrain` with everything else at its default: Earth gravity along −y, the
    /// default start pose, the robot's own tread friction, magnets on, no payload.
    pub fn on(terrain: TerrainGeometry) -> Self {
        Self {
            gravity: Vector::new(0.0, -9.81, 0.0),
            terrain,
            start: StartPose::default(),
            friction: None,
            magnets_on: true,
            payload_kg: 0.0,
            solver: SolverSettings::default(),
            obstacles: Vec::new(),
        }
    }
}

/// rapier's solver effort: `iterations` substeps (rapier's `num_solver_iterations`) per physics
/// step, each with `internal_iterations` projected Gauss–Seidel passes
/// (`num_internal_pgs_iterations`), and one physics step every `ticks_per_step` firmware ticks.
/// rapier's defaults are 4 and 1.
///
/// `cargo bench --bench solver_fidelity` measures what each setting buys against an 8 × 2
/// reference stepping every tick (table in docs/performance-world.md). The default, 3 × 3 every 2
/// ticks, stays inside every physics test's tolerance and settles the flat-line scenarios as
/// 3 × 2 every tick does; 3 × 2 every 2 ticks holds the physics tests too but settles a
/// line-following robot a third slower (its yaw stick–slip converges less per simulated
/// second), and fewer substeps (2 × 4, 1 × 8 every 2 ticks), as cheap in passes, let the treads
/// of a robot stalled under a 200 kg payload slide down the slope that friction holds it on:
/// rapier solves friction once per substep. `ticks_per_step = 1` steps rapier at the
/// firmware's own rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SolverSettings {
    pub iterations: NonZeroUsize,
    pub internal_iterations: NonZeroUsize,
    /// Servo firmware ticks per physics step: the servos' control loops, their Present
    /// registers and the magnet shafts always run at the firmware's tick (1 ms); rapier steps
    /// once every this many ticks (see [`RobotWorld::step`]).
    pub ticks_per_step: NonZeroUsize,
}

/// What rapier's step costs does not depend on its length: two 1 ms ticks per physics step
/// halve the physics' share of a simulated second.
const DEFAULT_TICKS_PER_STEP: usize = 2;

impl SolverSettings {
    /// `iterations` × `internal_iterations` (each at least 1), at the default ticks per step.
    pub fn new(iterations: usize, internal_iterations: usize) -> Self {
        Self { iterations: at_least_one(iterations), internal_iterations: at_least_one(internal_iterations), ticks_per_step: at_least_one(DEFAULT_TICKS_PER_STEP) }
    }

    /// The same passes with one physics step every `ticks` firmware ticks (at least 1).
    pub fn every(self, ticks: usize) -> Self {
        Self { ticks_per_step: at_least_one(ticks), ..self }
    }
}

fn at_least_one(n: usize) -> NonZeroUsize {
    NonZeroUsize::new(n).unwrap_or(NonZeroUsize::MIN)
}

impl Default for SolverSettings {
    fn default() -> Self {
        Self::new(3, 3)
    }
}

impl std::fmt::Display for SolverSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} × {}", self.iterations, self.internal_iterations)?;
        if self.ticks_per_step.get() != 1 {
            write!(f, " every {} ticks", self.ticks_per_step)?;
        }
        Ok(())
    }
}

/// One magnet's pull in the last step (for logs and tests).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AdhesionSample {
    /// Pull toward the surface (N); 0 without a surface in range.
    pub force_n: f32,
    /// Gap between tread and surface (m).
    pub gap_m: f32,
    /// Angle between the magnet and the surface normal (rad).
    pub misalignment_rad: f32,
    /// Contact point and surface normal (world).
    pub contact: Option<(Vector, Vector)>,
}

#[derive(Debug, Clone, Copy)]
struct WheelParts {
    section: RigidBodyHandle,
    wheel: RigidBodyHandle,
    /// The joint that carries the drive servo's motor, reacting on the middle body: the axle
    /// joint of a rear wheel, a spin-only joint for a front one (see `RobotWorld::new`).
    drive_joint: ImpulseJointHandle,
    /// Joint axes in the section's frame (positive servo rotation).
    wheel_axis: Vector,
    magnet_axis: Vector,
    /// The tread's collider (slip patches act on its contacts).
    collider: ColliderHandle,
}

/// A rectangle of terrain (x and z ranges, world frame) with its own tread friction.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SlipArea {
    key: usize,
    x_m: [f32; 2],
    z_m: [f32; 2],
    friction: f32,
}

impl SlipArea {
    fn contains(&self, p: Vector) -> bool {
        (self.x_m[0]..=self.x_m[1]).contains(&p.x) && (self.z_m[0]..=self.z_m[1]).contains(&p.z)
    }
}

/// Lowers the friction of a wheel's contact manifold where it touches a slip patch. rapier
/// combines the two colliders' friction per manifold; the hook overrides that combination. Pairs
/// with hooks are never recycled, so the hook runs on every step.
#[derive(Debug, Clone, Default)]
struct SlipPatches {
    areas: Vec<SlipArea>,
}

impl PhysicsHooks for SlipPatches {
    fn modify_solver_contacts(&self, context: &mut ContactModificationContext) {
        let Some(manifold) = context.rigid_mut() else { return };
        let n = manifold.solver_contacts.len();
        if n == 0 {
            return;
        }
        // The manifold's contact centre (world anchors while inside the hook).
        let centre = manifold.solver_contacts.iter().fold(Vector::ZERO, |sum, c| sum + c.anchor1) / n as f32;
        for area in self.areas.iter().filter(|a| a.contains(centre)) {
            *manifold.friction = manifold.friction.min(area.friction);
        }
    }
}

/// A magnet assembly: one rotational degree of freedom about its wheel's axle, relative to the
/// section, integrated here rather than by rapier (a rapier body and joint per magnet cost four
/// bodies and twenty constraint rows every step for a part that only turns about one axis).
/// Its shaft is the magnet servo's load, exactly as a bench load is.
#[derive(Debug, Clone, Default)]
struct MagnetShaft {
    load: BenchLoad,
    /// Torque from the surface (aligning pull on the lever) and gravity this step (N·m).
    external_nm: f64,
    /// Last drive from its servo.
    drive: ShaftDrive,
}

/// The rapier joint a wheel servo drives, with the state needed to report a multi-turn angle.
#[derive(Debug, Clone, Copy)]
struct ServoJoint {
    parent: RigidBodyHandle,
    child: RigidBodyHandle,
    joint: ImpulseJointHandle,
    axis: Vector,
    /// Unwrapped joint angle (rad) after the last physics step, and before it.
    angle: f64,
    angle_before: f64,
    last_wrapped: f64,
    /// rapier's solved joint rate after the last physics step, and before it (rad/s).
    solved_rate: f64,
    solved_rate_before: f64,
}

/// What a servo's shaft is attached to.
#[derive(Debug, Clone, Copy)]
enum ServoLink {
    Wheel(ServoJoint),
    /// The magnet shaft of wheel `wheel`; the encoder reads `zero_rad` with the magnet straight down.
    Magnet {
        wheel: usize,
        zero_rad: f64,
    },
}

/// The terrain's surface as triangles (see [`RobotWorld::terrain_mesh`]).
#[derive(Debug, Clone, PartialEq)]
pub struct TerrainMesh {
    pub vertices: Vec<Vector>,
    pub indices: Vec<[u32; 3]>,
}

/// The name of a wheel's frame for viewers (`wheel_front_left`, …).
pub fn wheel_frame(position: WheelPosition) -> String {
    format!("wheel_{}", position.name())
}

/// The name of a magnet's frame for viewers (`magnet_front_left`, …).
pub fn magnet_frame(position: WheelPosition) -> String {
    format!("magnet_{}", position.name())
}

/// The camera's optical frame's name (see [`RobotWorld::camera_optical_pose`]): the frame of its
/// images.
pub const CAMERA_FRAME: &str = "camera";

/// A named frame of the robot and its pose relative to its parent frame (see
/// [`RobotWorld::part_frames`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PartFrame {
    pub name: String,
    pub parent: String,
    pub pose: Pose,
}

/// A piece of the robot's shape in one of its frames (see [`RobotWorld::part_shapes`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PartShape {
    pub frame: String,
    /// Where the piece sits in its frame.
    pub pose: Pose,
    pub kind: PartShapeKind,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PartShapeKind {
    Box {
        half_extents: Vector,
    },
    /// A cylinder (a wheel, a pipe) about its pose's z axis.
    Cylinder {
        radius_m: f32,
        length_m: f32,
    },
}

pub struct RobotWorld {
    physics: PhysicsWorld,
    terrain: ColliderHandle,
    /// The obstacles standing on the terrain.
    obstacles: Vec<ColliderHandle>,
    /// The front section and the middle one (which carries the bolted rear section).
    sections: [RigidBodyHandle; 2],
    wheels: [WheelParts; 4],
    /// Per servo (in bus order): what it drives.
    links: Vec<ServoLink>,
    magnets: [MagnetShaft; 4],
    robot: RobotDescription,
    /// The robot's mechanics (the description's, checked when the world was built).
    climber: Climber,
    magnets_on: bool,
    /// Fraction of its pull each magnet keeps (1 unless a magnet-failure fault).
    magnet_pull: [f32; 4],
    slip: SlipPatches,
    adhesion: [AdhesionSample; 4],
    /// The servos' firmware tick.
    period: Duration,
    ticks_per_step: usize,
    /// Ticks until the physics, which runs up to `ticks_per_step − 1` ticks ahead of the
    /// firmware, needs its next step.
    ticks_ahead: usize,
    time: Duration,
    steps: u64,
}

impl std::fmt::Debug for RobotWorld {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RobotWorld").field("time", &self.time).field("steps", &self.steps).finish_non_exhaustive()
    }
}

mod build;
mod measure;
mod queries;
mod step;

/// The weld line drapes onto whatever terrain the world holds, trimeshes included.
impl super::line::Surface for RobotWorld {
    fn project_down(&self, x: f32, z: f32) -> Option<(Vector, Vector)> {
        self.surface_below(x, z)
    }
}

/// Lets the bus advance the world: one physics step per firmware tick up to `until`.
impl Plant for RobotWorld {
    fn advance(&mut self, servos: &mut [Servo], until: Duration) {
        while self.time + self.period <= until {
            self.step(servos);
        }
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn inject_fault(&mut self, key: usize, fault: &crate::fault::Fault, active: bool) -> bool {
        use crate::fault::Fault;
        match *fault {
            Fault::MagnetFailure { wheel, pull } => self.set_magnet_pull(wheel, if active { pull } else { 1.0 }),
            Fault::SlipPatch { x_m, z_m, friction } => self.set_slip_patch(key, active.then_some((x_m, z_m, friction))),
            _ => return false,
        }
        true
    }
}
