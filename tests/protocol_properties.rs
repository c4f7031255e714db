//! Property tests for the Protocol 2.0 codec and the bus (reference §1-§6).
//!
//! Case counts are kept modest so that `cargo test --test protocol_properties` stays well under
//! 20 s in a debug build.

use std::sync::OnceLock;
use std::time::Duration;

use climbsim::bus::{Bus, Timing, Transaction};
use climbsim::protocol::{
    BulkReadEntry, BulkWriteEntry, DEFAULT_INTER_BYTE_TIMEOUT, Decoder, FrameError, Instruction, RawPacket, SyncWriteEntry, crc16, encode_instruction, encode_status, opcode, stuff, unstuff,
};
use climbsim::robot::RobotDescription;
use proptest::collection::vec;
use proptest::prelude::*;
use proptest::sample::subsequence;

const HEADER: [u8; 3] = [0xFF, 0xFF, 0xFD];

const KNOWN_OPCODES: [u8; 16] = [
    opcode::PING,
    opcode::READ,
    opcode::WRITE,
    opcode::REG_WRITE,
    opcode::ACTION,
    opcode::FACTORY_RESET,
    opcode::REBOOT,
    opcode::CLEAR,
    opcode::CONTROL_TABLE_BACKUP,
    opcode::STATUS,
    opcode::SYNC_READ,
    opcode::SYNC_WRITE,
    opcode::FAST_SYNC_READ,
    opcode::BULK_READ,
    opcode::BULK_WRITE,
    opcode::FAST_BULK_READ,
];

// ---------------------------------------------------------------------------------------------
// Strategies
// ---------------------------------------------------------------------------------------------

/// Bytes rich in header fragments and stuffing: random bytes mixed with FF FF FD, FF FF FD FD, FF
/// FF and FD runs.
fn tricky_bytes(max_len: usize) -> impl Strategy<Value = Vec<u8>> {
    let piece = prop_oneof![
        4 => vec(any::<u8>(), 0..8),
        2 => Just(HEADER.to_vec()),
        1 => Just(vec![0xFF, 0xFF, 0xFD, 0xFD]),
        1 => Just(vec![0xFF, 0xFF]),
        1 => Just(vec![0xFD]),
        1 => Just(vec![0xFF, 0xFF, 0xFD, 0x00]),
    ];
    vec(piece, 0..max_len / 2 + 1).prop_map(move |pieces| {
        let mut out: Vec<u8> = pieces.concat();
        out.truncate(max_len);
        out
    })
}

/// IDs usable in an instruction packet: 0..=252 and broadcast.
fn packet_id() -> impl Strategy<Value = u8> {
    prop_oneof![0u8..=252, Just(0xFE)]
}

/// An instruction byte: mostly the defined ones, sometimes anything.
fn instruction_byte() -> impl Strategy<Value = u8> {
    prop_oneof![3 => proptest::sample::select(KNOWN_OPCODES.to_vec()), 1 => any::<u8>()]
}

/// A gap between two chunks: none, inside the 1.5 ms byte gap, exactly on it, or beyond it.
fn gap() -> impl Strategy<Value = Duration> {
    prop_oneof![
        Just(Duration::ZERO),
        (0u64..1_500_000).prop_map(Duration::from_nanos),
        Just(DEFAULT_INTER_BYTE_TIMEOUT),
        Just(DEFAULT_INTER_BYTE_TIMEOUT + Duration::from_nanos(1)),
        (1_500_001u64..50_000_000).prop_map(Duration::from_nanos),
    ]
}

/// A whole stream: random/tricky bytes interleaved with valid and corrupted packets.
fn stream() -> impl Strategy<Value = Vec<u8>> {
    let piece = prop_oneof![
        3 => tricky_bytes(64),
        2 => (packet_id(), instruction_byte(), tricky_bytes(40)).prop_map(|(id, code, params)| encode_instruction(id, code, &params)),
        1 => (0u8..=252, any::<u8>(), tricky_bytes(40)).prop_map(|(id, error, data)| encode_status(id, error, &data)),
        1 => (packet_id(), instruction_byte(), tricky_bytes(40), any::<prop::sample::Index>(), any::<u8>()).prop_map(
            |(id, code, params, at, flip)| {
                let mut bytes = encode_instruction(id, code, &params);
                let i = at.index(bytes.len());
                bytes[i] ^= flip | 1;
                bytes
            }
        ),
        1 => (packet_id(), any::<prop::sample::Index>()).prop_map(|(id, at)| {
            // A packet cut short.
            let bytes = encode_instruction(id, opcode::PING, &[]);
            bytes[..at.index(bytes.len())].to_vec()
        }),
    ];
    vec(piece, 0..40).prop_map(|pieces| {
        let mut out = pieces.concat();
        out.truncate(2000);
        out
    })
}

