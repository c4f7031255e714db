//! `climbsim serve` from the outside: clear errors for bad input, the bus trace, clean shutdown.

mod support;

use std::io::{Read, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use support::Options;

const BIN: &str = env!("CARGO_BIN_EXE_climbsim");

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("climbsim-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Run `climbsim serve` expecting it to fail at start-up; return its stderr.
fn serve_fails(args: &[&str]) -> String {
    let out = Command::new(BIN).arg("serve").args(args).output().unwrap();
    assert_eq!(out.status.code(), Some(2), "expected exit 2 (bad input), stdout: {}", String::from_utf8_lossy(&out.stdout));
    assert!(out.stdout.is_empty(), "no port line on failure");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!stderr.contains("panicked"), "{stderr}");
    stderr
}

#[test]
fn bad_robot_file_names_file_line_and_key() {
    let dir = temp_dir("robot");
    let robot = dir.join("robot.toml");
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("hil/robot.toml")).unwrap();
    let text = text.replace("supply_voltage_v = 12.0", "supply_voltage_v = 12.0\nsupply_volts = 12");
    std::fs::write(&robot, &text).unwrap();
    let line = text.lines().position(|l| l.starts_with("supply_volts")).unwrap() + 1;
    let stderr = serve_fails(&["--robot", robot.to_str().unwrap()]);
    assert!(stderr.contains(&format!("{}:{line}:", robot.display())), "{stderr}");
    assert!(stderr.contains("supply_volts"), "{stderr}");
}

#[test]
fn bad_profile_file_is_named() {
    let dir = temp_dir("profile");
    std::fs::write(dir.join("profile.toml"), "[model]\nname = \"X\"\nmodel_number = \"not a number\"\n").unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("hil/robot.toml")).unwrap();
    let text = text.replace("../firmware-profiles/xm540-w270-r.toml", "profile.toml");
    std::fs::write(dir.join("robot.toml"), text).unwrap();
    let stderr = serve_fails(&["--robot", dir.join("robot.toml").to_str().unwrap()]);
    assert!(stderr.contains("profile.toml:3:"), "{stderr}");
}

#[test]
fn busy_link_path_is_refused() {
    let dir = temp_dir("busy");
    let busy = dir.join("taken");
    std::fs::write(&busy, "mine").unwrap();
    let stderr = serve_fails(&["--link", busy.to_str().unwrap()]);
    assert!(stderr.contains("is busy"), "{stderr}");
    assert_eq!(std::fs::read_to_string(&busy).unwrap(), "mine", "the file was not touched");
}

