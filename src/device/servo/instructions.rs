//! What a servo does with a request (reference §4–§6): Ping, Read, Write, Reg Write and Action,
//! the Sync and Bulk addressing the bus resolves, Factory Reset, Reboot, Clear and Control
//! Table Backup; the status error byte; what happens after the reply has left (a reboot, a new
//! baud); and the side effects of writes (operating mode, torque on). The firmware's periodic
//! tick is in `firmware.rs`: this file runs when a packet arrives, that one every control
//! period.

use super::*;

impl Servo {
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

    pub(super) fn set_identity(&mut self) {
        let model = self.profile().model.clone();
        self.table.set(self.keys.model_number, i64::from(model.model_number));
        self.table.set(self.keys.firmware_version, i64::from(model.firmware_version));
        self.table.set(self.keys.model_information, i64::from(model.model_information));
    }

    pub(super) fn control_table_backup(&mut self, params: &[u8]) -> Outcome {
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
            self.set_if_present(self.keys.backup_ready, 1);
            return Outcome::done();
        }
        if self.backup.is_none() {
            return Outcome::reply(Err(DeviceError::ResultFail));
        }
        Outcome { reply: Ok(Vec::new()), after_reply: Some(AfterReply::RestoreBackup) }
    }

    /// Power-on / reboot: RAM to defaults, EEPROM kept, errors cleared, single-turn re-base.
    pub(super) fn boot(&mut self, now: Duration, restore_backup: bool) {
        let keys = self.keys;
        self.table.reset(|item: &ItemSpec| item.area == Area::Ram);
        if restore_backup && let Some(backup) = &self.backup {
            self.table.copy_items_from(backup, |item| item.backup);
        }
        let startup = self.get_or(keys.startup_configuration, 0);
        if startup & STARTUP_RESTORE_RAM != 0
            && let Some(backup) = &self.backup
        {
            self.table.copy_items_from(backup, |item| item.backup && item.area == Area::Ram);
        }
        self.set_if_present(keys.backup_ready, i64::from(self.backup.is_some()));
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
        self.set_if_present(keys.goal_current, self.get_or(keys.current_limit, 0));
        if startup & STARTUP_TORQUE_ON != 0 {
            self.enable_torque(now);
        }
    }

    pub(super) fn context(&self, addressing: Addressing) -> WriteContext {
        WriteContext { torque_on: self.torque_on(), operating_mode: self.operating_mode(), via_secondary_id: addressing.via_secondary_id }
    }

    /// The goal items the model has.
    pub(super) fn goal_keys(&self) -> impl Iterator<Item = usize> + use<> {
        [Some(self.keys.goal_pwm), self.keys.goal_current, Some(self.keys.goal_velocity), Some(self.keys.goal_position)].into_iter().flatten()
    }

    /// Every check of a write, including the firmware rules beyond the table's own.
    pub(super) fn stage(&self, address: u16, data: &[u8], addressing: Addressing) -> Result<StagedWrite, DeviceError> {
        let staged = self.table.stage_write(address, data, self.context(addressing))?;
        if self.watchdog_tripped {
            // After expiry, goal writes are refused until the watchdog is cleared with 0.
            if self.goal_keys().any(|k| staged.touches(k)) {
                return Err(DeviceError::DataRange);
            }
            if staged.value_of(self.keys.bus_watchdog).is_some_and(|v| v != 0) {
                return Err(DeviceError::DataRange);
            }
        }
        Ok(staged)
    }

    pub(super) fn write(&mut self, now: Duration, address: u16, data: &[u8], addressing: Addressing) -> Result<(), DeviceError> {
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
        let goal_written = self.goal_keys().any(|k| staged.touches(k));
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
    pub(super) fn change_operating_mode(&mut self, mode: i64) {
        let keys = self.keys;
        let gains = [keys.velocity_i_gain, keys.velocity_p_gain, keys.position_d_gain, keys.position_i_gain, keys.position_p_gain, keys.feedforward_2nd_gain, keys.feedforward_1st_gain];
        let profile = Arc::clone(self.profile());
        for index in gains {
            self.table.set(index, profile.items[index].spec.default.unwrap_or(0));
        }
        self.table.set(keys.profile_acceleration, 0);
        self.table.set(keys.profile_velocity, 0);
        self.table.set(keys.goal_pwm, self.get(keys.pwm_limit));
        self.set_if_present(keys.goal_current, self.get_or(keys.current_limit, 0));
        self.loops = LoopState::default();
        if mode == i64::from(profile.operating_modes.position) {
            self.rebase_single_turn();
        }
        self.publish_position();
        self.reset_trajectory();
    }

    /// Torque on: refused while a shutdown is latched; otherwise the goal becomes the present
    /// position so the horn does not jump (chosen; real X-series servos behave this way).
    pub(super) fn enable_torque(&mut self, now: Duration) {
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
}
