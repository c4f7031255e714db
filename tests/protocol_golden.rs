//! Golden byte vectors from `/work/shared/reference/dynamixel-protocol-2.md` (§2, §3, §5, §6,
//! §10), checked against the codec and, where the reply is determined, against the whole bus
//! (eight XM540-W270-R at factory defaults, firmware 48, model 1120, `Timing::Off`).
//!
//! Byte strings are written exactly as the reference prints them, CRC low byte first.

use std::time::Duration;

use climbsim::bus::{Bus, Timing, Transaction};
use climbsim::protocol::{BulkReadEntry, Decoder, FastReplyBuilder, FrameError, Instruction, RawPacket, crc16, encode_instruction, encode_status, opcode, stuff, unstuff};
use climbsim::robot::RobotDescription;

// ---------------------------------------------------------------------------------------------
// Reference byte strings
// ---------------------------------------------------------------------------------------------

/// §3 worked stuffing example: Read reply from ID 1 carrying `FF FF FD 00`.
const STUFFED_READ_REPLY: &str = "FF FF FD 00 01 09 00 55 00 FF FF FD FD 00 D8 9C";
/// §3: what the Python SDK sends for "write 0x00FDFFFF to 116 on ID 1" (unstuffed, LEN 9).
const PYTHON_SDK_UNSTUFFED_WRITE: &str = "FF FF FD 00 01 09 00 03 74 00 FF FF FD 00 C9 07";

/// §5, the three computed error replies.
const ACCESS_ERROR_REPLY: &str = "FF FF FD 00 01 04 00 55 07 B0 8C";
const ALERT_ONLY_REPLY: &str = "FF FF FD 00 01 04 00 55 80 A2 8F";
const NO_ERROR_REPLY: &str = "FF FF FD 00 01 04 00 55 00 A1 0C";

/// §6, Fast Sync Read example (IDs 3, 7, 4 each read 4 bytes at 132).
const FAST_SYNC_READ: &str = "FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2";
const FAST_SYNC_READ_REPLY: &str = "FF FF FD 00 FE 19 00 55  00 03 A6 00 00 00 84 08  00 07 1F 08 00 00 16 CA  00 04 FF 03 00 00 D1 9E";

/// §10 worked examples.
const PING_1: &str = "FF FF FD 00 01 03 00 01 19 4E";
const PING_1_REPLY: &str = "FF FF FD 00 01 07 00 55 00 60 04 30 EA DA";
const BROADCAST_PING: &str = "FF FF FD 00 FE 03 00 01 31 42";
const READ_PRESENT_POSITION_1: &str = "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15";
const READ_REPLY_166: &str = "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0";
const WRITE_TORQUE_ENABLE_1: &str = "FF FF FD 00 01 06 00 03 40 00 01 DB 66";
const WRITE_GOAL_POSITION_512: &str = "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89";
const SYNC_READ_132_4_IDS_1_2: &str = "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA";
const CLEAR_MULTI_TURN_1: &str = "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC";
const BACKUP_STORE_1: &str = "FF FF FD 00 01 08 00 20 01 43 54 52 4C 16 F5";

/// §2, the two corrected CRCs: Control Table Backup "restore" (S1 prints `92 F5`) and Fast Bulk
/// Read (S1 prints `20 F2`). The Fast Bulk Read instruction is the S1 example: ID 3 reads
/// 132/4, ID 7 reads 124/2, ID 4 reads 146/1.
const BACKUP_RESTORE_1: &str = "FF FF FD 00 01 08 00 20 02 43 54 52 4C 9E F5";
const BACKUP_RESTORE_1_AS_PRINTED: &str = "FF FF FD 00 01 08 00 20 02 43 54 52 4C 92 F5";
const FAST_BULK_READ: &str = "FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 DA 2D";
const FAST_BULK_READ_AS_PRINTED: &str = "FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 20 F2";
/// S1's Fast Bulk Read reply for the instruction above (reference §6: "verified against both S1
/// examples; every intermediate CRC matches").
const FAST_BULK_READ_REPLY: &str = "FF FF FD 00 FE 14 00 55  00 03 A6 00 00 00 67 A4  00 07 A5 01 24 74  00 04 1F D9 C1";

const XM540_PING_PARAMS: [u8; 3] = [0x60, 0x04, 0x30]; // model 1120 LE, firmware 48

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap_or_else(|_| panic!("bad hex byte {b:?}"))).collect()
}

fn show(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(" ")
}

#[track_caller]
fn assert_bytes(got: &[u8], expected: &[u8]) {
    assert_eq!(got, expected, "\n     got: {}\nexpected: {}", show(got), show(expected));
}

