//! The in-memory transport runs the same session code as the pty and TCP: a controller talking
//! bytes through a duplex pipe gets the servos' replies, with wire timing on or off.

use std::time::{Duration, Instant};

use climbsim::bus::Timing;
use climbsim::protocol::{Decoder, RawPacket, encode_instruction, opcode};
use climbsim::robot::RobotDescription;
use climbsim::transport::{BusHandle, memory};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

fn handle(timing: Timing) -> std::sync::Arc<BusHandle> {
    let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot description");
    BusHandle::new(robot.bench_bus(timing, None).expect("bus"), None)
}

async fn read_packets(stream: &mut DuplexStream, count: usize) -> Vec<RawPacket> {
    let mut decoder = Decoder::default();
    let mut packets = Vec::new();
    let mut buf = [0u8; 512];
    while packets.len() < count {
        let n = tokio::time::timeout(Duration::from_secs(2), stream.read(&mut buf)).await.expect("reply in time").expect("read");
        assert!(n > 0, "bus side closed");
        packets.extend(decoder.push(Duration::ZERO, &buf[..n]).into_iter().filter_map(Result::ok));
    }
    packets
}

#[tokio::test]
async fn broadcast_ping_over_memory_pipe_answers_in_id_order() {
    let mut controller = memory::connect(handle(Timing::Off));
    controller.write_all(&encode_instruction(0xFE, opcode::PING, &[])).await.unwrap();
    let replies = read_packets(&mut controller, 8).await;
    let ids: Vec<u8> = replies.iter().map(|p| p.id).collect();
    assert_eq!(ids, [1, 2, 3, 4, 5, 6, 7, 8]);
    assert!(replies.iter().all(|p| p.params == [0x00, 0x60, 0x04, 48]), "error byte 0, model 1120, FW 48");
}

#[tokio::test]
async fn wire_timing_delays_reply_by_return_delay_and_bytes() {
    let mut controller = memory::connect(handle(Timing::Wire));
    let ping = encode_instruction(1, opcode::PING, &[]);
    let started = Instant::now();
    controller.write_all(&ping).await.unwrap();
    read_packets(&mut controller, 1).await;
    let elapsed = started.elapsed();
    // 10-byte ping + 14-byte reply at 57600 bps (10 bits/byte) + 500 µs Return Delay Time.
    let wire = Duration::from_secs_f64((10.0 + 14.0) * 10.0 / 57600.0) + Duration::from_micros(500);
    assert!(elapsed >= wire, "reply after {elapsed:?}, the wire needs at least {wire:?}");
}
