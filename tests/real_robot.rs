//! The real robot in the loop, without hardware: `climbsim tap` between an unchanged controller
//! (the official Python SDK) and "real" servos, which are climbsim itself on the far end of two
//! pseudo-terminals joined like a null-modem cable (`serve --device`), with a robot description
//! the test keeps to itself; then `climbsim compare` and `climbsim fit` against the shipped
//! world. Everything here is real: the ptys, the SDK, the serial device's exclusive open and
//! termios, the bytes on both sides. (One test binary for all of it: each costs a link in CI.)

mod support;

use std::process::{Command, Stdio};
use std::time::Duration;

use climbsim::real_bus::RealRecord;
use climbsim::real_bus::transcript::{RealReply, read};
use climbsim::transcript::from_hex;

use support::null_modem::NullModem;
use support::tap::TapProcess;

/// Held by a test while a "real robot" runs on the wall clock, and by the tests that load both
/// cores meanwhile (a fit): the tests of this binary run in parallel, and a "real robot" starved
/// of its CPU for longer than the SDK's timeout (34 ms) misses its reply, as a real one never
/// would for that reason.
static WALL_CLOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn wall_clock() -> std::sync::MutexGuard<'static, ()> {
    WALL_CLOCK.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

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

fn compare(transcript: &std::path::Path, robot: &std::path::Path, out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["compare"])
        .arg(transcript)
        .args(["--scenario", "scenarios/external-line-follower.toml", "--robot"])
        .arg(robot)
        .arg("--out")
        .arg(out)
        .args(extra)
        .env("PATH", support::path_with_sdk_python())
        .current_dir(support::repo())
        .output()
        .expect("run climbsim compare")
}

/// `climbsim compare TRANSCRIPT` on the flat line with the shipped robot, into `out`.
fn compare_on_flat_line(transcript: &std::path::Path, out: &std::path::Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["compare"])
        .arg(transcript)
        .args(["--scenario", "scenarios/flat-line.toml", "--out"])
        .arg(out)
        .current_dir(support::repo())
        .output()
        .expect("run climbsim compare")
}