/// Decode `bytes` pushed in one go: exactly one packet, no framing error, nothing left over.
#[track_caller]
fn decode_one(bytes: &[u8]) -> RawPacket {
    let mut decoder = Decoder::default();
    let results = decoder.push(Duration::ZERO, bytes);
    assert_eq!(decoder.pending(), 0, "decoder kept bytes of {}", show(bytes));
    match results.as_slice() {
        [Ok(packet)] => {
            assert_eq!(packet.wire_len, bytes.len());
            assert_eq!(packet.bytes, bytes);
            packet.clone()
        }
        other => panic!("expected exactly one packet from {}, got {other:?}", show(bytes)),
    }
}

/// LEN field of a packet.
fn len_field(bytes: &[u8]) -> usize {
    usize::from(u16::from_le_bytes([bytes[5], bytes[6]]))
}

/// The trailing two bytes are the CRC-16 of everything before them, low byte first.
#[track_caller]
fn assert_crc_trailer(bytes: &[u8]) {
    let n = bytes.len();
    let computed = crc16(&bytes[..n - 2]);
    assert_eq!(u16::from_le_bytes([bytes[n - 2], bytes[n - 1]]), computed, "CRC of {}: computed {computed:04X}", show(bytes));
}

/// A plain (unstuffed) status packet from `id` with `error` and `data_len` data bytes: checks every
/// framing field and the CRC, returns the data.
#[track_caller]
fn assert_status_frame(bytes: &[u8], id: u8, error: u8, data_len: usize) -> Vec<u8> {
    assert_eq!(&bytes[..5], [0xFF, 0xFF, 0xFD, 0x00, id], "header/ID of {}", show(bytes));
    assert_eq!(len_field(bytes), data_len + 4, "LEN of {}", show(bytes));
    assert_eq!(bytes.len(), data_len + 11, "wire length of {}", show(bytes));
    assert_eq!(bytes[7], opcode::STATUS, "instruction of {}", show(bytes));
    assert_eq!(bytes[8], error, "error byte of {}", show(bytes));
    assert_crc_trailer(bytes);
    let packet = decode_one(bytes);
    assert_eq!((packet.id, packet.instruction), (id, opcode::STATUS));
    assert_eq!(packet.params[0], error);
    packet.params[1..].to_vec()
}

/// A Fast Sync/Bulk Read reply (§6): ID 0xFE, LEN = 1 + Σ(len+4), blocks `ERR ID data CRC` in
/// the listed order, each CRC the running CRC-16 of everything before it. Returns (error, data)
/// per block.
#[track_caller]
fn assert_fast_reply(bytes: &[u8], blocks: &[(u8, usize)]) -> Vec<(u8, Vec<u8>)> {
    let len = 1 + blocks.iter().map(|&(_, n)| n + 4).sum::<usize>();
    assert_eq!(&bytes[..5], [0xFF, 0xFF, 0xFD, 0x00, 0xFE], "header/ID of {}", show(bytes));
    assert_eq!(len_field(bytes), len, "LEN of {}", show(bytes));
    assert_eq!(bytes.len(), len + 7, "wire length of {}", show(bytes));
    assert_eq!(bytes[7], opcode::STATUS);
    let mut out = Vec::new();
    let mut at = 8;
    for (k, &(id, n)) in blocks.iter().enumerate() {
        let error = bytes[at];
        assert_eq!(bytes[at + 1], id, "block {k} ID in {}", show(bytes));
        let data_end = at + 2 + n;
        let running = crc16(&bytes[..data_end]);
        let sent = u16::from_le_bytes([bytes[data_end], bytes[data_end + 1]]);
        assert_eq!(sent, running, "running CRC of block {k} (ID {id}) in {}", show(bytes));
        out.push((error, bytes[at + 2..data_end].to_vec()));
        at = data_end + 2;
    }
    assert_eq!(at, bytes.len());
    // The decoder frames it like any other packet (never stuffed, so nothing to unstuff here).
    let packet = decode_one(bytes);
    assert_eq!((packet.id, packet.instruction), (0xFE, opcode::STATUS));
    out
}

/// The bus and a clock.
struct Sim {
    bus: Bus,
    now: Duration,
}

impl Sim {
    fn new() -> Self {
        let robot = RobotDescription::load(&RobotDescription::default_path()).unwrap();
        Self { bus: robot.bench_bus(Timing::Off, None).unwrap(), now: Duration::from_millis(1) }
    }

    /// Decode `wire` (it must be exactly one packet) and hand it to the bus 1 ms after the last one.
    fn transact(&mut self, wire: &[u8]) -> Transaction {
        self.now += Duration::from_millis(1);
        let packet = decode_one(wire);
        self.bus.handle(packet, self.now, None)
    }

    /// Reply bytes, in bus order.
    fn send(&mut self, wire: &[u8]) -> Vec<Vec<u8>> {
        self.transact(wire).replies.into_iter().map(|r| r.bytes).collect()
    }

    /// The single reply to `wire`.
    #[track_caller]
    fn send_one(&mut self, wire: &[u8]) -> Vec<u8> {
        let replies = self.send(wire);
        assert_eq!(replies.len(), 1, "expected one reply to {}, got {:?}", show(wire), replies.iter().map(|r| show(r)).collect::<Vec<_>>());
        replies.into_iter().next().unwrap()
    }

    fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Vec<u8> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(data);
        self.send_one(&encode_instruction(id, opcode::WRITE, &params))
    }

    fn read(&mut self, id: u8, address: u16, length: u16) -> Vec<u8> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(&length.to_le_bytes());
        self.send_one(&encode_instruction(id, opcode::READ, &params))
    }

    fn advance(&mut self, by: Duration) {
        self.now += by;
        self.bus.advance(self.now);
    }
}

// ---------------------------------------------------------------------------------------------
// §2 CRC-16
// ---------------------------------------------------------------------------------------------

#[test]
fn crc16_check_value_of_123456789_is_fee8() {
    assert_eq!(crc16(b"123456789"), 0xFEE8);
}

#[test]
fn crc16_matches_the_trailer_of_every_reference_packet() {
    for packet in [
        STUFFED_READ_REPLY,
        PYTHON_SDK_UNSTUFFED_WRITE,
        ACCESS_ERROR_REPLY,
        ALERT_ONLY_REPLY,
        NO_ERROR_REPLY,
        FAST_SYNC_READ,
        FAST_SYNC_READ_REPLY,
        PING_1,
        PING_1_REPLY,
        BROADCAST_PING,
        READ_PRESENT_POSITION_1,
        READ_REPLY_166,
        WRITE_TORQUE_ENABLE_1,
        WRITE_GOAL_POSITION_512,
        SYNC_READ_132_4_IDS_1_2,
        CLEAR_MULTI_TURN_1,
        BACKUP_STORE_1,
        BACKUP_RESTORE_1,
        FAST_BULK_READ,
        FAST_BULK_READ_REPLY,
    ] {
        let bytes = hex(packet);
        assert_crc_trailer(&bytes);
        assert_eq!(len_field(&bytes) + 7, bytes.len(), "LEN of {packet}");
    }
}

#[test]
fn backup_restore_instruction_has_corrected_crc_9e_f5() {
    let params = [0x02, 0x43, 0x54, 0x52, 0x4C];
    assert_bytes(&encode_instruction(1, opcode::CONTROL_TABLE_BACKUP, &params), &hex(BACKUP_RESTORE_1));
    let packet = decode_one(&hex(BACKUP_RESTORE_1));
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::ControlTableBackup { params: params.to_vec() }));
}

#[test]
fn backup_restore_as_printed_in_emanual_fails_crc() {
    let results = Decoder::default().push(Duration::ZERO, &hex(BACKUP_RESTORE_1_AS_PRINTED));
    assert!(results.iter().all(Result::is_err), "{results:?}");
    assert!(results.iter().any(|r| matches!(r, Err(FrameError::BadCrc { id: 1, received: 0xF592, computed: 0xF59E }))), "{results:?}");
}

#[test]
fn fast_bulk_read_instruction_has_corrected_crc_da_2d() {
    let instruction = Instruction::FastBulkRead {
        entries: vec![BulkReadEntry { id: 3, address: 132, length: 4 }, BulkReadEntry { id: 7, address: 124, length: 2 }, BulkReadEntry { id: 4, address: 146, length: 1 }],
    };
    assert_bytes(&encode_instruction(0xFE, instruction.code(), &instruction.params()), &hex(FAST_BULK_READ));
    let packet = decode_one(&hex(FAST_BULK_READ));
    assert_eq!((packet.id, packet.instruction), (0xFE, opcode::FAST_BULK_READ));
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(instruction));
}

#[test]
fn fast_bulk_read_as_printed_in_emanual_fails_crc() {
    let results = Decoder::default().push(Duration::ZERO, &hex(FAST_BULK_READ_AS_PRINTED));
    assert!(results.iter().all(Result::is_err), "{results:?}");
    assert!(results.iter().any(|r| matches!(r, Err(FrameError::BadCrc { id: 0xFE, received: 0xF220, computed: 0x2DDA }))), "{results:?}");
}

// ---------------------------------------------------------------------------------------------
// §3 Byte stuffing
// ---------------------------------------------------------------------------------------------

#[test]
fn stuffing_example_read_reply_carrying_ff_ff_fd_00_is_stuffed_with_len_9() {
    let expected = hex(STUFFED_READ_REPLY);
    assert_bytes(&encode_status(1, 0, &[0xFF, 0xFF, 0xFD, 0x00]), &expected);
    assert_eq!(len_field(&expected), 9);
    // Body from the error byte through the last parameter, before and after stuffing.
    assert_eq!(stuff(&[0x00, 0xFF, 0xFF, 0xFD, 0x00]), [0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00]);
    assert_eq!(unstuff(&[0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00]), [0x00, 0xFF, 0xFF, 0xFD, 0x00]);
}

