//! Firmware profiles: a servo model's control table and motor constants, loaded from a TOML file
//! in `firmware-profiles/`. The device code names items by `key` only; every address, size, range
//! and constant comes from here.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use thiserror::Error;

use crate::source_location::{DataFileError, load_toml, load_toml_with, parse_toml};

use super::keys::Keys;

pub const WHAT: &str = "firmware profile";

/// A profile file that cannot be used.
#[derive(Debug, Error)]
pub enum ProfileError {
    #[error(transparent)]
    File(#[from] DataFileError),
    #[error("firmware profile {path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum Access {
    R,
    RW,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Area {
    Eeprom,
    Ram,
}

/// One control-table item as written in the profile file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ItemSpec {
    pub key: String,
    pub name: String,
    pub address: u16,
    pub size: u16,
    pub access: Access,
    pub area: Area,
    #[serde(default)]
    pub default: Option<i64>,
    #[serde(default)]
    pub min: Option<i64>,
    #[serde(default)]
    pub max: Option<i64>,
    /// Lower bound taken from another item (`"-key"` negates it); breaking it is a Data Limit Error.
    #[serde(default)]
    pub min_ref: Option<String>,
    #[serde(default)]
    pub max_ref: Option<String>,
    /// Operating modes in which `min_ref`/`max_ref` apply (all modes when absent).
    #[serde(default)]
    pub refs_in_modes: Option<Vec<i64>>,
    /// The only values accepted.
    #[serde(default)]
    pub values: Option<Vec<i64>>,
    #[serde(default)]
    pub signed: bool,
    #[serde(default)]
    pub unit: Option<String>,
    #[serde(default)]
    pub scale: Option<f64>,
    /// Saved by Control Table Backup.
    #[serde(default)]
    pub backup: bool,
    #[serde(default)]
    pub note: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSpec {
    pub name: String,
    pub model_number: u16,
    pub firmware_version: u8,
    pub model_information: u32,
    pub boot_time_ms: u64,
    pub control_period_us: u64,
    pub in_position_window_pulses: i64,
    pub following_error_pulses: i64,
    pub bits_per_byte: u32,
    pub inter_byte_timeout_us: u64,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaudRate {
    pub code: u8,
    pub bps: u32,
}

/// Motor and gearbox constants (datasheet figures and documented choices).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotorSpec {
    pub rated_voltage_v: f64,
    pub stall_torque_nm: f64,
    pub stall_current_a: f64,
    pub no_load_speed_rpm: f64,
    pub standby_current_a: f64,
    pub gear_ratio: f64,
    pub pulses_per_rev: u32,
    pub rotor_inertia_kgm2: f64,
    pub coulomb_friction_nm: f64,
    pub viscous_friction_nm_per_rad_s: f64,
    pub thermal_resistance_c_per_w: f64,
    pub thermal_time_constant_s: f64,
    pub ambient_temperature_c: f64,
    pub overload_current_fraction: f64,
    pub overload_time_s: f64,
    /// The torque-speed slope at the horn (N·m per rad/s). Absent: the datasheet line through
    /// the stall torque and the no-load speed, friction left out. A profile with identified
    /// friction gives the slope that keeps the datasheet's no-load speed with that friction.
    #[serde(default)]
    pub back_emf_damping_nm_per_rad_s: Option<f64>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HardwareErrorBits {
    pub input_voltage: u8,
    pub overheating: u8,
    pub motor_encoder: u8,
    pub electrical_shock: u8,
    pub overload: u8,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IndirectBlock {
    pub address_start: u16,
    pub data_start: u16,
    pub count: u16,
}

/// The Operating Mode values a model has. A model without current sensing (XL430, XC430) has no
/// current or current-based position mode.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OperatingModes {
    #[serde(default)]
    pub current: Option<u8>,
    pub velocity: u8,
    pub position: u8,
    pub extended_position: u8,
    #[serde(default)]
    pub current_based_position: Option<u8>,
    pub pwm: u8,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct ProfileFile {
    model: ModelSpec,
    baud_rate: Vec<BaudRate>,
    motor: MotorSpec,
    hardware_error_bits: HardwareErrorBits,
    indirect_block: Vec<IndirectBlock>,
    operating_modes: OperatingModes,
    item: Vec<ItemSpec>,
}

/// A bound resolved against the table: a constant or (the negation of) another item's value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bound {
    Const(i64),
    Item { index: usize, negate: bool },
}

/// A control-table item with its references resolved.
#[derive(Debug, Clone)]
pub struct Item {
    pub spec: ItemSpec,
    pub min: Option<Bound>,
    pub max: Option<Bound>,
}

impl Item {
    pub fn address(&self) -> u16 {
        self.spec.address
    }
    pub fn size(&self) -> usize {
        usize::from(self.spec.size)
    }
    pub fn end(&self) -> usize {
        usize::from(self.spec.address) + self.size()
    }
}

/// A validated firmware profile.
#[derive(Debug, Clone)]
pub struct FirmwareProfile {
    pub path: PathBuf,
    pub model: ModelSpec,
    pub baud_rates: Vec<BaudRate>,
    pub motor: MotorSpec,
    pub hardware_error_bits: HardwareErrorBits,
    pub indirect_blocks: Vec<IndirectBlock>,
    pub operating_modes: OperatingModes,
    pub items: Vec<Item>,
    /// For every address of the table, the index of the item covering it.
    item_at: Vec<Option<usize>>,
    by_key: HashMap<String, usize>,
}

impl FirmwareProfile {
    /// Load and validate a profile file.
    pub fn load(path: &Path) -> Result<Self, ProfileError> {
        let file: ProfileFile = load_toml(WHAT, path)?;
        Self::from_file(path, file)
    }

    /// Load with `overrides` set in the file (`--set profile.motor.coulomb_friction_nm=0.04`).
    pub fn load_with(path: &Path, overrides: &[crate::overrides::Override]) -> Result<Self, ProfileError> {
        let file: ProfileFile = load_toml_with(WHAT, path, crate::overrides::PROFILE_PREFIX, overrides)?;
        Self::from_file(path, file)
    }

    /// Parse profile text; `path` is used in error messages only.
    pub fn parse(path: &Path, text: &str) -> Result<Self, ProfileError> {
        Self::from_file(path, parse_toml(WHAT, path, text)?)
    }

    fn from_file(path: &Path, file: ProfileFile) -> Result<Self, ProfileError> {
        let invalid = |message: String| ProfileError::Invalid { path: path.to_owned(), message };

        let mut specs = file.item;
        specs.sort_by_key(|i| i.address);
        let mut by_key = HashMap::new();
        for (index, spec) in specs.iter().enumerate() {
            if spec.size == 0 || spec.size > 4 {
                return Err(invalid(format!("item `{}` has size {}, expected 1..=4", spec.key, spec.size)));
            }
            if by_key.insert(spec.key.clone(), index).is_some() {
                return Err(invalid(format!("item key `{}` appears twice", spec.key)));
            }
        }
        let table_len = specs.iter().map(|s| usize::from(s.address) + usize::from(s.size)).max().unwrap_or(0);
        let mut item_at = vec![None; table_len];
        for (index, spec) in specs.iter().enumerate() {
            let start = usize::from(spec.address);
            for (offset, slot) in item_at[start..start + usize::from(spec.size)].iter_mut().enumerate() {
                if let Some(other) = *slot {
                    let other: &ItemSpec = &specs[other];
                    return Err(invalid(format!("items `{}` and `{}` overlap at address {}", other.key, spec.key, start + offset)));
                }
                *slot = Some(index);
            }
            if let Some(scale) = spec.scale
                && !(scale.is_finite() && scale > 0.0)
            {
                return Err(invalid(format!("item `{}` has scale {scale}; it must be a positive number", spec.key)));
            }
        }
        let resolve = |spec: &ItemSpec, reference: &Option<String>, constant: Option<i64>| -> Result<Option<Bound>, ProfileError> {
            match (reference, constant) {
                (Some(r), _) => {
                    let (negate, key) = match r.strip_prefix('-') {
                        Some(k) => (true, k),
                        None => (false, r.as_str()),
                    };
                    let index = *by_key.get(key).ok_or_else(|| invalid(format!("item `{}` refers to unknown item `{key}`", spec.key)))?;
                    Ok(Some(Bound::Item { index, negate }))
                }
                (None, Some(c)) => Ok(Some(Bound::Const(c))),
                (None, None) => Ok(None),
            }
        };
        let mut items = Vec::with_capacity(specs.len());
        for spec in &specs {
            let min = resolve(spec, &spec.min_ref, spec.min)?;
            let max = resolve(spec, &spec.max_ref, spec.max)?;
            items.push(Item { spec: spec.clone(), min, max });
        }
        let profile = Self {
            path: path.to_owned(),
            model: file.model,
            baud_rates: file.baud_rate,
            motor: file.motor,
            hardware_error_bits: file.hardware_error_bits,
            indirect_blocks: file.indirect_block,
            operating_modes: file.operating_modes,
            items,
            item_at,
            by_key,
        };
        profile.check_required_keys().map_err(invalid)?;
        Ok(profile)
    }

    fn check_required_keys(&self) -> Result<(), String> {
        let missing: Vec<_> = Keys::NAMES.iter().filter(|k| !self.by_key.contains_key(**k)).collect();
        if !missing.is_empty() {
            return Err(format!("missing control-table items: {missing:?}"));
        }
        if self.baud_rates.is_empty() {
            return Err("no [[baud_rate]] entries".into());
        }
        self.check_motor()?;
        self.check_modes_and_units()?;
        for block in &self.indirect_blocks {
            for n in 0..block.count {
                let addr = self.item_index_at(block.address_start + 2 * n);
                let data = self.item_index_at(block.data_start + n);
                if addr.is_none() || data.is_none() {
                    return Err(format!("indirect block at {} has no item for entry {n}", block.address_start));
                }
            }
        }
        Ok(())
    }

    /// The firmware's modes must be the ones Operating Mode accepts, a current mode needs the
    /// current items, and every unit the servo model converts with must be given: a missing one
    /// would silently be 1 (885 units of PWM Limit read as 885 %).
    fn check_modes_and_units(&self) -> Result<(), String> {
        let modes = &self.operating_modes;
        let mut declared: Vec<i64> =
            [modes.current, Some(modes.velocity), Some(modes.position), Some(modes.extended_position), modes.current_based_position, Some(modes.pwm)].into_iter().flatten().map(i64::from).collect();
        declared.sort_unstable();
        if declared.windows(2).any(|pair| pair[0] == pair[1]) {
            return Err(format!("[operating_modes] gives one value to two modes: {declared:?}"));
        }
        let operating_mode = &self.items[self.index("operating_mode")].spec;
        if let Some(values) = &operating_mode.values {
            let mut accepted = values.clone();
            accepted.sort_unstable();
            if accepted != declared {
                return Err(format!("item `operating_mode` accepts {accepted:?} but [operating_modes] names {declared:?}: each accepted value is one mode the firmware runs"));
            }
        }
        if modes.current.is_some() || modes.current_based_position.is_some() {
            let missing: Vec<&str> = ["goal_current", "current_limit", "present_current"].into_iter().filter(|key| self.find(key).is_none()).collect();
            if !missing.is_empty() {
                return Err(format!("[operating_modes] has a current mode but the table has no {missing:?}"));
            }
        }
        let converted = ["pwm_limit", "present_velocity", "profile_acceleration", "present_input_voltage", "return_delay_time", "bus_watchdog", "present_current", "current_limit", "goal_current"];
        if let Some(key) = converted.into_iter().find(|key| self.find(key).is_some_and(|index| self.items[index].spec.scale.is_none())) {
            return Err(format!("item `{key}` has no scale: the servo model converts its unit"));
        }
        Ok(())
    }

    /// The motor's figures divide and scale the servo model: each must be a finite number, and
    /// those it divides by above zero.
    fn check_motor(&self) -> Result<(), String> {
        let m = &self.motor;
        let positive = [
            ("rated_voltage_v", m.rated_voltage_v),
            ("stall_torque_nm", m.stall_torque_nm),
            ("stall_current_a", m.stall_current_a),
            ("no_load_speed_rpm", m.no_load_speed_rpm),
            ("gear_ratio", m.gear_ratio),
            ("thermal_time_constant_s", m.thermal_time_constant_s),
            ("back_emf_damping_nm_per_rad_s", m.back_emf_damping_nm_per_rad_s.unwrap_or(1.0)),
        ];
        if let Some((key, value)) = positive.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
            return Err(format!("[motor] {key} = {value}: it must be a number above zero"));
        }
        let non_negative = [
            ("standby_current_a", m.standby_current_a),
            ("rotor_inertia_kgm2", m.rotor_inertia_kgm2),
            ("coulomb_friction_nm", m.coulomb_friction_nm),
            ("viscous_friction_nm_per_rad_s", m.viscous_friction_nm_per_rad_s),
            ("thermal_resistance_c_per_w", m.thermal_resistance_c_per_w),
            ("overload_current_fraction", m.overload_current_fraction),
            ("overload_time_s", m.overload_time_s),
        ];
        if let Some((key, value)) = non_negative.iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
            return Err(format!("[motor] {key} = {value}: it must be a number of zero or more"));
        }
        if m.pulses_per_rev == 0 || !m.ambient_temperature_c.is_finite() {
            return Err("[motor] pulses_per_rev must be above zero and ambient_temperature_c a number".into());
        }
        Ok(())
    }

    /// Bytes in the control table (one past the highest defined address).
    pub fn table_len(&self) -> usize {
        self.item_at.len()
    }

    /// The item covering `address`, if any.
    pub fn item_index_at(&self, address: u16) -> Option<usize> {
        self.item_at.get(usize::from(address)).copied().flatten()
    }

    /// The index of item `key`.
    ///
    /// # Panics
    /// Never for a key in `Keys::NAMES`: `parse` has checked they exist.
    pub fn index(&self, key: &str) -> usize {
        // ok: required keys are validated at load time; other keys are a programming error.
        self.by_key[key]
    }

    /// The items the device code uses, resolved once (their keys were checked at load time).
    pub(crate) fn keys(&self) -> Keys {
        Keys::resolve(|key| self.find(key))
    }

    pub fn find(&self, key: &str) -> Option<usize> {
        self.by_key.get(key).copied()
    }

    /// Bits per second for Baud Rate code `code`.
    pub fn baud_bps(&self, code: u8) -> Option<u32> {
        self.baud_rates.iter().find(|b| b.code == code).map(|b| b.bps)
    }

    /// Baud Rate code for `bps`.
    pub fn baud_code(&self, bps: u32) -> Option<u8> {
        self.baud_rates.iter().find(|b| b.bps == bps).map(|b| b.code)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn xm540() -> FirmwareProfile {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profiles/xm540-w270-r.toml");
        FirmwareProfile::load(&path).unwrap()
    }

    #[test]
    fn xm540_profile_loads_with_every_csv_row() {
        let profile = xm540();
        assert_eq!(profile.items.len(), 171);
        assert_eq!(profile.table_len(), 662);
        let goal = &profile.items[profile.index("goal_position")];
        assert_eq!((goal.address(), goal.size()), (116, 4));
        assert_eq!(profile.item_index_at(40), None, "old Acceleration Limit is reserved");
    }

    #[test]
    fn parse_error_names_file_and_line() {
        let err = FirmwareProfile::parse(Path::new("bad.toml"), "[model]\nname = 3\n").unwrap_err();
        let text = err.to_string();
        assert!(text.contains("bad.toml:2:"), "{text}");
    }

    #[test]
    fn a_motor_figure_the_model_divides_by_must_be_above_zero() {
        let text = std::fs::read_to_string(xm540().path).unwrap().replace("stall_current_a = 4.4", "stall_current_a = 0.0");
        let err = FirmwareProfile::parse(Path::new("x.toml"), &text).unwrap_err();
        assert!(err.to_string().contains("[motor] stall_current_a = 0: it must be a number above zero"), "{err}");
        let text = std::fs::read_to_string(xm540().path).unwrap().replace("coulomb_friction_nm = 0.03", "coulomb_friction_nm = nan");
        let err = FirmwareProfile::parse(Path::new("x.toml"), &text).unwrap_err();
        assert!(err.to_string().contains("coulomb_friction_nm = NaN"), "{err}");
    }

    #[test]
    fn modes_and_units_the_firmware_relies_on_are_checked_at_load() {
        let text = std::fs::read_to_string(xm540().path).unwrap();
        let cases = [
            (text.replace("values = [0, 1, 3, 4, 5, 16]", "values = [1, 3, 4, 16]"), "accepts [1, 3, 4, 16] but [operating_modes] names [0, 1, 3, 4, 5, 16]"),
            (text.replace("current_based_position = 5", "current_based_position = 4"), "gives one value to two modes"),
            (text.replace("unit = \"%\"\nscale = 0.113\nbackup = true\nnote = \"885 = 100 %. Bounds Goal PWM.\"", "backup = true"), "item `pwm_limit` has no scale"),
        ];
        for (text, expected) in cases {
            let err = FirmwareProfile::parse(Path::new("x.toml"), &text).unwrap_err();
            assert!(err.to_string().contains(expected), "{err}");
        }
        let xl430 = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profiles/xl430-w250.toml")).unwrap();
        let text = xl430.replace("velocity = 1\n", "current = 0\nvelocity = 1\n").replace("values = [1, 3, 4, 16]", "values = [0, 1, 3, 4, 16]");
        let err = FirmwareProfile::parse(Path::new("x.toml"), &text).unwrap_err();
        assert!(err.to_string().contains("has a current mode but the table has no [\"goal_current\", \"current_limit\", \"present_current\"]"), "{err}");
    }

    #[test]
    fn unknown_reference_is_rejected() {
        let text = std::fs::read_to_string(xm540().path).unwrap().replace("max_ref = \"velocity_limit\"", "max_ref = \"nope\"");
        let err = FirmwareProfile::parse(Path::new("x.toml"), &text).unwrap_err();
        assert!(err.to_string().contains("unknown item `nope`"), "{err}");
    }
}