#[test]
fn a_tapped_session_of_the_reference_controller_tells_the_real_robot_from_the_shipped_world() {
    let dir = support::scratch_dir("real-robot");
    let robot = hidden_robot(&dir);
    let live = wall_clock();
    let cable = NullModem::new();
    // Its gearboxes too: twice the shipped profile's Coulomb friction.
    let real_robot = support::Options::default().stderr_log().sensors().start(&[
        "scenarios/external-line-follower.toml",
        "--robot",
        robot.to_str().expect("utf-8"),
        "--set",
        HIDDEN_GEARBOX,
        "--device",
        cable.b().to_str().expect("utf-8"),
    ]);
    // Re-enacted live in the shipped world, shown live beside the real servos (on a port the
    // kernel picks), and the real servos recorded for Foxglove as they go.
    let tap_mcap = dir.join("tap.mcap");
    let mut tap =
        TapProcess::start(cable.a(), &dir, &["--baud", "1000000", "--foxglove=127.0.0.1:0", "--mcap", tap_mcap.to_str().expect("utf-8"), "--scenario", "scenarios/external-line-follower.toml"]);

    // The reference controller as it would run on the robot: its port and the camera's URL.
    let mut controller = Command::new(support::sdk_python())
        .arg(support::repo().join("hil/controllers/line_follower.py"))
        .args(["--zeta", "1.4", "--omega-n", "0.3", "--max-yaw-rate", "0.5", "--read-current", "--log-offset"])
        .arg(dir.join("offset.csv"))
        .env("DXL_PORT", &tap.port)
        .env("DXL_BAUD", "1000000")
        .env("CLIMBSIM_SENSORS", real_robot.sensors())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("controller.log")).expect("log"))
        .spawn()
        .expect("start the reference controller");
    // One viewer, on the one connection, sees the world and the real servos beside it.
    let url = tap.foxglove_url(Duration::from_secs(10));
    let wanted = ["/tf", "/compare/robot", "/compare/world"];
    let viewer = std::thread::spawn(move || support::foxglove::watch(&url, &wanted, Duration::from_secs(6), |seen| wanted.iter().all(|topic| seen.count(topic) >= 20)));
    std::thread::sleep(session_length());
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(controller.id() as i32), nix::sys::signal::Signal::SIGINT).expect("SIGINT");
    let ended = controller.wait().expect("the controller ends");
    let log = std::fs::read_to_string(dir.join("controller.log")).unwrap_or_default();
    assert!(ended.success(), "the controller: {ended}\n{log}");
    tap.interrupt();
    // The live comparison with the shipped world fails, as `compare` does below.
    assert_eq!(tap.wait(Duration::from_secs(30)).code(), Some(1), "{}", tap.stderr());
    assert!(tap.stderr().contains("the world differs from the robot past tolerance"), "{}", tap.stderr());
    // One live view was served: the world re-enacting the session beside the real servos.
    let said = tap.stdout();
    assert_eq!(said.matches("foxglove: ws://127.0.0.1:").count(), 1, "{said}");
    assert!(said.contains("climbsim-compare-layout.json"), "the layout to import named: {said}");
    let seen = viewer.join().expect("the viewer");
    for topic in ["/tf", "/scene/robot", "/servos", "/log", "/bus/packets", "/compare/robot", "/compare/world"] {
        assert!(seen.advertised(topic), "{topic} on the one connection: {:?}", seen.channels);
    }
    for topic in wanted {
        assert!(seen.count(topic) >= 20, "{} messages of {topic} in 6 s", seen.count(topic));
    }
    let last = |topic: &str| -> serde_json::Value { serde_json::from_slice(&seen.received[topic].last().expect("one").1).expect("JSON") };
    let (real_reply, world_reply) = (last("/compare/robot"), last("/compare/world"));
    assert!(real_reply["magnet_front_left"]["present_position"].is_number() && world_reply["magnet_front_left"]["present_position"].is_number(), "{real_reply} {world_reply}");
    drop(real_robot);
    drop(live);

    let transcript = dir.join("real.jsonl");
    tap_recording_shows_the_real_servos(&tap_mcap, &transcript);
    // Against the shipped description: the magnet shafts' encoders read 12 pulses apart, and
    // the wheels, with less grip, do not turn as the world's do.
    let shipped = compare(&transcript, &support::repo().join("hil/robot.toml"), &dir.join("shipped"), &[]);
    let text = support::output_text(&shipped);
    assert_eq!(shipped.status.code(), Some(1), "{text}");
    for servo in 5..=8 {
        assert!(text.contains(&format!("servo {servo} present_position (RMS 12.0000 pulse")), "servo {servo} named with its 12-pulse offset: {text}");
    }
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("shipped/compare.json")).expect("compare.json")).expect("JSON");
    assert_eq!(report["passed"], false);
    assert!(report["replies_compared"].as_u64().is_some_and(|n| n > 8 * 100), "{report}");
    let magnet = report["registers"].as_array().expect("registers").iter().find(|r| r["id"] == 5 && r["key"] == "present_position").expect("servo 5");
    assert_eq!(magnet["bias"], -12.0, "the world reads 2048 where the robot reads 2060: {magnet}");
    for servo in 1..=8 {
        let plot = dir.join(format!("shipped/plots/servo{servo}_present_position.png"));
        assert!(std::fs::metadata(&plot).is_ok_and(|m| m.len() > 1000), "a plot per register: {}", plot.display());
    }

    compare_recording_holds_both_sides(&dir.join("shipped/compare.mcap"));
    let recording = std::fs::read(dir.join("shipped/compare.mcap")).expect("compare.mcap");
    support::layout::names_only_what_the_recording_has(&support::repo().join("hil/foxglove/climbsim-compare-layout.json"), &recording);
    // The world that re-enacted the session live, beside the "real robot", made the same
    // comparison as `compare` made of the finished transcript: the same records, in order.
    let live: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("real.compare/compare.json")).expect("tap's compare.json")).expect("JSON");
    for key in ["instructions", "replies_compared", "replies_the_world_missed", "registers", "latency", "passed"] {
        assert_eq!(live[key], report[key], "{key}: live {} against compare's {}", live[key], report[key]);
    }
    compare_recording_holds_both_sides(&dir.join("real.compare/compare.mcap"));

    // Against the robot's own description: the world matches it, open loop and closed: the
    // same controller run directly on the world (virtual time) follows the line as it did
    // through the tap on the "real robot" (wall clock), within the noise of the two clocks.
    let offsets = dir.join("offset.csv");
    let own = compare(&transcript, &robot, &dir.join("own"), &["--set", HIDDEN_GEARBOX, "--signals", offsets.to_str().expect("utf-8")]);
    let text = support::output_text(&own);
    assert_eq!(own.status.code(), Some(0), "{text}");
    let signals: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("own/signals.json")).expect("signals.json")).expect("JSON");
    for side in ["robot", "world"] {
        assert!(signals[side]["samples"].as_u64().is_some_and(|n| n > 150), "{side}: {signals}");
        assert!(signals[side]["step"]["reference"].as_f64().is_some_and(|e0| (e0 - 0.01).abs() < 0.002), "both start 10 mm off: {signals}");
    }
    let rms = signals["rms_difference_m"].as_f64().expect("an overlap");
    assert!(rms < 0.001, "the two closed loops within 1 mm RMS: {rms} m\n{text}");
    assert!(text.contains("steady-state error") && dir.join("own/plots/line_offset.png").exists(), "{text}");
    assert!(dir.join("own/world-run/summary.json").exists(), "the world's run keeps its outputs");

    // Fit the shipped world to the session: the tread's friction, the magnets' pull, the
    // gearboxes' friction (the controller reads the motors' current) and the encoders'
    // mounting, every value the "real robot" hides. Four parameters take about 300
    // evaluations (docs/real-robot.md).
    let fitted = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .arg("fit")
        .arg(&transcript)
        .args(["--scenario", "scenarios/external-line-follower.toml", "--max-evaluations", "300"])
        .args([
            "--param",
            "robot.wheel.friction=0.2..0.9",
            "--param",
            "robot.magnet.pull_at_contact_n=30.0..120.0",
            "--param",
            "profile.motor.coulomb_friction_nm=0.0..0.12",
            "--param",
            "robot.magnet.encoder_at_down_pulses=2000..2100",
            "--out",
        ])
        .arg(dir.join("fit"))
        .current_dir(support::repo())
        .output()
        .expect("run climbsim fit");
    let text = support::output_text(&fitted);
    assert_eq!(fitted.status.code(), Some(0), "the fitted world matches the robot: {text}");
    let fit: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("fit/fit.json")).expect("fit.json")).expect("JSON");
    let param = |key: &str| fit["parameters"].as_array().expect("parameters").iter().find(|p| p["key"] == key).cloned().unwrap_or_else(|| panic!("{key} in {fit}"));
    let offset = param("robot.magnet.encoder_at_down_pulses");
    assert_eq!(offset["value"], 2060.0, "{offset}");
    let friction = param("robot.wheel.friction");
    let (value, resolution) = (friction["value"].as_f64().expect("value"), friction["resolution"].as_f64().expect("determined"));
    // The session pins it sharply (the error rises by 10 % within a small part of the range),
    // but the "real robot" is a world on the wall clock: on a loaded machine its ticks come
    // late, and what it shows is biased by that, as a real robot's noise would bias it. Measured
    // (2026-11-27, all four fitted, 8 runs, 2 beside two busy loops): friction 0.331-0.370 ±
    // 0.009-0.011, pull 55.0-63.2 ± 1.7-2.8 N, gearbox 0.059-0.075 ± 0.006-0.018. So: within
    // 0.06 (17 %) of the hidden value, or three widths if wider.
    assert!(friction["identifiable"] == true && resolution < 0.05, "{friction}");
    assert!((value - 0.35).abs() <= (3.0 * resolution).max(0.06), "friction {value} against the hidden 0.35 (± {resolution}): {text}");
    // The pull, likewise: within 10 N (17 %), or three widths if wider.
    let pull = param("robot.magnet.pull_at_contact_n");
    let (value, resolution) = (pull["value"].as_f64().expect("value"), pull["resolution"].as_f64().expect("determined"));
    assert!(pull["identifiable"] == true, "{pull}");
    assert!((value - 60.0).abs() <= (3.0 * resolution).max(10.0), "pull {value} N against the hidden 60 (± {resolution}): {text}");
    // The gearbox shows in the wheels' current (about 12 mA more at twice the friction, a few
    // of its 2.69 mA steps).
    let gearbox = param("profile.motor.coulomb_friction_nm");
    let (value, resolution) = (gearbox["value"].as_f64().expect("value"), gearbox["resolution"].as_f64().expect("determined"));
    assert!(gearbox["identifiable"] == true, "{gearbox}");
    assert!((value - 0.06).abs() <= (3.0 * resolution).max(0.02), "gearbox friction {value} against the hidden 0.06 (± {resolution}): {text}");
    let sets = std::fs::read_to_string(dir.join("fit/fitted.sets")).expect("fitted.sets");
    assert!(sets.contains("robot.magnet.encoder_at_down_pulses=2060"), "{sets}");
    // The fitted description carries the robot's keys, and names a fitted profile beside it
    // that carries the gearbox.
    let fitted_robot = dir.join("fit/fitted-robot.toml");
    let fitted_profile: toml::Table = std::fs::read_to_string(dir.join("fit/fitted-profile.toml")).expect("fitted-profile.toml").parse().expect("TOML");
    let fitted_gearbox: f64 = sets.lines().find_map(|l| l.strip_prefix("profile.motor.coulomb_friction_nm=")).expect("the gearbox in fitted.sets").parse().expect("a number");
    assert_eq!(fitted_profile["motor"]["coulomb_friction_nm"].as_float(), Some(fitted_gearbox), "{fitted_profile:?}");
    let after = compare(&transcript, &fitted_robot, &dir.join("after"), &[]);
    assert_eq!(after.status.code(), Some(0), "the fitted description matches: {}", support::output_text(&after));
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("after/compare.json")).expect("compare.json")).expect("JSON");
    let magnet = report["registers"].as_array().expect("registers").iter().find(|r| r["id"] == 5 && r["key"] == "present_position").expect("servo 5");
    assert_eq!(magnet["bias"], 0.0, "{magnet}");
}