/// Split `bytes` at the given chunk sizes (cycled), each chunk with its own gap.
fn chunked<'a>(bytes: &'a [u8], cuts: &'a [(usize, Duration)]) -> Vec<(&'a [u8], Duration)> {
    let mut out = Vec::new();
    let mut at = 0;
    let mut k = 0;
    while at < bytes.len() {
        let (size, gap) = cuts[k % cuts.len()];
        let end = (at + size).min(bytes.len());
        out.push((&bytes[at..end], gap));
        at = end;
        k += 1;
    }
    out
}

fn unique_ids(max: usize) -> impl Strategy<Value = Vec<u8>> {
    // A shuffled subset keeps the IDs unique (Sync/Bulk Read reject repeats) in any order.
    subsequence((0u8..=252).collect::<Vec<_>>(), 1..=max).prop_shuffle()
}

/// Sync and Bulk instructions with valid layouts.
fn sync_bulk_instruction() -> impl Strategy<Value = Instruction> {
    let address = any::<u16>();
    prop_oneof![
        (address, any::<u16>(), unique_ids(12)).prop_map(|(address, length, ids)| Instruction::SyncRead { address, length, ids }),
        (address, any::<u16>(), unique_ids(12)).prop_map(|(address, length, ids)| Instruction::FastSyncRead { address, length, ids }),
        (address, 1u16..8, vec(any::<u8>(), 1..8)).prop_flat_map(|(address, length, ids)| {
            let entries = ids.into_iter().map(move |id| vec(any::<u8>(), usize::from(length)).prop_map(move |data| SyncWriteEntry { id, data })).collect::<Vec<_>>();
            entries.prop_map(move |entries| Instruction::SyncWrite { address, length, entries })
        }),
        unique_ids(10)
            .prop_flat_map(|ids| {
                let n = ids.len();
                (Just(ids), vec((any::<u16>(), any::<u16>()), n))
            })
            .prop_flat_map(|(ids, spans)| {
                let entries: Vec<_> = ids.into_iter().zip(spans).map(|(id, (address, length))| BulkReadEntry { id, address, length }).collect();
                prop_oneof![Just(Instruction::BulkRead { entries: entries.clone() }), Just(Instruction::FastBulkRead { entries }),]
            }),
        unique_ids(6)
            .prop_flat_map(|ids| {
                let n = ids.len();
                (Just(ids), vec((any::<u16>(), vec(any::<u8>(), 1..10)), n))
            })
            .prop_map(|(ids, parts)| Instruction::BulkWrite { entries: ids.into_iter().zip(parts).map(|(id, (address, data))| BulkWriteEntry { id, address, data }).collect() }),
    ]
}

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

fn decode_all(bytes: &[u8]) -> Vec<Result<RawPacket, FrameError>> {
    let mut decoder = Decoder::default();
    let mut out = decoder.push(Duration::ZERO, bytes);
    out.extend(decoder.flush());
    out
}

/// Bytes 8.. (parameters) of an encoded packet never hold an unstuffed `FF FF FD`.
fn body_is_stuffed(bytes: &[u8], from: usize) -> bool {
    let body = &bytes[from..bytes.len() - 2];
    body.windows(3).enumerate().all(|(i, w)| w != HEADER || body.get(i + 3) == Some(&0xFD))
}

/// Every decoded packet passed its CRC and is a contiguous frame of LEN + 7 bytes.
fn assert_packet_sane(packet: &RawPacket) -> Result<(), TestCaseError> {
    let b = &packet.bytes;
    prop_assert_eq!(b.len(), packet.wire_len);
    prop_assert_eq!(&b[..4], &[0xFF, 0xFF, 0xFD, 0x00]);
    prop_assert_eq!(usize::from(u16::from_le_bytes([b[5], b[6]])) + 7, b.len());
    prop_assert_eq!(crc16(&b[..b.len() - 2]), u16::from_le_bytes([b[b.len() - 2], b[b.len() - 1]]));
    prop_assert_eq!((packet.id, packet.instruction), (b[4], b[7]));
    Ok(())
}

