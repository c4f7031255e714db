//! Writing the shipped files out: `climbsim export` (a file to edit) and `climbsim init` (a
//! controller repository's skeleton).

use std::path::{Path, PathBuf};

use super::{COMPARE_LAYOUT, CONTROLLER, EmbeddedFile, LAYOUT, PROFILE, ROBOT, SCENARIO, shipped};

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
    pub const NAMES: [(&'static str, Export); 6] =
        [("robot", Self::Robot), ("profile", Self::Profile), ("layout", Self::Layout), ("controller", Self::Controller), ("scenario", Self::Scenario), ("all", Self::All)];
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
        Export::Layout => vec![(LAYOUT, LAYOUT.text.to_owned()), (COMPARE_LAYOUT, COMPARE_LAYOUT.text.to_owned())],
        Export::Controller => vec![(CONTROLLER, CONTROLLER.text.to_owned())],
        Export::Scenario => vec![(SCENARIO, SCENARIO.text.to_owned())],
        Export::All => vec![
            (ROBOT, robot_beside_its_profile()),
            (PROFILE, PROFILE.text.to_owned()),
            (LAYOUT, LAYOUT.text.to_owned()),
            (COMPARE_LAYOUT, COMPARE_LAYOUT.text.to_owned()),
            (CONTROLLER, CONTROLLER.text.to_owned()),
            (SCENARIO, SCENARIO.text.to_owned()),
        ],
    };
    let files: Vec<(PathBuf, String)> = files.into_iter().map(|(file, text)| (dir.join(file.file_name()), text)).collect();
    write_all(dir, &files, force)
}

/// A controller repository's skeleton, each file at its path in the new repository: a
/// scenario on the built-in robot, the reference controller to replace, a pytest test on
/// climbsim's plugin, CI, and what they need.
const SKELETON: [(&str, EmbeddedFile); 8] = [
    ("scenarios/line-follow.toml", shipped!("hil/init/scenarios/line-follow.toml")),
    ("controller/line_follower.py", CONTROLLER),
    ("tests/test_climbsim.py", shipped!("hil/init/tests/test_climbsim.py")),
    (".github/workflows/climbsim.yml", shipped!("hil/init/.github/workflows/climbsim.yml")),
    ("requirements.txt", shipped!("hil/init/requirements.txt")),
    ("pytest.ini", shipped!("hil/init/pytest.ini")),
    ("README.md", shipped!("hil/init/README.md")),
    // Not `.gitignore` in climbsim's tree, where it would ignore files of climbsim's own.
    (".gitignore", shipped!("hil/init/gitignore")),
];

/// The marker in the skeleton's files that becomes this climbsim's version (the one the
/// generated `requirements.txt` pins).
const VERSION_MARKER: &str = "@CLIMBSIM_VERSION@";

/// `climbsim init DIR`: write a controller repository's skeleton into `dir` (made if missing;
/// files of its own beside them are left alone). Nothing is written if one of the skeleton's
/// files is there already, unless `force`. The files written.
pub fn init(dir: &Path, force: bool) -> Result<Vec<PathBuf>, ExportError> {
    let files: Vec<(PathBuf, String)> = SKELETON.iter().map(|(path, file)| (dir.join(path), file.text.replace(VERSION_MARKER, env!("CARGO_PKG_VERSION")))).collect();
    write_all(dir, &files, force)
}

/// Write `files` (paths under `dir`), none if one is there already unless `force`; Python
/// files executable.
fn write_all(dir: &Path, files: &[(PathBuf, String)], force: bool) -> Result<Vec<PathBuf>, ExportError> {
    let existing: Vec<PathBuf> = files.iter().map(|(path, _)| path).filter(|p| p.exists()).cloned().collect();
    if !force && !existing.is_empty() {
        return Err(ExportError::Exists(existing));
    }
    std::fs::create_dir_all(dir).map_err(|source| ExportError::Write { path: dir.to_owned(), source })?;
    for (path, text) in files {
        if let Some(folder) = path.parent() {
            std::fs::create_dir_all(folder).map_err(|source| ExportError::Write { path: folder.to_owned(), source })?;
        }
        std::fs::write(path, text).map_err(|source| ExportError::Write { path: path.clone(), source })?;
        if path.extension().is_some_and(|e| e == "py") {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755)).map_err(|source| ExportError::Write { path: path.clone(), source })?;
        }
    }
    Ok(files.iter().map(|(path, _)| path.clone()).collect())
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
    fn init_writes_the_skeleton_with_this_version_and_refuses_to_overwrite_it() {
        let dir = std::env::temp_dir().join(format!("climbsim-init-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("made");
        std::fs::write(dir.join("mine.txt"), "kept").expect("written");
        let written = init(&dir, false).expect("written");
        assert_eq!(written.len(), SKELETON.len());
        let requirements = std::fs::read_to_string(dir.join("requirements.txt")).expect("written");
        assert!(requirements.contains(&format!("climbsim=={}", env!("CARGO_PKG_VERSION"))) && !requirements.contains(VERSION_MARKER), "{requirements}");
        let scenario = crate::scenario::Scenario::load(&dir.join("scenarios/line-follow.toml")).expect("the scenario loads");
        assert!(!scenario.expect.is_empty());
        let error = init(&dir, false).expect_err("the skeleton is there");
        assert!(error.to_string().contains("--force"), "{error}");
        init(&dir, true).expect("forced");
        assert_eq!(std::fs::read_to_string(dir.join("mine.txt")).expect("kept"), "kept");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_skeletons_files_are_the_checkouts() {
        for (_, file) in SKELETON {
            let on_disk = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(file.path)).expect("in the checkout");
            assert_eq!(on_disk, file.text, "{}", file.path);
        }
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
        assert!(dir.join("line_follower.py").exists() && dir.join("climbsim-layout.json").exists() && dir.join("climbsim-compare-layout.json").exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn export_choices_are_parsed_by_name_and_a_wrong_one_lists_them() {
        assert_eq!("controller".parse::<Export>(), Ok(Export::Controller));
        let error = "robots".parse::<Export>().expect_err("no such choice");
        assert!(error.contains("robot, profile, layout, controller, scenario, all"), "{error}");
    }
}
