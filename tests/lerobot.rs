//! LeRobot's own robot classes against climbsim: runs the pytest suite in `tests/lerobot` with
//! the climbsim binary this `cargo test` built, LeRobot 0.5.1 unchanged.
//!
//! Python comes from `$CLIMBSIM_LEROBOT_PYTHON`, else `<repo>/.venv-lerobot/bin/python` (made by
//! `./scripts/test.sh`: Python 3.12 or newer, `tests/lerobot/requirements.txt`). A missing
//! interpreter or package is a failure, never a silent skip.

use std::path::{Path, PathBuf};

mod support;

fn lerobot_python() -> PathBuf {
    match std::env::var_os("CLIMBSIM_LEROBOT_PYTHON") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv-lerobot/bin/python"),
    }
}

#[test]
fn lerobot_koch_follower_connects_calibrates_and_follows() {
    let hint = "run ./scripts/test.sh (it creates .venv-lerobot with Python 3.12+ and tests/lerobot/requirements.txt), \
                or point CLIMBSIM_LEROBOT_PYTHON at one";
    support::pytest_with(&lerobot_python(), "lerobot, dynamixel_sdk, pytest", hint, &["tests/lerobot".to_owned()]);
}
