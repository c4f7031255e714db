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

use rapier3d::parry::query::ShapeCastOptions;
use rapier3d::parry::shape::Ball;
use rapier3d::prelude::*;
use thiserror::Error;

use crate::device::{BenchLoad, Plant, Servo, ShaftDrive, ShaftLoad, ShaftState};
use crate::robot::{RobotDescription, SectionSpec, ServoRole, WheelPosition};

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
        Self { gravity: Vector::new(0.0, -9.81, 0.0), terrain, start: StartPose::default(), friction: None, magnets_on: true, payload_kg: 0.0, solver: SolverSettings::default(), obstacles: Vec::new() }
    }
}

/// rapier's solver effort: `iterations` substeps (rapier's `num_solver_iterations`) per physics
/// step, each with `internal_iterations` projected Gauss–Seidel passes
/// (`num_internal_pgs_iterations`), and one physics step every `ticks_per_step` firmware ticks.
/// rapier's defaults are 4 and 1.
///
/// `cargo bench --bench solver_fidelity` measures what each setting buys against an 8 × 2
/// reference stepping every tick (table in docs/performance.md). The default, 3 × 3 every 2
/// ticks, stays inside every physics test's tolerance and settles the flat-line scenarios as
/// 3 × 2 every tick does; 3 × 2 every 2 ticks holds the physics tests too but settles a
/// line-following robot a third slower (its yaw stick–slip converges less per simulated
/// second). `ticks_per_step = 1` steps rapier at the firmware's own rate.
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
    Magnet { wheel: usize, zero_rad: f64 },
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
    Box { half_extents: Vector },
    /// A cylinder (a wheel, a pipe) about its pose's z axis.
    Cylinder { radius_m: f32, length_m: f32 },
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

fn section_collider(spec: &SectionSpec) -> ColliderBuilder {
    let [x, y, z] = spec.half_extents_m;
    let [ix, iy, iz] = spec.inertia_kgm2;
    // The frame's box is only its collision shape: the servos that carry most of the mass sit
    // elsewhere than a uniform box would put them, so the description gives the inertia.
    let mass = MassProperties::new(Vector::ZERO, spec.mass_kg, Vector::new(ix, iy, iz));
    ColliderBuilder::cuboid(x, y, z).mass_properties(mass).collision_groups(robot_groups())
}

