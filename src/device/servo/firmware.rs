//! The servo's firmware control loop, run once per control period by the plant (reference §7,
//! the e-Manual's control diagrams): encoder reading, operating modes, the velocity, position
//! and current loops with their profiles, the thermal model and protections (overload,
//! overheating, input voltage), the Bus Watchdog, and skipping ticks while idle. What happens
//! when a packet arrives is in `instructions.rs`.

use super::*;

impl Servo {
    /// What the encoder reports for the true `shaft`: the shaft itself, or with noise on the
    /// position and speed. Noise is what the sensor reads, not what the motor feels: the back-EMF
    /// speed stays the true one.
    pub(super) fn read_encoder(&mut self, shaft: ShaftState) -> ShaftState {
        let Some(noise) = &mut self.encoder_noise else { return shaft };
        let position = noise.position_std_pulses * noise.rng.next_gaussian() * self.units.rad_per_pulse();
        let velocity = noise.velocity_std * noise.rng.next_gaussian() * self.units.rpm_per_velocity * TAU / 60.0;
        ShaftState { position_rad: shaft.position_rad + position, velocity_rad_s: shaft.velocity_rad_s + velocity, back_emf_velocity_rad_s: Some(shaft.back_emf_velocity()) }
    }

    pub(super) fn is_position_mode(&self, mode: i64) -> bool {
        let modes = &self.profile().operating_modes;
        [Some(modes.position), Some(modes.extended_position), modes.current_based_position].contains(&Some(mode as u8))
    }

    pub(super) fn reset_trajectory(&mut self) {
        self.loops.trajectory_position = self.get(self.keys.present_position) as f64;
        self.loops.trajectory_velocity = 0.0;
        self.loops.trajectory_velocity_units = self.get(self.keys.present_velocity) as f64;
        self.loops.planned_velocity = None;
    }

    /// Time-based profile (Drive Mode bit 2): Profile Velocity is the total time and Profile
    /// Acceleration the ramp time, both in ms; turn them into a speed and acceleration now.
    pub(super) fn plan_time_based_profile(&mut self) {
        self.loops.planned_velocity = None;
        if self.get(self.keys.drive_mode) & DRIVE_MODE_TIME_BASED == 0 {
            return;
        }
        let total_s = self.get(self.keys.profile_velocity) as f64 / 1000.0;
        let ramp_s = (self.get(self.keys.profile_acceleration) as f64 / 1000.0).min(total_s / 2.0);
        if total_s <= 0.0 {
            return;
        }
        let distance = (self.get(self.keys.goal_position) as f64 - self.loops.trajectory_position).abs();
        let cruise_s = (total_s - ramp_s).max(f64::EPSILON);
        let velocity = distance / cruise_s;
        let accel = if ramp_s > 0.0 { velocity / ramp_s } else { 0.0 };
        self.loops.planned_velocity = Some((velocity, accel));
    }

    /// Reduce the multi-turn count to one turn (reference §8). The goal and the trajectory move
    /// with it, so a servo holding position under torque does not spin back the turns it lost.
    pub(super) fn rebase_single_turn(&mut self) {
        let raw = self.raw_position_pulses();
        let ppr = self.units.pulses_per_rev as i64;
        let new_base = raw.div_euclid(ppr) * ppr;
        let shift = new_base - self.turn_base;
        self.turn_base = new_base;
        if shift != 0 {
            let goal = self.keys.goal_position;
            self.table.set(goal, self.get(goal) - shift);
            self.loops.trajectory_position -= shift as f64;
        }
    }

    pub(super) fn direction(&self) -> f64 {
        if self.get(self.keys.drive_mode) & DRIVE_MODE_REVERSE != 0 { -1.0 } else { 1.0 }
    }

    pub(super) fn raw_position_pulses(&self) -> i64 {
        (self.direction() * self.shaft.position_rad / self.units.rad_per_pulse()).round() as i64
    }

    pub(super) fn refresh_realtime_tick(&mut self, now: Duration) {
        self.table.set(self.keys.realtime_tick, (now.as_millis() % REALTIME_TICK_MODULO) as i64);
    }

