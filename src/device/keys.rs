//! The control-table items the device code uses, by key: the profile that owns them resolves
//! them once ([`super::FirmwareProfile::keys`]).

macro_rules! item_keys {
    (required: $($key:ident),* $(,)?; optional: $($optional:ident),* $(,)?) => {
        /// Indices (into the profile's item list) of every item the servo logic touches. An
        /// optional item is one some models lack (the XL430 has no Current Limit or Goal Current
        /// and reads Present Load where others read Present Current): the firmware skips what
        /// the model does not have, as the model's own firmware has no such item.
        #[derive(Debug, Clone, Copy)]
        pub struct Keys {
            $(pub $key: usize,)*
            $(pub $optional: Option<usize>,)*
        }

        impl Keys {
            /// Keys every profile must define.
            pub const NAMES: &'static [&'static str] = &[$(stringify!($key)),*];

            /// Every key's index as `find` finds it; `None` from `find` for a required key is a
            /// programming error, since a profile is checked against `NAMES` when it loads.
            pub(super) fn resolve(find: impl Fn(&str) -> Option<usize>) -> Self {
                Self {
                    // ok: required keys were checked when the profile loaded.
                    $($key: find(stringify!($key)).expect("a required item, checked at load"),)*
                    $($optional: find(stringify!($optional)),)*
                }
            }
        }
    };
}

item_keys!(
    required:
    model_number,
    model_information,
    firmware_version,
    id,
    baud_rate,
    return_delay_time,
    drive_mode,
    operating_mode,
    secondary_id,
    protocol_type,
    homing_offset,
    moving_threshold,
    temperature_limit,
    max_voltage_limit,
    min_voltage_limit,
    pwm_limit,
    velocity_limit,
    shutdown,
    torque_enable,
    status_return_level,
    registered_instruction,
    hardware_error_status,
    velocity_i_gain,
    velocity_p_gain,
    position_d_gain,
    position_i_gain,
    position_p_gain,
    feedforward_2nd_gain,
    feedforward_1st_gain,
    bus_watchdog,
    goal_pwm,
    goal_velocity,
    profile_acceleration,
    profile_velocity,
    goal_position,
    realtime_tick,
    moving,
    moving_status,
    present_pwm,
    present_velocity,
    present_position,
    velocity_trajectory,
    position_trajectory,
    present_input_voltage,
    present_temperature;
    optional:
    current_limit,
    goal_current,
    present_current,
    present_load,
    startup_configuration,
    backup_ready,
);
