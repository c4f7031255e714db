//! LeRobot's own robot classes against climbsim: runs the pytest suite in `tests/lerobot` with
//! the climbsim binary this `cargo test` built, LeRobot 0.5.1 unchanged.
//!
//! Python comes from `$CLIMBSIM_LEROBOT_PYTHON`, else `<repo>/.venv-lerobot/bin/python` (made by
//! `./scripts/test.sh`: Python 3.12 or newer, `tests/lerobot/requirements.txt`). A missing
//! interpreter or package is a failure, never a silent skip.

use std::path::{Path, PathBuf};
use std::process::Command;

fn lerobot_python() -> PathBuf {
    match std::env::var_os("CLIMBSIM_LEROBOT_PYTHON") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv-lerobot/bin/python"),
    }
}

#[test]
fn lerobot_koch_follower_connects_calibrates_and_follows() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let python = lerobot_python();
    let hint = "run ./scripts/test.sh (it creates .venv-lerobot with Python 3.12+ and tests/lerobot/requirements.txt), \
                or point CLIMBSIM_LEROBOT_PYTHON at one";
    match Command::new(&python).args(["-c", "import lerobot, dynamixel_sdk, pytest"]).output() {
        Err(e) => panic!("cannot run {}: {e}; {hint}", python.display()),
        Ok(out) if !out.status.success() => panic!("{} cannot import lerobot/dynamixel_sdk/pytest: {}; {hint}", python.display(), String::from_utf8_lossy(&out.stderr).trim()),
        Ok(_) => {}
    }
    let out = Command::new(&python)
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/lerobot"])
        .current_dir(repo)
        .env("CLIMBSIM_BIN", env!("CARGO_BIN_EXE_climbsim"))
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .unwrap_or_else(|e| panic!("cannot run pytest with {}: {e}", python.display()));
    print!("{}", String::from_utf8_lossy(&out.stdout));
    eprint!("{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "LeRobot's suite failed ({}); pytest's output is above", out.status);
}
