//! Official-SDK conformance: runs the pytest suite in `tests/sdk` against the climbsim binary
//! built by this `cargo test`, using the unmodified ROBOTIS DynamixelSDK 4.0.5 for Python.
//!
//! Python comes from `$CLIMBSIM_PYTHON`, else `<repo>/.venv/bin/python` (made by
//! `./scripts/test.sh`, which installs `tests/sdk/requirements.txt`). A missing interpreter or
//! SDK is a failure, never a silent skip.

use std::path::PathBuf;
use std::process::Command;

mod support;

#[test]
fn official_python_sdk_conformance() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let python = support::sdk_python();
    let hint = "run ./scripts/test.sh (it creates .venv and installs tests/sdk/requirements.txt), \
                or point CLIMBSIM_PYTHON at a python with dynamixel-sdk 4.0.5 and pytest";

    let probe = Command::new(&python)
        .args(["-c", "import dynamixel_sdk, pytest, serial"])
        .output();
    match probe {
        Err(e) => panic!("cannot run {}: {e}; {hint}", python.display()),
        Ok(out) if !out.status.success() => panic!(
            "{} cannot import dynamixel_sdk/pytest/serial: {}; {hint}",
            python.display(),
            String::from_utf8_lossy(&out.stderr).trim()
        ),
        Ok(_) => {}
    }

    let out = Command::new(&python)
        .args(["-m", "pytest", "tests/sdk", "-q", "-p", "no:cacheprovider"])
        .current_dir(&repo)
        .env("CLIMBSIM_BIN", env!("CARGO_BIN_EXE_climbsim"))
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .unwrap_or_else(|e| panic!("cannot run pytest with {}: {e}", python.display()));

    print!("{}", String::from_utf8_lossy(&out.stdout));
    eprint!("{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        out.status.success(),
        "official-SDK conformance suite failed ({}); pytest output is above",
        out.status
    );
}