impl RobotWorld {
    /// Build the world for `servos` (in bus order). Their firmware tick is the physics step, and
    /// their profile's reflected rotor inertia is added to every joint they drive.
    pub fn new(robot: &RobotDescription, config: WorldConfig, servos: &[Servo]) -> Result<Self, WorldError> {
        let period = servos.first().map_or(Duration::from_millis(1), Servo::control_period);
        let rotor_inertia = servos.first().map_or(0.0, |s| {
            let motor = &s.profile().motor;
            (motor.rotor_inertia_kgm2 * motor.gear_ratio * motor.gear_ratio) as f32
        });
        let mut physics = PhysicsWorld { gravity: config.gravity, narrow_phase: NarrowPhase::with_query_dispatcher(super::terrain_contacts::dispatcher()), ..PhysicsWorld::default() };
        let ticks_per_step = config.solver.ticks_per_step.get();
        physics.integration_parameters.dt = period.as_secs_f32() * ticks_per_step as f32;
        // rapier sizes its tolerances by a length unit (default 1 m): allowed penetration is
        // 0.5 % of it. At 1 m a wheel sinks ~3 mm under the magnets' pull, 6 % of its radius,
        // which would shorten the rolling radius by as much. The wheel diameter is the robot's
        // characteristic length.
        physics.integration_parameters.length_unit = 2.0 * robot.wheel.outer_radius_m;
        // Contacts with the (fixed) terrain are soft springs tuned for 60 Hz games: under 80 N of
        // magnet pull a wheel sank 2.6 mm (5 % of its radius, so 5 % of ground speed). Stiffer,
        // still well inside the 1 kHz step's stability: the sink drops below 0.2 mm.
        physics.integration_parameters.static_contact_softness.natural_frequency = STATIC_CONTACT_HZ;
        physics.integration_parameters.num_solver_iterations = config.solver.iterations.get();
        physics.integration_parameters.num_internal_pgs_iterations = config.solver.internal_iterations.get();

        let terrain_body = physics.insert_body(RigidBodyBuilder::fixed());
        let friction = config.friction.unwrap_or(robot.wheel.friction);
        let terrain_collider = config
            .terrain
            .collider()
            .friction(friction)
            .collision_groups(InteractionGroups::new(TERRAIN_GROUP, ROBOT_GROUP, InteractionTestMode::And));
        let terrain = physics.insert_collider(terrain_collider, Some(terrain_body));

        // Queries need one update of the query structures before they see the terrain.
        physics.step();
        let mut obstacles = Vec::with_capacity(config.obstacles.len());
        if !config.obstacles.is_empty() {
            let terrain_groups = InteractionGroups::new(TERRAIN_GROUP, ROBOT_GROUP, InteractionTestMode::And);
            for (index, obstacle) in config.obstacles.iter().enumerate() {
                obstacle.validate().map_err(|source| WorldError::Obstacle { index, source })?;
                let [x, z] = obstacle.at_m();
                // Found on the terrain alone: obstacles inserted before are not stood on.
                let ground = terrain_below(&physics, terrain, x, z).ok_or(WorldError::Obstacle { index, source: ObstacleError::OffTerrain { x, z } })?;
                obstacles.push(physics.insert_collider(obstacle.collider(ground).friction(friction).collision_groups(terrain_groups), Some(terrain_body)));
            }
            physics.step();
        }
        let body = &robot.body;
        let wheel = &robot.wheel;
        let half_base = body.wheelbase_m / 2.0;
        let (origin, attitude) = start_frame(&physics, &config.start, half_base, body.track_m / 2.0);
        let axle_y = wheel.outer_radius_m + config.start.clearance_m;
        let centre_y = axle_y + body.axle_drop_m;
        let place = |local: Vector| origin + attitude * local;
        let yaw = attitude;

        let section_at = |physics: &mut PhysicsWorld, spec: &SectionSpec, x: f32| {
            let rb = RigidBodyBuilder::dynamic().pose(Pose::from_parts(place(Vector::new(x, centre_y, 0.0)), yaw));
            let handle = physics.insert_body(rb);
            physics.insert_collider(section_collider(spec), Some(handle));
            handle
        };
        let front = section_at(&mut physics, &body.front, half_base);
        let middle = section_at(&mut physics, &body.middle, 0.0);
        // The rear section is bolted to the middle one: one rigid body with two colliders, each
        // carrying its section's mass and inertia (rapier sums them about the body's centre of
        // mass). A fixed joint in its place costs the solver a sixth joint every step (8.5 % of
        // the step's instructions) to keep two bodies together that never move apart.
        let rear_collider = section_collider(&body.rear).position(Pose::from_translation(Vector::new(-half_base, 0.0, 0.0)));
        physics.insert_collider(rear_collider, Some(middle));
        if config.payload_kg > 0.0 {
            // A compact payload (radius of gyration 0.1 m) on the middle section.
            let payload = MassProperties::new(Vector::ZERO, config.payload_kg, Vector::splat(config.payload_kg * 0.01));
            if let Some(rb) = physics.bodies.get_mut(middle) {
                rb.set_additional_mass_properties(payload, true);
            }
        }

        // The front section rolls about x against the middle one (the rocker).
        let limit = body.rocker.limit_deg.to_radians();
        let rocker = RevoluteJointBuilder::new(Vector::X)
            .local_anchor1(Vector::new(half_base / 2.0, 0.0, 0.0))
            .local_anchor2(Vector::new(-half_base / 2.0, 0.0, 0.0))
            .limits([-limit, limit]);
        physics.insert_impulse_joint(middle, front, rocker);

        let mut wheels = Vec::with_capacity(4);
        for position in WheelPosition::ALL {
            let section = if position.is_front() { front } else { middle };
            // z points to the robot's right (x forward × y up), so the left wheels sit at −z.
            let side = if position.is_left() { -1.0 } else { 1.0 };
            let section_x = if position.is_front() { half_base } else { -half_base };
            // Axle anchor in the carrying body's frame: the front section's origin is over the
            // front axle, the middle body's half a wheelbase ahead of the rear axle.
            let carrier_x = if position.is_front() { half_base } else { 0.0 };
            let anchor = Vector::new(section_x - carrier_x, -body.axle_drop_m, side * body.track_m / 2.0);
            let centre = place(Vector::new(section_x, axle_y, side * body.track_m / 2.0));

            // Hollow wheel: a ball collider rolls robustly on heightfields; its mass properties
            // are those of a thick ring about its axle, plus the drive servo's reflected rotor.
            let ring = 0.5 * wheel.mass_kg * (wheel.outer_radius_m.powi(2) + wheel.inner_radius_m.powi(2));
            let ring_cross = 0.5 * ring + wheel.mass_kg * wheel.width_m.powi(2) / 12.0;
            // The magnet assembly's mass rides on the axle, so it is carried by the wheel body;
            // its rotation is the magnet shaft's own degree of freedom (`MagnetShaft`).
            let wheel_mass = MassProperties::new(Vector::ZERO, wheel.mass_kg + robot.magnet.mass_kg, Vector::new(ring_cross, ring_cross, ring + rotor_inertia));
            let wheel_body = physics.insert_body(RigidBodyBuilder::dynamic().pose(Pose::from_parts(centre, yaw)).additional_mass_properties(wheel_mass));
            let collider = physics.insert_collider(
                ColliderBuilder::ball(wheel.outer_radius_m)
                    .density(0.0)
                    .friction(friction)
                    .collision_groups(robot_groups()),
                Some(wheel_body),
            );
            // Positive wheel-servo rotation drives the robot forward (about -z); positive magnet
            // rotation swings the magnet forward from straight down (about +z).
            let wheel_axis = -Vector::Z;
            let magnet_axis = Vector::Z;
            let axle = RevoluteJointBuilder::new(wheel_axis).local_anchor1(anchor).local_anchor2(Vector::ZERO).motor_model(MotorModel::ForceBased);
            let axle_joint = physics.insert_impulse_joint(section, wheel_body, axle);
            // The drive servo's torque acts between the wheel and the middle body: a rear wheel's
            // axle joint carries the motor; a front wheel gets a second joint that only drives
            // its spin against the middle body, not the front section that carries its axle.
            // That is the torque the rocker would pass on: the rocker frees only roll about x,
            // perpendicular to the axle, so it hands a torque about the axle to the middle body
            // whole, and the wheel's spin relative to either section is the same. With the motor
            // on the axle joint, the light front section (pitch inertia 9.8e-4 kg·m²) sat
            // between the motors, whose wheels carry the servos' reflected rotor inertia
            // (7.9e-3 kg·m² each about the axle), and the body that takes their reaction.
            // rapier's Gauss–Seidel never converged on that chain with an impulse-joint rocker:
            // the section kept a pitch rate in the solved velocities that its poses did not have
            // (measured: 25 % front-tread scrub on a straight drive). A multibody rocker solved
            // it exactly, at 1.8× the step's instructions.
            let drive_joint = if section == middle {
                axle_joint
            } else {
                // The motor row's axis is in the first body's frame: the wheel's own axle, which
                // stays the front section's z. rapier drives (ω_middle − ω_wheel)·axis, so +z
                // turns the servo's positive rotation (about −z) into the motor's.
                let drive = GenericJointBuilder::new(JointAxesMask::empty())
                    .local_axis1(Vector::Z)
                    .local_axis2(Vector::Z)
                    .motor_model(JointAxis::AngX, MotorModel::ForceBased)
                    .contacts_enabled(false);
                physics.insert_impulse_joint(wheel_body, middle, drive)
            };
            wheels.push(WheelParts { section, wheel: wheel_body, drive_joint, wheel_axis, magnet_axis, collider });
        }
        let wheels: [WheelParts; 4] = [wheels[0], wheels[1], wheels[2], wheels[3]];

        let mut links = Vec::with_capacity(servos.len());
        for servo in servos {
            let Some(spec) = robot.servo.iter().find(|s| s.id == servo.id()) else { continue };
            let parts = wheels[spec.wheel.index()];
            links.push(match spec.role {
                ServoRole::WheelDrive => {
                    ServoLink::Wheel(ServoJoint { parent: parts.section, child: parts.wheel, joint: parts.drive_joint, axis: parts.wheel_axis, angle: 0.0, angle_before: 0.0, last_wrapped: 0.0, solved_rate: 0.0, solved_rate_before: 0.0 })
                }
                ServoRole::MagnetShaft => {
                    let zero_rad = f64::from(robot.magnet.encoder_at_down_pulses) / 4096.0 * std::f64::consts::TAU;
                    ServoLink::Magnet { wheel: spec.wheel.index(), zero_rad }
                }
            });
        }
        // The magnet assembly on its lever (a disc of the lever's radius about its own centre).
        let magnet = &robot.magnet;
        let magnet_inertia = f64::from(magnet.mass_kg * magnet.lever_m.powi(2) * 1.25);
        let magnets: [MagnetShaft; 4] = std::array::from_fn(|_| MagnetShaft { load: BenchLoad::new(magnet_inertia), ..MagnetShaft::default() });
        for role in [ServoRole::WheelDrive, ServoRole::MagnetShaft] {
            for wheel in WheelPosition::ALL {
                if !robot.servo.iter().any(|s| s.role == role && s.wheel == wheel) {
                    return Err(WorldError::MissingServo { role, wheel });
                }
            }
        }

        let world = Self {
            physics,
            terrain,
            obstacles,
            sections: [front, middle],
            wheels,
            links,
            magnets,
            robot: robot.clone(),
            magnets_on: config.magnets_on,
            magnet_pull: [1.0; 4],
            slip: SlipPatches::default(),
            adhesion: [AdhesionSample::default(); 4],
            period,
            ticks_per_step,
            ticks_ahead: 0,
            time: Duration::ZERO,
            steps: 0,
        };
        Ok(world)
    }