    pub(super) fn publish_position(&mut self) {
        let present = self.raw_position_pulses() - self.turn_base + self.get(self.keys.homing_offset);
        self.table.set(self.keys.present_position, present);
    }

    /// When the next firmware tick is due.
    pub fn next_tick(&self) -> Duration {
        self.next_tick
    }

    pub fn control_period(&self) -> Duration {
        self.period
    }

    /// Run the firmware's control loop for one tick and return what the motor does to the shaft.
    pub fn drive(&mut self) -> ShaftDrive {
        let dt = self.period.as_secs_f64();
        if !self.torque_on() {
            self.last_duty = 0.0;
            self.last_drive = self.motor.coast();
            return self.last_drive;
        }
        let duty = self.control_duty(dt);
        // Goal PWM is the output in PWM mode and a limit on it in every other mode (e-manual,
        // Goal PWM(100)); PWM Limit bounds both.
        let limit_units = self.get(self.keys.pwm_limit).min(self.get(self.keys.goal_pwm).abs());
        let pwm_limit = limit_units as f64 * self.units.percent_per_pwm / 100.0;
        self.last_duty = duty.clamp(-pwm_limit, pwm_limit);
        self.last_drive = self.motor.drive(self.direction() * self.last_duty, self.supply_voltage_v);
        self.last_drive
    }

    /// Take the shaft state after the tick, update every Present register and the protections.
    pub fn sense(&mut self, now: Duration, shaft: ShaftState) {
        let dt = self.period.as_secs_f64();
        self.shaft = self.read_encoder(shaft);
        self.next_tick = now + self.period;
        let torque = self.last_drive.electrical_torque(self.shaft.back_emf_velocity());
        let current_a = self.motor.current_for_torque(torque);
        self.update_thermal(current_a, dt);
        self.publish_state(now);
        self.set_if_present(self.keys.present_current, (self.direction() * current_a * 1000.0 / self.units.ma_per_current).round() as i64);
        // Present Load (XL430, XC430): 0.1 % of the maximum, signed by direction. Chosen: the
        // winding current over the stall current (the e-manual gives the unit, not the estimate).
        if let Some(present_load) = self.keys.present_load {
            let load_permille = (self.direction() * current_a / self.motor.spec().stall_current_a * 1000.0).clamp(-1000.0, 1000.0);
            self.table.set(present_load, load_permille.round() as i64);
        }
        self.table.set(self.keys.present_pwm, (self.last_duty * 100.0 / self.units.percent_per_pwm).round() as i64);
        self.check_protections(current_a, dt);
        self.check_watchdog(now);
    }

    /// Present Position/Velocity/Voltage/Temperature, Moving, Moving Status, Realtime Tick.
    pub(super) fn publish_state(&mut self, now: Duration) {
        let keys = self.keys;
        self.publish_position();
        let velocity = self.units.velocity_units(self.direction() * self.shaft.velocity_rad_s).round() as i64;
        self.table.set(keys.present_velocity, velocity);
        self.table.set(keys.present_input_voltage, (self.supply_voltage_v / self.units.volts_per_voltage).round() as i64);
        self.table.set(keys.present_temperature, self.temperature_c.round() as i64);
        self.refresh_realtime_tick(now);
        let moving = velocity.abs() > self.get(keys.moving_threshold) || self.loops.profile_ongoing;
        self.table.set(keys.moving, i64::from(moving));
        let present = self.get(keys.present_position);
        let model = &self.profile().model;
        let mut status = self.loops.profile_type << 4;
        if self.loops.profile_ongoing {
            status |= MOVING_STATUS_PROFILE_ONGOING;
        }
        if self.is_position_mode(self.operating_mode()) && self.torque_on() {
            if (self.get(keys.goal_position) - present).abs() <= model.in_position_window_pulses {
                status |= MOVING_STATUS_IN_POSITION;
            }
            if (self.loops.trajectory_position - present as f64).abs() > model.following_error_pulses as f64 {
                status |= MOVING_STATUS_FOLLOWING_ERROR;
            }
        }
        self.table.set(keys.moving_status, status);
    }

