//! One emulated servo: control table + firmware behaviour + servo model (reference §4–§8).
//!
//! The bus hands a servo one [`Request`] at a time together with the time it arrived; the plant
//! (bench or rapier world) calls [`Servo::drive`] and [`Servo::sense`] once per firmware tick.
//!
//! The servo's state and small accessors live here; what it does when a packet arrives is in
//! `instructions.rs`, what its firmware does every control period in `firmware.rs`. The two
//! meet only through the control table and the loop state, which is why they split cleanly.

use std::f64::consts::TAU;
use std::sync::Arc;
use std::time::Duration;

use super::control_table::{ControlTable, StagedWrite, WriteContext};
use super::error::DeviceError;
use super::keys::Keys;
use super::motor::Motor;
use super::profile::{Area, FirmwareProfile, ItemSpec};
use super::shaft::{ShaftDrive, ShaftState};

mod firmware;
mod instructions;

/// What the bus asks of one servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request<'a> {
    Ping,
    Read {
        address: u16,
        length: u16,
    },
    Write {
        address: u16,
        data: &'a [u8],
    },
    RegWrite {
        address: u16,
        data: &'a [u8],
    },
    Action,
    FactoryReset {
        option: u8,
    },
    Reboot,
    Clear {
        params: &'a [u8],
    },
    ControlTableBackup {
        params: &'a [u8],
    },
    /// An instruction code the firmware does not know.
    Unknown {
        code: u8,
    },
}

/// How the packet reached the servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Addressing {
    /// Sent to the broadcast ID.
    pub broadcast: bool,
    /// Sent to the servo's Secondary ID.
    pub via_secondary_id: bool,
}

/// Work that happens after the status packet has gone out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AfterReply {
    Reboot,
    FactoryReset { option: u8 },
    RestoreBackup,
}

/// The result of one request: reply parameters or an error, and deferred work.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Outcome {
    pub reply: Result<Vec<u8>, DeviceError>,
    pub after_reply: Option<AfterReply>,
}

impl Outcome {
    fn reply(reply: Result<Vec<u8>, DeviceError>) -> Self {
        Self { reply, after_reply: None }
    }
    fn done() -> Self {
        Self::reply(Ok(Vec::new()))
    }
}

/// Parameters of Clear (reset the multi-turn count) and Control Table Backup (reference §4).
const CLEAR_MULTI_TURN: [u8; 5] = [0x01, 0x44, 0x58, 0x4C, 0x22];
const BACKUP_MAGIC: [u8; 4] = [0x43, 0x54, 0x52, 0x4C];
const BACKUP_STORE: u8 = 0x01;
const BACKUP_RESTORE: u8 = 0x02;
const FACTORY_RESET_ALL: u8 = 0xFF;
const FACTORY_RESET_KEEP_ID: u8 = 0x01;
const FACTORY_RESET_KEEP_ID_AND_BAUD: u8 = 0x02;
/// Drive Mode bits (reference §8, control table notes).
const DRIVE_MODE_REVERSE: i64 = 0x01;
const DRIVE_MODE_TIME_BASED: i64 = 0x04;
const DRIVE_MODE_TORQUE_ON_BY_GOAL: i64 = 0x08;
/// Startup Configuration bits.
const STARTUP_TORQUE_ON: i64 = 0x01;
const STARTUP_RESTORE_RAM: i64 = 0x02;
/// Realtime Tick wraps after this many milliseconds.
const REALTIME_TICK_MODULO: u128 = 32768;
/// Bus Watchdog reads this after it has tripped (-1 in one byte).
const WATCHDOG_TRIPPED: i64 = 0xFF;
/// Moving Status bits.
const MOVING_STATUS_IN_POSITION: i64 = 0x01;
const MOVING_STATUS_PROFILE_ONGOING: i64 = 0x02;
const MOVING_STATUS_FOLLOWING_ERROR: i64 = 0x08;

/// Conversions from register units, taken from the profile's item scales.
#[derive(Debug, Clone, Copy)]
struct Units {
    /// rev/min per Present Velocity unit.
    rpm_per_velocity: f64,
    /// rev/min² per Profile Acceleration unit.
    rpm_per_min_per_accel: f64,
    /// Percent per PWM unit.
    percent_per_pwm: f64,
    /// mA per current unit.
    ma_per_current: f64,
    /// Volts per voltage unit.
    volts_per_voltage: f64,
    /// µs per Return Delay Time unit.
    us_per_return_delay: f64,
    /// ms per Bus Watchdog unit.
    ms_per_watchdog: f64,
    pulses_per_rev: f64,
}