    pub fn time(&self) -> Duration {
        self.time
    }

    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The terrain's surface as an indexed triangle mesh in the world frame, for viewers: a
    /// heightfield every `stride`-th row and column, where `stride` keeps each side to at most
    /// `max_vertices_per_side` vertices (the last row and column always kept); a mesh as it is.
    pub fn terrain_mesh(&self, max_vertices_per_side: usize) -> TerrainMesh {
        let collider = &self.physics.colliders[self.terrain];
        let place = *collider.position();
        if let Some(field) = collider.shape().as_heightfield() {
            let picks = |n: usize| -> Vec<usize> {
                let stride = (n.saturating_sub(1)).div_ceil(max_vertices_per_side.max(2) - 1).max(1);
                let mut picked: Vec<usize> = (0..n).step_by(stride).collect();
                if picked.last() != Some(&(n - 1)) {
                    picked.push(n - 1);
                }
                picked
            };
            // parry's nrows/ncols count cells; the grid of heights has one more of each.
            let heights = field.heights();
            let (rows, cols) = (picks(heights.nrows()), picks(heights.ncols()));
            let scale_y = field.scale().y;
            let vertices = rows.iter().flat_map(|&i| cols.iter().map(move |&j| place * Vector::new(field.x_at(j), heights[(i, j)] * scale_y, field.z_at(i)))).collect();
            let width = cols.len() as u32;
            let mut indices = Vec::with_capacity((rows.len() - 1) * (cols.len() - 1) * 2);
            for i in 0..rows.len() as u32 - 1 {
                for j in 0..width - 1 {
                    let (a, b, c, d) = (i * width + j, i * width + j + 1, (i + 1) * width + j, (i + 1) * width + j + 1);
                    // Counter-clockwise seen from above (+y), as parry's own cells.
                    indices.push([a, c, b]);
                    indices.push([b, c, d]);
                }
            }
            return TerrainMesh { vertices, indices };
        }
        if let Some(mesh) = collider.shape().as_trimesh() {
            return TerrainMesh { vertices: mesh.vertices().iter().map(|&v| place * v).collect(), indices: mesh.indices().to_vec() };
        }
        TerrainMesh { vertices: Vec::new(), indices: Vec::new() }
    }

    pub fn terrain_collider(&self) -> ColliderHandle {
        self.terrain
    }

    /// The rapier world (read-only), for sensors and tests.
    pub fn physics(&self) -> &PhysicsWorld {
        &self.physics
    }

    pub fn adhesion(&self) -> &[AdhesionSample; 4] {
        &self.adhesion
    }

    pub fn set_magnets_on(&mut self, on: bool) {
        self.magnets_on = on;
    }

    pub fn set_gravity(&mut self, gravity: Vector) {
        self.physics.gravity = gravity;
    }

    /// Fraction of its pull the magnet of `wheel` keeps (1 = healthy, 0 = failed).
    pub fn set_magnet_pull(&mut self, wheel: WheelPosition, fraction: f32) {
        self.magnet_pull[wheel.index()] = fraction;
    }

