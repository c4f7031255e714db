//! The data files climbsim ships, compiled into the binary: the robot description, the firmware
//! profile, the Foxglove layouts, the reference controller and `run`'s default scenario. A binary installed anywhere
//! (`cargo install`, `pip install`) runs without its source tree: when no file is given and the
//! checkout's is not there, these are used, under paths that say so (`embedded:hil/robot.toml`
//! in errors and in `settings.json`). `climbsim export` writes them out to edit.
//!
//! An embedded path is the file's path in the checkout behind [`PREFIX`]; relative paths inside
//! an embedded file (the robot's `profile = "../firmware-profiles/…"`) resolve among the
//! embedded files as they would in the checkout.

use std::path::{Component, Path, PathBuf};

mod write;
pub use write::{Export, ExportError, export, init};

/// What marks a path as one of these files.
pub const PREFIX: &str = "embedded:";

/// One shipped file.
#[derive(Debug, Clone, Copy)]
pub struct EmbeddedFile {
    /// Its path in climbsim's checkout.
    pub path: &'static str,
    pub text: &'static str,
}

/// The file at `$path` in the checkout, built in (its path written once: the one it is read
/// from is the one it is named by).
macro_rules! shipped {
    ($path:literal) => {
        EmbeddedFile { path: $path, text: include_str!(concat!("../../", $path)) }
    };
}
pub(crate) use shipped;

/// The robot description (`--robot`'s default).
pub const ROBOT: EmbeddedFile = shipped!("hil/robot.toml");
/// The XM540-W270-R's control table and motor (the robot's `profile`).
pub const PROFILE: EmbeddedFile = shipped!("firmware-profiles/xm540-w270-r.toml");
/// Foxglove's layout for a run's topics.
pub const LAYOUT: EmbeddedFile = shipped!("hil/foxglove/climbsim-layout.json");
/// Foxglove's layout for a real session re-enacted in the world (`compare`, `tap --scenario`):
/// the robot's replies and the world's answers side by side.
pub const COMPARE_LAYOUT: EmbeddedFile = shipped!("hil/foxglove/climbsim-compare-layout.json");
/// The reference external controller (Python, the official SDK).
pub const CONTROLLER: EmbeddedFile = shipped!("hil/controllers/line_follower.py");

/// `run`'s default scenario: the built-in controller following a weld line on flat steel.
pub const SCENARIO: EmbeddedFile = shipped!("scenarios/flat-line.toml");

/// LeRobot's Koch follower arm, its bus alone.
pub const KOCH_FOLLOWER: EmbeddedFile = shipped!("hil/robots/koch-follower.toml");
/// LeRobot's Koch leader arm, its bus alone.
pub const KOCH_LEADER: EmbeddedFile = shipped!("hil/robots/koch-leader.toml");

/// The robots `--robot NAME` names: the description in the checkout when climbsim runs in one,
/// else the one built in.
pub const ROBOTS: [(&str, EmbeddedFile); 3] = [("climber", ROBOT), ("koch-follower", KOCH_FOLLOWER), ("koch-leader", KOCH_LEADER)];

/// Every servo model's firmware profile (a robot's `profile` resolves among them).
pub const PROFILES: [EmbeddedFile; 11] = [
    PROFILE,
    shipped!("firmware-profiles/xl330-m077.toml"),
    shipped!("firmware-profiles/xl330-m288.toml"),
    shipped!("firmware-profiles/xc330-t288.toml"),
    shipped!("firmware-profiles/xl430-w250.toml"),
    shipped!("firmware-profiles/xc430-w150.toml"),
    shipped!("firmware-profiles/xm430-w210.toml"),
    shipped!("firmware-profiles/xm430-w350.toml"),
    shipped!("firmware-profiles/xh430-w350.toml"),
    shipped!("firmware-profiles/xm540-w150.toml"),
    shipped!("firmware-profiles/xw540-t260.toml"),
];

/// Every shipped file but the profiles.
pub const FILES: [EmbeddedFile; 8] = [ROBOT, KOCH_FOLLOWER, KOCH_LEADER, PROFILE, LAYOUT, COMPARE_LAYOUT, CONTROLLER, SCENARIO];

/// Every shipped file, the profiles too (the robot's own profile is in both lists: a lookup
/// finds it in the first).
fn every_file() -> impl Iterator<Item = &'static EmbeddedFile> {
    FILES.iter().chain(&PROFILES)
}

/// The built-in robot called `name` (`koch-follower`), if there is one.
pub fn robot_named(name: &str) -> Option<&'static EmbeddedFile> {
    ROBOTS.iter().find(|(robot, _)| *robot == name).map(|(_, file)| file)
}

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
    every_file().find(|file| file.path == wanted)
}

/// The text at `path`: an embedded file's, or the file system's.
pub fn read_to_string(path: &Path) -> std::io::Result<String> {
    if is_embedded(path) {
        return find(path).map(|file| file.text.to_owned()).ok_or_else(|| {
            let known: Vec<String> = FILES.iter().map(|f| f.embedded_path().display().to_string()).collect();
            std::io::Error::new(std::io::ErrorKind::NotFound, format!("climbsim has no such file built in (it has {}, and each servo model's profile in {PREFIX}firmware-profiles/)", known.join(", ")))
        });
    }
    std::fs::read_to_string(path)
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
    fn paths_outside_the_embedded_files_are_not_found() {
        assert!(find(Path::new("embedded:hil/../../etc/passwd")).is_none());
        assert!(find(Path::new("embedded:/hil/robot.toml")).is_none());
        assert!(find(Path::new("hil/robot.toml")).is_none(), "a path on disk is not embedded");
        assert!(find(Path::new("embedded:hil/./foxglove/../robot.toml")).is_some());
        let error = read_to_string(Path::new("embedded:hil/nothing.toml")).expect_err("not built in");
        assert!(error.to_string().contains("embedded:hil/robot.toml"), "{error}");
    }

    #[test]
    fn the_embedded_files_are_the_checkouts() {
        for file in FILES {
            let on_disk = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(file.path)).expect("in the checkout");
            assert_eq!(on_disk, file.text, "{}", file.path);
        }
    }
}
