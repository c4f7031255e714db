//! Stepping the world: the servos' drives become joint motors, rapier steps (every
//! `ticks_per_step` firmware ticks), encoders and magnet shafts follow, adhesion is applied.

use rapier3d::prelude::*;

use crate::device::{Servo, ShaftDrive, ShaftLoad, ShaftState};

use super::measure::{find_surface, joint_angle, joint_rate};
use super::{AdhesionSample, FRICTION_MOTOR_GAIN, RobotWorld, ServoJoint, ServoLink, robot_groups};

impl RobotWorld {
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
            if let Some(joint) = self.physics.impulse_joints.get_mut(parts.drive_joint, true)
                && let Some(motor) = joint.data.motor(JointAxis::AngX).copied()
            {
                joint.data.set_motor_velocity(JointAxis::AngX, motor.target_vel, motor.damping);
                joint.data.set_motor_max_force(JointAxis::AngX, motor.max_force);
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
        let damping = f64::from(self.climber.magnet.damping_nm_s_per_rad);
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
        let magnet = &self.climber.magnet;
        let outer = self.climber.wheel.outer_radius_m;
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

/// A servo's torque-speed line as the joint's velocity motor: torque = b·(ω_target − ω) with
/// ω_target = τ₀/b, limited to the stall torque; gearbox Coulomb friction opposes the motion.
/// A coasting servo (torque off, b = 0) becomes a stiff velocity-zero motor whose force limit is
/// the friction torque: dry friction with stiction.
///
/// Rewriting the motor every step makes rapier re-stage its joint solver (a mutable joint access
/// bumps its assembly epoch). Splitting τ₀ off as an external torque pair would keep the motor
/// constant, but it saves only 1 % of the step: the adhesion forces mutate the same bodies every
/// step, and rapier re-stages for any mutated jointed body anyway (measured with callgrind).
pub(super) fn set_joint_motor(physics: &mut PhysicsWorld, handle: ImpulseJointHandle, drive: &ShaftDrive, omega: f64) {
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
pub(super) fn track_angle(physics: &PhysicsWorld, joint: &mut ServoJoint) -> f64 {
    let wrapped = joint_angle(physics, joint) as f64;
    let mut delta = wrapped - joint.last_wrapped;
    delta -= (delta / std::f64::consts::TAU).round() * std::f64::consts::TAU;
    joint.angle += delta;
    joint.last_wrapped = wrapped;
    delta
}