    pub(super) fn control_duty(&mut self, dt: f64) -> f64 {
        let keys = self.keys;
        let modes = self.profile().operating_modes;
        let mode = self.operating_mode() as u8;
        let percent = self.units.percent_per_pwm / 100.0;
        let omega = self.direction() * self.shaft.back_emf_velocity();
        let current_duty = |servo: &Self, current_units: f64| {
            let torque = servo.motor.torque_for_current(current_units * servo.units.ma_per_current / 1000.0);
            servo.motor.duty_for_torque(torque, omega, servo.supply_voltage_v)
        };
        if mode == modes.pwm {
            self.loops.profile_ongoing = false;
            self.get(keys.goal_pwm) as f64 * percent
        } else if Some(mode) == modes.current {
            self.loops.profile_ongoing = false;
            current_duty(self, self.get_or(keys.goal_current, 0) as f64)
        } else if mode == modes.velocity {
            self.velocity_loop(dt) * percent
        } else if self.is_position_mode(i64::from(mode)) {
            let duty = self.position_loop(dt) * percent;
            if Some(mode) == modes.current_based_position {
                // Goal Current "sets a limit to current in Current-based Position Control mode"
                // (e-manual, Goal Current(102)): the position loop drives the motor's voltage as
                // in position mode, and the current that voltage would draw is held within Goal
                // Current. climbsim had taken the loop's output for a current command, which
                // leaves the shaft undamped (no back-EMF through an ideal current loop): a
                // gripper at rest oscillated ±170 pulses; the manual wins.
                let limit_units = self.get_or(keys.goal_current, 0).abs() as f64;
                let drawn_a = self.motor.current_for_torque(self.motor.drive(duty, self.supply_voltage_v).electrical_torque(omega));
                let limit_a = limit_units * self.units.ma_per_current / 1000.0;
                if drawn_a.abs() > limit_a { current_duty(self, limit_units.copysign(drawn_a)) } else { duty }
            } else {
                duty
            }
        } else {
            0.0
        }
    }

    pub(super) fn gain(&self, index: usize) -> f64 {
        self.get(index) as f64 * self.profile().items[index].spec.scale.unwrap_or(1.0)
    }

    /// Velocity mode: acceleration profile, then the PI loop (output in PWM units).
    pub(super) fn velocity_loop(&mut self, dt: f64) -> f64 {
        let keys = self.keys;
        let goal = self.get(keys.goal_velocity) as f64;
        let accel_units = self.get(keys.profile_acceleration) as f64 * self.units.rpm_per_min_per_accel / 60.0 / self.units.rpm_per_velocity;
        let trajectory = &mut self.loops.trajectory_velocity_units;
        if accel_units <= 0.0 {
            *trajectory = goal;
        } else {
            let step = accel_units * dt;
            *trajectory += (goal - *trajectory).clamp(-step, step);
        }
        self.loops.profile_ongoing = (goal - *trajectory).abs() > f64::EPSILON;
        self.loops.profile_type = if accel_units > 0.0 { 1 } else { 0 };
        let trajectory = *trajectory;
        self.table.set(keys.velocity_trajectory, trajectory.round() as i64);
        // The firmware's own speed estimate is finer than the Present Velocity register (0.229
        // rev/min steps): with the rounded value a held wheel could creep below one step unseen.
        let measured = self.units.velocity_units(self.direction() * self.shaft.velocity_rad_s);
        let error = trajectory - measured;
        let ki = self.gain(keys.velocity_i_gain);
        let kp = self.gain(keys.velocity_p_gain);
        let limit = self.get(keys.pwm_limit) as f64;
        self.loops.velocity_integral += error;
        if ki > 0.0 {
            // Anti-windup: the integral alone never asks for more than the PWM limit.
            self.loops.velocity_integral = self.loops.velocity_integral.clamp(-limit / ki, limit / ki);
        }
        kp * error + ki * self.loops.velocity_integral
    }