impl Units {
    fn new(profile: &FirmwareProfile, keys: &Keys) -> Self {
        let scale = |index: usize| profile.items[index].spec.scale.unwrap_or(1.0);
        Self {
            rpm_per_velocity: scale(keys.present_velocity),
            rpm_per_min_per_accel: scale(keys.profile_acceleration),
            // PWM Limit's unit: every page gives it (most leave Present PWM's blank).
            percent_per_pwm: scale(keys.pwm_limit),
            // A model without current sensing never converts current units (it has no current
            // modes); 1 mA keeps the conversion finite.
            ma_per_current: keys.present_current.or(keys.current_limit).map_or(1.0, scale),
            volts_per_voltage: scale(keys.present_input_voltage),
            us_per_return_delay: scale(keys.return_delay_time),
            ms_per_watchdog: scale(keys.bus_watchdog),
            pulses_per_rev: f64::from(profile.motor.pulses_per_rev),
        }
    }
    /// Velocity units → pulses per second.
    fn pulses_per_s(&self, velocity: f64) -> f64 {
        velocity * self.rpm_per_velocity / 60.0 * self.pulses_per_rev
    }
    /// Acceleration units → pulses per second².
    fn pulses_per_s2(&self, accel: f64) -> f64 {
        accel * self.rpm_per_min_per_accel / 3600.0 * self.pulses_per_rev
    }
    fn rad_per_pulse(&self) -> f64 {
        TAU / self.pulses_per_rev
    }
    /// Shaft rad/s → velocity units.
    fn velocity_units(&self, rad_s: f64) -> f64 {
        rad_s * 60.0 / TAU / self.rpm_per_velocity
    }
}

/// The firmware's trajectory and loop state.
#[derive(Debug, Clone, Copy, Default)]
struct LoopState {
    /// Profile output in position modes (pulses) and its speed (pulses/s).
    trajectory_position: f64,
    trajectory_velocity: f64,
    /// Velocity-mode profile output (velocity units).
    trajectory_velocity_units: f64,
    /// Time-based profile: speed and acceleration planned when the goal was written.
    planned_velocity: Option<(f64, f64)>,
    velocity_integral: f64,
    position_integral: f64,
    previous_position_error: f64,
    previous_trajectory_velocity: f64,
    profile_ongoing: bool,
    /// Moving Status bits 4-5: 0 none, 1 rectangular, 2 triangular, 3 trapezoidal; a property
    /// of the whole move, classified when it is planned.
    profile_type: i64,
    /// The goal the position profile's type was classified for.
    profile_goal: Option<f64>,
}

/// One emulated servo.
#[derive(Debug, Clone)]
pub struct Servo {
    table: ControlTable,
    keys: Keys,
    units: Units,
    motor: Motor,
    period: Duration,
    registered_write: Option<(u16, Vec<u8>)>,
    backup: Option<Vec<u8>>,
    booting_until: Option<Duration>,
    last_packet_at: Duration,
    watchdog_tripped: bool,
    /// Times the bus watchdog has expired since power-on (for the timing report).
    watchdog_expiries: u64,
    /// Set when a Shutdown-mask error forced torque off; only a reboot clears it.
    shutdown_latched: bool,
    loops: LoopState,
    /// The drive chosen for the current tick, kept to compute Present Current.
    last_drive: ShaftDrive,
    last_duty: f64,
    shaft: ShaftState,
    /// Multiple of a turn subtracted from the raw multi-turn count (single-turn re-basing).
    turn_base: i64,
    temperature_c: f64,
    /// Air around the servo (°C): the profile's ambient unless a fault heats it.
    ambient_c: f64,
    overload_s: f64,
    supply_voltage_v: f64,
    /// Noise on what the encoder reads (a fault), with its own seeded generator.
    encoder_noise: Option<EncoderNoise>,
    next_tick: Duration,
}

/// Gaussian encoder noise: position (pulses) and speed estimate (Present Velocity units).
#[derive(Debug, Clone)]
struct EncoderNoise {
    position_std_pulses: f64,
    velocity_std: f64,
    rng: crate::fault::SplitMix64,
}