/// How long the tapped session lasts: 8 s in CI (each second is a second of wall time; at 5 s
/// the gearbox friction came out "not identifiable" about once in 17 runs), the issue's 30 s
/// with `CLIMBSIM_TAPPED_SESSION_S=30` (docs/real-robot.md has that run's numbers).
fn session_length() -> Duration {
    let seconds = std::env::var("CLIMBSIM_TAPPED_SESSION_S").map_or(8.0, |s| s.parse::<f64>().unwrap_or_else(|_| panic!("CLIMBSIM_TAPPED_SESSION_S={s}: seconds")));
    Duration::from_secs_f64(seconds)
}

/// The "real robot"'s gearbox friction, which only it has.
const HIDDEN_GEARBOX: &str = "profile.motor.coulomb_friction_nm=0.06";

/// `tap --mcap` (read back with the `mcap` crate): a message on `/servos` for each Sync Read,
/// with the real magnet shafts' positions where the transcript has them, and every record of
/// the transcript on `/bus/packets`.
fn tap_recording_shows_the_real_servos(path: &std::path::Path, transcript: &std::path::Path) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let (mut servos, mut packets) = (Vec::new(), 0usize);
    for message in mcap::MessageStream::new(&bytes).expect("an MCAP") {
        let message = message.expect("a complete message");
        match message.channel.topic.as_str() {
            "/servos" => servos.push(serde_json::from_slice::<serde_json::Value>(&message.data).expect("JSON")),
            "/bus/packets" => packets += 1,
            _ => {}
        }
    }
    let records = read(transcript).expect("the transcript").records;
    let transactions = records.iter().filter(|(_, r)| matches!(r, RealRecord::Tx { .. })).count();
    assert_eq!(packets, records.iter().filter(|(_, r)| !matches!(r, RealRecord::End { .. })).count(), "every record shown");
    let magnet_readings: Vec<i64> = servos.iter().filter_map(|m| m["magnet_front_left"]["present_position"].as_i64()).collect();
    assert!(magnet_readings.len() > 100 && magnet_readings.len() <= transactions, "{} readings of servo 5 in {transactions} transactions", magnet_readings.len());
    assert!(magnet_readings.iter().all(|p| (2000..2120).contains(p)), "the real magnet shaft reads about 2060: {:?}", &magnet_readings[..5]);
    assert!(servos.iter().any(|m| m["wheel_rear_right"]["id"] == 4), "the wheels by name: {}", servos[0]);
}

