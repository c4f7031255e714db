//! The robot description (`hil/robot.toml`): which servos sit on the bus, with which firmware.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::Deserialize;
use thiserror::Error;

use crate::bus::{self, Bus, BusError, Timing};
use crate::device::{BenchPlant, FirmwareProfile, ProfileError};
use crate::source_location::{DataFileError, load_toml};

#[derive(Debug, Error)]
pub enum RobotError {
    #[error(transparent)]
    File(#[from] DataFileError),
    #[error(transparent)]
    Profile(#[from] ProfileError),
    #[error("robot description {path}: {source}")]
    Bus { path: PathBuf, source: BusError },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ServoRole {
    WheelDrive,
    MagnetShaft,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServoSpec {
    pub id: u8,
    pub name: String,
    pub role: ServoRole,
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
pub struct RobotDescription {
    pub bus: BusSpec,
    pub servo: Vec<ServoSpec>,
    #[serde(skip)]
    pub path: PathBuf,
}

impl RobotDescription {
    /// The description shipped with climbsim.
    pub fn default_path() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("hil/robot.toml")
    }

    pub fn load(path: &Path) -> Result<Self, RobotError> {
        let mut robot: Self = load_toml("robot description", path)?;
        robot.path = path.to_owned();
        Ok(robot)
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
        let profile = Arc::new(FirmwareProfile::load(&self.profile_path())?);
        let baud = baud_override.unwrap_or(self.bus.baud_bps);
        let wrap = |source| RobotError::Bus { path: self.path.clone(), source };
        let servos = bus::servos_from_profile(&profile, &self.ids(), baud, self.bus.supply_voltage_v).map_err(wrap)?;
        Bus::new(servos, Box::new(BenchPlant::default()), timing, baud).map_err(wrap)
    }
}