fn robot() -> &'static RobotDescription {
    static ROBOT: OnceLock<RobotDescription> = OnceLock::new();
    ROBOT.get_or_init(|| RobotDescription::load(&RobotDescription::default_path()).unwrap())
}

fn fresh_bus() -> Bus {
    robot().bench_bus(Timing::Off, None).unwrap()
}

/// Would this instruction change a servo's ID (directly, or by a full factory reset)? Such packets
/// are left out of the bus property: two servos with one ID collide on the wire by design.
fn changes_an_id(id: u8, instruction: &Instruction) -> bool {
    const ID_ADDRESS: usize = 7;
    let covers = |address: u16, len: usize| (usize::from(address)..usize::from(address) + len).contains(&ID_ADDRESS);
    match instruction {
        Instruction::Write { address, data } | Instruction::RegWrite { address, data } => covers(*address, data.len()),
        Instruction::SyncWrite { address, length, .. } => covers(*address, usize::from(*length)),
        Instruction::BulkWrite { entries } => entries.iter().any(|e| covers(e.address, e.data.len())),
        Instruction::FactoryReset { option } => *option == 0xFF && id != 0xFE,
        _ => false,
    }
}

/// Check a Fast reply's blocks (as many as are present) against the listed data lengths: each
/// CRC is the running CRC of everything before it.
fn assert_fast_blocks(bytes: &[u8], lens: &[usize], from: &[u8]) -> Result<(), TestCaseError> {
    let mut at = 8;
    for (k, &n) in lens.iter().enumerate() {
        if at >= bytes.len() {
            break;
        }
        let data_end = at + 2 + n;
        prop_assert!(data_end + 2 <= bytes.len(), "partial block {} in fast reply", k);
        prop_assert_eq!(bytes[at + 1], from[k], "block {} names the wrong ID", k);
        prop_assert_eq!(crc16(&bytes[..data_end]), u16::from_le_bytes([bytes[data_end], bytes[data_end + 1]]), "running CRC of block {}", k);
        at = data_end + 2;
    }
    prop_assert_eq!(at, bytes.len(), "fast reply ends inside a block");
    Ok(())
}

/// Every reply on the bus is a well-formed status packet from a servo 1..=8 (or a Fast reply
/// from 0xFE). A Fast reply may be cut short, but only where the chain of listed servos broke.
fn assert_replies_sane(transaction: &Transaction) -> Result<(), TestCaseError> {
    let fast_lens: Option<Vec<usize>> = match &transaction.instruction {
        Ok(Instruction::FastSyncRead { length, ids, .. }) => Some(vec![usize::from(*length); ids.len()]),
        Ok(Instruction::FastBulkRead { entries }) => Some(entries.iter().map(|e| usize::from(e.length)).collect()),
        _ => None,
    };
    for reply in &transaction.replies {
        let b = &reply.bytes;
        prop_assert!(!reply.from.is_empty());
        prop_assert!(reply.from.iter().all(|id| (1..=8).contains(id)), "reply from {:?}", reply.from);
        prop_assert!(b.len() >= 11, "reply of {} bytes", b.len());
        prop_assert_eq!(&b[..4], &[0xFF, 0xFF, 0xFD, 0x00]);
        prop_assert_eq!(b[7], opcode::STATUS);
        let id = b[4];
        prop_assert!((1..=8).contains(&id) || id == 0xFE, "reply ID {}", id);
        let len = usize::from(u16::from_le_bytes([b[5], b[6]]));
        if id == 0xFE {
            let lens = fast_lens.as_ref();
            prop_assert!(lens.is_some(), "ID 0xFE reply to {:?}", transaction.instruction);
            let lens = lens.unwrap();
            prop_assert_eq!(len, 1 + lens.iter().map(|n| n + 4).sum::<usize>(), "Fast reply LEN");
            prop_assert!(reply.from.len() <= lens.len());
            assert_fast_blocks(b, lens, &reply.from)?;
            if reply.from.len() < lens.len() {
                // The chain broke: the packet is short of its LEN, as on a real bus.
                prop_assert!(b.len() < len + 7);
                continue;
            }
        } else {
            prop_assert_eq!(&reply.from, &vec![id]);
        }
        // Frame with a decoder that allows any 16-bit LEN: this checks the packet, not the SDK's
        // 1024-byte buffer.
        let mut decoder = Decoder::new(DEFAULT_INTER_BYTE_TIMEOUT, usize::from(u16::MAX));
        let results = decoder.push(Duration::ZERO, b);
        prop_assert_eq!(decoder.pending(), 0, "bytes left over from reply {:02X?}", &b[..b.len().min(16)]);
        prop_assert_eq!(results.len(), 1, "reply (LEN {}, {} bytes) decodes to {:?}", len, b.len(), results.iter().map(|r| r.as_ref().map(|p| p.wire_len)).collect::<Vec<_>>());
        let packet = results[0].as_ref();
        prop_assert!(packet.is_ok(), "reply does not decode: {:?}", packet.err());
        let packet = packet.unwrap();
        assert_packet_sane(packet)?;
        prop_assert_eq!(packet.wire_len, b.len());
    }
    Ok(())
}

