//! The CAN transport: a controller-side ISO-TP endpoint (the same codec, driven from the test)
//! talks to the real bus through the in-memory CAN frame pipe, so every run covers the framing
//! without kernel CAN. The `vcan` test at the end drives `climbsim serve --can` through a real
//! SocketCAN interface; it is ignored unless asked for (`scripts/test.sh` runs it when vcan0
//! exists or `CLIMBSIM_VCAN` names an interface).

mod support;

use std::sync::Arc;
use std::time::Duration;

use climbsim::bus::Timing;
use climbsim::protocol::{Decoder, RawPacket, encode_instruction, opcode};
use climbsim::robot::RobotDescription;
use climbsim::transport::BusHandle;
use climbsim::transport::can::{CanFrame, CanFrameIo, CanId, CanIds, IsoTpChannel, MemoryCanPort, frame_pipe, isotp, serve_can};

/// Guards against a hang; never a timing assertion.
const WITHIN: Duration = Duration::from_secs(5);
const PROFILE_VELOCITY: u16 = 112;
const IDS: [u8; 8] = [1, 2, 3, 4, 5, 6, 7, 8];

fn handle(timing: Timing) -> Arc<BusHandle> {
    let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot description");
    BusHandle::new(robot.bench_bus(timing, None).expect("bus"), None)
}

/// The bus served on one end of a frame pipe (default IDs and ISO-TP settings); the other end.
fn bus_on_pipe(timing: Timing) -> MemoryCanPort {
    let (controller, bus) = frame_pipe(256);
    tokio::spawn(serve_can(bus, CanIds::default(), isotp::Config::default(), handle(timing)));
    controller
}

fn controller(port: MemoryCanPort) -> IsoTpChannel<MemoryCanPort> {
    IsoTpChannel::controller_side(port, CanIds::default(), isotp::Config::default())
}

/// One ISO-TP message from the bus, which must be exactly one Dynamixel packet.
async fn next_packet<F: CanFrameIo>(channel: &mut IsoTpChannel<F>) -> RawPacket {
    let message = tokio::time::timeout(WITHIN, channel.recv()).await.expect("reply in time").expect("CAN I/O").expect("link open");
    let mut decoder = Decoder::default();
    let mut decoded = decoder.push(Duration::ZERO, &message);
    assert_eq!(decoded.len(), 1, "one packet per ISO-TP message: {message:02X?}");
    assert_eq!(decoder.pending(), 0, "nothing after the packet: {message:02X?}");
    decoded.remove(0).expect("a valid status packet")
}

async fn request<F: CanFrameIo>(channel: &mut IsoTpChannel<F>, packet: Vec<u8>) {
    tokio::time::timeout(WITHIN, channel.send(packet)).await.expect("request sent in time").expect("CAN I/O");
}

fn read(id: u8, address: u16, length: u16) -> Vec<u8> {
    encode_instruction(id, opcode::READ, &[address.to_le_bytes(), length.to_le_bytes()].concat())
}

async fn recv_frame(port: &mut MemoryCanPort) -> CanFrame {
    tokio::time::timeout(WITHIN, port.recv()).await.expect("frame in time").expect("pipe").expect("pipe open")
}

async fn send_frame(port: &mut MemoryCanPort, id: CanId, data: &[u8]) {
    port.send(CanFrame::new(id, data).expect("at most 8 bytes")).await.expect("pipe open");
}

#[tokio::test]
async fn ping_on_the_wire_frame_by_frame() {
    let mut port = bus_on_pipe(Timing::Off);
    let (request_id, response_id) = (CanId::Standard(0x7E0), CanId::Standard(0x7E8));
    // A 10-byte ping: first frame with 6 bytes, the bus's flow control, one consecutive frame.
    let ping = encode_instruction(1, opcode::PING, &[]);
    assert_eq!(ping.len(), 10);
    send_frame(&mut port, request_id, &[&[0x10, 10][..], &ping[..6]].concat()).await;
    let flow_control = recv_frame(&mut port).await;
    assert_eq!(flow_control.id, response_id);
    assert_eq!(flow_control.data.as_slice(), [0x30, 0x00, 0x00, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC], "CTS, BS 0, STmin 0, padded");
    send_frame(&mut port, request_id, &[&[0x21][..], &ping[6..], &[0xCC; 3]].concat()).await;

    // The 14-byte status packet: first frame, then (after our CTS) two consecutive frames.
    let first = recv_frame(&mut port).await;
    assert_eq!(first.id, response_id);
    assert_eq!(&first.data.as_slice()[..2], [0x10, 14]);
    send_frame(&mut port, request_id, &[0x30, 0x00, 0x00]).await;
    let cf1 = recv_frame(&mut port).await;
    let cf2 = recv_frame(&mut port).await;
    assert_eq!((cf1.data.as_slice()[0], cf2.data.as_slice()[0]), (0x21, 0x22));
    assert_eq!(cf2.data.as_slice(), [0x22, cf2.data.as_slice()[1], 0xCC, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC], "last frame padded");
    let reply: Vec<u8> = [&first.data.as_slice()[2..], &cf1.data.as_slice()[1..], &cf2.data.as_slice()[1..2]].concat();
    let packets = Decoder::default().push(Duration::ZERO, &reply);
    let status = packets[0].as_ref().expect("status packet");
    assert_eq!((status.id, status.instruction), (1, opcode::STATUS));
    assert_eq!(status.params, [0x00, 0x60, 0x04, 48], "error 0, model 1120, firmware 48");
}