#[test]
fn bad_tcp_address_is_refused() {
    let out = Command::new(BIN).args(["serve", "--tcp", "localhost:99999"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not PORT or HOST:PORT"));
}

#[test]
fn unsupported_baud_is_refused() {
    let stderr = serve_fails(&["--baud", "12345"]);
    assert!(stderr.contains("12345"), "{stderr}");
}

fn open_raw(path: &Path) -> std::fs::File {
    let file = std::fs::OpenOptions::new().read(true).write(true).open(path).unwrap();
    let mut termios = nix::sys::termios::tcgetattr(&file).unwrap();
    nix::sys::termios::cfmakeraw(&mut termios);
    nix::sys::termios::cfsetspeed(&mut termios, nix::sys::termios::BaudRate::B57600).unwrap();
    nix::sys::termios::tcsetattr(&file, nix::sys::termios::SetArg::TCSANOW, &termios).unwrap();
    file
}

fn read_exact_within(file: &mut std::fs::File, n: usize, limit: Duration) -> Vec<u8> {
    let deadline = Instant::now() + limit;
    let mut out = Vec::new();
    let mut buf = [0u8; 256];
    while out.len() < n {
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "only {} of {n} bytes: {out:02X?}", out.len());
        let mut poll = [nix::poll::PollFd::new(unsafe { std::os::fd::BorrowedFd::borrow_raw(file.as_raw_fd()) }, nix::poll::PollFlags::POLLIN)];
        nix::poll::poll(&mut poll, nix::poll::PollTimeout::try_from(left.as_millis() as i32).unwrap()).unwrap();
        let got = file.read(&mut buf).unwrap();
        out.extend_from_slice(&buf[..got]);
    }
    out
}

#[test]
fn trace_bus_writes_each_transaction_as_json_lines_and_shutdown_removes_link() {
    let dir = temp_dir("trace");
    let link = dir.join("ttyDXL");
    let trace = dir.join("bus.jsonl");
    let mut serve = Options::default().stderr_log().start(&["--link", link.to_str().unwrap(), "--timing", "off", "--trace-bus", trace.to_str().unwrap()]);
    assert_eq!(serve.port(), link);
    let mut port = open_raw(&link);
    port.write_all(&[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E]).unwrap();
    let reply = read_exact_within(&mut port, 14, Duration::from_secs(2));
    assert_eq!(reply, [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x55, 0x00, 0x60, 0x04, 0x30, 0xEA, 0xDA]);
    drop(port);
    let status = serve.terminate().expect("climbsim did not exit within 10 s of SIGTERM");
    assert!(status.success(), "{status:?}");
    assert!(!link.exists() && std::fs::symlink_metadata(&link).is_err(), "link removed on shutdown");
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(&trace).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 2, "{lines:?}");
    assert_eq!(lines[0]["dir"], "controller->servos");
    assert_eq!(lines[0]["decoded"]["instruction"], "Ping");
    assert_eq!(lines[0]["hex"], "FF FF FD 00 01 03 00 01 19 4E");
    assert_eq!(lines[1]["dir"], "servos->controller");
    assert_eq!(lines[1]["hex"], "FF FF FD 00 01 07 00 55 00 60 04 30 EA DA");
    assert_eq!(lines[1]["from"], serde_json::json!([1]));
}

/// Write then expect the 11-byte no-error status from `id`.
fn write_ok(port: &mut std::fs::File, id: u8, address: u16, data: &[u8]) {
    let mut params = address.to_le_bytes().to_vec();
    params.extend_from_slice(data);
    port.write_all(&climbsim::protocol::encode_instruction(id, climbsim::protocol::opcode::WRITE, &params)).unwrap();
    let reply = read_exact_within(port, 11, Duration::from_secs(2));
    assert_eq!(reply[8], 0, "status error from ID {id}: {reply:02X?}");
}

fn read_i32(port: &mut std::fs::File, id: u8, address: u16) -> i32 {
    let mut params = address.to_le_bytes().to_vec();
    params.extend_from_slice(&4u16.to_le_bytes());
    port.write_all(&climbsim::protocol::encode_instruction(id, climbsim::protocol::opcode::READ, &params)).unwrap();
    let reply = read_exact_within(port, 15, Duration::from_secs(2));
    assert_eq!(reply[8], 0, "status error from ID {id}: {reply:02X?}");
    i32::from_le_bytes(reply[9..13].try_into().unwrap())
}

#[test]
fn serve_with_a_scenario_runs_the_world_on_the_wall_clock() {
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/flat.toml");
    let mut serve = Options::default().stderr_log().start(&[scenario.to_str().unwrap(), "--timing", "off"]);
    let mut port = open_raw(serve.port());
    write_ok(&mut port, 1, 11, &[1]); // velocity mode
    write_ok(&mut port, 1, 64, &[1]); // torque on
    write_ok(&mut port, 1, 104, &50i32.to_le_bytes());
    let start = read_i32(&mut port, 1, 132);
    // No packets for a second: the world still moves (the pacer advances it).
    std::thread::sleep(Duration::from_secs(1));
    let moved = read_i32(&mut port, 1, 132) - start;
    // 50 × 0.229 rev/min for ~1 s is ~780 pulses; the wheel loop ramps up first.
    assert!((500..900).contains(&moved), "wheel 1 turned {moved} pulses in 1 s");
    // The magnets of a robot on flat steel point straight down: encoder at mid-range.
    for id in 5..=8 {
        let magnet = read_i32(&mut port, id, 132);
        assert!((magnet - 2048).abs() <= 12, "magnet {id} reads {magnet}");
    }
    drop(port);
    let status = serve.terminate().expect("exit");
    assert!(status.success(), "{status:?}");
}