#[test]
fn stuffing_example_decodes_to_data_ff_ff_fd_00() {
    let bytes = hex(STUFFED_READ_REPLY);
    let packet = decode_one(&bytes);
    assert_eq!((packet.id, packet.instruction, packet.wire_len), (1, opcode::STATUS, 16));
    assert_eq!(packet.params, [0x00, 0xFF, 0xFF, 0xFD, 0x00]);
    // Fed one byte at a time, the stuffed FF FF FD FD inside is never taken for a header.
    let mut decoder = Decoder::default();
    let got: Vec<_> = bytes.iter().flat_map(|&b| decoder.push(Duration::ZERO, &[b])).collect();
    assert_eq!(got, vec![Ok(packet)]);
}

#[test]
fn python_sdk_unstuffed_write_decodes_by_len() {
    let bytes = hex(PYTHON_SDK_UNSTUFFED_WRITE);
    let packet = decode_one(&bytes);
    assert_eq!((packet.id, packet.instruction, packet.wire_len), (1, opcode::WRITE, 16));
    assert_eq!(packet.params, [0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00]);
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::Write { address: 116, data: vec![0xFF, 0xFF, 0xFD, 0x00] }));
}

#[test]
fn python_sdk_unstuffed_write_byte_by_byte_and_followed_by_a_ping_gives_both_packets() {
    // Never resynchronise on the FF FF FD inside a packet whose CRC is not checked yet.
    let mut stream = hex(PYTHON_SDK_UNSTUFFED_WRITE);
    stream.extend(hex(PING_1));
    let mut decoder = Decoder::default();
    let results: Vec<_> = stream.iter().flat_map(|&b| decoder.push(Duration::ZERO, &[b])).collect();
    let packets: Vec<_> = results.iter().map(|r| r.clone().expect("no framing error")).collect();
    assert_eq!(packets.len(), 2, "{results:?}");
    assert_eq!((packets[0].instruction, packets[0].wire_len), (opcode::WRITE, 16));
    assert_eq!((packets[1].instruction, packets[1].wire_len), (opcode::PING, 10));
}

#[test]
fn stuffing_scan_covers_the_instruction_byte() {
    // §3 sender side: scan "from the Instruction byte up to the last parameter". With instruction
    // byte 0xFF and parameters starting FF FD, the FF FF FD begins at the instruction byte and must
    // be stuffed; the receiver side then turns FF FF FD FD back into FF FF FD.
    let wire = encode_instruction(1, 0xFF, &[0xFF, 0xFD, 0x00]);
    let mut expected = hex("FF FF FD 00 01 07 00 FF FF FD FD 00");
    let crc = crc16(&expected);
    expected.extend_from_slice(&crc.to_le_bytes());
    let decoded = decode_one(&expected);
    let encoder_ok = wire == expected;
    let decoder_ok = (decoded.instruction, decoded.params.as_slice()) == (0xFF, &[0xFF, 0xFD, 0x00][..]);
    assert!(encoder_ok && decoder_ok, "encoder: got {} expected {}; decoder: params of {} are {} (expected FF FD 00)", show(&wire), show(&expected), show(&expected), show(&decoded.params));
}

#[test]
fn write_with_ff_ff_fd_in_data_is_stuffed_and_read_reply_is_stuffed() {
    let mut sim = Sim::new();
    // Extended position mode (4) so that Goal Position may be -131073 = FF FF FD FF.
    assert_bytes(&sim.write(1, 11, &[4]), &hex(NO_ERROR_REPLY));
    let goal = (-131073i32).to_le_bytes();
    assert_eq!(goal, [0xFF, 0xFF, 0xFD, 0xFF]);

    let write = encode_instruction(1, opcode::WRITE, &[0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFF]);
    let mut expected = hex("FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD FF");
    let crc = crc16(&expected);
    expected.extend_from_slice(&crc.to_le_bytes());
    assert_bytes(&write, &expected);
    assert_eq!(decode_one(&write).params, [0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFF]);
    assert_bytes(&sim.send_one(&write), &hex(NO_ERROR_REPLY));

    // LEN 9 = instruction + error + 4 data + 1 stuffed FD + CRC; CRC over the stuffed bytes.
    let reply = sim.read(1, 116, 4);
    let mut expected = hex("FF FF FD 00 01 09 00 55 00 FF FF FD FD FF");
    let crc = crc16(&expected);
    expected.extend_from_slice(&crc.to_le_bytes());
    assert_bytes(&reply, &expected);
    assert_bytes(&reply[reply.len() - 2..], &[0xDA, 0x9E]);
    let packet = decode_one(&reply);
    assert_eq!(packet.params, [0x00, 0xFF, 0xFF, 0xFD, 0xFF]);
    assert_eq!(i32::from_le_bytes(packet.params[1..].try_into().unwrap()), -131073);
}

// ---------------------------------------------------------------------------------------------
// §5 Status packet error byte
// ---------------------------------------------------------------------------------------------