    pub fn magnet_pull(&self, wheel: WheelPosition) -> f32 {
        self.magnet_pull[wheel.index()]
    }

    /// Start (`Some`) or end (`None`) slip patch `key`: tread friction `friction` over the x and z
    /// ranges. The wheel colliders ask for the contact hook only while a patch exists, so a world
    /// without one steps exactly as before.
    pub fn set_slip_patch(&mut self, key: usize, patch: Option<([f32; 2], [f32; 2], f32)>) {
        self.slip.areas.retain(|a| a.key != key);
        if let Some((x_m, z_m, friction)) = patch {
            self.slip.areas.push(SlipArea { key, x_m, z_m, friction });
        }
        let hooks = if self.slip.areas.is_empty() { ActiveHooks::empty() } else { ActiveHooks::MODIFY_SOLVER_CONTACTS };
        for parts in self.wheels {
            if let Some(collider) = self.physics.colliders.get_mut(parts.collider) {
                collider.set_active_hooks(hooks);
            }
        }
    }

    /// How much faster the tread turns than its centre moves over the ground (m/s): wheel rate
    /// × outer radius − the wheel centre's speed along its section's forward axis. Near 0 when
    /// rolling; large when the wheel spins on a slippery patch.
    pub fn wheel_slip(&self, wheel: WheelPosition) -> f32 {
        let parts = self.wheels[wheel.index()];
        let forward = self.physics.bodies[parts.section].rotation() * Vector::X;
        let ground = self.physics.bodies[parts.wheel].linvel().dot(forward);
        self.wheel_rate(wheel) * self.robot.wheel.outer_radius_m - ground
    }

    /// The middle section's pose (the robot's reference frame).
    pub fn chassis_pose(&self) -> Pose {
        *self.physics.bodies[self.sections[1]].position()
    }

    /// The robot as a tree of named frames, for viewers (a recording's `/tf`): `middle` (which
    /// carries the bolted rear section) in `world`, `front` on the rocker in `middle`, each wheel
    /// (`wheel_front_left`, …) in the section that carries it, and each magnet (`magnet_front_left`,
    /// …) in its wheel, turned about the axle by its shaft's angle (its −y points where it pulls).
    pub fn part_frames(&self) -> Vec<PartFrame> {
        let pose = |handle: RigidBodyHandle| *self.physics.bodies[handle].position();
        let section_name = |handle: RigidBodyHandle| if handle == self.sections[0] { "front" } else { "middle" };
        let (front, middle) = (pose(self.sections[0]), pose(self.sections[1]));
        let mut frames = Vec::with_capacity(10);
        frames.push(PartFrame { name: "middle".to_owned(), parent: "world".to_owned(), pose: middle });
        frames.push(PartFrame { name: "front".to_owned(), parent: "middle".to_owned(), pose: middle.inv_mul(&front) });
        for position in WheelPosition::ALL {
            let parts = self.wheels[position.index()];
            let (section, wheel) = (pose(parts.section), pose(parts.wheel));
            let magnet = Pose::from_parts(wheel.translation, self.magnet_rotation_at(position.index()));
            frames.push(PartFrame { name: wheel_frame(position), parent: section_name(parts.section).to_owned(), pose: section.inv_mul(&wheel) });
            frames.push(PartFrame { name: magnet_frame(position), parent: wheel_frame(position), pose: wheel.inv_mul(&magnet) });
        }
        frames
    }