/// A packet for the bus property: raw (random parameters) or structured (valid layouts aimed at
/// servos 1..=8 and real addresses).
fn bus_packet() -> impl Strategy<Value = (u8, u8, Vec<u8>)> {
    let id = prop_oneof![4 => 1u8..=8, 3 => Just(0xFE), 1 => any::<u8>()];
    let raw = (id.clone(), instruction_byte(), vec(any::<u8>(), 0..=64));
    let address = prop_oneof![
        3 => proptest::sample::select(vec![0u16, 6, 7, 8, 9, 10, 11, 12, 13, 20, 31, 40, 44, 48, 52, 63, 64, 65, 68, 69, 70, 98, 100, 104, 108, 112, 116, 120, 122, 124, 126, 128, 132, 146, 168, 224, 578, 634, 661]),
        1 => 0u16..700,
        1 => any::<u16>(),
    ];
    let length = prop_oneof![4 => 0u16..=8, 1 => 0u16..700, 1 => any::<u16>()];
    let ids = subsequence((1u8..=9).collect::<Vec<_>>(), 1..=9).prop_shuffle();
    let structured = prop_oneof![
        (id.clone(), address.clone(), length.clone()).prop_map(|(id, address, length)| (id, Instruction::Read { address, length })),
        (id.clone(), address.clone(), vec(any::<u8>(), 1..=4)).prop_map(|(id, address, data)| (id, Instruction::Write { address, data })),
        (id.clone(), address.clone(), vec(any::<u8>(), 1..=4)).prop_map(|(id, address, data)| (id, Instruction::RegWrite { address, data })),
        id.clone().prop_map(|id| (id, Instruction::Action)),
        id.clone().prop_map(|id| (id, Instruction::Reboot)),
        (id.clone(), prop_oneof![Just(0x01u8), Just(0x02), Just(0xFF), any::<u8>()]).prop_map(|(id, option)| (id, Instruction::FactoryReset { option })),
        id.clone().prop_map(|id| (id, Instruction::Clear { params: vec![0x01, 0x44, 0x58, 0x4C, 0x22] })),
        (id.clone(), prop_oneof![Just(1u8), Just(2u8)]).prop_map(|(id, op)| (id, Instruction::ControlTableBackup { params: vec![op, 0x43, 0x54, 0x52, 0x4C] })),
        (address.clone(), length.clone(), ids.clone()).prop_map(|(address, length, ids)| (0xFE, Instruction::SyncRead { address, length, ids })),
        (address.clone(), length.clone(), ids.clone()).prop_map(|(address, length, ids)| (0xFE, Instruction::FastSyncRead { address, length, ids })),
        (ids.clone(), vec((address.clone(), length.clone()), 9)).prop_map(|(ids, spans)| {
            let entries = ids.into_iter().zip(spans).map(|(id, (address, length))| BulkReadEntry { id, address, length }).collect();
            (0xFE, Instruction::BulkRead { entries })
        }),
        (ids.clone(), vec((address.clone(), length.clone()), 9)).prop_map(|(ids, spans)| {
            let entries = ids.into_iter().zip(spans).map(|(id, (address, length))| BulkReadEntry { id, address, length }).collect();
            (0xFE, Instruction::FastBulkRead { entries })
        }),
        (address.clone(), 1u16..=4, ids.clone(), vec(any::<u8>(), 36)).prop_map(|(address, length, ids, pool)| {
            let n = usize::from(length);
            let entries = ids.into_iter().enumerate().map(|(k, id)| SyncWriteEntry { id, data: pool[k * n..k * n + n].to_vec() }).collect();
            (0xFE, Instruction::SyncWrite { address, length, entries })
        }),
        (ids, vec((address, vec(any::<u8>(), 1..=4)), 9)).prop_map(|(ids, parts)| {
            let entries = ids.into_iter().zip(parts).map(|(id, (address, data))| BulkWriteEntry { id, address, data }).collect();
            (0xFE, Instruction::BulkWrite { entries })
        }),
    ]
    .prop_map(|(id, instruction)| (id, instruction.code(), instruction.params()));
    prop_oneof![raw, structured]
}

