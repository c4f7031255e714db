//! Official-SDK conformance: runs the pytest suite in `tests/sdk` against the climbsim binary
//! built by this `cargo test`, using the unmodified ROBOTIS DynamixelSDK 4.0.5 for Python.
//!
//! Python comes from `$CLIMBSIM_PYTHON`, else `<repo>/.venv/bin/python` (made by
//! `./scripts/test.sh`, which installs `tests/sdk/requirements.txt`). A missing interpreter or
//! SDK is a failure, never a silent skip.

use std::path::PathBuf;

mod support;

/// The suite in two halves, run side by side (the harness runs two tests at once): the soak
/// (15 s at the SDK's full loop rate) with the files listed here, and every other file. The
/// suite was written for a loaded machine (lower bounds only, and a long latency timer in the
/// soak); whole, it was a minute of CI alone on one core. A new file joins the second half.
const WITH_THE_SOAK: [&str; 4] = ["test_soak.py", "test_reboot_reset.py", "test_motion.py", "test_identity.py"];

#[test]
fn official_python_sdk_conformance_the_soak_and_its_half() {
    pytest(&WITH_THE_SOAK.map(|file| format!("tests/sdk/{file}")));
}

#[test]
fn official_python_sdk_conformance_every_other_file() {
    let mut args = vec!["tests/sdk".to_owned()];
    args.extend(WITH_THE_SOAK.map(|file| format!("--ignore=tests/sdk/{file}")));
    pytest(&args);
}

/// pytest on `selection` (files, or a folder less `--ignore`d files), with the official SDK.
fn pytest(selection: &[String]) {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    for file in WITH_THE_SOAK {
        assert!(repo.join("tests/sdk").join(file).is_file(), "tests/sdk/{file} is gone: take it out of WITH_THE_SOAK");
    }
    let hint = "run ./scripts/test.sh (it creates .venv and installs tests/sdk/requirements.txt), \
                or point CLIMBSIM_PYTHON at a python with dynamixel-sdk 4.0.5 and pytest";
    support::pytest_with(&support::sdk_python(), "dynamixel_sdk, pytest, serial", hint, selection);
}