    /// The obstacles' shapes for viewers, in `world`: boxes, and cylinders about their pose's z.
    pub fn obstacle_shapes(&self) -> Vec<PartShape> {
        let mut shapes = Vec::with_capacity(self.obstacles.len());
        for &handle in &self.obstacles {
            let collider = &self.physics.colliders[handle];
            let pose = *collider.position();
            let kind = if let Some(cuboid) = collider.shape().as_cuboid() {
                (pose, PartShapeKind::Box { half_extents: cuboid.half_extents })
            } else if let Some(cylinder) = collider.shape().as_cylinder() {
                // rapier's cylinder stands along its y axis: a quarter turn about x puts it on z.
                (pose * Pose::from_rotation(Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2)), PartShapeKind::Cylinder { radius_m: cylinder.radius, length_m: 2.0 * cylinder.half_height })
            } else {
                continue;
            };
            shapes.push(PartShape { frame: "world".to_owned(), pose: kind.0, kind: kind.1 });
        }
        shapes
    }

    /// The robot's shapes for viewers, each in the frame of [`RobotWorld::part_frames`] it moves
    /// with: the sections' boxes as their colliders have them, and each wheel as the hollow
    /// cylinder it is (its collider is a ball, which rolls more robustly on heightfields).
    pub fn part_shapes(&self) -> Vec<PartShape> {
        let mut shapes = Vec::with_capacity(7);
        for (frame, section) in [("front", self.sections[0]), ("middle", self.sections[1])] {
            for &collider in self.physics.bodies[section].colliders() {
                if let Some(cuboid) = self.physics.colliders[collider].shape().as_cuboid() {
                    let pose = self.physics.colliders[collider].position_wrt_parent().copied().unwrap_or_default();
                    shapes.push(PartShape { frame: frame.to_owned(), pose, kind: PartShapeKind::Box { half_extents: cuboid.half_extents } });
                }
            }
        }
        let wheel = &self.robot.wheel;
        for position in WheelPosition::ALL {
            // The wheel body's z axis is its axle.
            shapes.push(PartShape { frame: wheel_frame(position), pose: Pose::IDENTITY, kind: PartShapeKind::Cylinder { radius_m: wheel.outer_radius_m, length_m: wheel.width_m } });
        }
        shapes
    }

    /// The downward camera's pose: its mount (`[camera] position_m`) on the middle section,
    /// looking along the section's −y axis.
    pub fn camera_pose(&self) -> Pose {
        let [x, y, z] = self.robot.camera.position_m;
        self.chassis_pose() * Pose::from_translation(Vector::new(x, y, z))
    }

    /// The terrain surface straight below (x, z): point and outward normal, from a ray cast down
    /// from high above (the robot is not in the terrain group, so it never hides the ground).
    pub fn surface_below(&self, x: f32, z: f32) -> Option<(Vector, Vector)> {
        surface_below(&self.physics, x, z)
    }

    /// The terrain's own surface straight below (x, z) and its normal, obstacles ignored.
    pub fn terrain_surface_below(&self, x: f32, z: f32) -> Option<(Vector, Vector)> {
        terrain_and_normal_below(&self.physics, self.terrain, x, z)
    }

    /// How far along `direction` (unit) from `origin` the nearest surface of the terrain or an
    /// obstacle is, up to `max_m`; the robot's own parts are never hit. For range sensors.
    pub fn cast_ray_at_surroundings(&self, origin: Vector, direction: Vector, max_m: f32) -> Option<f32> {
        let ray = Ray::new(origin, direction);
        let filter = QueryFilter::default().groups(robot_groups());
        self.physics.cast_ray(&ray, max_m, true, filter).map(|(_, toi)| toi)
    }

    /// The chassis' linear velocity.
    pub fn chassis_velocity(&self) -> Vector {
        self.physics.bodies[self.sections[1]].linvel()
    }

    /// Centre of a wheel.
    pub fn wheel_centre(&self, wheel: WheelPosition) -> Vector {
        self.physics.bodies[self.wheels[wheel.index()].wheel].translation()
    }

    /// A wheel's rate about its axle relative to its section (rad/s, positive rolls forward).
    pub fn wheel_rate(&self, wheel: WheelPosition) -> f32 {
        self.links
            .iter()
            .find_map(|link| match link {
                ServoLink::Wheel(joint) if joint.child == self.wheels[wheel.index()].wheel => Some(joint_rate(&self.physics, joint)),
                _ => None,
            })
            .unwrap_or(0.0)
    }

    /// Direction the magnet of a wheel points (world, unit).
    pub fn magnet_direction(&self, wheel: WheelPosition) -> Vector {
        self.magnet_direction_at(wheel.index())
    }

    fn magnet_direction_at(&self, index: usize) -> Vector {
        self.magnet_rotation_at(index) * -Vector::Y
    }

    /// The magnet's orientation in the world: its section's, turned about the magnet axis by the
    /// shaft's angle (its −y points where it pulls).
    fn magnet_rotation_at(&self, index: usize) -> Rotation {
        let parts = self.wheels[index];
        let angle = self.magnets[index].load.state().position_rad as f32;
        self.physics.bodies[parts.section].rotation() * Rotation::from_axis_angle(parts.magnet_axis, angle)
    }

    /// Gap between a wheel's tread and the nearest terrain (m; 0 when touching), `None` when no
    /// terrain is within the magnet's range of it.
    pub fn tread_gap_m(&self, wheel: WheelPosition) -> Option<f32> {
        let centre = self.physics.bodies[self.wheels[wheel.index()].wheel].translation();
        let filter = QueryFilter::default().groups(robot_groups());
        let outer = self.robot.wheel.outer_radius_m;
        let (_, projection) = self.physics.project_point(centre, outer + self.robot.magnet.range_m, true, filter)?;
        Some(((projection.point - centre).length() - outer).max(0.0))
    }

    /// The geometric contact angle of a wheel: the direction from its centre to the closest
    /// terrain point, as an angle in the wheel's plane from straight down (positive toward the
    /// front), in its section's frame. What a perfectly aligned passive magnet would read.
    pub fn contact_angle(&self, wheel: WheelPosition) -> Option<f32> {
        self.contact_angles(wheel).map(|(in_plane, _)| in_plane)
    }

    /// Both angles of a wheel's contact direction (centre to the closest terrain point), in its
    /// section's frame: in the wheel's plane from straight down, positive toward the front (the
    /// seed's β: what a magnet turning about the axle can follow), and out of that plane,
    /// positive toward the section's +z (the seed's α: the contact off the tread's middle).
    pub fn contact_angles(&self, wheel: WheelPosition) -> Option<(f32, f32)> {
        let parts = self.wheels[wheel.index()];
        let centre = self.physics.bodies[parts.wheel].translation();
        let filter = QueryFilter::default().groups(robot_groups());
        let reach = self.robot.wheel.outer_radius_m + self.robot.magnet.range_m;
        let (_, projection) = self.physics.project_point(centre, reach, true, filter)?;
        let local = self.physics.bodies[parts.section].rotation().inverse() * (projection.point - centre);
        let in_plane = local.x.hypot(local.y);
        Some((local.x.atan2(-local.y), local.z.atan2(in_plane)))
    }

    /// The magnet's angle from straight down in its section's frame (positive toward the front).
    pub fn magnet_angle(&self, wheel: WheelPosition) -> f32 {
        let parts = self.wheels[wheel.index()];
        let local = self.physics.bodies[parts.section].rotation().inverse() * self.magnet_direction(wheel);
        local.x.atan2(-local.y)
    }

    /// Step the rapier world alone: the same bodies, joints and motor settings, without the
    /// servo models or adhesion (the bare-rapier baseline of the real-time-factor bench).
    pub fn step_physics_only(&mut self) {
        self.physics.step();
        // Keep the encoders counting, so that the next full step's rate is one step's change.
        self.read_wheel_encoders();
    }

    /// After a physics step: each wheel joint's angle and solved rate, keeping the previous ones
    /// for the ticks that fall inside the step.
    fn read_wheel_encoders(&mut self) {
        for link in &mut self.links {
            if let ServoLink::Wheel(joint) = link {
                joint.angle_before = joint.angle;
                joint.solved_rate_before = joint.solved_rate;
                track_angle(&self.physics, joint);
                joint.solved_rate = joint_rate(&self.physics, joint) as f64;
            }
        }
    }

    /// Step the rapier world alone, re-applying the last step's inputs unchanged: each body's
    /// force and torque and each wheel joint's motor are written back through rapier's API before
    /// the step, as any program that drives a rapier robot and holds it with forces must do every
    /// step. rapier re-stages its joint solver whenever a jointed body or a joint is accessed
    /// mutably, so this baseline costs more than [`Self::step_physics_only`]; the difference is
    /// rapier's price for per-step inputs, not climbsim's models.
    pub fn step_physics_with_held_inputs(&mut self) {
        let bodies = self.sections.iter().copied().chain(self.wheels.iter().map(|w| w.wheel));
        for handle in bodies {
            let body = &mut self.physics.bodies[handle];
            let (force, torque) = (body.user_force(), body.user_torque());
            body.reset_forces(false);
            body.reset_torques(false);
            body.add_force(force, true);
            body.add_torque(torque, true);
        }
        for parts in self.wheels {
            if let Some(joint) = self.physics.impulse_joints.get_mut(parts.drive_joint, true) {
                if let Some(motor) = joint.data.motor(JointAxis::AngX).copied() {
                    joint.data.set_motor_velocity(JointAxis::AngX, motor.target_vel, motor.damping);
                    joint.data.set_motor_max_force(JointAxis::AngX, motor.max_force);
                }
            }
        }
        self.step_physics_only();
    }

    /// Advance one firmware tick with the servos in bus order.
    ///
    /// Every tick runs every servo's firmware and integrates the magnet shafts. rapier steps on
    /// the first tick of every `ticks_per_step` (its step spans them all), so the physics runs
    /// up to `ticks_per_step − 1` ticks ahead of the firmware. The wheel motors take the drive
    /// their servos chose on that first tick and hold it through the step; the servos' encoders
    /// read the wheel angle interpolated across the step at each tick, and its mean rate. The
    /// magnet shafts' reaction on the sections enters the step from its first tick.
    pub fn step(&mut self, servos: &mut [Servo]) {
        let physics_due = self.ticks_ahead == 0;
        for (servo, link) in servos.iter_mut().zip(&self.links) {
            let drive = servo.drive();
            match *link {
                ServoLink::Wheel(joint) if physics_due => {
                    let omega = joint_rate(&self.physics, &joint) as f64;
                    set_joint_motor(&mut self.physics, joint.joint, &drive, omega);
                }
                ServoLink::Wheel(_) => {}
                ServoLink::Magnet { wheel, .. } => self.magnets[wheel].drive = drive,
            }
        }
        if physics_due {
            self.reset_applied_loads();
            self.apply_adhesion();
            tracing::trace!(
                target: "climbsim::adhesion",
                t = self.time.as_secs_f64(),
                fl = self.adhesion[0].force_n,
                fr = self.adhesion[1].force_n,
                rl = self.adhesion[2].force_n,
                rr = self.adhesion[3].force_n,
                "magnet pull (N)"
            );
        }
        self.step_magnets(physics_due);
        if physics_due {
            if self.slip.areas.is_empty() {
                self.physics.step();
            } else {
                self.physics.step_with_events(&self.slip, &());
            }
            self.ticks_ahead = self.ticks_per_step;
            self.read_wheel_encoders();
        }
        self.ticks_ahead -= 1;
        self.time += self.period;
        self.steps += 1;
        let step_s = self.period.as_secs_f64() * self.ticks_per_step as f64;
        // How far through the physics step the firmware now is (1 at its end).
        let through = (self.ticks_per_step - self.ticks_ahead) as f64 / self.ticks_per_step as f64;
        for (servo, link) in servos.iter_mut().zip(self.links.iter()) {
            let state = match link {
                ServoLink::Wheel(joint) => {
                    // The rate the encoder sees: the angle's change over the step. rapier
                    // integrates positions with the velocities of its biased (position-
                    // correcting) pass and reports those of the relaxed pass; under the magnets'
                    // pull, with the wheels scrubbing in a turn, the two differed by up to 60 %
                    // (the wheel turned faster than its reported rate). The servo's velocity loop
                    // must close on what the shaft actually does.
                    // The torque rapier applied follows its solved (relaxed) rate, and so does
                    // the current: from the encoder's rate, a climbing wheel that the position
                    // pass pushes ahead would read less current than the load it carries.
                    let change = joint.angle - joint.angle_before;
                    let solved = joint.solved_rate_before + through * (joint.solved_rate - joint.solved_rate_before);
                    ShaftState { position_rad: joint.angle_before + through * change, velocity_rad_s: change / step_s, back_emf_velocity_rad_s: Some(solved) }
                }
                ServoLink::Magnet { wheel, zero_rad } => {
                    let shaft = self.magnets[*wheel].load.state();
                    ShaftState { position_rad: *zero_rad + shaft.position_rad, ..shaft }
                }
            };
            servo.sense(self.time, state);
        }
    }

    /// Integrate each magnet shaft over one tick: its servo's torque-speed line, gearbox
    /// friction, swing damping, and the external torque from the surface and gravity. With
    /// `react`, the section takes the reaction of everything the servo and its bearings exert
    /// (for the physics step about to run).
    fn step_magnets(&mut self, react: bool) {
        let dt = self.period.as_secs_f64();
        let damping = f64::from(self.robot.magnet.damping_nm_s_per_rad);
        for index in 0..4 {
            let parts = self.wheels[index];
            let shaft = &mut self.magnets[index];
            let mut drive = shaft.drive;
            drive.viscous_friction += damping;
            let before = shaft.load.state().velocity_rad_s;
            shaft.load.external_torque_nm = shaft.external_nm;
            let after = shaft.load.step(&drive, dt).velocity_rad_s;
            if !react {
                continue;
            }
            let inertia = drive.rotor_inertia_kgm2 + shaft.load.extra_inertia_kgm2;
            // J·α = internal + external: the section feels −internal about the axle.
            let internal = inertia * (after - before) / dt - shaft.external_nm;
            let axis = self.physics.bodies[parts.section].rotation() * parts.magnet_axis;
            self.physics.bodies[parts.section].add_torque(-(internal as f32) * axis, true);
        }
    }

    /// Forces and torques added to bodies persist until reset: every step starts from zero.
    fn reset_applied_loads(&mut self) {
        for section in self.sections {
            self.physics.bodies[section].reset_torques(false);
        }
        for parts in self.wheels {
            self.physics.bodies[parts.wheel].reset_forces(false);
        }
    }

    /// Per wheel: sweep a small sphere from the wheel centre along the magnet's direction to find
    /// the surface and its normal; pull the wheel toward the surface by the gap law, scaled by the
    /// magnet's alignment with the normal, and turn the magnet toward the normal with the same
    /// pull on its lever.
    fn apply_adhesion(&mut self) {
        let magnet = &self.robot.magnet;
        let outer = self.robot.wheel.outer_radius_m;
        let gravity = self.physics.gravity;
        for index in 0..4 {
            let parts = self.wheels[index];
            self.adhesion[index] = AdhesionSample::default();
            let direction = self.magnet_direction_at(index);
            let axis = self.physics.bodies[parts.section].rotation() * parts.magnet_axis;
            // Gravity on the magnet's mass, on its lever.
            let pendulum = (direction * magnet.lever_m).cross(gravity * magnet.mass_kg).dot(axis);
            self.magnets[index].external_nm = f64::from(pendulum);
            if !self.magnets_on {
                continue;
            }
            let centre = self.physics.bodies[parts.wheel].translation();
            let filter = QueryFilter::default().groups(robot_groups());
            let Some((contact, normal)) = find_surface(&self.physics, self.terrain, centre, direction, outer + magnet.range_m, magnet.probe_radius_m, filter) else {
                continue;
            };
            // The magnet pulls toward the steel, i.e. against the surface normal; the gap is the
            // tread's distance from the surface along that normal, and the pull weakens with the
            // angle between the magnet and the normal (not the cast direction: on a plane the
            // cast point always lies on the magnet's own line).
            let pull_direction = -normal;
            let gap = ((centre - contact).dot(normal) - outer).max(0.0);
            let misalignment = direction.dot(pull_direction).clamp(-1.0, 1.0).acos();
            let alignment = misalignment.cos().max(0.0).powf(magnet.alignment_exponent);
            let force = magnet.pull_at_contact_n / (1.0 + gap / magnet.decay_length_m).powi(2) * alignment * self.magnet_pull[index];
            self.physics.bodies[parts.wheel].add_force(pull_direction * force, true);
            // Aligning torque on the magnet: its lever pulled toward the surface.
            let aligning = (direction * magnet.lever_m).cross(pull_direction * force).dot(axis);
            self.magnets[index].external_nm += f64::from(aligning);
            self.adhesion[index] = AdhesionSample { force_n: force, gap_m: gap, misalignment_rad: misalignment, contact: Some((contact, normal)) };
        }
    }
}