#[test]
fn access_error_no_error_and_alert_only_replies_match_encode_status() {
    assert_bytes(&encode_status(1, 0x07, &[]), &hex(ACCESS_ERROR_REPLY));
    assert_bytes(&encode_status(1, 0x80, &[]), &hex(ALERT_ONLY_REPLY));
    assert_bytes(&encode_status(1, 0x00, &[]), &hex(NO_ERROR_REPLY));
    for (bytes, error) in [(ACCESS_ERROR_REPLY, 0x07), (ALERT_ONLY_REPLY, 0x80), (NO_ERROR_REPLY, 0x00)] {
        assert_status_frame(&hex(bytes), 1, error, 0);
    }
}

#[test]
fn access_error_reply_from_bus_on_write_to_read_only_address() {
    let mut sim = Sim::new();
    // Present Position (132, 4 bytes, R) and Model Number (0, 2 bytes, R).
    assert_bytes(&sim.write(1, 132, &[0, 0, 0, 0]), &hex(ACCESS_ERROR_REPLY));
    assert_bytes(&sim.write(1, 0, &[0x60, 0x04]), &hex(ACCESS_ERROR_REPLY));
}

#[test]
fn access_error_reply_from_bus_on_read_of_undefined_address_has_no_params() {
    let mut sim = Sim::new();
    // 40..43 is reserved on current firmware (§11.2); 1000 is past the control table.
    assert_bytes(&sim.read(1, 40, 4), &hex(ACCESS_ERROR_REPLY));
    assert_bytes(&sim.read(1, 1000, 4), &hex(ACCESS_ERROR_REPLY));
}

#[test]
fn access_error_reply_from_bus_on_eeprom_write_with_torque_on() {
    let mut sim = Sim::new();
    assert_bytes(&sim.send_one(&hex(WRITE_TORQUE_ENABLE_1)), &hex(NO_ERROR_REPLY));
    assert_bytes(&sim.write(1, 11, &[1]), &hex(ACCESS_ERROR_REPLY)); // Operating Mode is EEPROM
}

#[test]
fn read_longer_than_a_packet_can_carry_gets_the_access_error_reply() {
    // A Read of 0xFFFF bytes from 0 runs far past the control table (S1: "outside the range of
    // the Control Table" -> Access Error with no parameters). Whatever the answer, it must be a
    // well-formed packet: a status packet carrying 65535 bytes would need LEN 65539.
    let mut sim = Sim::new();
    let reply = sim.read(1, 0, 0xFFFF);
    assert!(reply.len() < 64, "reply of {} bytes, LEN field {} (starts {})", reply.len(), len_field(&reply), show(&reply[..16]));
    assert_bytes(&reply, &hex(ACCESS_ERROR_REPLY));
}

#[test]
fn no_error_reply_from_bus_on_valid_write() {
    let mut sim = Sim::new();
    assert_bytes(&sim.write(1, 65, &[1]), &hex(NO_ERROR_REPLY)); // LED on
}

#[test]
fn alert_only_reply_after_overheating_shutdown() {
    let mut sim = Sim::new();
    // Temperature Limit 20 degC, below the 25 degC ambient: the servo overheats as soon as it looks.
    assert_bytes(&sim.write(1, 31, &[20]), &hex(NO_ERROR_REPLY));
    sim.advance(Duration::from_millis(50));

    // A plain write now gets only the alert bit.
    assert_bytes(&sim.write(1, 65, &[1]), &hex(ALERT_ONLY_REPLY));

    // Hardware Error Status (70) has the overheating bit (bit 2); the reply carries the alert.
    let status = assert_status_frame(&sim.read(1, 70, 1), 1, 0x80, 1);
    assert_eq!(status[0] & 0x04, 0x04, "Hardware Error Status {:#04X}", status[0]);

    // Ping too carries the alert; another servo is unaffected.
    assert_bytes(&sim.send_one(&hex(PING_1)), &encode_status(1, 0x80, &XM540_PING_PARAMS));
    assert_bytes(&sim.send_one(&encode_instruction(2, opcode::PING, &[])), &encode_status(2, 0x00, &XM540_PING_PARAMS));
}

// ---------------------------------------------------------------------------------------------
// §6 Response rules
// ---------------------------------------------------------------------------------------------

#[test]
fn fast_sync_read_instruction_from_emanual_encodes_and_decodes() {
    let bytes = hex(FAST_SYNC_READ);
    assert_bytes(&encode_instruction(0xFE, opcode::FAST_SYNC_READ, &[0x84, 0x00, 0x04, 0x00, 0x03, 0x07, 0x04]), &bytes);
    let packet = decode_one(&bytes);
    assert_eq!((packet.id, packet.instruction), (0xFE, opcode::FAST_SYNC_READ));
    let instruction = Instruction::parse(packet.instruction, &packet.params).unwrap();
    assert_eq!(instruction, Instruction::FastSyncRead { address: 132, length: 4, ids: vec![3, 7, 4] });
    assert_eq!(instruction.params(), packet.params);
}