    /// Position modes: the profile generator, then the PID with feedforward. Output is PWM units
    /// in every position mode (current-based position caps the current it draws afterwards).
    pub(super) fn position_loop(&mut self, dt: f64) -> f64 {
        let keys = self.keys;
        let goal = self.get(keys.goal_position) as f64;
        self.advance_position_profile(goal, dt);
        let present = self.get(keys.present_position) as f64;
        self.table.set(keys.position_trajectory, self.loops.trajectory_position.round() as i64);
        let velocity_units = self.loops.trajectory_velocity / self.units.pulses_per_s(1.0);
        self.table.set(keys.velocity_trajectory, velocity_units.round() as i64);
        let error = self.loops.trajectory_position - present;
        let derivative = error - self.loops.previous_position_error;
        self.loops.previous_position_error = error;
        let ki = self.gain(keys.position_i_gain);
        self.loops.position_integral += error;
        let limit = self.get(keys.pwm_limit) as f64;
        if ki > 0.0 {
            self.loops.position_integral = self.loops.position_integral.clamp(-limit / ki, limit / ki);
        }
        let acceleration_units = (velocity_units - self.loops.previous_trajectory_velocity) / dt;
        self.loops.previous_trajectory_velocity = velocity_units;
        self.gain(keys.position_p_gain) * error
            + ki * self.loops.position_integral
            + self.gain(keys.position_d_gain) * derivative
            + self.gain(keys.feedforward_1st_gain) * velocity_units
            + self.gain(keys.feedforward_2nd_gain) * acceleration_units * dt
    }

    /// Trapezoidal (or triangular, or rectangular) profile towards `goal`, re-planned each tick.
    pub(super) fn advance_position_profile(&mut self, goal: f64, dt: f64) {
        let keys = self.keys;
        let (velocity_limit, accel) = match self.loops.planned_velocity {
            Some(plan) => plan,
            // Velocity Limit bounds Profile Velocity (e-manual, Velocity Limit(44)). The register
            // takes 0..32 767 (it is a time in ms with a time-based profile), so a larger value
            // is accepted and the profile cruises at the limit.
            None => (self.units.pulses_per_s(self.get(keys.profile_velocity).min(self.get(keys.velocity_limit)) as f64), self.units.pulses_per_s2(self.get(keys.profile_acceleration) as f64)),
        };
        let loops = &mut self.loops;
        let remaining = goal - loops.trajectory_position;
        if velocity_limit <= 0.0 {
            // Profile Velocity 0: no profile, the goal is a step.
            loops.trajectory_position = goal;
            loops.trajectory_velocity = 0.0;
            loops.profile_ongoing = false;
            loops.profile_type = 0;
            loops.profile_goal = None;
            return;
        }
        // The profile's type is the whole move's (triangular only when the move is too short to
        // reach the profile velocity), classified when the goal is new, not as it runs out.
        if loops.profile_goal != Some(goal) {
            loops.profile_goal = Some(goal);
            loops.profile_type = if accel <= 0.0 {
                1
            } else if velocity_limit * velocity_limit / accel > remaining.abs() {
                2
            } else {
                3
            };
        }
        let direction = remaining.signum();
        let mut speed = loops.trajectory_velocity * direction;
        let stopping_speed = if accel > 0.0 { (2.0 * accel * remaining.abs()).sqrt() } else { f64::INFINITY };
        let target_speed = velocity_limit.min(stopping_speed);
        speed = if accel > 0.0 { (speed + accel * dt).min(target_speed) } else { target_speed };
        let step = (speed * dt).min(remaining.abs());
        loops.trajectory_position += direction * step;
        loops.trajectory_velocity = direction * step / dt;
        loops.profile_ongoing = (goal - loops.trajectory_position).abs() > 0.5;
        if !loops.profile_ongoing {
            loops.trajectory_position = goal;
            loops.trajectory_velocity = 0.0;
        }
    }

    pub(super) fn update_thermal(&mut self, current_a: f64, dt: f64) {
        let spec = self.motor.spec();
        let steady = self.ambient_c + self.motor.copper_loss_w(current_a) * spec.thermal_resistance_c_per_w;
        self.temperature_c += (steady - self.temperature_c) * (dt / spec.thermal_time_constant_s).min(1.0);
    }

