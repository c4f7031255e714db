//! `climbsim tap` between an unchanged controller (the official Python SDK) and "real" servos:
//! climbsim itself on the far end of two pseudo-terminals joined like a null-modem cable
//! (`serve --device`). Everything here is real: the ptys, the SDK, the serial device's
//! exclusive open and termios, the bytes on both sides.

mod support;

use std::process::Command;
use std::time::Duration;

use climbsim::real_bus::RealRecord;
use climbsim::real_bus::transcript::{RealReply, read};
use climbsim::transcript::from_hex;
use support::null_modem::NullModem;
use support::tap::TapProcess;

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
    let txs: Vec<Tx<'_>> = records.iter().filter_map(|r| if let RealRecord::Tx { hex, replies, missed, end, .. } = r { Some((hex.as_str(), replies.as_slice(), missed.as_slice(), *end)) } else { None }).collect();
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