/// `compare.mcap` (read back with the `mcap` crate): the world as a run records it, and each
/// read reply of the session as the robot and the world gave it, at the same instants; the
/// magnet shafts 12 pulses apart.
fn compare_recording_holds_both_sides(path: &std::path::Path) {
    use std::collections::BTreeMap;
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut readings: BTreeMap<(String, u64), serde_json::Value> = BTreeMap::new();
    let mut topics = std::collections::BTreeSet::new();
    for message in mcap::MessageStream::new(&bytes).expect("an MCAP") {
        let message = message.expect("a complete message");
        let topic = message.channel.topic.clone();
        if topic.starts_with("/compare/") {
            readings.insert((topic.clone(), message.log_time), serde_json::from_slice(&message.data).expect("JSON"));
        }
        topics.insert(topic);
    }
    for topic in ["/tf", "/servos", "/bus/packets", "/compare/robot", "/compare/world"] {
        assert!(topics.contains(topic), "{topic} in {topics:?}");
    }
    let mut magnet_pairs = 0;
    for ((topic, at), robot) in readings.iter().filter(|((topic, _), _)| topic == "/compare/robot") {
        let world = readings.get(&("/compare/world".to_owned(), *at)).unwrap_or_else(|| panic!("the world's answer at {at} ns beside {topic}'s"));
        if let Some(robot) = robot.get("magnet_front_left") {
            assert_eq!(robot["id"], 5);
            let (real, simulated) = (robot["present_position"].as_i64().expect("a position"), world["magnet_front_left"]["present_position"].as_i64().expect("the world's"));
            assert_eq!(real - simulated, 12, "at {at} ns: {robot} against {world}");
            magnet_pairs += 1;
        }
    }
    assert!(magnet_pairs > 100, "{magnet_pairs} readings of servo 5");
}