    /// Hardware errors (reference §8): latched in Hardware Error Status until reboot; those in
    /// the Shutdown mask also force torque off.
    pub(super) fn check_protections(&mut self, current_a: f64, dt: f64) {
        let keys = self.keys;
        let bits = self.profile().hardware_error_bits;
        let spec = self.motor.spec();
        let volts = self.supply_voltage_v;
        let volt_unit = self.units.volts_per_voltage;
        let mut raised = 0u8;
        let min_v = self.get(keys.min_voltage_limit) as f64 * volt_unit;
        let max_v = self.get(keys.max_voltage_limit) as f64 * volt_unit;
        if volts < min_v - 1e-9 || volts > max_v + 1e-9 {
            raised |= 1 << bits.input_voltage;
        }
        if self.temperature_c.round() as i64 > self.get(keys.temperature_limit) {
            raised |= 1 << bits.overheating;
        }
        if current_a.abs() > spec.overload_current_fraction * spec.stall_current_a {
            self.overload_s += dt;
        } else {
            self.overload_s = 0.0;
        }
        if self.overload_s > spec.overload_time_s {
            raised |= 1 << bits.overload;
        }
        if raised != 0 {
            self.raise_hardware_error(raised);
        }
    }

    /// Latch hardware error bits (faults from outside, e.g. a scenario, use this too).
    pub fn raise_hardware_error(&mut self, bits: u8) {
        let keys = self.keys;
        let status = self.hardware_error_status() | bits;
        self.table.set(keys.hardware_error_status, i64::from(status));
        if i64::from(bits) & self.get(keys.shutdown) != 0 {
            self.shutdown_latched = true;
            self.table.set(keys.torque_enable, 0);
        }
    }

    pub(super) fn check_watchdog(&mut self, now: Duration) {
        let keys = self.keys;
        let setting = self.get(keys.bus_watchdog);
        if self.watchdog_tripped || setting == 0 || !self.torque_on() {
            return;
        }
        let timeout = Duration::from_secs_f64(setting as f64 * self.units.ms_per_watchdog / 1000.0);
        if now.saturating_sub(self.last_packet_at) > timeout {
            self.watchdog_tripped = true;
            self.watchdog_expiries += 1;
            self.table.set(keys.bus_watchdog, WATCHDOG_TRIPPED);
            self.stop_for_watchdog();
        }
    }

    /// The expiry's stop (reference §8, e-manual Bus Watchdog(98)): the mode's own goal becomes
    /// "stay here" and the profile is applied as 0 for the stop, so it is immediate. Only the goal
    /// the mode follows changes. Goal PWM and Goal Current are limits outside PWM and current
    /// modes: zeroing them left a servo unable to move once the watchdog was cleared with 0,
    /// which the manual says makes goals work again. The profile items are the controller's
    /// settings ("applied as 0", not written): zeroing them turned its next move into a step.
    fn stop_for_watchdog(&mut self) {
        let keys = self.keys;
        let modes = self.profile().operating_modes;
        let mode = self.operating_mode();
        if self.is_position_mode(mode) {
            self.table.set(keys.goal_position, self.get(keys.present_position));
        } else if mode == i64::from(modes.velocity) {
            self.table.set(keys.goal_velocity, 0);
        } else if mode == i64::from(modes.pwm) {
            self.table.set(keys.goal_pwm, 0);
        } else if modes.current.is_some_and(|current| mode == i64::from(current)) {
            self.set_if_present(keys.goal_current, 0);
        }
        self.reset_trajectory();
        // Profile Acceleration applied as 0: the velocity profile starts at its goal, not at the
        // present speed (reset_trajectory already leaves the position profile at rest).
        self.loops.trajectory_velocity_units = 0.0;
    }

    /// A servo whose torque is off and shaft at rest has nothing to simulate: the plant may skip
    /// its ticks (only its clocks move).
    pub fn is_idle(&self) -> bool {
        !self.torque_on() && self.shaft.velocity_rad_s == 0.0
    }

    /// Skip idle ticks up to `now`.
    pub fn skip_idle_until(&mut self, now: Duration) {
        let spec = self.motor.spec();
        let elapsed = now.saturating_sub(self.next_tick).as_secs_f64();
        let ambient = self.ambient_c;
        self.temperature_c = ambient + (self.temperature_c - ambient) * (-elapsed / spec.thermal_time_constant_s).exp();
        self.next_tick = now;
        self.publish_state(now);
        // Voltage and temperature limits are watched even when nothing moves.
        self.check_protections(0.0, 0.0);
    }
}
