//! The reference controller: line following and wheel-speed PID on the real bus (seed §4–5).
//!
//! Every period it Sync Reads Present Position (132) of the four wheel drives and the four
//! magnet shafts, estimates the robot's speed from the wheels, runs the speed PID and the line
//! follower, and Sync Writes Goal Velocity (104) to the wheels.
//!
//! Two choices a real firmware for a 250 mm/min welding robot has to make, made here too:
//! - **Speed from positions, not Present Velocity.** Present Velocity counts 0.229 rev/min,
//!   1.2 mm/s of ground speed on a 50 mm wheel: 29 % of 250 mm/min. Wheel rates come from
//!   Present Position differences over a sliding window (`speed_window_s`), 0.077 mm a pulse.
//! - **Goal Velocity dithered.** 250 mm/min needs 3.5 velocity units; a rounded command would
//!   be 14 % off. The rounding residual is carried to the next period (first-order sigma-delta),
//!   so the servo's own velocity loop (time constant ≈ 0.26 s) sees the exact mean.

use std::collections::VecDeque;
use std::f64::consts::TAU;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::device::FirmwareProfile;
use crate::robot::{RobotDescription, ServoRole, WheelPosition};

use super::client::{BusLink, ControlError, ServoClient};
use super::line_follower::{LineFollower, LineFollowerGains};
use super::pid::{Pid, PidGains};
use super::relocation::{Pose2, Relocation};
use super::transition::{WallSighting, WallTransition, WallTransitionConfig};

fn default_period_s() -> f64 {
    0.02
}
fn default_zeta() -> f64 {
    0.7
}
fn default_omega_n() -> f64 {
    0.3
}
fn default_true() -> bool {
    true
}
fn default_kp() -> f64 {
    1.0
}
fn default_speed_window_s() -> f64 {
    0.5
}
fn default_max_yaw_rate() -> f64 {
    0.2
}

/// The built-in controller's settings (a scenario's `[controller]` with `kind = "builtin"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceConfig {
    /// Control period (s): one Sync Read and one Sync Write each.
    #[serde(default = "default_period_s")]
    pub period_s: f64,
    /// Follow the line (otherwise drive straight at the target speed).
    #[serde(default = "default_true")]
    pub follow_line: bool,
    /// Line follower damping ratio ζ and natural frequency ω_n (rad/s).
    #[serde(default = "default_zeta")]
    pub zeta: f64,
    #[serde(default = "default_omega_n")]
    pub omega_n: f64,
    /// Integral action on the distance error: its pole p (rad/s), 0 = none (the seed's law).
    /// See [`LineFollowerGains`].
    #[serde(default)]
    pub integral_pole_rad_s: f64,
    /// Largest yaw-rate command (rad/s).
    #[serde(default = "default_max_yaw_rate")]
    pub max_yaw_rate_rad_s: f64,
    /// Speed PID on the speed error (m/s), output in m/s. With `feedforward` the commanded
    /// ground speed is target + PID; without it the PID output alone (as the seed's Unity
    /// motors took it), so that with `ki = 0` the loop keeps a steady-state error of about
    /// target/(1 + kp) — the trade-off of the seed's Fig. 14.
    #[serde(default = "default_true")]
    pub feedforward: bool,
    #[serde(default = "default_kp")]
    pub kp: f64,
    #[serde(default)]
    pub ki: f64,
    #[serde(default)]
    pub kd: f64,
    /// Normal compensation (seed §2.5): each wheel's radius taken as R / cos α, α its magnet
    /// shaft's angle from straight down.
    #[serde(default = "default_true")]
    pub normal_compensation: bool,
    /// Window (s) over which wheel rates are taken from position differences.
    #[serde(default = "default_speed_window_s")]
    pub speed_window_s: f64,
    /// The seed's wall transition (see [`WallTransition`]); none without the table.
    #[serde(default)]
    pub wall_transition: Option<WallTransitionConfig>,
}

impl Default for ReferenceConfig {
    fn default() -> Self {
        Self {
            period_s: default_period_s(),
            follow_line: true,
            zeta: default_zeta(),
            omega_n: default_omega_n(),
            integral_pole_rad_s: 0.0,
            max_yaw_rate_rad_s: default_max_yaw_rate(),
            feedforward: true,
            kp: default_kp(),
            ki: 0.0,
            kd: 0.0,
            normal_compensation: true,
            speed_window_s: default_speed_window_s(),
            wall_transition: None,
        }
    }
}

impl ReferenceConfig {
    pub fn period(&self) -> Duration {
        Duration::from_secs_f64(self.period_s)
    }
}