/// The controller: pings 1 to 9 (there is no 9), twenty Sync Reads of Present Position from
/// the eight servos, an LED write, then its port switched to 1 Mbps and one more ping. It
/// prints what it got, one line each.
const CONTROLLER: &str = r#"
import sys
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, PacketHandler, PortHandler
port = PortHandler(sys.argv[1])
assert port.openPort() and port.setBaudRate(57600)
packets = PacketHandler(2.0)
for servo in range(1, 10):
    _, result, _ = packets.ping(port, servo)
    print("ping", servo, result == COMM_SUCCESS)
sync_read = GroupSyncRead(port, packets, 132, 4)
for servo in range(1, 9):
    sync_read.addParam(servo)
print("sync reads", sum(sync_read.txRxPacket() == COMM_SUCCESS for _ in range(20)))
result, _ = packets.write1ByteTxRx(port, 3, 65, 1)
print("led", result == COMM_SUCCESS)
assert port.setBaudRate(1000000)
_, result, _ = packets.ping(port, 1)
print("ping at 1 Mbps", result == COMM_SUCCESS)
"#;

/// An instruction in the transcript: its hex, replies, missed servos and its last byte's time.
type Tx<'a> = (&'a str, &'a [RealReply], &'a [u8], u64);

#[test]
fn tap_forwards_an_unchanged_sdk_controller_and_records_each_transaction_with_its_replies() {
    let dir = support::scratch_dir("tap-sdk");
    let _live = wall_clock();
    let cable = NullModem::new();
    let servos = support::Options::default().stderr_log().start(&["--device", cable.b().to_str().expect("utf-8")]);
    let mut tap = TapProcess::start(cable.a(), &dir, &[]);

    let controller = Command::new(support::sdk_python()).arg("-c").arg(CONTROLLER).arg(&tap.port).output().expect("run the SDK controller");
    let said = String::from_utf8_lossy(&controller.stdout).into_owned();
    assert!(controller.status.success(), "the controller failed: {said}{}", String::from_utf8_lossy(&controller.stderr));
    // Through the tap the controller sees the servos as it would directly.
    for servo in 1..=8 {
        assert!(said.contains(&format!("ping {servo} True")), "{said}");
    }
    assert!(said.contains("ping 9 False") && said.contains("sync reads 20") && said.contains("led True") && said.contains("ping at 1 Mbps True"), "{said}");
    assert_eq!(cable.baud_a(), Some(1_000_000), "the device follows the controller's rate");

    tap.interrupt();
    let status = tap.wait(Duration::from_secs(10));
    let stderr = tap.stderr();
    assert!(status.success(), "tap exited {status}: {stderr}");
    drop(servos);

    let transcript = read(&dir.join("real.jsonl")).expect("the transcript reads back");
    assert!(transcript.complete && !transcript.torn_tail);
    assert_eq!(transcript.header.mode, "tap");
    let records: Vec<&RealRecord> = transcript.records.iter().map(|(_, r)| r).collect();
    let txs: Vec<Tx<'_>> =
        records.iter().filter_map(|r| if let RealRecord::Tx { hex, replies, missed, end, .. } = r { Some((hex.as_str(), replies.as_slice(), missed.as_slice(), *end)) } else { None }).collect();
    // 9 pings, 20 Sync Reads, the LED write, the last ping (the SDK adds nothing else).
    assert_eq!(txs.len(), 31, "{records:?}");
    let missed: Vec<u8> = txs.iter().flat_map(|tx| tx.2.iter().copied()).collect();
    assert_eq!(missed, vec![9], "only the absent servo is missed");
    let sync_reads: Vec<_> = txs.iter().filter(|tx| tx.0.get(14..16) == Some("82")).collect();
    assert_eq!(sync_reads.len(), 20);
    for tx in &sync_reads {
        let ids: Vec<u8> = tx.1.iter().map(|r| r.id).collect();
        assert_eq!(ids, (1..=8).collect::<Vec<u8>>(), "each Sync Read paired with its eight replies, in order");
        assert!(tx.1.iter().all(|r| r.t >= tx.3 && r.end >= r.t), "replies come after the request's last byte");
    }
    // Every byte the tap forwarded is in the transcript: instructions, replies and nothing raw.
    let Some(RealRecord::End { from_controller, from_servos, why, .. }) = records.last() else { panic!("no end line") };
    assert_eq!(why, "interrupted");
    let sent: usize = txs.iter().map(|tx| from_hex(tx.0).expect("hex").len()).sum();
    let answered: usize = txs.iter().flat_map(|tx| tx.1.iter()).map(|r| from_hex(&r.hex).expect("hex").len()).sum();
    assert_eq!((sent as u64, answered as u64), (*from_controller, *from_servos));
    assert!(records.iter().any(|r| matches!(r, RealRecord::Baud { baud: 1_000_000, .. })));
    assert!(!records.iter().any(|r| matches!(r, RealRecord::Raw { .. } | RealRecord::Unpaired { .. } | RealRecord::FrameError { .. })), "{records:?}");

    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("real.timing.json")).expect("the timing report")).expect("JSON");
    let servos = report["servos"].as_array().expect("servos");
    assert_eq!(servos.len(), 9, "{report}");
    assert_eq!(servos[8]["id"], 9);
    assert_eq!(servos[8]["missed"], 1);
    assert_eq!(servos[0]["replies"], 22, "servo 1: its ping, 20 Sync Reads and the last ping");
    assert!(servos[0]["latency_us"]["median"].as_f64().is_some_and(|m| m > 0.0), "{report}");
    assert!(stderr.contains("transactions; reply latency"), "the table is printed: {stderr}");
}