#[tokio::test]
async fn ping_read_and_write_through_the_frame_pipe() {
    let mut channel = controller(bus_on_pipe(Timing::Off));
    request(&mut channel, encode_instruction(3, opcode::PING, &[])).await;
    let pong = next_packet(&mut channel).await;
    assert_eq!((pong.id, pong.params.as_slice()), (3, &[0x00, 0x60, 0x04, 48][..]));

    // Model Number (address 0, 2 bytes) of servo 5: 1120.
    request(&mut channel, read(5, 0, 2)).await;
    let model = next_packet(&mut channel).await;
    assert_eq!((model.id, model.params.as_slice()), (5, &[0x00, 0x60, 0x04][..]));

    let velocity = 1234u32.to_le_bytes();
    request(&mut channel, encode_instruction(5, opcode::WRITE, &[&PROFILE_VELOCITY.to_le_bytes()[..], &velocity].concat())).await;
    let written = next_packet(&mut channel).await;
    assert_eq!((written.id, written.params.as_slice()), (5, &[0x00][..]));
    request(&mut channel, read(5, PROFILE_VELOCITY, 4)).await;
    let back = next_packet(&mut channel).await;
    assert_eq!(back.params, [&[0x00][..], &velocity].concat());
}

#[tokio::test]
async fn multi_frame_sync_write_then_sync_read_with_one_message_per_reply() {
    let mut channel = controller(bus_on_pipe(Timing::Off));
    // Sync Write Profile Velocity = 10 × ID to all eight: a 54-byte packet, 8 CAN frames.
    let mut params = [PROFILE_VELOCITY.to_le_bytes(), 4u16.to_le_bytes()].concat();
    for id in IDS {
        params.push(id);
        params.extend_from_slice(&(10 * u32::from(id)).to_le_bytes());
    }
    let sync_write = encode_instruction(0xFE, opcode::SYNC_WRITE, &params);
    assert!(sync_write.len() > 4 * isotp::SINGLE_FRAME_MAX, "several consecutive frames");
    request(&mut channel, sync_write).await;

    let mut params = [PROFILE_VELOCITY.to_le_bytes(), 4u16.to_le_bytes()].concat();
    params.extend_from_slice(&IDS);
    request(&mut channel, encode_instruction(0xFE, opcode::SYNC_READ, &params)).await;
    for id in IDS {
        let reply = next_packet(&mut channel).await;
        assert_eq!(reply.id, id, "replies in ID order, each its own message");
        assert_eq!(reply.params, [&[0x00][..], &(10 * u32::from(id)).to_le_bytes()].concat());
    }
}

#[tokio::test]
async fn malformed_frames_then_a_good_request_is_answered() {
    let mut port = bus_on_pipe(Timing::Off);
    let request_id = CanId::Standard(0x7E0);
    // A consecutive frame out of nowhere, an unknown PCI, an empty frame, a frame for another
    // ID, a single frame claiming more bytes than it has.
    send_frame(&mut port, request_id, &[0x21, 1, 2, 3, 4, 5, 6, 7]).await;
    send_frame(&mut port, request_id, &[0x70, 1, 2]).await;
    send_frame(&mut port, request_id, &[]).await;
    send_frame(&mut port, CanId::Standard(0x123), &[0x03, 1, 2, 3]).await;
    send_frame(&mut port, request_id, &[0x07, 1, 2]).await;
    // A first frame (answered with CTS) followed by a consecutive frame with the wrong number.
    send_frame(&mut port, request_id, &[0x10, 20, 0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x0D]).await;
    let cts = recv_frame(&mut port).await;
    assert_eq!(cts.data.as_slice()[0], 0x30);
    send_frame(&mut port, request_id, &[0x23, 0, 0, 0, 0, 0, 0, 0]).await;
    // Another first frame left hanging, interrupted by a single frame that is not Dynamixel.
    send_frame(&mut port, request_id, &[0x10, 30, 1, 2, 3, 4, 5, 6]).await;
    let cts = recv_frame(&mut port).await;
    assert_eq!(cts.data.as_slice()[0], 0x30);
    send_frame(&mut port, request_id, &[0x03, 0xFF, 0xFF, 0xFD]).await;

    // The bus still answers, and only this request: the first reply is the ping's.
    let mut channel = controller(port);
    request(&mut channel, encode_instruction(2, opcode::PING, &[])).await;
    let pong = next_packet(&mut channel).await;
    assert_eq!((pong.id, pong.instruction), (2, opcode::STATUS));
    request(&mut channel, read(7, 0, 2)).await;
    let model = next_packet(&mut channel).await;
    assert_eq!((model.id, model.params.as_slice()), (7, &[0x00, 0x60, 0x04][..]));
}