/// What the line sensor says, in the controller's convention.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineError {
    /// The robot's distance from the line (m), positive when the robot is left of it.
    pub d_err_m: f64,
    /// The robot's heading relative to the line (rad), positive when it points left of it.
    pub psi_err_rad: f64,
}

/// What the controller perceives in one period besides its servos.
#[derive(Debug, Clone, Copy, Default)]
pub struct Senses<'a> {
    /// The latest valid line measurement, if any.
    pub line: Option<LineError>,
    /// What the LIDAR sees ahead (for the wall transition).
    pub wall: Option<WallSighting>,
    /// The robot's pose (for relocation; see [`Relocation`]).
    pub pose: Option<Pose2>,
    /// The LIDAR's returns in plan (for relocation's map).
    pub lidar_returns: &'a [[f32; 2]],
}

/// One period's view and decisions, for the time series.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ControlSample {
    /// Wheel rates from position differences (rad/s), bus order FL, FR, RL, RR.
    pub wheel_rate_rad_s: [f64; 4],
    /// Magnet shaft angles from straight down (rad).
    pub magnet_angle_rad: [f64; 4],
    /// The controller's speed estimate (m/s), compensated or not.
    pub measured_speed_m_s: f64,
    /// Commanded ground speed (m/s) and yaw rate (rad/s).
    pub speed_command_m_s: f64,
    pub yaw_rate_command_rad_s: f64,
    /// Goal Velocity written to each wheel (velocity units).
    pub goal_velocity: [i32; 4],
    /// The wall transition's phase ([`super::Phase::code`]; NaN without one).
    pub transition_phase: f64,
    /// Relocation's leg ([`super::Leg::code`]; NaN without relocation).
    pub relocation_leg: f64,
}

#[derive(Debug, Clone, Copy)]
struct WheelServos {
    drive: u8,
    magnet: u8,
}

/// The reference controller. Call [`ReferenceController::start`] once, then
/// [`ReferenceController::tick`] every [`ReferenceConfig::period`].
pub struct ReferenceController {
    config: ReferenceConfig,
    wheels: [WheelServos; 4],
    radius_m: f64,
    track_m: f64,
    rad_per_pulse: f64,
    rpm_per_velocity_unit: f64,
    velocity_limit_units: f64,
    magnet_zero_pulses: i64,
    target_speed_m_s: f64,
    pid: Pid,
    line_follower: LineFollower,
    /// (time, wheel positions in pulses), oldest first, spanning the speed window.
    history: VecDeque<(Duration, [i64; 4])>,
    dither_residual: [f64; 4],
    last_tick: Option<Duration>,
    sample: ControlSample,
    addresses: Addresses,
    transition: Option<WallTransition>,
    relocation: Option<Relocation>,
}

/// Control-table addresses and values the controller uses, from the firmware profile (resolved
/// once: the profile's lookups by key stay off the control period).
#[derive(Debug, Clone, Copy)]
struct Addresses {
    operating_mode: u16,
    velocity_mode: u8,
    position_mode: u8,
    torque_enable: u16,
    goal_position: u16,
    goal_velocity: u16,
    present_position: u16,
}

impl Addresses {
    fn of(profile: &FirmwareProfile) -> Self {
        let at = |key: &str| profile.items[profile.index(key)].address();
        Addresses {
            operating_mode: at("operating_mode"),
            velocity_mode: profile.operating_modes.velocity,
            position_mode: profile.operating_modes.position,
            torque_enable: at("torque_enable"),
            goal_position: at("goal_position"),
            goal_velocity: at("goal_velocity"),
            present_position: at("present_position"),
        }
    }
}