#[test]
fn a_device_that_goes_away_ends_the_tap_with_complete_outputs() {
    let dir = support::scratch_dir("tap-unplug");
    let cable = NullModem::new();
    let mut tap = TapProcess::start(cable.a(), &dir, &[]);
    cable.unplug_a();
    let status = tap.wait(Duration::from_secs(10));
    let stderr = tap.stderr();
    assert!(status.success(), "tap exited {status}: {stderr}");
    let transcript = read(&dir.join("real.jsonl")).expect("the transcript reads back");
    assert!(transcript.complete, "an end line");
    assert!(matches!(transcript.records.last(), Some((_, RealRecord::End { why, .. })) if why.contains("went away")), "{:?}", transcript.records);
    assert!(dir.join("real.timing.json").exists());
    assert!(!dir.join("ttyDXL").exists(), "the link is removed");
}

#[test]
fn a_device_that_is_not_there_is_named_and_nothing_is_left_behind() {
    let dir = support::scratch_dir("tap-missing");
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["tap", "--device", "/dev/does-not-exist", "--link"])
        .arg(dir.join("ttyDXL"))
        .arg("--record")
        .arg(dir.join("real.jsonl"))
        .output()
        .expect("run climbsim tap");
    let text = support::output_text(&output);
    assert_eq!(output.status.code(), Some(2), "{text}");
    assert!(text.contains("/dev/does-not-exist") && text.contains("no such device"), "{text}");
    assert!(!dir.join("real.jsonl").exists() && !dir.join("ttyDXL").exists());
}

/// A controller that reads with Fast Sync Read: its one combined reply is split per servo and
/// compared register by register. The session is written with the library's own recorder (a
/// Fast Sync Read of Present Position from all eight, every 20 ms for 2 s, each servo's block
/// saying 2048 + its ID), and compared against the world at rest on flat ground.
#[test]
fn a_fast_sync_read_session_is_compared_per_servo() {
    let dir = support::scratch_dir("fast-compare");
    let path = dir.join("fast.jsonl");
    fast_read_session(&path, &[1, 2, 3, 4, 5, 6, 7, 8], |id| 2048 + i32::from(id));
    let out = dir.join("compared");
    let compared = compare_on_flat_line(&path, &out);
    let text = support::output_text(&compared);
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("compare.json")).unwrap_or_else(|e| panic!("{e}: {text}"))).expect("JSON");
    assert_eq!(report["replies_compared"], 800, "eight servos in each of 100 combined replies: {text}");
    assert_eq!(report["replies_the_world_missed"], 0, "{text}");
    let registers = report["registers"].as_array().expect("registers");
    assert_eq!(registers.len(), 8, "{text}");
    for (register, id) in registers.iter().zip(1..=8) {
        assert_eq!((register["id"].as_u64(), register["key"].as_str(), register["samples"].as_u64()), (Some(id), Some("present_position"), Some(100)), "{register}");
    }
    // The world's magnet shafts rest at 2048 (pointing down): servo N's block said 2048 + N.
    let magnet = registers.iter().find(|r| r["id"] == 6).expect("servo 6");
    assert_eq!(magnet["bias"], -6.0, "{magnet}");
}