#[tokio::test]
async fn wire_timing_and_unpadded_extended_ids() {
    // Another ID pair (29-bit) and no padding, with the wire model on.
    let ids = CanIds::parse("0x18DA01F1,0x18DAF101").expect("ids");
    assert_eq!(ids.request, CanId::Extended(0x18DA_01F1));
    let config = isotp::Config { padding: None, ..isotp::Config::default() };
    let (controller_port, bus) = frame_pipe(256);
    tokio::spawn(serve_can(bus, ids, config.clone(), handle(Timing::Wire)));
    let mut channel = IsoTpChannel::controller_side(controller_port, ids, config);
    request(&mut channel, encode_instruction(0xFE, opcode::PING, &[])).await;
    for id in IDS {
        assert_eq!(next_packet(&mut channel).await.id, id);
    }
}

#[tokio::test]
async fn the_session_ends_when_the_frame_pipe_closes() {
    let (controller_port, bus) = frame_pipe(16);
    let session = tokio::spawn(serve_can(bus, CanIds::default(), isotp::Config::default(), handle(Timing::Off)));
    drop(controller_port);
    let result = tokio::time::timeout(WITHIN, session).await.expect("session ends in time").expect("no panic");
    assert!(result.is_ok(), "{result:?}");
}

#[test]
fn can_id_pairs_parse_and_reject() {
    assert_eq!(CanIds::parse("0x7E0,0x7E8").unwrap(), CanIds::default());
    assert_eq!(CanIds::parse("2016, 2024").unwrap(), CanIds::default());
    assert_eq!(CanIds::parse("0x800,0x7FF").unwrap().request, CanId::Extended(0x800));
    for bad in ["0x7E0", "0x7E0,0x7E0", "0x7E0,0x20000000", "x,0x7E8"] {
        assert!(CanIds::parse(bad).is_err(), "{bad}");
    }
}

/// The real thing: `climbsim serve --can` on a SocketCAN interface, a controller on a raw socket
/// of the library's. 29-bit IDs so that the default pair of anything else on the bus is left
/// alone.
#[cfg(all(feature = "can", target_os = "linux"))]
#[test]
#[ignore = "needs vcan0: sudo hil/vcan-setup.sh, then CLIMBSIM_VCAN=vcan0 ./scripts/test.sh"]
fn serve_can_on_vcan() {
    use climbsim::transport::can::SocketCanPort;

    let iface = std::env::var("CLIMBSIM_VCAN").unwrap_or_else(|_| "vcan0".into());
    let sys = std::path::Path::new("/sys/class/net").join(&iface);
    assert!(sys.exists(), "no network interface {iface} here: create it with sudo hil/vcan-setup.sh");
    let ids_arg = "0x18DA01F1,0x18DAF101";
    let ids = CanIds::parse(ids_arg).expect("ids");
    let emulator = support::Emulator::start(&["--can", &iface, "--can-ids", ids_arg, "--timing", "off"]);
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
    runtime.block_on(async {
        let port = SocketCanPort::open(&iface, ids.response).unwrap_or_else(|e| panic!("{e} (sudo hil/vcan-setup.sh)"));
        let mut channel = IsoTpChannel::controller_side(port, ids, isotp::Config::default());
        request(&mut channel, encode_instruction(4, opcode::PING, &[])).await;
        assert_eq!(next_packet(&mut channel).await.id, 4);
        let mut params = [PROFILE_VELOCITY.to_le_bytes(), 4u16.to_le_bytes()].concat();
        params.extend_from_slice(&IDS);
        request(&mut channel, encode_instruction(0xFE, opcode::SYNC_READ, &params)).await;
        for id in IDS {
            assert_eq!(next_packet(&mut channel).await.id, id);
        }
    });
    emulator.finish();
}