impl ReferenceController {
    pub fn new(robot: &RobotDescription, profile: &FirmwareProfile, config: ReferenceConfig, target_speed_m_s: f64) -> Result<Self, ControlError> {
        let climber = robot.climber().map_err(|error| ControlError::NotAClimber(error.to_string()))?;
        let find = |role: ServoRole, wheel: WheelPosition, what: &'static str| {
            robot.servo.iter().find(|s| s.role == Some(role) && s.wheel == Some(wheel)).map(|s| s.id).ok_or(ControlError::MissingServo(what))
        };
        let mut wheels = [WheelServos { drive: 0, magnet: 0 }; 4];
        for position in WheelPosition::ALL {
            wheels[position.index()] = WheelServos { drive: find(ServoRole::WheelDrive, position, "wheel drive servo")?, magnet: find(ServoRole::MagnetShaft, position, "magnet shaft servo")? };
        }
        let goal_velocity = &profile.items[profile.index("goal_velocity")];
        let velocity_limit = &profile.items[profile.index("velocity_limit")];
        // Spin the speed loop's integral no further than the fastest the wheels can go.
        let radius_m = f64::from(climber.wheel.outer_radius_m);
        let rpm_per_velocity_unit = goal_velocity.spec.scale.unwrap_or(0.229);
        let velocity_limit_units = velocity_limit.spec.default.unwrap_or(128) as f64;
        let top_speed = velocity_limit_units * rpm_per_velocity_unit / 60.0 * TAU * radius_m;
        let transition = config.wall_transition.clone().map(WallTransition::new);
        Ok(Self {
            pid: Pid::new(PidGains { kp: config.kp, ki: config.ki, kd: config.kd }, top_speed),
            line_follower: LineFollower::new(LineFollowerGains { zeta: config.zeta, omega_n: config.omega_n, integral_pole_rad_s: config.integral_pole_rad_s }),
            config,
            wheels,
            radius_m,
            track_m: f64::from(climber.body.track_m),
            rad_per_pulse: TAU / f64::from(profile.motor.pulses_per_rev),
            rpm_per_velocity_unit,
            velocity_limit_units,
            magnet_zero_pulses: i64::from(climber.magnet.encoder_at_down_pulses),
            target_speed_m_s,
            history: VecDeque::new(),
            dither_residual: [0.0; 4],
            last_tick: None,
            sample: ControlSample::default(),
            addresses: Addresses::of(profile),
            transition,
            relocation: None,
        })
    }

    /// Relocate between welds (see [`Relocation`]).
    pub fn with_relocation(mut self, relocation: Relocation) -> Self {
        self.relocation = Some(relocation);
        self
    }

    pub fn relocation(&self) -> Option<&Relocation> {
        self.relocation.as_ref()
    }

    pub fn config(&self) -> &ReferenceConfig {
        &self.config
    }

    pub fn target_speed_m_s(&self) -> f64 {
        self.target_speed_m_s
    }

    /// A scripted speed step.
    pub fn set_target_speed(&mut self, speed_m_s: f64) {
        self.target_speed_m_s = speed_m_s;
    }

    /// The last period's sample.
    pub fn sample(&self) -> &ControlSample {
        &self.sample
    }

    /// Put the wheel drives in velocity mode with torque on; leave the magnet shafts' torque off
    /// so that they follow the surface normal passively (their encoders are the seed's
    /// potentiometers).
    pub fn start<L: BusLink>(&mut self, link: &mut L) -> Result<(), ControlError> {
        let at = self.addresses;
        let mut client = ServoClient::new(link);
        for wheel in self.wheels {
            client.write(wheel.drive, at.torque_enable, &[0], "Torque Enable = 0")?;
            client.write(wheel.drive, at.operating_mode, &[at.velocity_mode], "Operating Mode = velocity")?;
            client.write(wheel.drive, at.torque_enable, &[1], "Torque Enable = 1")?;
            client.write(wheel.magnet, at.torque_enable, &[0], "Torque Enable = 0")?;
        }
        Ok(())
    }

    /// One control period at time `now` with what the robot perceives.
    pub fn tick<L: BusLink>(&mut self, link: &mut L, now: Duration, senses: &Senses<'_>) -> Result<&ControlSample, ControlError> {
        let Senses { line, wall, pose, lidar_returns } = *senses;
        let at = self.addresses;
        let dt = self.last_tick.map_or(0.0, |last| (now - last).as_secs_f64());
        self.last_tick = Some(now);

        let mut client = ServoClient::new(link);
        let ids: Vec<u8> = self.wheels.iter().map(|w| w.drive).chain(self.wheels.iter().map(|w| w.magnet)).collect();
        let data = client.sync_read(&ids, at.present_position, 4, "Sync Read of Present Position")?;
        let pulses: Vec<i64> = data.iter().map(|bytes| crate::device::decode_item(bytes, true)).collect();
        let wheel_pulses = [pulses[0], pulses[1], pulses[2], pulses[3]];
        let mut magnet_angle_rad = [0.0; 4];
        for (angle, p) in magnet_angle_rad.iter_mut().zip(&pulses[4..8]) {
            *angle = (p - self.magnet_zero_pulses) as f64 * self.rad_per_pulse;
        }

        // Wheel rates over the sliding window.
        self.history.push_back((now, wheel_pulses));
        let window = Duration::from_secs_f64(self.config.speed_window_s);
        while self.history.len() > 2 && self.history.get(1).is_some_and(|(t, _)| now - *t >= window) {
            self.history.pop_front();
        }
        let mut wheel_rate_rad_s = [0.0; 4];
        if let (Some((t0, p0)), true) = (self.history.front(), self.history.len() > 1) {
            let span = (now - *t0).as_secs_f64();
            if span > 0.0 {
                for i in 0..4 {
                    wheel_rate_rad_s[i] = (wheel_pulses[i] - p0[i]) as f64 * self.rad_per_pulse / span;
                }
            }
        }

        // Speed estimate: each wheel's rate times its (compensated) rolling radius.
        let radius = |alpha: f64| {
            if self.config.normal_compensation {
                // Past 60° the magnet has lost the surface; do not let 1/cos blow up.
                self.radius_m / alpha.cos().max(0.5)
            } else {
                self.radius_m
            }
        };
        let measured_speed_m_s = (0..4).map(|i| wheel_rate_rad_s[i] * radius(magnet_angle_rad[i])).sum::<f64>() / 4.0;
        // Relocation drives between welds at its own speed and steers on its path.
        let relocating = match (self.relocation.as_mut(), pose) {
            (Some(relocation), Some(pose)) => relocation.update(pose, lidar_returns, line.is_some()),
            _ => Default::default(),
        };
        let target = relocating.speed_m_s.unwrap_or(self.target_speed_m_s);
        let feedforward = if self.config.feedforward { target } else { 0.0 };
        let speed_command_m_s = feedforward + self.pid.update(target - measured_speed_m_s, dt);

        // Odometry: the wheels' mean roll since the start.
        let odometry_m = wheel_pulses.iter().sum::<i64>() as f64 / 4.0 * self.rad_per_pulse * self.radius_m;
        let decision = self.transition.as_mut().map(|t| t.update(wall, odometry_m)).unwrap_or_default();
        let limit = self.config.max_yaw_rate_rad_s;
        let yaw_rate = match (decision.yaw_rate_rad_s.or(relocating.yaw_rate_rad_s), line) {
            (Some(rate), _) => rate.clamp(-limit, limit),
            (None, Some(error)) if self.config.follow_line && target > 0.0 => self.line_follower.yaw_rate(target, error.d_err_m, error.psi_err_rad, dt, limit),
            _ => 0.0,
        };
        let front_magnets = [self.wheels[WheelPosition::FrontLeft.index()].magnet, self.wheels[WheelPosition::FrontRight.index()].magnet];
        if let Some(angle) = decision.hold_front_magnets_rad {
            // Torque-on sets Goal Position to Present Position (so the shaft does not jump): the
            // goal is written after it.
            // ±180° are one shaft angle; a position-mode goal must stay within one turn of the
            // magnet's zero (at 2048 of 0..4095, +180° would be 4096: a Data Limit Error), so the
            // angle is taken in [-180°, 180°).
            let angle = (angle + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
            let goal = self.magnet_zero_pulses + (angle / self.rad_per_pulse).round() as i64;
            for id in front_magnets {
                client.write(id, at.operating_mode, &[at.position_mode], "Operating Mode = position")?;
                client.write(id, at.torque_enable, &[1], "Torque Enable = 1")?;
                client.write(id, at.goal_position, &(goal as i32).to_le_bytes(), "Goal Position")?;
            }
        }
        if decision.release_front_magnets {
            for id in front_magnets {
                client.write(id, at.torque_enable, &[0], "Torque Enable = 0")?;
            }
        }

        // Skid steering: a left turn (positive yaw rate) speeds the right wheels up.
        let half_track = self.track_m / 2.0;
        let mut goal_velocity = [0i32; 4];
        let mut blocks = Vec::with_capacity(4);
        for position in WheelPosition::ALL {
            let i = position.index();
            let side = if position.is_left() { -1.0 } else { 1.0 };
            let wheel_rad_s = (speed_command_m_s + side * yaw_rate * half_track) / self.radius_m;
            let units = wheel_rad_s * 60.0 / TAU / self.rpm_per_velocity_unit + self.dither_residual[i];
            let rounded = units.round().clamp(-self.velocity_limit_units, self.velocity_limit_units);
            self.dither_residual[i] = (units - rounded).clamp(-1.0, 1.0);
            goal_velocity[i] = rounded as i32;
            blocks.push((self.wheels[i].drive, goal_velocity[i].to_le_bytes().to_vec()));
        }
        client.sync_write(at.goal_velocity, &blocks);

        let transition_phase = self.transition.as_ref().map_or(f64::NAN, |t| t.phase().code());
        let relocation_leg = self.relocation.as_ref().map_or(f64::NAN, |r| r.leg().code());
        self.sample = ControlSample { wheel_rate_rad_s, magnet_angle_rad, measured_speed_m_s, speed_command_m_s, yaw_rate_command_rad_s: yaw_rate, goal_velocity, transition_phase, relocation_leg };
        Ok(&self.sample)
    }
}