// ---------------------------------------------------------------------------------------------
// Decoder robustness
// ---------------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig { cases: 192, failure_persistence: None, ..ProptestConfig::default() })]

    /// Random byte streams, cut anywhere, arriving with gaps inside and beyond 1.5 ms, never panic
    /// the decoder, and whatever it returns as a packet passed its CRC.
    #[test]
    fn decoder_never_panics_on_random_streams(
        bytes in prop_oneof![vec(any::<u8>(), 0..2000), stream()],
        cuts in vec((1usize..80, gap()), 1..64),
    ) {
        let mut decoder = Decoder::default();
        let mut now = Duration::ZERO;
        let mut results = Vec::new();
        for (chunk, gap) in chunked(&bytes, &cuts) {
            now += gap;
            results.extend(decoder.push(now, chunk));
            prop_assert!(decoder.pending() <= bytes.len());
        }
        results.extend(decoder.flush());
        prop_assert_eq!(decoder.pending(), 0);
        for packet in results.iter().filter_map(|r| r.as_ref().ok()) {
            assert_packet_sane(packet)?;
        }
    }

    /// Garbage followed by a valid packet, all at once, then flush: the packet is among the
    /// decoded ones (a false header in the garbage may swallow bytes until the flush).
    #[test]
    fn valid_packet_after_garbage_is_found(
        garbage in prop_oneof![vec(any::<u8>(), 0..300), tricky_bytes(300)],
        id in 0u8..=252,
        code in any::<u8>(),
        params in tricky_bytes(120),
    ) {
        let mut stream = garbage.clone();
        stream.extend(encode_instruction(id, code, &params));
        let results = decode_all(&stream);
        let found = results.iter().filter_map(|r| r.as_ref().ok()).any(|p| p.id == id && p.instruction == code && p.params == params);
        prop_assert!(found, "garbage {:02X?}: got {:?}", garbage, results);
    }

    /// Valid packets back to back decode the same however they are cut, as long as every gap is
    /// within 1.5 ms.
    #[test]
    fn chunking_within_the_byte_gap_does_not_change_the_packets(
        packets in vec((packet_id(), instruction_byte(), tricky_bytes(60)), 1..8),
        cuts in vec((1usize..40, (0u64..=1_500_000).prop_map(Duration::from_nanos)), 1..16),
    ) {
        let stream: Vec<u8> = packets.iter().flat_map(|(id, code, params)| encode_instruction(*id, *code, params)).collect();
        let mut decoder = Decoder::default();
        let mut now = Duration::ZERO;
        let mut got = Vec::new();
        for (chunk, gap) in chunked(&stream, &cuts) {
            now += gap;
            got.extend(decoder.push(now, chunk));
        }
        prop_assert_eq!(decoder.pending(), 0);
        let got: Vec<_> = got.into_iter().map(|r| r.map(|p| (p.id, p.instruction, p.params))).collect();
        let expected: Vec<_> = packets.into_iter().map(Ok).collect();
        prop_assert_eq!(got, expected);
    }
}

