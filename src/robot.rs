//! The robot description (`hil/robot.toml`): which servos sit on the bus, with which firmware,
//! and the climbing robot's mechanics the world is built from. A description with a bus alone
//! (`hil/robots/koch-follower.toml`) is a robot served on the bench: each servo may name its own
//! profile and power-on baud, so one bus can mix models as real ones do.

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
    #[error("robot description {path} describes no climbing robot: it has no {missing}, so it can be served on the bench only (`climbsim serve --robot {path}` without a scenario)")]
    NotAClimber { path: PathBuf, missing: String },
    #[error("robot description {path} has {present} but no {missing}: the climbing robot's mechanics are [body], [wheel], [magnet], [camera] and [lidar] together")]
    PartialClimber { path: PathBuf, present: String, missing: String },
    #[error("robot description {path}: servo {id} ({name}): {message}")]
    ServoProfile { path: PathBuf, id: u8, name: String, message: String },
    #[error("robot description {path}: servo {id} ({name}) has {what}; every servo of the climbing robot has a role and a wheel")]
    ServoWithoutPlace { path: PathBuf, id: u8, name: String, what: String },
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServoSpec {
    pub id: u8,
    pub name: String,
    /// The climbing robot's: the servo's job and its wheel (absent on a bench robot).
    #[serde(default)]
    pub role: Option<ServoRole>,
    #[serde(default)]
    pub wheel: Option<WheelPosition>,
    /// This servo's firmware profile, relative to the description (the bus's when absent).
    #[serde(default)]
    pub profile: Option<PathBuf>,
    /// This servo's Baud Rate at power-on (the bus's when absent).
    #[serde(default)]
    pub baud_bps: Option<u32>,
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
    /// The profile of every servo that names none.
    pub profile: PathBuf,
    /// The Baud Rate at power-on of every servo that names none.
    pub baud_bps: u32,
    /// The supply at every servo (V). Absent: each servo at the voltage its profile rates
    /// (`[motor] rated_voltage_v`, its e-manual page's recommended one).
    #[serde(default)]
    pub supply_voltage_v: Option<f64>,
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
    /// The climbing robot's mechanics: all five, or none for a robot served on the bench only
    /// ([`RobotDescription::climber`]).
    #[serde(default)]
    pub body: Option<BodySpec>,
    #[serde(default)]
    pub wheel: Option<WheelSpec>,
    #[serde(default)]
    pub magnet: Option<MagnetSpec>,
    #[serde(default)]
    pub camera: Option<CameraMount>,
    #[serde(default)]
    pub lidar: Option<LidarMount>,
    #[serde(skip)]
    pub path: PathBuf,
    /// `--set profile.KEY=VALUE`: set in the firmware profile whenever it is loaded.
    #[serde(skip)]
    pub profile_overrides: Vec<Override>,
}

