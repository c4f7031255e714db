//! The data files climbsim ships, compiled into the binary: the robot description, the firmware
//! profile, the Foxglove layout, the reference controller and `run`'s default scenario. A binary installed anywhere
//! (`cargo install`, `pip install`) runs without its source tree: when no file is given and the
//! checkout's is not there, these are used, under paths that say so (`embedded:hil/robot.toml`
//! in errors and in `settings.json`). `climbsim export` writes them out to edit.
//!
//! An embedded path is the file's path in the checkout behind [`PREFIX`]; relative paths inside
//! an embedded file (the robot's `profile = "../firmware-profiles/…"`) resolve among the
//! embedded files as they would in the checkout.

use std::path::{Component, Path, PathBuf};

/// What marks a path as one of these files.
pub const PREFIX: &str = "embedded:";

/// One shipped file.
#[derive(Debug, Clone, Copy)]
pub struct EmbeddedFile {
    /// Its path in climbsim's checkout.
    pub path: &'static str,
    pub text: &'static str,
}

/// The robot description (`--robot`'s default).
pub const ROBOT: EmbeddedFile = EmbeddedFile { path: "hil/robot.toml", text: include_str!("../hil/robot.toml") };
/// The XM540-W270-R's control table and motor (the robot's `profile`).
pub const PROFILE: EmbeddedFile = EmbeddedFile { path: "firmware-profiles/xm540-w270-r.toml", text: include_str!("../firmware-profiles/xm540-w270-r.toml") };
/// Foxglove's layout for a run's topics.
pub const LAYOUT: EmbeddedFile = EmbeddedFile { path: "hil/foxglove/climbsim-layout.json", text: include_str!("../hil/foxglove/climbsim-layout.json") };
/// The reference external controller (Python, the official SDK).
pub const CONTROLLER: EmbeddedFile = EmbeddedFile { path: "hil/controllers/line_follower.py", text: include_str!("../hil/controllers/line_follower.py") };

/// `run`'s default scenario: the built-in controller following a weld line on flat steel.
pub const SCENARIO: EmbeddedFile = EmbeddedFile { path: "scenarios/flat-line.toml", text: include_str!("../scenarios/flat-line.toml") };

/// Every shipped file.
pub const FILES: [EmbeddedFile; 5] = [ROBOT, PROFILE, LAYOUT, CONTROLLER, SCENARIO];

impl EmbeddedFile {
    /// The path that names it (`embedded:hil/robot.toml`).
    pub fn embedded_path(&self) -> PathBuf {
        PathBuf::from(format!("{PREFIX}{}", self.path))
    }

    /// Its file name (`robot.toml`).
    pub fn file_name(&self) -> &'static str {
        self.path.rsplit('/').next().unwrap_or(self.path)
    }
}

/// Whether `path` names an embedded file (whether or not one is there).
pub fn is_embedded(path: &Path) -> bool {
    path.to_str().is_some_and(|p| p.starts_with(PREFIX))
}

/// The embedded file `path` names, `..` and `.` resolved lexically (`embedded:hil/../x` is
/// `x`), if there is one.
pub fn find(path: &Path) -> Option<&'static EmbeddedFile> {
    let inner = path.to_str()?.strip_prefix(PREFIX)?;
    let mut parts: Vec<&str> = Vec::new();
    for component in Path::new(inner).components() {
        match component {
            Component::Normal(part) => parts.push(part.to_str()?),
            Component::ParentDir => {
                parts.pop()?;
            }
            Component::CurDir => {}
            Component::RootDir | Component::Prefix(_) => return None,
        }
    }
    let wanted = parts.join("/");
    FILES.iter().find(|file| file.path == wanted)
}

/// The text at `path`: an embedded file's, or the file system's.
pub fn read_to_string(path: &Path) -> std::io::Result<String> {
    if is_embedded(path) {
        return find(path).map(|file| file.text.to_owned()).ok_or_else(|| {
            let known: Vec<String> = FILES.iter().map(|f| f.embedded_path().display().to_string()).collect();
            std::io::Error::new(std::io::ErrorKind::NotFound, format!("climbsim has no such file built in (it has {})", known.join(", ")))
        });
    }
    std::fs::read_to_string(path)
}

/// What `climbsim export` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Export {
    /// The robot description, and the firmware profile beside it (the description names it).
    Robot,
    Profile,
    Layout,
    Controller,
    Scenario,
    All,
}

