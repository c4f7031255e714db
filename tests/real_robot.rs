//! The real robot in the loop, without hardware: the "real robot" is climbsim itself with a
//! robot description the test keeps to itself (`serve SCENARIO --device` on the far end of a
//! null-modem pty pair), the reference controller on the official SDK drives it through
//! `climbsim tap`, and `climbsim compare` sets the recorded session beside the shipped world.

mod support;

use std::process::{Command, Stdio};
use std::time::Duration;

use support::null_modem::NullModem;
use support::tap::TapProcess;

/// The shipped robot description with the values only the "real robot" has: less grip, a
/// weaker magnet, and magnet-shaft encoders mounted 12 pulses off.
fn hidden_robot(dir: &std::path::Path) -> std::path::PathBuf {
    let repo = support::repo();
    let shipped = std::fs::read_to_string(repo.join("hil/robot.toml")).expect("the shipped robot");
    let profile = repo.join("firmware-profiles/xm540-w270-r.toml");
    let mut text = String::new();
    for line in shipped.lines() {
        let line = match line {
            l if l.starts_with("profile = ") => format!("profile = {:?}", profile.display().to_string()),
            "friction = 0.6" => "friction = 0.35".to_owned(),
            "pull_at_contact_n = 80.0" => "pull_at_contact_n = 60.0".to_owned(),
            "encoder_at_down_pulses = 2048" => "encoder_at_down_pulses = 2060".to_owned(),
            l => l.to_owned(),
        };
        text.push_str(&line);
        text.push('\n');
    }
    for changed in ["friction = 0.35", "pull_at_contact_n = 60.0", "encoder_at_down_pulses = 2060"] {
        assert!(text.contains(changed), "the shipped robot no longer has the line this test changes to `{changed}`");
    }
    let path = dir.join("hidden-robot.toml");
    std::fs::write(&path, text).expect("write the hidden robot");
    path
}

fn compare(transcript: &std::path::Path, robot: &std::path::Path, out: &std::path::Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["compare"])
        .arg(transcript)
        .args(["--scenario", "scenarios/external-line-follower.toml", "--robot"])
        .arg(robot)
        .arg("--out")
        .arg(out)
        .current_dir(support::repo())
        .output()
        .expect("run climbsim compare")
}

#[test]
fn a_tapped_session_of_the_reference_controller_tells_the_real_robot_from_the_shipped_world() {
    let dir = support::scratch_dir("real-robot");
    let robot = hidden_robot(&dir);
    let cable = NullModem::new();
    let real_robot = support::Options::default().stderr_log().sensors().start(&["scenarios/external-line-follower.toml", "--robot", robot.to_str().expect("utf-8"), "--device", cable.b().to_str().expect("utf-8")]);
    let mut tap = TapProcess::start(cable.a(), &dir, &["--baud", "1000000"]);

    // The reference controller as it would run on the robot: its port and the camera's URL.
    let mut controller = Command::new(support::sdk_python())
        .arg(support::repo().join("hil/controllers/line_follower.py"))
        .args(["--zeta", "1.4", "--omega-n", "0.3", "--max-yaw-rate", "0.5"])
        .env("DXL_PORT", &tap.port)
        .env("DXL_BAUD", "1000000")
        .env("CLIMBSIM_SENSORS", real_robot.sensors())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("controller.log")).expect("log"))
        .spawn()
        .expect("start the reference controller");
    std::thread::sleep(Duration::from_secs(5));
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(controller.id() as i32), nix::sys::signal::Signal::SIGINT).expect("SIGINT");
    let ended = controller.wait().expect("the controller ends");
    let log = std::fs::read_to_string(dir.join("controller.log")).unwrap_or_default();
    assert!(ended.success(), "the controller: {ended}\n{log}");
    tap.interrupt();
    assert!(tap.wait(Duration::from_secs(10)).success(), "{}", tap.stderr());
    drop(real_robot);

    let transcript = dir.join("real.jsonl");
    // Against the shipped description: the magnet shafts' encoders read 12 pulses apart, and
    // the wheels, with less grip, do not turn as the world's do.
    let shipped = compare(&transcript, &support::repo().join("hil/robot.toml"), &dir.join("shipped"));
    let text = support::output_text(&shipped);
    assert_eq!(shipped.status.code(), Some(1), "{text}");
    for servo in 5..=8 {
        assert!(text.contains(&format!("servo {servo} present_position (RMS 12.0000 pulse")), "servo {servo} named with its 12-pulse offset: {text}");
    }
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("shipped/compare.json")).expect("compare.json")).expect("JSON");
    assert_eq!(report["passed"], false);
    assert!(report["replies_compared"].as_u64().is_some_and(|n| n > 8 * 100), "{report}");
    let magnet = report["registers"].as_array().expect("registers").iter().find(|r| r["id"] == 5).expect("servo 5");
    assert_eq!(magnet["bias"], -12.0, "the world reads 2048 where the robot reads 2060: {magnet}");

    // Against the robot's own description: the world matches it.
    let own = compare(&transcript, &robot, &dir.join("own"));
    assert_eq!(own.status.code(), Some(0), "{}", support::output_text(&own));
}