/// The surface a magnet faces: contact point and outward normal, looking from `centre` along
/// `direction` up to `reach`. A ray gives the exact face normal; a ray that passes exactly
/// through a grid vertex or edge can miss, and then the seed's sphere cast (radius `probe`)
/// finds the surface. The sphere cast is not the first choice because parry's shape cast
/// against a fine heightfield returned normals tilted by up to 20° on flat cells (measured).
///
/// The ray goes straight to the terrain collider's shape: the terrain is the only collider in
/// the magnets' filter, and skipping the query pipeline's tree walk halves the cast's cost
/// (it runs four times a step).
fn find_surface(physics: &PhysicsWorld, terrain: ColliderHandle, centre: Vector, direction: Vector, reach: f32, probe: f32, filter: QueryFilter<'_>) -> Option<(Vector, Vector)> {
    let ray = Ray::new(centre, direction);
    let terrain = physics.colliders.get(terrain)?;
    if let Some(hit) = terrain.shape().cast_ray_and_get_normal(terrain.position(), &ray, reach, true) {
        return Some((ray.point_at(hit.time_of_impact), hit.normal));
    }
    let options = ShapeCastOptions { max_time_of_impact: reach, target_distance: 0.0, stop_at_penetration: true, compute_impact_geometry_on_penetration: true };
    let (_, hit) = physics.cast_shape(&Pose::from_translation(centre), direction, &Ball::new(probe), options, filter)?;
    Some((hit.witness1, hit.normal1))
}