/// The climbing robot's mechanics, which its world is built from.
#[derive(Debug, Clone)]
pub struct Climber {
    pub body: BodySpec,
    pub wheel: WheelSpec,
    pub magnet: MagnetSpec,
    pub camera: CameraMount,
    pub lidar: LidarMount,
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
        // Half a climber is a mistake in the file, whatever it is served with; so is a servo whose
        // own profile does not load or does not offer its baud.
        robot.mechanics_present()?;
        if robot.servo.iter().any(|s| s.profile.is_some() || s.baud_bps.is_some()) {
            robot.servos(None)?;
        }
        Ok(robot)
    }

    /// The climbing robot's mechanics present and absent, or an error for some without others.
    fn mechanics_present(&self) -> Result<bool, RobotError> {
        let parts = [("[body]", self.body.is_some()), ("[wheel]", self.wheel.is_some()), ("[magnet]", self.magnet.is_some()), ("[camera]", self.camera.is_some()), ("[lidar]", self.lidar.is_some())];
        let named = |present: bool| parts.iter().filter(|(_, p)| *p == present).map(|(name, _)| *name).collect::<Vec<_>>().join(", ");
        match parts.iter().filter(|(_, present)| *present).count() {
            0 => Ok(false),
            n if n == parts.len() => Ok(true),
            _ => Err(RobotError::PartialClimber { path: self.path.clone(), present: named(true), missing: named(false) }),
        }
    }

    /// The climbing robot's mechanics and every servo's place in them, or why this description
    /// has none (a robot served on the bench only).
    pub fn climber(&self) -> Result<Climber, RobotError> {
        let (Some(body), Some(wheel), Some(magnet), Some(camera), Some(lidar)) = (&self.body, &self.wheel, &self.magnet, &self.camera, &self.lidar) else {
            return Err(match self.mechanics_present() {
                Ok(_) => RobotError::NotAClimber { path: self.path.clone(), missing: "[body], [wheel], [magnet], [camera] or [lidar]".into() },
                Err(partial) => partial,
            });
        };
        if let Some(servo) = self.servo.iter().find(|s| s.role.is_none() || s.wheel.is_none()) {
            let what = if servo.role.is_none() { "no role" } else { "no wheel" };
            return Err(RobotError::ServoWithoutPlace { path: self.path.clone(), id: servo.id, name: servo.name.clone(), what: what.into() });
        }
        Ok(Climber { body: body.clone(), wheel: wheel.clone(), magnet: magnet.clone(), camera: camera.clone(), lidar: lidar.clone() })
    }

    /// The bus's firmware profile (every servo's that names none), with this description's
    /// `--set profile.…` keys.
    pub fn profile(&self) -> Result<FirmwareProfile, RobotError> {
        Ok(FirmwareProfile::load_with(&self.profile_path(), &self.profile_overrides)?)
    }

    /// The bus's firmware profile path, resolved against this file's folder.
    pub fn profile_path(&self) -> PathBuf {
        self.resolve(&self.bus.profile)
    }

    /// `path` as the description names it, resolved against its folder.
    fn resolve(&self, path: &Path) -> PathBuf {
        self.path.parent().unwrap_or(Path::new(".")).join(path)
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

    /// Factory-fresh servos for this description, each with its own profile and power-on baud
    /// (`baud_override`, `--baud`, over every servo's). `--set profile.…` keys apply to every
    /// profile loaded.
    pub fn servos(&self, baud_override: Option<u32>) -> Result<Vec<Servo>, RobotError> {
        let mut loaded: Vec<(PathBuf, Arc<FirmwareProfile>)> = vec![(self.profile_path(), Arc::new(self.profile()?))];
        let mut servos = Vec::with_capacity(self.servo.len());
        for spec in &self.servo {
            let path = spec.profile.as_deref().map_or_else(|| self.profile_path(), |p| self.resolve(p));
            let this_servo = |message: String| RobotError::ServoProfile { path: self.path.clone(), id: spec.id, name: spec.name.clone(), message };
            let profile = match loaded.iter().find(|(p, _)| *p == path) {
                Some((_, profile)) => Arc::clone(profile),
                None => {
                    let profile = Arc::new(FirmwareProfile::load_with(&path, &self.profile_overrides).map_err(|e| this_servo(e.to_string()))?);
                    loaded.push((path, Arc::clone(&profile)));
                    profile
                }
            };
            let baud = baud_override.or(spec.baud_bps).unwrap_or(self.bus.baud_bps);
            let supply = self.bus.supply_voltage_v.unwrap_or(profile.motor.rated_voltage_v);
            let servo = bus::servos_from_profile(&profile, &[spec.id], baud, supply)
                .map_err(|source| if spec.profile.is_some() || spec.baud_bps.is_some() { this_servo(source.to_string()) } else { RobotError::Bus { path: self.path.clone(), source } })?;
            servos.extend(servo);
        }
        Ok(servos)
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
        assert_eq!(robot.climber().expect("the climbing robot").wheel.friction, 0.35);
        assert_eq!(robot.profile().expect("the profile loads").motor.coulomb_friction_nm, 0.05);
    }

    /// Load `text` as a description from a file of its own (tests run side by side: each call
    /// gets its own name).
    fn parse(text: &str) -> Result<RobotDescription, RobotError> {
        static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path = std::env::temp_dir().join(format!("climbsim-robot-{}-{call}.toml", std::process::id()));
        std::fs::write(&path, text).expect("a temporary file");
        let loaded = RobotDescription::load(&path);
        let _ = std::fs::remove_file(&path);
        loaded
    }

    const BENCH_BUS: &str = "[bus]\nprofile = \"xm540-w270-r.toml\"\nbaud_bps = 1000000\n\n[[servo]]\nid = 1\nname = \"pan\"\n";

    #[test]
    fn a_bus_alone_is_a_bench_robot_and_says_so_when_asked_for_a_world() {
        let robot = parse(BENCH_BUS).expect("a bus alone loads");
        let error = robot.climber().expect_err("no mechanics").to_string();
        assert!(error.contains("describes no climbing robot") && error.contains("served on the bench only"), "{error}");
    }

    #[test]
    fn half_a_climber_is_refused_when_the_file_loads() {
        let text = format!("{BENCH_BUS}\n[wheel]\nouter_radius_m = 0.05\ninner_radius_m = 0.04\nwidth_m = 0.03\nmass_kg = 0.2\nfriction = 0.6\n");
        let error = parse(&text).expect_err("a wheel without a body").to_string();
        assert!(error.contains("has [wheel] but no [body], [magnet], [camera], [lidar]"), "{error}");
    }

    /// The firmware profiles' folder, absolute, for descriptions written to a temporary file.
    fn profiles() -> String {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profiles").display().to_string()
    }

    #[test]
    fn a_climber_servo_without_a_role_is_named() {
        let shipped = std::fs::read_to_string(RobotDescription::default_path()).expect("the shipped description");
        let text = shipped.replacen("role = \"wheel_drive\"\n", "", 1).replace("\"../firmware-profiles", &format!("\"{}", profiles()));
        let error = parse(&text).expect("loads").climber().expect_err("servo 1 has no role").to_string();
        assert!(error.contains("servo 1 (wheel_front_left) has no role"), "{error}");
    }

    #[test]
    fn a_servos_own_baud_is_its_power_on_one_and_a_bad_profile_or_baud_names_the_servo() {
        let dir = profiles();
        let bus = format!(
            "[bus]\nprofile = \"{dir}/xl330-m288.toml\"\nbaud_bps = 1000000\n\n[[servo]]\nid = 1\nname = \"pan\"\n\n[[servo]]\nid = 7\nname = \"spare\"\nprofile = \"{dir}/xl430-w250.toml\"\nbaud_bps = 57600\n"
        );
        let robot = parse(&bus).expect("loads");
        let bauds: Vec<Option<u32>> = robot.servos(None).expect("builds").iter().map(Servo::baud_bps).collect();
        assert_eq!(bauds, [Some(1_000_000), Some(57_600)]);
        // 4.5 Mbps is an XL430's code 7: servo 7 may start there.
        parse(&bus.replace("baud_bps = 57600", "baud_bps = 4500000")).expect("the XL430 offers 4.5 Mbps");
        // An XL330 (the bus's profile) has no 4.5 Mbps: the servo asking for it is named.
        let error = parse(&bus.replace(&format!("profile = \"{dir}/xl430-w250.toml\"\nbaud_bps = 57600"), "baud_bps = 4500000")).expect_err("the XL330 has no 4.5 Mbps").to_string();
        assert!(error.contains("servo 7 (spare)") && error.contains("4500000"), "{error}");
        let error = parse(&bus.replace("xl430-w250.toml", "xl999.toml")).expect_err("no such profile").to_string();
        assert!(error.contains("servo 7 (spare)") && error.contains("xl999.toml"), "{error}");
    }

    #[test]
    fn each_servo_has_its_own_profile_baud_and_supply() {
        let koch = Path::new(env!("CARGO_MANIFEST_DIR")).join("hil/robots/koch-follower.toml");
        let robot = RobotDescription::load(&koch).expect("the Koch follower's bus loads");
        let servos = robot.servos(None).expect("every profile loads");
        let models: Vec<u16> = servos.iter().map(|s| s.profile().model.model_number).collect();
        assert_eq!(models, [1060, 1060, 1200, 1200, 1200, 1200]);
        assert!(servos.iter().all(|s| s.baud_bps() == Some(1_000_000)));
        assert_eq!(servos.iter().map(Servo::supply_voltage).collect::<Vec<_>>(), [11.1, 11.1, 5.0, 5.0, 5.0, 5.0]);
        // --baud reaches every servo; a servo's own baud is its power-on one otherwise.
        assert!(robot.servos(Some(57_600)).expect("57 600 is every model's").iter().all(|s| s.baud_bps() == Some(57_600)));
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