impl Servo {
    /// A servo fresh from power-on with `id` and `baud_code` written to its EEPROM.
    pub fn new(profile: Arc<FirmwareProfile>, id: u8, baud_code: u8, supply_voltage_v: f64) -> Self {
        let keys = profile.keys();
        let units = Units::new(&profile, &keys);
        let motor = Motor::new(&profile.motor);
        let period = Duration::from_micros(profile.model.control_period_us.max(1));
        let mut table = ControlTable::new(Arc::clone(&profile));
        table.set(keys.id, i64::from(id));
        table.set(keys.baud_rate, i64::from(baud_code));
        table.set(keys.model_number, i64::from(profile.model.model_number));
        table.set(keys.firmware_version, i64::from(profile.model.firmware_version));
        table.set(keys.model_information, i64::from(profile.model.model_information));
        let mut servo = Self {
            table,
            keys,
            units,
            motor,
            period,
            registered_write: None,
            backup: None,
            booting_until: None,
            last_packet_at: Duration::ZERO,
            watchdog_tripped: false,
            watchdog_expiries: 0,
            shutdown_latched: false,
            loops: LoopState::default(),
            last_drive: ShaftDrive::default(),
            last_duty: 0.0,
            shaft: ShaftState::default(),
            turn_base: 0,
            temperature_c: profile.motor.ambient_temperature_c,
            ambient_c: profile.motor.ambient_temperature_c,
            overload_s: 0.0,
            supply_voltage_v,
            encoder_noise: None,
            next_tick: Duration::ZERO,
        };
        servo.boot(Duration::ZERO, false);
        servo.booting_until = None; // powered before the controller connects
        servo
    }

    pub fn profile(&self) -> &Arc<FirmwareProfile> {
        self.table.profile()
    }

    pub fn table(&self) -> &ControlTable {
        &self.table
    }

    fn get(&self, index: usize) -> i64 {
        self.table.get(index)
    }

    /// An optional item's value, or `absent` on a model without it.
    fn get_or(&self, index: Option<usize>, absent: i64) -> i64 {
        index.map_or(absent, |index| self.table.get(index))
    }

    /// Set an optional item; nothing on a model without it.
    fn set_if_present(&mut self, index: Option<usize>, value: i64) {
        if let Some(index) = index {
            self.table.set(index, value);
        }
    }

    pub fn id(&self) -> u8 {
        self.get(self.keys.id) as u8
    }

    /// The Secondary ID if enabled (values above the ID range disable it).
    pub fn secondary_id(&self) -> Option<u8> {
        let value = self.get(self.keys.secondary_id);
        let max_id = self.profile().items[self.keys.id].spec.max.unwrap_or(252);
        (value <= max_id).then_some(value as u8)
    }

    pub fn baud_code(&self) -> u8 {
        self.get(self.keys.baud_rate) as u8
    }

    pub fn baud_bps(&self) -> Option<u32> {
        self.profile().baud_bps(self.baud_code())
    }

    pub fn return_delay(&self) -> Duration {
        Duration::from_secs_f64(self.get(self.keys.return_delay_time) as f64 * self.units.us_per_return_delay * 1e-6)
    }

    pub fn status_return_level(&self) -> u8 {
        self.get(self.keys.status_return_level) as u8
    }

    /// Protocol Type item: a servo switched to Protocol 1.0 no longer understands 2.0 packets.
    pub fn speaks_protocol_2(&self) -> bool {
        self.get(self.keys.protocol_type) == 2
    }

    /// A rebooting servo hears nothing.
    pub fn is_booting(&self, now: Duration) -> bool {
        self.booting_until.is_some_and(|until| now < until)
    }

    pub fn hardware_error_status(&self) -> u8 {
        self.get(self.keys.hardware_error_status) as u8
    }

    pub fn torque_on(&self) -> bool {
        self.get(self.keys.torque_enable) != 0
    }

    pub fn operating_mode(&self) -> i64 {
        self.get(self.keys.operating_mode)
    }

    /// Times the bus watchdog has expired since power-on.
    pub fn watchdog_expiries(&self) -> u64 {
        self.watchdog_expiries
    }

    pub fn shaft(&self) -> ShaftState {
        self.shaft
    }

    /// The supply voltage at the servo's connector (a fault may change it).
    pub fn set_supply_voltage(&mut self, volts: f64) {
        self.supply_voltage_v = volts;
    }

    pub fn supply_voltage(&self) -> f64 {
        self.supply_voltage_v
    }

    /// Winding temperature (°C) of the thermal model (Present Temperature is it rounded).
    pub fn temperature_c(&self) -> f64 {
        self.temperature_c
    }

    /// The air temperature around the servo (a fault); `None` restores the profile's ambient.
    pub fn set_ambient_temperature(&mut self, celsius: Option<f64>) {
        self.ambient_c = celsius.unwrap_or(self.motor.spec().ambient_temperature_c);
    }

    /// Gaussian noise on what the encoder reads: position (standard deviation in pulses) and
    /// speed estimate (in Present Velocity units), from a generator seeded with `seed`; `None`
    /// for a clean encoder.
    pub fn set_encoder_noise(&mut self, noise: Option<(f64, f64)>, seed: u64) {
        self.encoder_noise = noise.map(|(position_std_pulses, velocity_std)| EncoderNoise { position_std_pulses, velocity_std, rng: crate::fault::SplitMix64::new(seed) });
    }
}

#[cfg(test)]
mod tests;