/// The terrain straight below (x, z): point and outward normal, from a ray cast down from high
/// above against the terrain group only.
fn surface_below(physics: &PhysicsWorld, x: f32, z: f32) -> Option<(Vector, Vector)> {
    let ray = ray_down(x, z);
    let filter = QueryFilter::default().groups(robot_groups());
    let (_, hit) = physics.cast_ray_and_get_normal(&ray, 2.0 * RAY_DOWN_FROM_M, true, filter)?;
    Some((ray.point_at(hit.time_of_impact), hit.normal))
}

/// How high above the origin a ray looking straight down starts (terrains stay far below).
const RAY_DOWN_FROM_M: f32 = 100.0;

/// A ray straight down onto (x, z) from [`RAY_DOWN_FROM_M`] up.
fn ray_down(x: f32, z: f32) -> Ray {
    Ray::new(Vector::new(x, RAY_DOWN_FROM_M, z), -Vector::Y)
}

/// The terrain collider's surface straight below (x, z), obstacles ignored.
fn terrain_below(physics: &PhysicsWorld, terrain: ColliderHandle, x: f32, z: f32) -> Option<Vector> {
    terrain_and_normal_below(physics, terrain, x, z).map(|(point, _)| point)
}

/// [`terrain_below`] with the surface's outward normal there.
fn terrain_and_normal_below(physics: &PhysicsWorld, terrain: ColliderHandle, x: f32, z: f32) -> Option<(Vector, Vector)> {
    let ray = ray_down(x, z);
    let collider = physics.colliders.get(terrain)?;
    let hit = collider.shape().cast_ray_and_get_normal(collider.position(), &ray, 2.0 * RAY_DOWN_FROM_M, true)?;
    Some((ray.point_at(hit.time_of_impact), hit.normal))
}