#[test]
fn fast_sync_read_reply_from_emanual_with_every_running_crc() {
    let expected = hex(FAST_SYNC_READ_REPLY);
    let mut builder = FastReplyBuilder::new([4, 4, 4]).expect("fits the LEN field");
    builder.push_block(0, 3, &166u32.to_le_bytes());
    builder.push_block(0, 7, &2079u32.to_le_bytes());
    builder.push_block(0, 4, &1023u32.to_le_bytes());
    assert_bytes(&builder.into_bytes(), &expected);

    // Each CRC_k is the CRC of everything before it, prior CRC pairs included.
    assert_eq!(crc16(&expected[..14]), 0x0884);
    assert_eq!(crc16(&expected[..22]), 0xCA16);
    assert_eq!(crc16(&expected[..30]), 0x9ED1);
    assert_eq!(len_field(&expected), 1 + 3 * (4 + 4));
    let blocks = assert_fast_reply(&expected, &[(3, 4), (7, 4), (4, 4)]);
    assert_eq!(blocks, vec![(0, vec![0xA6, 0, 0, 0]), (0, vec![0x1F, 0x08, 0, 0]), (0, vec![0xFF, 0x03, 0, 0])]);
}

#[test]
fn fast_bulk_read_reply_from_emanual_with_every_running_crc() {
    let expected = hex(FAST_BULK_READ_REPLY);
    let mut builder = FastReplyBuilder::new([4, 2, 1]).expect("fits the LEN field");
    builder.push_block(0, 3, &[0xA6, 0, 0, 0]);
    builder.push_block(0, 7, &[0xA5, 0x01]);
    builder.push_block(0, 4, &[0x1F]);
    assert_bytes(&builder.into_bytes(), &expected);
    assert_eq!(crc16(&expected[..14]), 0xA467);
    assert_eq!(crc16(&expected[..20]), 0x7424);
    assert_eq!(crc16(&expected[..25]), 0xC1D9);
    assert_fast_reply(&expected, &[(3, 4), (7, 2), (4, 1)]);
}

#[test]
fn broadcast_ping_gives_eight_replies_in_id_order() {
    let mut sim = Sim::new();
    let transaction = sim.transact(&hex(BROADCAST_PING));
    let from: Vec<_> = transaction.replies.iter().map(|r| r.from.clone()).collect();
    assert_eq!(from, (1..=8u8).map(|id| vec![id]).collect::<Vec<_>>());
    for (reply, id) in transaction.replies.iter().zip(1..=8u8) {
        assert_bytes(&reply.bytes, &encode_status(id, 0, &XM540_PING_PARAMS));
        assert_eq!(assert_status_frame(&reply.bytes, id, 0, 3), XM540_PING_PARAMS);
    }
    assert_bytes(&transaction.replies[0].bytes, &hex(PING_1_REPLY));
}

#[test]
fn sync_read_replies_come_in_listed_order_3_1_2() {
    let mut sim = Sim::new();
    // Read the ID item itself (7, 1 byte), so every reply also names its sender in its data.
    let replies = sim.send(&encode_instruction(0xFE, opcode::SYNC_READ, &[7, 0, 1, 0, 3, 1, 2]));
    assert_eq!(replies, vec![encode_status(3, 0, &[3]), encode_status(1, 0, &[1]), encode_status(2, 0, &[2])]);

    let transaction = sim.transact(&encode_instruction(0xFE, opcode::SYNC_READ, &[0x84, 0, 4, 0, 3, 1, 2]));
    let order: Vec<_> = transaction.replies.iter().map(|r| r.bytes[4]).collect();
    assert_eq!(order, [3, 1, 2]);
    for reply in &transaction.replies {
        assert_status_frame(&reply.bytes, reply.bytes[4], 0, 4);
        assert_eq!(reply.from, [reply.bytes[4]]);
    }
}

#[test]
fn bulk_read_replies_come_in_listed_order() {
    let mut sim = Sim::new();
    let instruction =
        Instruction::BulkRead { entries: vec![BulkReadEntry { id: 5, address: 7, length: 1 }, BulkReadEntry { id: 2, address: 0, length: 2 }, BulkReadEntry { id: 8, address: 6, length: 2 }] };
    let replies = sim.send(&encode_instruction(0xFE, instruction.code(), &instruction.params()));
    assert_eq!(replies, vec![encode_status(5, 0, &[5]), encode_status(2, 0, &[0x60, 0x04]), encode_status(8, 0, &[0x30, 8])]);
}

#[test]
fn fast_sync_read_reply_through_bus_for_ids_3_7_4() {
    let mut sim = Sim::new();
    assert_error_free_fast_transaction(&mut sim, FAST_SYNC_READ, 0x19, &[(3, 4), (7, 4), (4, 4)]);

    // Same with data that names each block's sender: ID item (7), 1 byte.
    let replies = sim.send(&encode_instruction(0xFE, opcode::FAST_SYNC_READ, &[7, 0, 1, 0, 3, 7, 4]));
    assert_eq!(replies.len(), 1);
    let blocks = assert_fast_reply(&replies[0], &[(3, 1), (7, 1), (4, 1)]);
    assert_eq!(blocks, vec![(0, vec![3]), (0, vec![7]), (0, vec![4])]);
}