impl Export {
    /// Each choice by the name `climbsim export` takes.
    pub const NAMES: [(&'static str, Export); 6] = [("robot", Self::Robot), ("profile", Self::Profile), ("layout", Self::Layout), ("controller", Self::Controller), ("scenario", Self::Scenario), ("all", Self::All)];
}

impl std::str::FromStr for Export {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, String> {
        Self::NAMES.iter().find(|(n, _)| *n == name).map(|(_, what)| *what).ok_or_else(|| format!("`{name}` is not one of {}", Self::NAMES.map(|(n, _)| n).join(", ")))
    }
}

/// Why files could not be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("{} already exist(s): not overwritten (--force to overwrite)", .0.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "))]
    Exists(Vec<PathBuf>),
    #[error("cannot write {}: {source}", path.display())]
    Write { path: PathBuf, source: std::io::Error },
}

/// Write the shipped files `what` asks for into `dir` (made if missing), each under its own
/// name; an exported robot description names the profile exported beside it. Nothing is
/// written if a file is there already, unless `force`. The files written.
pub fn export(what: Export, dir: &Path, force: bool) -> Result<Vec<PathBuf>, ExportError> {
    let files: Vec<(EmbeddedFile, String)> = match what {
        Export::Robot => vec![(ROBOT, robot_beside_its_profile()), (PROFILE, PROFILE.text.to_owned())],
        Export::Profile => vec![(PROFILE, PROFILE.text.to_owned())],
        Export::Layout => vec![(LAYOUT, LAYOUT.text.to_owned())],
        Export::Controller => vec![(CONTROLLER, CONTROLLER.text.to_owned())],
        Export::Scenario => vec![(SCENARIO, SCENARIO.text.to_owned())],
        Export::All => vec![(ROBOT, robot_beside_its_profile()), (PROFILE, PROFILE.text.to_owned()), (LAYOUT, LAYOUT.text.to_owned()), (CONTROLLER, CONTROLLER.text.to_owned()), (SCENARIO, SCENARIO.text.to_owned())],
    };
    let paths: Vec<PathBuf> = files.iter().map(|(file, _)| dir.join(file.file_name())).collect();
    let existing: Vec<PathBuf> = paths.iter().filter(|p| p.exists()).cloned().collect();
    if !force && !existing.is_empty() {
        return Err(ExportError::Exists(existing));
    }
    std::fs::create_dir_all(dir).map_err(|source| ExportError::Write { path: dir.to_owned(), source })?;
    for ((file, text), path) in files.iter().zip(&paths) {
        std::fs::write(path, text).map_err(|source| ExportError::Write { path: path.clone(), source })?;
        if file.path.ends_with(".py") {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755)).map_err(|source| ExportError::Write { path: path.clone(), source })?;
        }
    }
    Ok(paths)
}

/// The robot description with its `profile` naming the profile's file beside it (its comments
/// kept: the one line is replaced).
fn robot_beside_its_profile() -> String {
    let mut text = String::with_capacity(ROBOT.text.len());
    for line in ROBOT.text.lines() {
        if line.trim_start().starts_with("profile = ") {
            text.push_str(&format!("profile = {:?}", PROFILE.file_name()));
        } else {
            text.push_str(line);
        }
        text.push('\n');
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_robots_profile_resolves_among_the_embedded_files() {
        let robot = ROBOT.embedded_path();
        let text: toml::Table = read_to_string(&robot).expect("the robot is built in").parse().expect("TOML");
        let relative = text["bus"]["profile"].as_str().expect("a profile path");
        let profile: toml::Table = read_to_string(&robot.parent().expect("a folder").join(relative)).expect("the profile is built in").parse().expect("TOML");
        assert!(profile.contains_key("motor"), "{profile:?}");
    }

    #[test]
    fn an_exported_robot_loads_with_its_profile_beside_it_and_nothing_is_overwritten() {
        let dir = std::env::temp_dir().join(format!("climbsim-export-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let written = export(Export::Robot, &dir, false).expect("exported");
        assert_eq!(written, vec![dir.join("robot.toml"), dir.join("xm540-w270-r.toml")]);
        let robot = crate::robot::RobotDescription::load(&dir.join("robot.toml")).expect("the exported robot loads");
        assert_eq!(robot.profile().expect("its profile loads").motor.gear_ratio, 272.5);
        let error = export(Export::All, &dir, false).expect_err("two files are there");
        assert!(error.to_string().contains("robot.toml") && error.to_string().contains("--force"), "{error}");
        assert!(!dir.join("line_follower.py").exists(), "nothing written when refused");
        export(Export::All, &dir, true).expect("forced");
        assert!(dir.join("line_follower.py").exists() && dir.join("climbsim-layout.json").exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn paths_outside_the_embedded_files_are_not_found() {
        assert!(find(Path::new("embedded:hil/../../etc/passwd")).is_none());
        assert!(find(Path::new("embedded:/hil/robot.toml")).is_none());
        assert!(find(Path::new("hil/robot.toml")).is_none(), "a path on disk is not embedded");
        assert!(find(Path::new("embedded:hil/./foxglove/../robot.toml")).is_some());
        let error = read_to_string(Path::new("embedded:hil/nothing.toml")).expect_err("not built in");
        assert!(error.to_string().contains("embedded:hil/robot.toml"), "{error}");
    }

    #[test]
    fn export_choices_are_parsed_by_name_and_a_wrong_one_lists_them() {
        assert_eq!("controller".parse::<Export>(), Ok(Export::Controller));
        let error = "robots".parse::<Export>().expect_err("no such choice");
        assert!(error.contains("robot, profile, layout, controller, scenario, all"), "{error}");
    }

    #[test]
    fn the_embedded_files_are_the_checkouts() {
        for file in FILES {
            let on_disk = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(file.path)).expect("in the checkout");
            assert_eq!(on_disk, file.text, "{}", file.path);
        }
    }
}