// ---------------------------------------------------------------------------------------------
// Encode/decode round trips
// ---------------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn instruction_packet_round_trips(id in packet_id(), code in instruction_byte(), params in tricky_bytes(300)) {
        let bytes = encode_instruction(id, code, &params);
        let inserted = stuff(&params).len() - params.len();
        prop_assert_eq!(usize::from(u16::from_le_bytes([bytes[5], bytes[6]])), params.len() + inserted + 3, "LEN counts the stuffed bytes");
        prop_assert!(body_is_stuffed(&bytes, 8), "unstuffed FF FF FD in {:02X?}", bytes);
        let results = decode_all(&bytes);
        prop_assert_eq!(results.len(), 1, "{:?}", results);
        let packet = results[0].as_ref().unwrap();
        assert_packet_sane(packet)?;
        prop_assert_eq!((packet.id, packet.instruction, &packet.params), (id, code, &params));
        prop_assert_eq!(&packet.bytes, &bytes);
    }

    #[test]
    fn status_packet_round_trips(id in 0u8..=252, error in any::<u8>(), data in tricky_bytes(300)) {
        let bytes = encode_status(id, error, &data);
        let mut body = vec![error];
        body.extend_from_slice(&data);
        let inserted = stuff(&body).len() - body.len();
        prop_assert_eq!(usize::from(u16::from_le_bytes([bytes[5], bytes[6]])), data.len() + inserted + 4, "LEN counts the stuffed bytes");
        // For a status packet the scan covers the instruction (0x55) and error bytes too.
        prop_assert!(body_is_stuffed(&bytes, 7), "unstuffed FF FF FD in {:02X?}", bytes);
        let results = decode_all(&bytes);
        prop_assert_eq!(results.len(), 1, "{:?}", results);
        let packet = results[0].as_ref().unwrap();
        assert_packet_sane(packet)?;
        prop_assert_eq!((packet.id, packet.instruction), (id, opcode::STATUS));
        prop_assert_eq!(&packet.params, &body);
    }

    #[test]
    fn stuff_then_unstuff_is_identity(body in tricky_bytes(400)) {
        let stuffed = stuff(&body);
        prop_assert_eq!(unstuff(&stuffed), body.clone());
        // No unstuffed header is left, and stuffing only ever inserts FD after FF FF FD.
        prop_assert!(stuffed.windows(3).enumerate().all(|(i, w)| w != HEADER || stuffed.get(i + 3) == Some(&0xFD)));
        let headers = body.windows(3).filter(|w| *w == HEADER).count();
        prop_assert_eq!(stuffed.len(), body.len() + headers);
    }

    #[test]
    fn sync_and_bulk_instructions_parse_back_from_their_params(instruction in sync_bulk_instruction()) {
        let params = instruction.params();
        prop_assert_eq!(Instruction::parse(instruction.code(), &params), Ok(instruction.clone()));
        // And through the wire.
        let packet = decode_all(&encode_instruction(0xFE, instruction.code(), &params)).remove(0).unwrap();
        prop_assert_eq!(Instruction::parse(packet.instruction, &packet.params), Ok(instruction));
    }
}

// ---------------------------------------------------------------------------------------------
// The whole bus
// ---------------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, failure_persistence: None, ..ProptestConfig::default() })]

    /// Arbitrary decoded packets through `Bus::handle` never panic, and every reply is a
    /// well-formed status packet from servo 1..=8 (or a Fast reply from 0xFE).
    #[test]
    fn bus_never_panics_and_every_reply_is_well_formed(
        packets in vec((bus_packet(), prop_oneof![4 => 0u64..3_000, 1 => 100_000u64..200_000]), 1..24),
    ) {
        let mut bus = fresh_bus();
        let mut now = Duration::from_millis(1);
        for ((id, code, params), gap_us) in packets {
            if let Ok(instruction) = Instruction::parse(code, &params)
                && changes_an_id(id, &instruction)
            {
                continue;
            }
            let wire = encode_instruction(id, code, &params);
            let mut decoder = Decoder::new(DEFAULT_INTER_BYTE_TIMEOUT, usize::from(u16::MAX));
            let packet = decoder.push(now, &wire).remove(0).unwrap();
            now += Duration::from_micros(gap_us);
            let transaction = bus.handle(packet, now, None);
            assert_replies_sane(&transaction)?;
        }
    }
}