#[test]
fn fast_bulk_read_reply_through_bus_for_corrected_emanual_instruction() {
    let mut sim = Sim::new();
    assert_error_free_fast_transaction(&mut sim, FAST_BULK_READ, 0x14, &[(3, 4), (7, 2), (4, 1)]);
}

/// One combined reply from the listed servos, with the given LEN, blocks in order, no errors.
fn assert_error_free_fast_transaction(sim: &mut Sim, instruction: &str, len: usize, expected: &[(u8, usize)]) {
    let transaction = sim.transact(&hex(instruction));
    assert_eq!(transaction.replies.len(), 1);
    let reply = &transaction.replies[0];
    let ids: Vec<u8> = expected.iter().map(|(id, _)| *id).collect();
    assert_eq!(reply.from, ids);
    assert_eq!(len_field(&reply.bytes), len);
    let blocks = assert_fast_reply(&reply.bytes, expected);
    assert!(blocks.iter().all(|(error, _)| *error == 0), "{blocks:?}");
}

#[test]
fn fast_sync_read_reply_too_long_for_len_is_still_well_formed() {
    // IDs 1..=5 each read 0x332F bytes from 0: LEN would be 1 + 5 * (0x332F + 4) = 65536, one more
    // than the 16-bit field holds. The spec gives no answer for this; whatever the bus sends (or
    // not) must at least be a packet whose LEN field matches its length.
    let mut sim = Sim::new();
    let replies = sim.send(&encode_instruction(0xFE, opcode::FAST_SYNC_READ, &[0, 0, 0x2F, 0x33, 1, 2, 3, 4, 5]));
    for reply in &replies {
        assert_eq!(len_field(reply) + 7, reply.len(), "LEN field {} for a reply of {} bytes (starts {})", len_field(reply), reply.len(), show(&reply[..16]));
    }
}

#[test]
fn fast_sync_read_reply_is_never_stuffed() {
    let mut sim = Sim::new();
    // Goal Position FF FF FD FF on IDs 1 and 2 (extended position mode).
    for id in [1, 2] {
        assert_bytes(&sim.write(id, 11, &[4]), &encode_status(id, 0, &[]));
        assert_bytes(&sim.write(id, 116, &(-131073i32).to_le_bytes()), &encode_status(id, 0, &[]));
    }
    let replies = sim.send(&encode_instruction(0xFE, opcode::FAST_SYNC_READ, &[0x74, 0, 4, 0, 1, 2]));
    assert_eq!(replies.len(), 1);
    let blocks = assert_fast_reply(&replies[0], &[(1, 4), (2, 4)]);
    assert_eq!(blocks, vec![(0, vec![0xFF, 0xFF, 0xFD, 0xFF]), (0, vec![0xFF, 0xFF, 0xFD, 0xFF])]);
}

// ---------------------------------------------------------------------------------------------
// §10 Worked examples, row by row
// ---------------------------------------------------------------------------------------------

/// Every §10 instruction row is reproduced by encoding its own decoded fields.
#[test]
fn every_worked_example_instruction_re_encodes_byte_for_byte() {
    for row in [
        PING_1,
        BROADCAST_PING,
        READ_PRESENT_POSITION_1,
        WRITE_TORQUE_ENABLE_1,
        WRITE_GOAL_POSITION_512,
        SYNC_READ_132_4_IDS_1_2,
        CLEAR_MULTI_TURN_1,
        BACKUP_STORE_1,
        BACKUP_RESTORE_1,
        FAST_SYNC_READ,
        FAST_BULK_READ,
    ] {
        let bytes = hex(row);
        let packet = decode_one(&bytes);
        let instruction = Instruction::parse(packet.instruction, &packet.params).unwrap();
        assert_eq!(instruction.code(), packet.instruction);
        assert_bytes(&encode_instruction(packet.id, instruction.code(), &instruction.params()), &bytes);
    }
}

#[test]
fn ping_id1_decodes_and_bus_replies_with_reference_ping_reply() {
    let packet = decode_one(&hex(PING_1));
    assert_eq!((packet.id, packet.instruction, packet.params.as_slice(), packet.wire_len), (1, opcode::PING, &[][..], 10));
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::Ping));
    let mut sim = Sim::new();
    assert_bytes(&sim.send_one(&hex(PING_1)), &hex(PING_1_REPLY));
}

#[test]
fn ping_reply_from_xm540_fw48_matches_encode_status_and_decodes() {
    let bytes = hex(PING_1_REPLY);
    assert_bytes(&encode_status(1, 0, &XM540_PING_PARAMS), &bytes);
    let data = assert_status_frame(&bytes, 1, 0, 3);
    assert_eq!(u16::from_le_bytes([data[0], data[1]]), 1120);
    assert_eq!(data[2], 48);
}

