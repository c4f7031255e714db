//! The robot description (`hil/robot.toml`): which servos sit on the bus, with which firmware.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::Deserialize;
use thiserror::Error;

use crate::bus::{self, Bus, BusError, Timing};
// Defined below the bus (fault descriptions name wheels too); part of the robot description.
use crate::device::{BenchPlant, FirmwareProfile, Plant, ProfileError, Servo};
use crate::overrides::{Override, PROFILE_PREFIX, ROBOT_PREFIX};
pub use crate::parts::{ServoRole, WheelPosition};
use crate::source_location::{DataFileError, load_toml_with};

/// What a robot description is called in errors.
pub const WHAT: &str = "robot description";

#[derive(Debug, Error)]
pub enum RobotError {
    #[error(transparent)]
    File(#[from] DataFileError),
    #[error(transparent)]
    Profile(#[from] ProfileError),
    #[error("robot description {path}: {source}")]
    Bus { path: PathBuf, source: BusError },
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServoSpec {
    pub id: u8,
    pub name: String,
    pub role: ServoRole,
    pub wheel: WheelPosition,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SectionSpec {
    /// Collision box.
    pub half_extents_m: [f32; 3],
    pub mass_kg: f32,
    /// Principal moments of inertia about the section's centre, along x (roll), y (yaw) and z
    /// (pitch), in kg·m².
    pub inertia_kgm2: [f32; 3],
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RockerSpec {
    pub limit_deg: f32,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    pub wheelbase_m: f32,
    pub track_m: f32,
    pub axle_drop_m: f32,
    pub front: SectionSpec,
    pub middle: SectionSpec,
    pub rear: SectionSpec,
    pub rocker: RockerSpec,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WheelSpec {
    pub outer_radius_m: f32,
    pub inner_radius_m: f32,
    pub width_m: f32,
    pub mass_kg: f32,
    pub friction: f32,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MagnetSpec {
    pub mass_kg: f32,
    pub lever_m: f32,
    pub pull_at_contact_n: f32,
    pub decay_length_m: f32,
    pub range_m: f32,
    pub alignment_exponent: f32,
    pub damping_nm_s_per_rad: f32,
    pub probe_radius_m: f32,
    pub encoder_at_down_pulses: u32,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSpec {
    pub profile: PathBuf,
    pub baud_bps: u32,
    pub supply_voltage_v: f64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraMount {
    pub position_m: [f32; 3],
    pub orthographic_size_m: f32,
    pub image_px: u32,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LidarMount {
    pub position_m: [f32; 3],
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotDescription {
    pub bus: BusSpec,
    pub servo: Vec<ServoSpec>,
    pub body: BodySpec,
    pub wheel: WheelSpec,
    pub magnet: MagnetSpec,
    pub camera: CameraMount,
    pub lidar: LidarMount,
    #[serde(skip)]
    pub path: PathBuf,
    /// `--set profile.KEY=VALUE`: set in the firmware profile whenever it is loaded.
    #[serde(skip)]
    pub profile_overrides: Vec<Override>,
}

/// `--set robot.KEY=VALUE` and `--set profile.KEY=VALUE`: keys of the robot description and of
/// its firmware profile, set as a scenario's are (`robot.wheel.friction=0.35`,
/// `profile.motor.coulomb_friction_nm=0.04`). One key syntax for `run`, `sweep`, `serve`,
/// `compare`, `fit` and a recording's `replay`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RobotOverrides {
    /// `robot.…` keys, as given.
    pub robot: Vec<Override>,
    /// `profile.…` keys, as given.
    pub profile: Vec<Override>,
}

impl RobotOverrides {
    /// Split `--set` overrides into the scenario's (returned) and the robot's and profile's.
    pub fn split(all: &[Override]) -> (Vec<Override>, Self) {
        let mut scenario = Vec::new();
        let mut these = Self::default();
        for set in all {
            if set.key.starts_with(ROBOT_PREFIX) {
                these.robot.push(set.clone());
            } else if set.key.starts_with(PROFILE_PREFIX) {
                these.profile.push(set.clone());
            } else {
                scenario.push(set.clone());
            }
        }
        (scenario, these)
    }

    pub fn is_empty(&self) -> bool {
        self.robot.is_empty() && self.profile.is_empty()
    }
}

impl RobotDescription {
    /// The description shipped with climbsim.
    pub fn default_path() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("hil/robot.toml")
    }

    pub fn load(path: &Path) -> Result<Self, RobotError> {
        Self::load_with(path, &RobotOverrides::default())
    }

    /// Load with `--set robot.…` and `--set profile.…` keys set (the profile's when it is
    /// loaded; it is checked here, so that a bad key fails before anything runs).
    pub fn load_with(path: &Path, overrides: &RobotOverrides) -> Result<Self, RobotError> {
        let mut robot: Self = load_toml_with(WHAT, path, ROBOT_PREFIX, &overrides.robot)?;
        robot.path = path.to_owned();
        robot.profile_overrides = overrides.profile.clone();
        if !robot.profile_overrides.is_empty() {
            robot.profile()?;
        }
        Ok(robot)
    }

    /// The firmware profile, with this description's `--set profile.…` keys.
    pub fn profile(&self) -> Result<FirmwareProfile, RobotError> {
        Ok(FirmwareProfile::load_with(&self.profile_path(), &self.profile_overrides)?)
    }

    /// The firmware profile path, resolved against this file's folder.
    pub fn profile_path(&self) -> PathBuf {
        self.path.parent().unwrap_or(Path::new(".")).join(&self.bus.profile)
    }

    pub fn ids(&self) -> Vec<u8> {
        self.servo.iter().map(|s| s.id).collect()
    }

    /// A bus of bench-loaded servos at factory defaults (baud from the description unless given).
    pub fn bench_bus(&self, timing: Timing, baud_override: Option<u32>) -> Result<Bus, RobotError> {
        self.bus_with_plant(Box::new(BenchPlant::default()), timing, baud_override)
    }

    /// A bus of factory-fresh servos whose shafts `plant` drives.
    pub fn bus_with_plant(&self, plant: Box<dyn Plant>, timing: Timing, baud_override: Option<u32>) -> Result<Bus, RobotError> {
        let servos = self.servos(baud_override)?;
        self.bus_of(servos, plant, timing, baud_override)
    }

    /// Factory-fresh servos for this description (power-on baud from it unless given).
    pub fn servos(&self, baud_override: Option<u32>) -> Result<Vec<Servo>, RobotError> {
        let profile = Arc::new(self.profile()?);
        let baud = baud_override.unwrap_or(self.bus.baud_bps);
        bus::servos_from_profile(&profile, &self.ids(), baud, self.bus.supply_voltage_v).map_err(|source| RobotError::Bus { path: self.path.clone(), source })
    }

    /// A bus of `servos` driving `plant`.
    pub fn bus_of(&self, servos: Vec<Servo>, plant: Box<dyn Plant>, timing: Timing, baud_override: Option<u32>) -> Result<Bus, RobotError> {
        let baud = baud_override.unwrap_or(self.bus.baud_bps);
        Bus::new(servos, plant, timing, baud).map_err(|source| RobotError::Bus { path: self.path.clone(), source })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sets(texts: &[&str]) -> Vec<Override> {
        texts.iter().map(|t| Override::parse(t).expect("KEY=VALUE")).collect()
    }

    #[test]
    fn robot_and_profile_keys_are_split_from_the_scenarios_and_set_in_their_files() {
        let (scenario, robot_sets) = RobotOverrides::split(&sets(&["world.seed=3", "robot.wheel.friction=0.35", "profile.motor.coulomb_friction_nm=0.05"]));
        assert_eq!(scenario, sets(&["world.seed=3"]));
        assert_eq!((robot_sets.robot.clone(), robot_sets.profile.clone()), (sets(&["robot.wheel.friction=0.35"]), sets(&["profile.motor.coulomb_friction_nm=0.05"])));
        let robot = RobotDescription::load_with(&RobotDescription::default_path(), &robot_sets).expect("loads");
        assert_eq!(robot.wheel.friction, 0.35);
        assert_eq!(robot.profile().expect("the profile loads").motor.coulomb_friction_nm, 0.05);
    }

    #[test]
    fn a_key_neither_file_has_is_named_as_given() {
        let (_, robot_sets) = RobotOverrides::split(&sets(&["robot.wheel.frction=0.35"]));
        let error = RobotDescription::load_with(&RobotDescription::default_path(), &robot_sets).expect_err("no such key").to_string();
        assert!(error.contains("--set robot.wheel.frction=0.35") && error.contains("unknown field `frction`"), "{error}");
        let (_, profile_sets) = RobotOverrides::split(&sets(&["profile.motor.coulomb_friction_nm=\"x\""]));
        let error = RobotDescription::load_with(&RobotDescription::default_path(), &profile_sets).expect_err("not a number").to_string();
        assert!(error.contains("profile.motor.coulomb_friction_nm"), "{error}");
    }
}
