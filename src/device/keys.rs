//! The control-table items the device code uses, by key: the profile that owns them resolves
//! them once ([`super::FirmwareProfile::keys`]).

macro_rules! item_keys {
    ($($key:ident),* $(,)?) => {
        /// Indices (into the profile's item list) of every item the servo logic touches.
        #[derive(Debug, Clone, Copy)]
        pub struct Keys { $(pub $key: usize,)* }

        impl Keys {
            /// Keys every profile must define.
            pub const NAMES: &'static [&'static str] = &[$(stringify!($key)),*];

            /// Every key's index, as `index` finds it.
            pub(super) fn resolve(index: impl Fn(&str) -> usize) -> Self {
                Self { $($key: index(stringify!($key)),)* }
            }
        }
    };
}

item_keys!(
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
    current_limit,
    velocity_limit,
    startup_configuration,
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
    goal_current,
    goal_velocity,
    profile_acceleration,
    profile_velocity,
    goal_position,
    realtime_tick,
    moving,
    moving_status,
    present_pwm,
    present_current,
    present_velocity,
    present_position,
    velocity_trajectory,
    position_trajectory,
    present_input_voltage,
    present_temperature,
    backup_ready,
);