/// What the real bus said besides its readings is on the compare recording's log beside the
/// world's own lines: a servo that did not answer, a framing error, a reply to nothing (a
/// session written by hand: Sync Reads of the magnet shafts, servo 8 silent once).
#[test]
fn the_robots_missed_replies_and_bus_errors_are_on_the_compare_recordings_log() {
    use climbsim::protocol::{encode_instruction, encode_status};
    use climbsim::real_bus::{RealHeader, Side};
    use climbsim::transcript::Recorder;
    use foxglove::Decode;

    let dir = support::scratch_dir("compare-log");
    let path = dir.join("session.jsonl");
    let recorder = Recorder::create(&path, &RealHeader::new(std::path::Path::new("/dev/null"), &dir.join("ttyDXL"), 57_600, 0)).expect("a transcript");
    let hex = |bytes: &[u8]| bytes.iter().map(|b| format!("{b:02x}")).collect::<String>();
    let request = encode_instruction(0xFE, 0x82, &[132, 0, 4, 0, 5, 6, 7, 8]);
    for period in 0..50u64 {
        let t = 50_000_000 + period * 20_000_000;
        let silent = period == 10;
        let answering: Vec<u8> = (5..=8).filter(|&id| !(silent && id == 8)).collect();
        let replies = answering.iter().enumerate().map(|(k, &id)| {
            let at = t + 3_000_000 + k as u64 * 3_000_000;
            RealReply { id, t: at, end: at + 2_600_000, hex: hex(&encode_status(id, 0, &2048i32.to_le_bytes())) }
        });
        recorder.append(&RealRecord::Tx { t, end: t + 2_000_000, baud: 57_600, hex: hex(&request), replies: replies.collect(), missed: if silent { vec![8] } else { Vec::new() } });
        if period == 20 {
            recorder.append(&RealRecord::FrameError { from: Side::Servos, t: t + 15_000_000, what: "a byte without its stop bit".into() });
            recorder.append(&RealRecord::Unpaired { t: t + 16_000_000, hex: hex(&encode_status(6, 0, &2048i32.to_le_bytes())) });
        }
    }
    recorder.finish_with(&RealRecord::End { t: 1_100_000_000, why: "written by the test".into(), from_controller: 0, from_servos: 0 }).expect("complete");
    let out = dir.join("compared");
    let compared = compare_on_flat_line(&path, &out);
    let text = support::output_text(&compared);
    let bytes = std::fs::read(out.join("compare.mcap")).unwrap_or_else(|e| panic!("compare.mcap: {e}: {text}"));
    let mut lines = Vec::new();
    for message in mcap::MessageStream::new(&bytes).expect("an MCAP") {
        let message = message.expect("a complete message");
        if message.channel.topic == "/log" {
            lines.push(foxglove::messages::Log::decode(&message.data[..]).expect("a Log").message);
        }
    }
    for expected in [
        "the robot: no reply from magnet_rear_right (8)",
        "the robot: from the servos: a byte without its stop bit",
        "the robot: a status packet from magnet_front_right (6) that answered nothing pending (late?)",
    ] {
        assert!(lines.iter().any(|line| line == expected), "{expected:?} on /log: {lines:?}\n{text}");
    }
}

