//! Building the robot's world: bodies, colliders and joints from the robot description, and
//! the start pose on the terrain.

use std::time::Duration;

use rapier3d::prelude::*;

use crate::device::{BenchLoad, Servo};
use crate::robot::{RobotDescription, SectionSpec, ServoRole, WheelPosition};
use crate::sim::obstacles::ObstacleError;

use super::measure::{surface_below, terrain_below};
use super::{AdhesionSample, MagnetShaft, ROBOT_GROUP, RobotWorld, STATIC_CONTACT_HZ, ServoJoint, ServoLink, SlipPatches, StartPose, TERRAIN_GROUP, WheelParts, WorldConfig, WorldError, robot_groups};

impl RobotWorld {
    /// Build the world for `servos` (in bus order). Their firmware tick is the physics step, and
    /// their profile's reflected rotor inertia is added to every joint they drive.
    pub fn new(robot: &RobotDescription, config: WorldConfig, servos: &[Servo]) -> Result<Self, WorldError> {
        let climber = robot.climber()?;
        let period = servos.first().map_or(Duration::from_millis(1), Servo::control_period);
        let rotor_inertia = servos.first().map_or(0.0, |s| {
            let motor = &s.profile().motor;
            (motor.rotor_inertia_kgm2 * motor.gear_ratio * motor.gear_ratio) as f32
        });
        let mut physics = PhysicsWorld { gravity: config.gravity, narrow_phase: NarrowPhase::with_query_dispatcher(crate::sim::terrain_contacts::dispatcher()), ..PhysicsWorld::default() };
        let ticks_per_step = config.solver.ticks_per_step.get();
        physics.integration_parameters.dt = period.as_secs_f32() * ticks_per_step as f32;
        // rapier sizes its tolerances by a length unit (default 1 m): allowed penetration is
        // 0.5 % of it. At 1 m a wheel sinks ~3 mm under the magnets' pull, 6 % of its radius,
        // which would shorten the rolling radius by as much. The wheel diameter is the robot's
        // characteristic length.
        physics.integration_parameters.length_unit = 2.0 * climber.wheel.outer_radius_m;
        // Contacts with the (fixed) terrain are soft springs tuned for 60 Hz games: under 80 N of
        // magnet pull a wheel sank 2.6 mm (5 % of its radius, so 5 % of ground speed). Stiffer,
        // still well inside the 1 kHz step's stability: the sink drops below 0.2 mm.
        physics.integration_parameters.static_contact_softness.natural_frequency = STATIC_CONTACT_HZ;
        physics.integration_parameters.num_solver_iterations = config.solver.iterations.get();
        physics.integration_parameters.num_internal_pgs_iterations = config.solver.internal_iterations.get();

        let terrain_body = physics.insert_body(RigidBodyBuilder::fixed());
        let friction = config.friction.unwrap_or(climber.wheel.friction);
        let terrain_collider = config.terrain.collider().friction(friction).collision_groups(InteractionGroups::new(TERRAIN_GROUP, ROBOT_GROUP, InteractionTestMode::And));
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
        let body = &climber.body;
        let wheel = &climber.wheel;
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
        let rocker = RevoluteJointBuilder::new(Vector::X).local_anchor1(Vector::new(half_base / 2.0, 0.0, 0.0)).local_anchor2(Vector::new(-half_base / 2.0, 0.0, 0.0)).limits([-limit, limit]);
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
            let wheel_mass = MassProperties::new(Vector::ZERO, wheel.mass_kg + climber.magnet.mass_kg, Vector::new(ring_cross, ring_cross, ring + rotor_inertia));
            let wheel_body = physics.insert_body(RigidBodyBuilder::dynamic().pose(Pose::from_parts(centre, yaw)).additional_mass_properties(wheel_mass));
            let collider = physics.insert_collider(ColliderBuilder::ball(wheel.outer_radius_m).density(0.0).friction(friction).collision_groups(robot_groups()), Some(wheel_body));
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
                let drive = GenericJointBuilder::new(JointAxesMask::empty()).local_axis1(Vector::Z).local_axis2(Vector::Z).motor_model(JointAxis::AngX, MotorModel::ForceBased).contacts_enabled(false);
                physics.insert_impulse_joint(wheel_body, middle, drive)
            };
            wheels.push(WheelParts { section, wheel: wheel_body, drive_joint, wheel_axis, magnet_axis, collider });
        }
        let wheels: [WheelParts; 4] = [wheels[0], wheels[1], wheels[2], wheels[3]];

        let mut links = Vec::with_capacity(servos.len());
        for servo in servos {
            let Some(spec) = robot.servo.iter().find(|s| s.id == servo.id()) else { continue };
            // `climber()` has checked every servo has its role and wheel.
            let (Some(role), Some(wheel)) = (spec.role, spec.wheel) else { continue };
            let parts = wheels[wheel.index()];
            links.push(match role {
                ServoRole::WheelDrive => ServoLink::Wheel(ServoJoint {
                    parent: parts.section,
                    child: parts.wheel,
                    joint: parts.drive_joint,
                    axis: parts.wheel_axis,
                    angle: 0.0,
                    angle_before: 0.0,
                    last_wrapped: 0.0,
                    solved_rate: 0.0,
                    solved_rate_before: 0.0,
                }),
                ServoRole::MagnetShaft => {
                    let zero_rad = f64::from(climber.magnet.encoder_at_down_pulses) / 4096.0 * std::f64::consts::TAU;
                    ServoLink::Magnet { wheel: wheel.index(), zero_rad }
                }
            });
        }
        // The magnet assembly on its lever (a disc of the lever's radius about its own centre).
        let magnet = &climber.magnet;
        let magnet_inertia = f64::from(magnet.mass_kg * magnet.lever_m.powi(2) * 1.25);
        let magnets: [MagnetShaft; 4] = std::array::from_fn(|_| MagnetShaft { load: BenchLoad::new(magnet_inertia), ..MagnetShaft::default() });
        for role in [ServoRole::WheelDrive, ServoRole::MagnetShaft] {
            for wheel in WheelPosition::ALL {
                if !robot.servo.iter().any(|s| s.role == Some(role) && s.wheel == Some(wheel)) {
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
            climber,
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
}

fn section_collider(spec: &SectionSpec) -> ColliderBuilder {
    let [x, y, z] = spec.half_extents_m;
    let [ix, iy, iz] = spec.inertia_kgm2;
    // The frame's box is only its collision shape: the servos that carry most of the mass sit
    // elsewhere than a uniform box would put them, so the description gives the inertia.
    let mass = MassProperties::new(Vector::ZERO, spec.mass_kg, Vector::new(ix, iy, iz));
    ColliderBuilder::cuboid(x, y, z).mass_properties(mass).collision_groups(robot_groups())
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
