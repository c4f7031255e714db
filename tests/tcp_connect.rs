//! `serve --tcp-connect`: climbsim as the TCP client of a controller that is a server (firmware
//! in QEMU or Renode). A std `TcpListener` plays the emulator: it starts after climbsim, greets
//! with Renode's telnet negotiation, pings, then "restarts" (closes and accepts again).

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

mod support;

/// Ping ID `id`: FF FF FD 00, ID, length 3, instruction 0x01, CRC.
fn ping(id: u8) -> Vec<u8> {
    let mut packet = vec![0xFF, 0xFF, 0xFD, 0x00, id, 0x03, 0x00, 0x01];
    let crc = crc16(&packet);
    packet.extend(crc.to_le_bytes());
    packet
}

/// The Protocol 2.0 CRC (CRC-16/BUYPASS), written out here so that the test does not trust the
/// emulator's own.
fn crc16(bytes: &[u8]) -> u16 {
    let mut crc: u16 = 0;
    for &byte in bytes {
        crc ^= u16::from(byte) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ 0x8005 } else { crc << 1 };
        }
    }
    crc
}

/// Read one status packet (14 bytes for a ping reply) within a second.
fn read_status(stream: &mut TcpStream) -> Vec<u8> {
    stream.set_read_timeout(Some(Duration::from_secs(1))).expect("timeout");
    let mut reply = vec![0u8; 14];
    stream.read_exact(&mut reply).expect("a ping reply within 1 s");
    reply
}

fn accept_within(listener: &TcpListener, limit: Duration) -> TcpStream {
    listener.set_nonblocking(true).expect("nonblocking");
    let deadline = Instant::now() + limit;
    loop {
        match listener.accept() {
            Ok((stream, _)) => {
                stream.set_nonblocking(false).expect("blocking");
                return stream;
            }
            Err(error) if error.kind() == std::io::ErrorKind::WouldBlock && Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            Err(error) => panic!("climbsim did not connect within {limit:?}: {error}"),
        }
    }
}

#[test]
fn climbsim_connects_to_a_late_server_survives_its_telnet_greeting_and_reconnects_after_a_restart() {
    // A free port, then nothing listening on it while climbsim starts.
    let port = TcpListener::bind("127.0.0.1:0").expect("bind").local_addr().expect("addr").port();
    let addr = format!("127.0.0.1:{port}");
    let mut emulator = support::Options::default().stderr_log().start(&["--tcp-connect", &addr, "--timing", "off"]);
    std::thread::sleep(Duration::from_millis(800));

    let listener = TcpListener::bind(&addr).expect("bind the emulator's port");
    let mut stream = accept_within(&listener, Duration::from_secs(5));
    // Renode's server socket terminal without `false` first negotiates telnet options: IAC WILL
    // ECHO, IAC WILL SUPPRESS-GO-AHEAD, IAC DO SUPPRESS-GO-AHEAD.
    stream.write_all(&[0xFF, 0xFB, 0x01, 0xFF, 0xFB, 0x03, 0xFF, 0xFD, 0x03]).expect("greeting");
    stream.write_all(&ping(1)).expect("ping");
    let reply = read_status(&mut stream);
    assert_eq!(&reply[..5], &[0xFF, 0xFF, 0xFD, 0x00, 1], "{reply:02X?}");
    assert_eq!(reply[7], 0x55, "a status packet: {reply:02X?}");
    assert_eq!(&reply[9..12], &[0x60, 0x04, 48], "model 1120, firmware 48: {reply:02X?}");
    assert_eq!(crc16(&reply[..12]).to_le_bytes(), [reply[12], reply[13]], "CRC");

    // The emulator restarts: the connection closes and a new one is accepted.
    drop(stream);
    let mut stream = accept_within(&listener, Duration::from_secs(5));
    stream.write_all(&ping(2)).expect("ping");
    let reply = read_status(&mut stream);
    assert_eq!(reply[4], 2, "{reply:02X?}");
    drop(stream);

    let stderr = emulator.stderr();
    assert!(stderr.contains("reconnecting"), "{stderr}");
    // The wait for a late server was said at the default log level, once.
    assert_eq!(stderr.matches("cannot connect yet").count(), 1, "{stderr}");
    assert!(emulator.stop(), "{}", emulator.stderr());
}

/// The docs' QEMU recipe's far side as QEMU's UART makes it: every byte of a packet handed to the
/// socket by its own write, with Nagle on (QEMU's default without `nodelay=on`), so the rest of
/// each packet waits for the first byte's ACK. Every packet is answered, also the one sent
/// right after a reply, and nothing is counted as cut by a gap (the servos' 1.5 ms inter-byte
/// timeout once dropped almost every packet on this stream).
#[test]
fn a_uart_that_writes_byte_by_byte_with_nagle_on_is_answered_every_time() {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr").to_string();
    let report = support::scratch_dir("tcp-bytewise").join("timing.json");
    let mut emulator = support::Options::default().stderr_log().start(&["--tcp-connect", &addr, "--report", report.to_str().expect("UTF-8")]);
    let mut stream = accept_within(&listener, Duration::from_secs(5));
    assert!(!stream.nodelay().expect("nodelay"), "Nagle is on, as in QEMU");
    const TRANSACTIONS: u8 = 40;
    for n in 0..TRANSACTIONS {
        let id = 1 + n % 8;
        for byte in ping(id) {
            stream.write_all(&[byte]).expect("one byte");
        }
        let reply = read_status(&mut stream);
        assert_eq!(reply[4], id, "transaction {n}: {reply:02X?}\n{}", emulator.stderr());
    }
    drop(stream);
    assert!(emulator.stop(), "{}", emulator.stderr());
    let timing: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).expect("timing report")).expect("JSON");
    assert_eq!((timing["inter_byte_gaps"].as_u64(), timing["frame_errors"].as_u64()), (Some(0), Some(0)), "{timing}");
}

/// Port 0 (or an unspecified address) names no server to connect to: refused at once, instead of
/// retrying forever.
#[test]
fn a_port_that_names_no_server_is_refused() {
    for addr in ["127.0.0.1:0", "0.0.0.0:5555"] {
        let output = support::climbsim(&["serve", "--tcp-connect", addr]);
        assert_eq!(output.status.code(), Some(2), "{addr}: {}", support::output_text(&output));
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(stderr.contains("--tcp-connect") && stderr.contains("no server to connect to"), "{addr}: {stderr}");
    }
}