/// A real session written by hand at `path`: 2 s of a Fast Sync Read of Present Position
/// (132) from servos `ids` every 20 ms, servo N answering `position(N)`.
fn fast_read_session(path: &std::path::Path, ids: &[u8], position: impl Fn(u8) -> i32) {
    use climbsim::protocol::{FastReplyBuilder, encode_instruction};
    use climbsim::real_bus::RealHeader;
    use climbsim::transcript::Recorder;

    let dir = path.parent().expect("a folder");
    let recorder = Recorder::create(path, &RealHeader::new(std::path::Path::new("/dev/null"), &dir.join("ttyDXL"), 57_600, 0)).expect("a transcript");
    let hex = |bytes: &[u8]| bytes.iter().map(|b| format!("{b:02x}")).collect::<String>();
    let request = encode_instruction(0xFE, 0x8A, &[&[132, 0, 4, 0][..], ids].concat());
    for period in 0..100u64 {
        let t = 50_000_000 + period * 20_000_000;
        let mut reply = FastReplyBuilder::new(vec![4; ids.len()]).expect("fits");
        for &id in ids {
            reply.push_block(0, id, &position(id).to_le_bytes());
        }
        let replies = vec![RealReply { id: 0xFE, t: t + 3_200_000, end: t + 10_000_000, hex: hex(&reply.into_bytes()) }];
        recorder.append(&RealRecord::Tx { t, end: t + 2_600_000, baud: 57_600, hex: hex(&request), replies, missed: Vec::new() });
    }
    recorder.finish_with(&RealRecord::End { t: 2_100_000_000, why: "written by the test".into(), from_controller: 0, from_servos: 0 }).expect("complete");
}

/// `fit --session`: two sessions are fitted at once, to the mean of their errors. The magnet
/// shafts (only they are read) read 2050 in one and 2070 in the other; the world's shafts rest
/// at the encoder offset, so one session alone gives 2050, the other 2070, and both the value
/// between (± 2: an integer parameter's steps are plateaus the search may stop on), each
/// session's reports in a folder of its own.
#[test]
fn a_fit_of_two_sessions_minimises_their_mean_error() {
    let _both_cores = wall_clock();
    let dir = support::scratch_dir("fit-sessions");
    let (low, high) = (dir.join("low.jsonl"), dir.join("high.jsonl"));
    fast_read_session(&low, &[5, 6, 7, 8], |_| 2050);
    fast_read_session(&high, &[5, 6, 7, 8], |_| 2070);
    let fit = |transcript: &std::path::Path, more: &[&str], out: &str| {
        let output = Command::new(env!("CARGO_BIN_EXE_climbsim"))
            .arg("fit")
            .arg(transcript)
            .args(["--scenario", "scenarios/flat-line.toml", "--param", "robot.magnet.encoder_at_down_pulses=2000..2100", "--jobs", "2", "--out"])
            .arg(dir.join(out))
            .args(more)
            .current_dir(support::repo())
            .output()
            .expect("run climbsim fit");
        let text = support::output_text(&output);
        let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join(out).join("fit.json")).unwrap_or_else(|e| panic!("{e}: {text}"))).expect("JSON");
        (report["parameters"][0]["value"].as_f64().unwrap_or_else(|| panic!("no value: {text}")), report, text)
    };
    let (alone_low, _, text) = fit(&low, &[], "low");
    assert!((2048.0..=2052.0).contains(&alone_low), "{alone_low}: {text}");
    let (alone_high, _, text) = fit(&high, &[], "high");
    assert!((2068.0..=2072.0).contains(&alone_high), "{alone_high}: {text}");
    let session = format!("{}=scenarios/flat-line.toml", high.display());
    let (both, report, text) = fit(&low, &["--session", &session], "both");
    assert!((2058.0..=2062.0).contains(&both), "{both}: {text}");
    let sessions = report["sessions"].as_array().expect("sessions");
    assert_eq!(sessions.len(), 2, "{report}");
    let errors: Vec<f64> = sessions.iter().map(|s| s["error_after"].as_f64().expect("an error")).collect();
    let mean = (errors[0] + errors[1]) / 2.0;
    assert!((report["error_after"].as_f64().expect("an error") - mean).abs() < 1e-12, "{report}");
    for folder in ["both/after/compare.json", "both/session-2/before/compare.json", "both/session-2/after/compare.json"] {
        assert!(dir.join(folder).is_file(), "{folder}: {text}");
    }
    // A session that cannot be read is named.
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .arg("fit")
        .arg(&low)
        .args(["--scenario", "scenarios/flat-line.toml", "--param", "robot.magnet.encoder_at_down_pulses=2000..2100", "--session", "nothing-here.jsonl", "--out"])
        .arg(dir.join("bad"))
        .current_dir(support::repo())
        .output()
        .expect("run climbsim fit");
    assert_eq!(output.status.code(), Some(2), "{}", support::output_text(&output));
    assert!(support::output_text(&output).contains("nothing-here.jsonl"), "{}", support::output_text(&output));
}
