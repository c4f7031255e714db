//! One emulated servo: control table + firmware behaviour + servo model (reference §4–§8).
//!
//! The bus hands a servo one [`Request`] at a time together with the time it arrived; the plant
//! (bench or rapier world) calls [`Servo::drive`] and [`Servo::sense`] once per firmware tick.

use std::f64::consts::TAU;
use std::sync::Arc;
use std::time::Duration;

use super::control_table::{ControlTable, StagedWrite, WriteContext};
use super::error::DeviceError;
use super::keys::Keys;
use super::motor::Motor;
use super::profile::{Area, FirmwareProfile, ItemSpec};
use super::shaft::{ShaftDrive, ShaftState};

/// What the bus asks of one servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request<'a> {
    Ping,
    Read { address: u16, length: u16 },
    Write { address: u16, data: &'a [u8] },
    RegWrite { address: u16, data: &'a [u8] },
    Action,
    FactoryReset { option: u8 },
    Reboot,
    Clear { params: &'a [u8] },
    ControlTableBackup { params: &'a [u8] },
    /// An instruction code the firmware does not know.
    Unknown { code: u8 },
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
            percent_per_pwm: scale(keys.present_pwm),
            ma_per_current: scale(keys.present_current),
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
    /// Moving Status bits 4-5: 0 none, 1 rectangular, 2 triangular, 3 trapezoidal.
    profile_type: i64,
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
        let keys = Keys::resolve(&profile);
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

    /// What the encoder reports for the true `shaft`: the shaft itself, or with noise on the
    /// position and speed. Noise is what the sensor reads, not what the motor feels: the back-EMF
    /// speed stays the true one.
    fn read_encoder(&mut self, shaft: ShaftState) -> ShaftState {
        let Some(noise) = &mut self.encoder_noise else { return shaft };
        let position = noise.position_std_pulses * noise.rng.next_gaussian() * self.units.rad_per_pulse();
        let velocity = noise.velocity_std * noise.rng.next_gaussian() * self.units.rpm_per_velocity * TAU / 60.0;
        ShaftState {
            position_rad: shaft.position_rad + position,
            velocity_rad_s: shaft.velocity_rad_s + velocity,
            back_emf_velocity_rad_s: Some(shaft.back_emf_velocity()),
        }
    }

    /// The status error byte for an outcome: error number plus the alert bit.
    pub fn status_error_byte(&self, result: &Result<Vec<u8>, DeviceError>) -> u8 {
        let code = result.as_ref().err().map_or(0, |e| e.code());
        let alert = if self.hardware_error_status() != 0 { crate::protocol::ALERT_BIT } else { 0 };
        code | alert
    }

    /// Note that a packet concerning this servo arrived at `now`: it restarts the Bus Watchdog.
    /// (Reference §8 leaves open whether foreign packets do; chosen: only packets the servo
    /// processes, as the firmware only parses those.)
    pub fn note_packet(&mut self, now: Duration) {
        self.last_packet_at = now;
    }

    /// Carry out one request.
    pub fn handle(&mut self, now: Duration, request: Request<'_>, addressing: Addressing) -> Outcome {
        match request {
            Request::Ping => {
                let mut params = (self.get(self.keys.model_number) as u16).to_le_bytes().to_vec();
                params.push(self.get(self.keys.firmware_version) as u8);
                Outcome::reply(Ok(params))
            }
            Request::Read { address, length } => {
                self.refresh_realtime_tick(now);
                Outcome::reply(self.table.read(address, length))
            }
            Request::Write { address, data } => Outcome::reply(self.write(now, address, data, addressing).map(|()| Vec::new())),
            Request::RegWrite { address, data } => {
                let result = self.stage(address, data, addressing).map(|_| {
                    self.registered_write = Some((address, data.to_vec()));
                    self.table.set(self.keys.registered_instruction, 1);
                    Vec::new()
                });
                Outcome::reply(result)
            }
            Request::Action => {
                let Some((address, data)) = self.registered_write.take() else {
                    return Outcome::reply(Err(DeviceError::Instruction));
                };
                self.table.set(self.keys.registered_instruction, 0);
                Outcome::reply(self.write(now, address, &data, addressing).map(|()| Vec::new()))
            }
            Request::FactoryReset { option } => {
                if addressing.broadcast && option == FACTORY_RESET_ALL {
                    return Outcome::done(); // ignored (FW42+), and a broadcast gets no reply anyway
                }
                if ![FACTORY_RESET_ALL, FACTORY_RESET_KEEP_ID, FACTORY_RESET_KEEP_ID_AND_BAUD].contains(&option) {
                    return Outcome::reply(Err(DeviceError::DataRange));
                }
                Outcome { reply: Ok(Vec::new()), after_reply: Some(AfterReply::FactoryReset { option }) }
            }
            Request::Reboot => Outcome { reply: Ok(Vec::new()), after_reply: Some(AfterReply::Reboot) },
            Request::Clear { params } => {
                if params != CLEAR_MULTI_TURN {
                    return Outcome::reply(Err(DeviceError::DataRange));
                }
                if self.get(self.keys.moving) != 0 {
                    return Outcome::reply(Err(DeviceError::ResultFail));
                }
                self.rebase_single_turn();
                self.publish_position();
                Outcome::done()
            }
            Request::ControlTableBackup { params } => self.control_table_backup(params),
            Request::Unknown { .. } => Outcome::reply(Err(DeviceError::Instruction)),
        }
    }

    /// Deferred work after the reply went out.
    pub fn finish(&mut self, now: Duration, after: AfterReply) {
        match after {
            AfterReply::Reboot => self.boot(now, false),
            AfterReply::RestoreBackup => self.boot(now, true),
            AfterReply::FactoryReset { option } => {
                let keys = self.keys;
                let id = self.get(keys.id);
                let baud = self.get(keys.baud_rate);
                self.table.reset(|item| item.area == Area::Eeprom);
                self.set_identity();
                if option != FACTORY_RESET_ALL {
                    self.table.set(keys.id, id);
                }
                if option == FACTORY_RESET_KEEP_ID_AND_BAUD {
                    self.table.set(keys.baud_rate, baud);
                }
                self.boot(now, false);
            }
        }
    }

    fn set_identity(&mut self) {
        let model = self.profile().model.clone();
        self.table.set(self.keys.model_number, i64::from(model.model_number));
        self.table.set(self.keys.firmware_version, i64::from(model.firmware_version));
        self.table.set(self.keys.model_information, i64::from(model.model_information));
    }

    fn control_table_backup(&mut self, params: &[u8]) -> Outcome {
        let Some((&option, magic)) = params.split_first() else {
            return Outcome::reply(Err(DeviceError::DataRange));
        };
        if magic != BACKUP_MAGIC || ![BACKUP_STORE, BACKUP_RESTORE].contains(&option) {
            return Outcome::reply(Err(DeviceError::DataRange));
        }
        if self.torque_on() {
            return Outcome::reply(Err(DeviceError::ResultFail));
        }
        if option == BACKUP_STORE {
            self.backup = Some(self.table.bytes().to_vec());
            self.table.set(self.keys.backup_ready, 1);
            return Outcome::done();
        }
        if self.backup.is_none() {
            return Outcome::reply(Err(DeviceError::ResultFail));
        }
        Outcome { reply: Ok(Vec::new()), after_reply: Some(AfterReply::RestoreBackup) }
    }

    /// Power-on / reboot: RAM to defaults, EEPROM kept, errors cleared, single-turn re-base.
    fn boot(&mut self, now: Duration, restore_backup: bool) {
        let keys = self.keys;
        self.table.reset(|item: &ItemSpec| item.area == Area::Ram);
        if restore_backup && let Some(backup) = &self.backup {
            self.table.copy_items_from(backup, |item| item.backup);
        }
        let startup = self.get(keys.startup_configuration);
        if startup & STARTUP_RESTORE_RAM != 0
            && let Some(backup) = &self.backup
        {
            self.table.copy_items_from(backup, |item| item.backup && item.area == Area::Ram);
        }
        self.table.set(keys.backup_ready, i64::from(self.backup.is_some()));
        self.set_identity();
        self.registered_write = None;
        self.watchdog_tripped = false;
        self.shutdown_latched = false;
        self.overload_s = 0.0;
        self.loops = LoopState::default();
        self.booting_until = Some(now + Duration::from_millis(self.profile().model.boot_time_ms));
        self.last_packet_at = now;
        self.rebase_single_turn();
        self.publish_state(now);
        self.table.set(keys.goal_position, self.get(keys.present_position));
        self.table.set(keys.goal_pwm, self.get(keys.pwm_limit));
        self.table.set(keys.goal_current, self.get(keys.current_limit));
        if startup & STARTUP_TORQUE_ON != 0 {
            self.enable_torque(now);
        }
    }

    fn context(&self, addressing: Addressing) -> WriteContext {
        WriteContext { torque_on: self.torque_on(), operating_mode: self.operating_mode(), via_secondary_id: addressing.via_secondary_id }
    }

    fn goal_keys(&self) -> [usize; 4] {
        [self.keys.goal_pwm, self.keys.goal_current, self.keys.goal_velocity, self.keys.goal_position]
    }

    /// Every check of a write, including the firmware rules beyond the table's own.
    fn stage(&self, address: u16, data: &[u8], addressing: Addressing) -> Result<StagedWrite, DeviceError> {
        let staged = self.table.stage_write(address, data, self.context(addressing))?;
        if self.watchdog_tripped {
            // After expiry, goal writes are refused until the watchdog is cleared with 0.
            if self.goal_keys().iter().any(|&k| staged.touches(k)) {
                return Err(DeviceError::DataRange);
            }
            if staged.value_of(self.keys.bus_watchdog).is_some_and(|v| v != 0) {
                return Err(DeviceError::DataRange);
            }
        }
        Ok(staged)
    }

    fn write(&mut self, now: Duration, address: u16, data: &[u8], addressing: Addressing) -> Result<(), DeviceError> {
        let staged = self.stage(address, data, addressing)?;
        let keys = self.keys;
        let old_mode = self.operating_mode();
        let was_on = self.torque_on();
        // Torque Enable is applied through `enable_torque`, not as a plain byte.
        let torque_request = staged.value_of(keys.torque_enable);
        let plain = StagedWrite { items: staged.items.iter().copied().filter(|(i, _)| *i != keys.torque_enable).collect() };
        self.table.apply(&plain);

        if let Some(mode) = staged.value_of(keys.operating_mode)
            && mode != old_mode
        {
            self.change_operating_mode(mode);
        }
        if staged.value_of(keys.bus_watchdog) == Some(0) {
            self.watchdog_tripped = false;
        }
        if staged.touches(keys.bus_watchdog) {
            self.last_packet_at = now;
        }
        let goal_written = self.goal_keys().iter().any(|&k| staged.touches(k));
        match torque_request {
            Some(0) => self.table.set(keys.torque_enable, 0),
            Some(_) if !was_on => self.enable_torque(now),
            _ => {}
        }
        if goal_written && !self.torque_on() && self.get(keys.drive_mode) & DRIVE_MODE_TORQUE_ON_BY_GOAL != 0 {
            let goal = self.get(keys.goal_position);
            self.enable_torque(now);
            self.table.set(keys.goal_position, goal);
        }
        if staged.touches(keys.goal_position) {
            self.plan_time_based_profile();
        }
        if staged.touches(keys.homing_offset) {
            self.publish_position();
        }
        Ok(())
    }

    /// Reference §8: gains reloaded, profile zeroed, goal PWM/current to their limits.
    fn change_operating_mode(&mut self, mode: i64) {
        let keys = self.keys;
        let gains = [
            keys.velocity_i_gain, keys.velocity_p_gain, keys.position_d_gain, keys.position_i_gain, keys.position_p_gain,
            keys.feedforward_2nd_gain, keys.feedforward_1st_gain,
        ];
        let profile = Arc::clone(self.profile());
        for index in gains {
            self.table.set(index, profile.items[index].spec.default.unwrap_or(0));
        }
        self.table.set(keys.profile_acceleration, 0);
        self.table.set(keys.profile_velocity, 0);
        self.table.set(keys.goal_pwm, self.get(keys.pwm_limit));
        self.table.set(keys.goal_current, self.get(keys.current_limit));
        self.loops = LoopState::default();
        if mode == i64::from(profile.operating_modes.position) {
            self.rebase_single_turn();
        }
        self.publish_position();
        self.reset_trajectory();
    }

    fn is_position_mode(&self, mode: i64) -> bool {
        let modes = &self.profile().operating_modes;
        [modes.position, modes.extended_position, modes.current_based_position].contains(&(mode as u8))
    }

    /// Torque on: refused while a shutdown is latched; otherwise the goal becomes the present
    /// position so the horn does not jump (chosen; real X-series servos behave this way).
    fn enable_torque(&mut self, now: Duration) {
        if self.shutdown_latched {
            return;
        }
        let keys = self.keys;
        if self.operating_mode() == i64::from(self.profile().operating_modes.position) {
            self.rebase_single_turn();
            self.publish_position();
        }
        self.table.set(keys.torque_enable, 1);
        self.table.set(keys.goal_position, self.get(keys.present_position));
        self.last_packet_at = now;
        self.loops = LoopState::default();
        self.reset_trajectory();
    }

    fn reset_trajectory(&mut self) {
        self.loops.trajectory_position = self.get(self.keys.present_position) as f64;
        self.loops.trajectory_velocity = 0.0;
        self.loops.trajectory_velocity_units = self.get(self.keys.present_velocity) as f64;
        self.loops.planned_velocity = None;
    }

    /// Time-based profile (Drive Mode bit 2): Profile Velocity is the total time and Profile
    /// Acceleration the ramp time, both in ms; turn them into a speed and acceleration now.
    fn plan_time_based_profile(&mut self) {
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
    fn rebase_single_turn(&mut self) {
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

    fn direction(&self) -> f64 {
        if self.get(self.keys.drive_mode) & DRIVE_MODE_REVERSE != 0 { -1.0 } else { 1.0 }
    }

    fn raw_position_pulses(&self) -> i64 {
        (self.direction() * self.shaft.position_rad / self.units.rad_per_pulse()).round() as i64
    }

    fn refresh_realtime_tick(&mut self, now: Duration) {
        self.table.set(self.keys.realtime_tick, (now.as_millis() % REALTIME_TICK_MODULO) as i64);
    }

    fn publish_position(&mut self) {
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
        let pwm_limit = self.get(self.keys.pwm_limit) as f64 * self.units.percent_per_pwm / 100.0;
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
        self.table.set(self.keys.present_current, (self.direction() * current_a * 1000.0 / self.units.ma_per_current).round() as i64);
        self.table.set(self.keys.present_pwm, (self.last_duty * 100.0 / self.units.percent_per_pwm).round() as i64);
        self.check_protections(current_a, dt);
        self.check_watchdog(now);
    }

    /// Present Position/Velocity/Voltage/Temperature, Moving, Moving Status, Realtime Tick.
    fn publish_state(&mut self, now: Duration) {
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

    fn control_duty(&mut self, dt: f64) -> f64 {
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
        } else if mode == modes.current {
            self.loops.profile_ongoing = false;
            current_duty(self, self.get(keys.goal_current) as f64)
        } else if mode == modes.velocity {
            self.velocity_loop(dt) * percent
        } else if self.is_position_mode(i64::from(mode)) {
            let output = self.position_loop(dt);
            if mode == modes.current_based_position {
                let limit = self.get(keys.goal_current).abs() as f64;
                current_duty(self, output.clamp(-limit, limit))
            } else {
                output * percent
            }
        } else {
            0.0
        }
    }

    fn gain(&self, index: usize) -> f64 {
        self.get(index) as f64 * self.profile().items[index].spec.scale.unwrap_or(1.0)
    }

    /// Velocity mode: acceleration profile, then the PI loop (output in PWM units).
    fn velocity_loop(&mut self, dt: f64) -> f64 {
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

    /// Position modes: the profile generator, then the PID with feedforward. Output is PWM units,
    /// or current units in current-based position mode.
    fn position_loop(&mut self, dt: f64) -> f64 {
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
    fn advance_position_profile(&mut self, goal: f64, dt: f64) {
        let keys = self.keys;
        let (velocity_limit, accel) = match self.loops.planned_velocity {
            Some(plan) => plan,
            None => (
                self.units.pulses_per_s(self.get(keys.profile_velocity) as f64),
                self.units.pulses_per_s2(self.get(keys.profile_acceleration) as f64),
            ),
        };
        let loops = &mut self.loops;
        let remaining = goal - loops.trajectory_position;
        if velocity_limit <= 0.0 {
            // Profile Velocity 0: no profile, the goal is a step.
            loops.trajectory_position = goal;
            loops.trajectory_velocity = 0.0;
            loops.profile_ongoing = false;
            loops.profile_type = 0;
            return;
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
        loops.profile_type = if accel <= 0.0 {
            1
        } else if velocity_limit * velocity_limit / accel > remaining.abs() + step {
            2
        } else {
            3
        };
    }

    fn update_thermal(&mut self, current_a: f64, dt: f64) {
        let spec = self.motor.spec();
        let steady = self.ambient_c + self.motor.copper_loss_w(current_a) * spec.thermal_resistance_c_per_w;
        self.temperature_c += (steady - self.temperature_c) * (dt / spec.thermal_time_constant_s).min(1.0);
    }

    /// Hardware errors (reference §8): latched in Hardware Error Status until reboot; those in
    /// the Shutdown mask also force torque off.
    fn check_protections(&mut self, current_a: f64, dt: f64) {
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

    fn check_watchdog(&mut self, now: Duration) {
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
            // Stop as if both profile values were 0: hold here, or zero speed/effort.
            self.table.set(keys.profile_velocity, 0);
            self.table.set(keys.profile_acceleration, 0);
            self.table.set(keys.goal_position, self.get(keys.present_position));
            self.table.set(keys.goal_velocity, 0);
            self.table.set(keys.goal_pwm, 0);
            self.table.set(keys.goal_current, 0);
            self.reset_trajectory();
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::profile::tests::xm540;
    use crate::device::shaft::{BenchLoad, ShaftLoad};

    fn servo() -> Servo {
        Servo::new(Arc::new(xm540()), 1, 1, 12.0)
    }

    fn write(servo: &mut Servo, now: Duration, address: u16, data: &[u8]) -> Result<Vec<u8>, DeviceError> {
        servo.handle(now, Request::Write { address, data }, Addressing::default()).reply
    }

    fn run(servo: &mut Servo, load: &mut BenchLoad, from: Duration, seconds: f64) -> Duration {
        let mut now = from;
        let ticks = (seconds / servo.control_period().as_secs_f64()) as usize;
        for _ in 0..ticks {
            now += servo.control_period();
            let drive = servo.drive();
            let state = load.step(&drive, servo.control_period().as_secs_f64());
            servo.sense(now, state);
        }
        now
    }

    fn read_i32(servo: &mut Servo, address: u16) -> i32 {
        let bytes = servo.handle(Duration::ZERO, Request::Read { address, length: 4 }, Addressing::default()).reply.unwrap();
        i32::from_le_bytes(bytes.try_into().unwrap())
    }

    #[test]
    fn ping_reports_model_and_firmware() {
        let reply = servo().handle(Duration::ZERO, Request::Ping, Addressing::default()).reply.unwrap();
        assert_eq!(reply, [0x60, 0x04, 48]);
    }

    #[test]
    fn position_mode_reaches_goal() {
        let mut s = servo();
        let mut load = BenchLoad::new(0.0);
        write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
        write(&mut s, Duration::ZERO, 116, &1000i32.to_le_bytes()).unwrap();
        run(&mut s, &mut load, Duration::ZERO, 1.0);
        let present = read_i32(&mut s, 132);
        assert!((present - 1000).abs() <= 5, "present {present}");
    }

    #[test]
    fn velocity_mode_tracks_goal() {
        let mut s = servo();
        let mut load = BenchLoad::new(0.0);
        write(&mut s, Duration::ZERO, 11, &[1]).unwrap();
        write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
        write(&mut s, Duration::ZERO, 104, &50i32.to_le_bytes()).unwrap();
        run(&mut s, &mut load, Duration::ZERO, 2.0);
        let velocity = read_i32(&mut s, 128);
        assert!((velocity - 50).abs() <= 2, "velocity {velocity}");
    }

    #[test]
    fn full_pwm_runs_at_datasheet_no_load_speed() {
        let mut s = servo();
        let mut load = BenchLoad::new(0.0);
        write(&mut s, Duration::ZERO, 11, &[16]).unwrap();
        write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
        write(&mut s, Duration::ZERO, 100, &885i16.to_le_bytes()).unwrap();
        run(&mut s, &mut load, Duration::ZERO, 0.5);
        let rpm = load.state().velocity_rad_s * 60.0 / TAU;
        assert!((rpm - 30.0).abs() / 30.0 < 0.02, "no-load speed {rpm} rev/min");
    }

    #[test]
    fn watchdog_trips_and_refuses_goals_until_cleared() {
        let mut s = servo();
        let mut load = BenchLoad::new(0.0);
        write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
        write(&mut s, Duration::ZERO, 98, &[5]).unwrap();
        let now = run(&mut s, &mut load, Duration::ZERO, 0.2);
        assert_eq!(s.table().read(98, 1).unwrap(), [0xFF]);
        assert_eq!(write(&mut s, now, 116, &0i32.to_le_bytes()), Err(DeviceError::DataRange));
        write(&mut s, now, 98, &[0]).unwrap();
        assert!(write(&mut s, now, 116, &0i32.to_le_bytes()).is_ok());
    }

    #[test]
    fn shutdown_error_forces_torque_off_until_reboot() {
        let mut s = servo();
        let mut load = BenchLoad::new(0.0);
        write(&mut s, Duration::ZERO, 31, &[20]).unwrap(); // Temperature Limit below ambient
        write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
        let now = run(&mut s, &mut load, Duration::ZERO, 0.01);
        assert_eq!(s.hardware_error_status() & 0x04, 0x04);
        assert!(!s.torque_on());
        write(&mut s, now, 64, &[1]).unwrap();
        assert!(!s.torque_on(), "torque stays off while the shutdown is latched");
        assert_eq!(s.status_error_byte(&Ok(vec![])), 0x80);
        write(&mut s, now, 31, &[80]).unwrap();
        s.finish(now, AfterReply::Reboot);
        assert_eq!(s.hardware_error_status(), 0);
    }

    #[test]
    fn operating_mode_change_resets_profile_and_goal_limits() {
        let mut s = servo();
        write(&mut s, Duration::ZERO, 112, &100i32.to_le_bytes()).unwrap();
        write(&mut s, Duration::ZERO, 100, &10i16.to_le_bytes()).unwrap();
        write(&mut s, Duration::ZERO, 11, &[1]).unwrap();
        assert_eq!(read_i32(&mut s, 112), 0);
        assert_eq!(s.table().read(100, 2).unwrap(), 885u16.to_le_bytes());
    }

    #[test]
    fn reg_write_waits_for_action() {
        let mut s = servo();
        let reply = s.handle(Duration::ZERO, Request::RegWrite { address: 65, data: &[1] }, Addressing::default()).reply;
        assert!(reply.is_ok());
        assert_eq!(s.table().read(65, 1).unwrap(), [0]);
        assert_eq!(s.table().read(69, 1).unwrap(), [1]);
        assert!(s.handle(Duration::ZERO, Request::Action, Addressing::default()).reply.is_ok());
        assert_eq!(s.table().read(65, 1).unwrap(), [1]);
        assert_eq!(s.table().read(69, 1).unwrap(), [0]);
        assert_eq!(s.handle(Duration::ZERO, Request::Action, Addressing::default()).reply, Err(DeviceError::Instruction));
    }

    #[test]
    fn reverse_drive_mode_flips_present_position() {
        let mut s = servo();
        let mut load = BenchLoad::new(0.0);
        write(&mut s, Duration::ZERO, 10, &[1]).unwrap();
        write(&mut s, Duration::ZERO, 11, &[4]).unwrap();
        write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
        write(&mut s, Duration::ZERO, 116, &500i32.to_le_bytes()).unwrap();
        run(&mut s, &mut load, Duration::ZERO, 1.0);
        assert!((read_i32(&mut s, 132) - 500).abs() <= 5);
        assert!(load.state().position_rad < 0.0, "the shaft turned the other way");
    }
}
