//! Scenario files (TOML): the world a run happens in. Issue #3 needs terrain, start pose, gravity
//! and duration; issue #4 adds the line, controller, events and metrics.

use std::path::{Path, PathBuf};

use rapier3d::prelude::Vector;
use serde::Deserialize;
use thiserror::Error;

use crate::sim::terrain::{TerrainError, TerrainSpec, generate};
use crate::sim::{StartPose, WorldConfig};
use crate::source_location::{DataFileError, load_toml};

#[derive(Debug, Error)]
pub enum ScenarioError {
    #[error(transparent)]
    File(#[from] DataFileError),
    #[error("scenario {path}: terrain: {source}")]
    Terrain { path: PathBuf, source: TerrainError },
}

fn default_gravity() -> [f32; 3] {
    [0.0, -9.81, 0.0]
}

fn default_true() -> bool {
    true
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldSection {
    /// Seed of every random choice (terrain noise).
    pub seed: u64,
    /// Gravity (m/s²) in the world frame (y up). Tilting it is how a slope or wall is simulated
    /// on flat steel; `[0, 0, 0]` turns it off as in the seed's experiments.
    #[serde(default = "default_gravity")]
    pub gravity_m_s2: [f32; 3],
    /// Length of a headless run (s).
    pub duration_s: f64,
    /// Magnets on at the start.
    #[serde(default = "default_true")]
    pub magnets: bool,
    /// Tread-on-terrain friction, if not the robot description's.
    #[serde(default)]
    pub friction: Option<f32>,
    /// Extra mass carried on the middle section (kg), e.g. a towed welding carriage.
    #[serde(default)]
    pub payload_kg: f32,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartSection {
    #[serde(default)]
    pub x_m: f32,
    #[serde(default)]
    pub z_m: f32,
    #[serde(default)]
    pub yaw_deg: f32,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    pub world: WorldSection,
    pub terrain: TerrainSpec,
    #[serde(default)]
    pub start: Option<StartSection>,
    #[serde(skip)]
    pub path: PathBuf,
}

impl Scenario {
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let mut scenario: Self = load_toml("scenario", path)?;
        scenario.path = path.to_owned();
        Ok(scenario)
    }

    /// The world this scenario describes (terrain generated from its seed).
    pub fn world_config(&self) -> Result<WorldConfig, ScenarioError> {
        let base = self.path.parent().unwrap_or(Path::new("."));
        let terrain = generate(&self.terrain, self.world.seed, base).map_err(|source| ScenarioError::Terrain { path: self.path.clone(), source })?;
        let start = self.start.as_ref().map_or_else(StartPose::default, |s| StartPose { x_m: s.x_m, z_m: s.z_m, yaw_deg: s.yaw_deg, ..StartPose::default() });
        let [gx, gy, gz] = self.world.gravity_m_s2;
        Ok(WorldConfig {
            gravity: Vector::new(gx, gy, gz),
            terrain,
            start,
            friction: self.world.friction,
            magnets_on: self.world.magnets,
            payload_kg: self.world.payload_kg,
        })
    }
}