/// The robot's start frame: origin on the ground under the start point, rotated by the yaw and
/// tilted to the plane through the terrain under the four wheels, so the robot starts resting on
/// slopes and pipes instead of inside them.
fn start_frame(physics: &PhysicsWorld, start: &StartPose, half_base: f32, half_track: f32) -> (Vector, Rotation) {
    if let Some(frame) = start.on_surface {
        // Body axes: x forward, y up (the normal), z to the right = x × y.
        let up = frame.normal.normalize_or(Vector::Y);
        let forward = (frame.forward - up * frame.forward.dot(up)).normalize_or(Vector::X);
        let right = forward.cross(up);
        return (frame.point, Rotation::from_mat3(&rapier3d::math::Matrix::from_cols(forward, up, right)));
    }
    let yaw = Rotation::from_rotation_y(start.yaw_deg.to_radians());
    let at = |x: f32, z: f32| {
        let p = Vector::new(start.x_m, 0.0, start.z_m) + yaw * Vector::new(x, 0.0, z);
        surface_below(physics, p.x, p.z).map_or(0.0, |(point, _)| point.y)
    };
    let (fl, fr, rl, rr) = (at(half_base, half_track), at(half_base, -half_track), at(-half_base, half_track), at(-half_base, -half_track));
    let pitch = ((fl + fr) - (rl + rr)).atan2(4.0 * half_base);
    let roll = ((fr + rr) - (fl + rl)).atan2(4.0 * half_track);
    let attitude = yaw * Rotation::from_rotation_z(pitch) * Rotation::from_rotation_x(roll);
    let origin = Vector::new(start.x_m, (fl + fr + rl + rr) / 4.0, start.z_m);
    (origin, attitude)
}

/// A servo's torque-speed line as the joint's velocity motor: torque = b·(ω_target − ω) with
/// ω_target = τ₀/b, limited to the stall torque; gearbox Coulomb friction opposes the motion.
/// A coasting servo (torque off, b = 0) becomes a stiff velocity-zero motor whose force limit is
/// the friction torque: dry friction with stiction.
///
/// Rewriting the motor every step makes rapier re-stage its joint solver (a mutable joint access
/// bumps its assembly epoch). Splitting τ₀ off as an external torque pair would keep the motor
/// constant, but it saves only 1 % of the step: the adhesion forces mutate the same bodies every
/// step, and rapier re-stages for any mutated jointed body anyway (measured with callgrind).
fn set_joint_motor(physics: &mut PhysicsWorld, handle: ImpulseJointHandle, drive: &ShaftDrive, omega: f64) {
    let Some(joint) = physics.impulse_joints.get_mut(handle, true) else { return };
    let damping = drive.back_emf_damping + drive.viscous_friction;
    let (target, gain, max_torque) = if drive.back_emf_damping <= 0.0 {
        (0.0, FRICTION_MOTOR_GAIN, drive.coulomb_friction_nm as f32)
    } else {
        let friction = if omega.abs() > 1e-3 { drive.coulomb_friction_nm * omega.signum() } else { 0.0 };
        let target = (drive.torque_at_standstill_nm - friction) / damping;
        (target as f32, damping as f32, (drive.torque_at_standstill_nm.abs() + drive.back_emf_damping * omega.abs()).max(drive.coulomb_friction_nm) as f32)
    };
    joint.data.set_motor_velocity(JointAxis::AngX, target, gain);
    joint.data.set_motor_max_force(JointAxis::AngX, max_torque);
}

/// Advance a joint's unwrapped (multi-turn) angle to the present pose; the change.
fn track_angle(physics: &PhysicsWorld, joint: &mut ServoJoint) -> f64 {
    let wrapped = joint_angle(physics, joint) as f64;
    let mut delta = wrapped - joint.last_wrapped;
    delta -= (delta / std::f64::consts::TAU).round() * std::f64::consts::TAU;
    joint.angle += delta;
    joint.last_wrapped = wrapped;
    delta
}

/// Joint axis in world coordinates.
fn world_axis(physics: &PhysicsWorld, joint: &ServoJoint) -> Vector {
    physics.bodies[joint.parent].rotation() * joint.axis
}

fn joint_rate(physics: &PhysicsWorld, joint: &ServoJoint) -> f32 {
    let axis = world_axis(physics, joint);
    (physics.bodies[joint.child].angvel() - physics.bodies[joint.parent].angvel()).dot(axis)
}

/// Angle of the child about the joint axis relative to the parent, in (−π, π].
fn joint_angle(physics: &PhysicsWorld, joint: &ServoJoint) -> f32 {
    let parent = physics.bodies[joint.parent].rotation();
    let child = physics.bodies[joint.child].rotation();
    let relative = parent.inverse() * *child;
    // Twist of the relative rotation about the (parent-frame) axis.
    let v = Vector::new(relative.x, relative.y, relative.z);
    2.0 * v.dot(joint.axis).atan2(relative.w)
}

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