#[test]
fn broadcast_ping_decodes_to_id_fe() {
    let packet = decode_one(&hex(BROADCAST_PING));
    assert_eq!((packet.id, packet.instruction, packet.params.len()), (0xFE, opcode::PING, 0));
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::Ping));
}

#[test]
fn read_present_position_decodes_and_bus_reply_is_well_framed() {
    let packet = decode_one(&hex(READ_PRESENT_POSITION_1));
    assert_eq!((packet.id, packet.instruction), (1, opcode::READ));
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::Read { address: 132, length: 4 }));

    let mut sim = Sim::new();
    let reply = sim.send_one(&hex(READ_PRESENT_POSITION_1));
    // The value depends on the shaft; the framing does not: LEN 8, 4 data bytes, valid CRC.
    let data = assert_status_frame(&reply, 1, 0, 4);
    assert_bytes(&reply, &encode_status(1, 0, &data));
}

#[test]
fn read_reply_value_166_matches_encode_status() {
    let bytes = hex(READ_REPLY_166);
    assert_bytes(&encode_status(1, 0, &[0xA6, 0, 0, 0]), &bytes);
    let data = assert_status_frame(&bytes, 1, 0, 4);
    assert_eq!(i32::from_le_bytes(data.try_into().unwrap()), 166);
}

#[test]
fn write_torque_enable_decodes_and_bus_replies_no_error() {
    let packet = decode_one(&hex(WRITE_TORQUE_ENABLE_1));
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::Write { address: 64, data: vec![1] }));
    let mut sim = Sim::new();
    assert_bytes(&sim.send_one(&hex(WRITE_TORQUE_ENABLE_1)), &hex(NO_ERROR_REPLY));
    assert_bytes(&sim.read(1, 64, 1), &encode_status(1, 0, &[1]));
}

#[test]
fn write_goal_position_512_decodes_and_bus_replies_no_error() {
    let packet = decode_one(&hex(WRITE_GOAL_POSITION_512));
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::Write { address: 116, data: vec![0x00, 0x02, 0x00, 0x00] }));
    let mut sim = Sim::new();
    assert_bytes(&sim.send_one(&hex(WRITE_GOAL_POSITION_512)), &hex(NO_ERROR_REPLY));
    assert_bytes(&sim.read(1, 116, 4), &encode_status(1, 0, &512i32.to_le_bytes()));
}

#[test]
fn sync_read_of_132_4_from_ids_1_2_decodes_and_bus_replies_from_1_then_2() {
    let packet = decode_one(&hex(SYNC_READ_132_4_IDS_1_2));
    assert_eq!(packet.id, 0xFE);
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::SyncRead { address: 132, length: 4, ids: vec![1, 2] }));
    let mut sim = Sim::new();
    let transaction = sim.transact(&hex(SYNC_READ_132_4_IDS_1_2));
    assert_eq!(transaction.replies.len(), 2);
    for (reply, id) in transaction.replies.iter().zip([1u8, 2]) {
        assert_eq!(reply.from, [id]);
        let data = assert_status_frame(&reply.bytes, id, 0, 4);
        assert_bytes(&reply.bytes, &encode_status(id, 0, &data));
    }
}

#[test]
fn clear_multi_turn_decodes_and_bus_replies_no_error() {
    let packet = decode_one(&hex(CLEAR_MULTI_TURN_1));
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::Clear { params: vec![0x01, 0x44, 0x58, 0x4C, 0x22] }));
    let mut sim = Sim::new();
    assert_bytes(&sim.send_one(&hex(CLEAR_MULTI_TURN_1)), &hex(NO_ERROR_REPLY));
}

#[test]
fn control_table_backup_store_then_restore_decode_and_bus_replies_no_error() {
    let packet = decode_one(&hex(BACKUP_STORE_1));
    assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(Instruction::ControlTableBackup { params: vec![0x01, 0x43, 0x54, 0x52, 0x4C] }));
    let mut sim = Sim::new();
    assert_bytes(&sim.send_one(&hex(BACKUP_STORE_1)), &hex(NO_ERROR_REPLY));
    // Restore (corrected CRC) answers first, then reboots.
    assert_bytes(&sim.send_one(&hex(BACKUP_RESTORE_1)), &hex(NO_ERROR_REPLY));
    sim.advance(Duration::from_millis(500));
    assert_bytes(&sim.send_one(&hex(PING_1)), &hex(PING_1_REPLY));
}

#[test]
fn control_table_backup_with_torque_on_is_result_fail() {
    let mut sim = Sim::new();
    assert_bytes(&sim.send_one(&hex(WRITE_TORQUE_ENABLE_1)), &hex(NO_ERROR_REPLY));
    assert_bytes(&sim.send_one(&hex(BACKUP_STORE_1)), &encode_status(1, 0x01, &[]));
}
