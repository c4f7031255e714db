//! Pairs what the controller sent on a real bus with what the servos answered: each instruction
//! with its status packets and their times, and the servos that should have answered and did
//! not. Sans-IO: `climbsim tap` feeds it the bytes it forwards, with the times it read them.

use std::time::Duration;

use crate::protocol::{BROADCAST_ID, FrameError, Instruction, MAX_ID, RawPacket, STATUS_INSTRUCTION};

use super::stream::{Piece, TimedStream};

/// Status Return Level's address in the X-series control table (firmware-profiles, key
/// `status_return_level`; the reference's §6): which instructions a servo answers.
const STATUS_RETURN_LEVEL_ADDRESS: u16 = 68;
/// Its factory value: every instruction is answered.
const STATUS_RETURN_LEVEL_DEFAULT: u8 = 2;

/// A status packet as it arrived.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SeenReply {
    pub id: u8,
    /// When its first and last byte were read from the servos' side.
    pub first: Duration,
    pub last: Duration,
    pub bytes: Vec<u8>,
}

/// An instruction the controller sent, with what answered it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Seen {
    /// When its first byte was read from the controller.
    pub t: Duration,
    /// When its last byte had been handed to the servos' side.
    pub end: Duration,
    /// The line's rate then.
    pub baud: u32,
    pub instruction: RawPacket,
    pub replies: Vec<SeenReply>,
    /// The servos that should have answered (as the Status Return Level they were last told
    /// says, the factory level before) and did not.
    pub missed: Vec<u8>,
}

/// Something `climbsim tap` records.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// An instruction, once the next one came (or the session ended).
    Transaction(Seen),
    /// Bytes in no packet, from the controller (`from_servos` false) or the servos.
    Raw { from_servos: bool, at: Duration, bytes: Vec<u8> },
    /// A packet from the servos that answered nothing pending (a late reply after the next
    /// instruction, or an instruction echoed by a half-duplex adapter).
    Unpaired { at: Duration, packet: RawPacket },
    /// A framing error (a failed CRC, a cut packet) in one direction; its bytes come raw.
    FrameError { from_servos: bool, at: Duration, error: FrameError },
}

/// The controller's and the servos' streams, and the instruction waiting for its replies.
#[derive(Debug)]
pub struct Pairing {
    from_controller: TimedStream,
    from_servos: TimedStream,
    pending: Option<Pending>,
    /// Each ID's Status Return Level as the controller last wrote it.
    status_return_level: [u8; MAX_ID as usize + 1],
}

#[derive(Debug)]
struct Pending {
    seen: Seen,
    expected: Vec<u8>,
}

impl Default for Pairing {
    fn default() -> Self {
        Self { from_controller: TimedStream::default(), from_servos: TimedStream::default(), pending: None, status_return_level: [STATUS_RETURN_LEVEL_DEFAULT; MAX_ID as usize + 1] }
    }
}

impl Pairing {
    /// The controller's bytes: read at `read_at`, handed to the servos' side by `forwarded_at`,
    /// on a line at `baud`.
    pub fn from_controller(&mut self, read_at: Duration, forwarded_at: Duration, baud: u32, bytes: &[u8]) -> Vec<Event> {
        let pieces = self.from_controller.push(read_at, bytes);
        let mut events = Vec::new();
        for piece in pieces {
            match piece {
                Piece::Packet { packet, first, .. } => {
                    events.extend(self.close_pending());
                    let expected = self.expected_repliers(&packet);
                    self.follow_status_return_level(&packet);
                    self.pending = Some(Pending { seen: Seen { t: first, end: forwarded_at, baud, instruction: packet, replies: Vec::new(), missed: Vec::new() }, expected });
                }
                Piece::Raw { bytes, first } => events.push(Event::Raw { from_servos: false, at: first, bytes }),
                Piece::FrameError(error) => events.push(Event::FrameError { from_servos: false, at: read_at, error }),
            }
        }
        events
    }

    /// The servos' bytes, read at `at`.
    pub fn from_servos(&mut self, at: Duration, bytes: &[u8]) -> Vec<Event> {
        let pieces = self.from_servos.push(at, bytes);
        let mut events = Vec::new();
        for piece in pieces {
            match piece {
                Piece::Packet { packet, first, last } => {
                    let answers = packet.instruction == STATUS_INSTRUCTION && self.pending.as_ref().is_some_and(|p| p.awaits(packet.id));
                    match &mut self.pending {
                        Some(pending) if answers => pending.seen.replies.push(SeenReply { id: packet.id, first, last, bytes: packet.bytes }),
                        _ => events.push(Event::Unpaired { at: first, packet }),
                    }
                }
                Piece::Raw { bytes, first } => events.push(Event::Raw { from_servos: true, at: first, bytes }),
                Piece::FrameError(error) => events.push(Event::FrameError { from_servos: true, at, error }),
            }
        }
        events
    }

    /// The session has ended at `at`: the last instruction and every partial packet come out
    /// (a cut packet's framing error at that time).
    pub fn finish(&mut self, at: Duration) -> Vec<Event> {
        let mut events = Vec::new();
        let from_servos = self.from_servos.flush();
        let from_controller = self.from_controller.flush();
        for (servos, pieces) in [(true, from_servos), (false, from_controller)] {
            for piece in pieces {
                match piece {
                    Piece::Raw { bytes, first } => events.push(Event::Raw { from_servos: servos, at: first, bytes }),
                    Piece::FrameError(error) => events.push(Event::FrameError { from_servos: servos, at, error }),
                    // A flush completes nothing new that a push had not (it only drops).
                    Piece::Packet { packet, first, .. } => events.push(Event::Unpaired { at: first, packet }),
                }
            }
        }
        events.extend(self.close_pending());
        events
    }

    fn close_pending(&mut self) -> Option<Event> {
        let Pending { mut seen, expected } = self.pending.take()?;
        seen.missed = expected.into_iter().filter(|id| !seen.replies.iter().any(|r| r.id == *id)).collect();
        Some(Event::Transaction(seen))
    }

    /// Who answers `packet`, as the protocol's response rules and each servo's Status Return
    /// Level say. A broadcast Ping is answered by whoever is there: nobody is missed.
    fn expected_repliers(&self, packet: &RawPacket) -> Vec<u8> {
        let Ok(instruction) = Instruction::parse(packet.instruction, &packet.params) else { return Vec::new() };
        let level = |id: u8| self.status_return_level.get(usize::from(id)).copied().unwrap_or(STATUS_RETURN_LEVEL_DEFAULT);
        let reads = |ids: Vec<u8>| ids.into_iter().filter(|id| level(*id) >= 1).collect::<Vec<u8>>();
        match (packet.id, instruction) {
            (BROADCAST_ID, Instruction::SyncRead { ids, .. }) => reads(ids),
            (BROADCAST_ID, Instruction::BulkRead { entries }) => reads(entries.iter().map(|e| e.id).collect()),
            (BROADCAST_ID, Instruction::FastSyncRead { .. } | Instruction::FastBulkRead { .. }) => vec![BROADCAST_ID],
            (BROADCAST_ID, _) => Vec::new(),
            (id, _) if id > MAX_ID => Vec::new(),
            (id, Instruction::Ping) => vec![id],
            (id, Instruction::Read { .. }) => reads(vec![id]),
            (id, _) => (level(id) >= 2).then_some(id).into_iter().collect(),
        }
    }

    /// A write of Status Return Level changes which instructions the servo answers from now on.
    fn follow_status_return_level(&mut self, packet: &RawPacket) {
        let Ok(instruction) = Instruction::parse(packet.instruction, &packet.params) else { return };
        let mut set = |id: u8, address: u16, data: &[u8]| {
            let offset = STATUS_RETURN_LEVEL_ADDRESS.checked_sub(address).map(usize::from);
            if let (Some(offset), Some(slot)) = (offset, self.status_return_level.get_mut(usize::from(id)))
                && let Some(value) = data.get(offset)
            {
                *slot = *value;
            }
        };
        match instruction {
            Instruction::Write { address, data } if packet.id == BROADCAST_ID => (0..=MAX_ID).for_each(|id| set(id, address, &data)),
            Instruction::Write { address, data } => set(packet.id, address, &data),
            Instruction::SyncWrite { address, entries, .. } => entries.iter().for_each(|e| set(e.id, address, &e.data)),
            Instruction::BulkWrite { entries } => entries.iter().for_each(|e| set(e.id, e.address, &e.data)),
            _ => {}
        }
    }
}

impl Pending {
    fn awaits(&self, id: u8) -> bool {
        self.expected.contains(&id) || (self.seen.instruction.id == BROADCAST_ID && self.seen.instruction.instruction == crate::protocol::opcode::PING)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{encode_instruction, encode_status};

    fn us(n: u64) -> Duration {
        Duration::from_micros(n)
    }

    fn transactions(events: &[Event]) -> Vec<&Seen> {
        events.iter().filter_map(|e| if let Event::Transaction(seen) = e { Some(seen) } else { None }).collect()
    }

    #[test]
    fn a_sync_read_pairs_each_reply_and_names_the_servo_that_did_not_answer() {
        let mut pairing = Pairing::default();
        // Sync Read of Present Position (132, 4 bytes) from 1, 2 and 3.
        let request = encode_instruction(BROADCAST_ID, 0x82, &[132, 0, 4, 0, 1, 2, 3]);
        assert!(pairing.from_controller(us(0), us(10), 1_000_000, &request).is_empty());
        let mut replies = encode_status(1, 0, &[1, 2, 3, 4]);
        replies.extend(encode_status(3, 0, &[5, 6, 7, 8]));
        assert!(pairing.from_servos(us(300), &replies[..20]).is_empty());
        assert!(pairing.from_servos(us(450), &replies[20..]).is_empty());
        let events = pairing.from_controller(us(2000), us(2010), 1_000_000, &encode_instruction(1, 0x01, &[]));
        let seen = transactions(&events);
        assert_eq!(seen.len(), 1);
        let ids: Vec<(u8, Duration, Duration)> = seen[0].replies.iter().map(|r| (r.id, r.first, r.last)).collect();
        // Status 1 is 15 bytes: it came whole in the first read, status 3 across both.
        assert_eq!(ids, vec![(1, us(300), us(300)), (3, us(300), us(450))]);
        assert_eq!(seen[0].missed, vec![2]);
        assert_eq!((seen[0].t, seen[0].end, seen[0].baud), (us(0), us(10), 1_000_000));
    }

    #[test]
    fn status_return_level_decides_who_is_missed_and_a_late_reply_is_unpaired() {
        let mut pairing = Pairing::default();
        // Level 1 for ID 5 (Write of 68): its later writes are not answered, its reads are.
        let set_level = encode_instruction(5, 0x03, &[68, 0, 1]);
        pairing.from_controller(us(0), us(1), 57_600, &set_level);
        let write = encode_instruction(5, 0x03, &[65, 0, 1]);
        let events = pairing.from_controller(us(100), us(101), 57_600, &write);
        assert_eq!(transactions(&events)[0].missed, vec![5], "the level-setting write itself was due an answer");
        let read = encode_instruction(5, 0x02, &[132, 0, 4, 0]);
        let events = pairing.from_controller(us(200), us(201), 57_600, &read);
        assert!(transactions(&events)[0].missed.is_empty(), "a write at level 1 is not answered");
        let events = pairing.from_controller(us(300), us(301), 57_600, &encode_instruction(BROADCAST_ID, 0x01, &[]));
        assert_eq!(transactions(&events)[0].missed, vec![5], "the read was due an answer");
        // Pings to broadcast: whoever answers is paired, nobody is missed.
        pairing.from_servos(us(400), &encode_status(7, 0, &[0x06, 0x04, 0x2D]));
        let events = pairing.finish(us(450));
        let seen = transactions(&events);
        assert_eq!((seen[0].replies.len(), seen[0].missed.len()), (1, 0));
        // A status with nothing pending is kept, unpaired.
        let events = pairing.from_servos(us(500), &encode_status(7, 0, &[]));
        assert!(matches!(events.as_slice(), [Event::Unpaired { packet, .. }] if packet.id == 7));
    }

    #[test]
    fn garbage_in_either_direction_is_kept_raw_and_the_crc_failure_said() {
        let mut pairing = Pairing::default();
        let events = pairing.from_controller(us(0), us(1), 57_600, &[0x01, 0x02, 0x03]);
        assert!(matches!(events.as_slice(), [Event::Raw { from_servos: false, bytes, .. }] if bytes == &[1, 2, 3]));
        let mut bad = encode_status(1, 0, &[]);
        let n = bad.len();
        bad[n - 2] ^= 0x55;
        let events = pairing.from_servos(us(5), &bad);
        assert!(events.iter().any(|e| matches!(e, Event::FrameError { from_servos: true, error: FrameError::BadCrc { id: 1, .. }, .. })), "{events:?}");
        let mut events = events;
        events.extend(pairing.finish(us(10)));
        let raw: usize = events.iter().map(|e| if let Event::Raw { from_servos: true, bytes, .. } = e { bytes.len() } else { 0 }).sum();
        assert_eq!(raw, bad.len());
        // A packet cut by the session's end: its error carries the end's time.
        let ping = encode_instruction(2, 0x01, &[]);
        pairing.from_controller(us(20), us(21), 57_600, &ping[..6]);
        let events = pairing.finish(us(30));
        assert!(events.iter().any(|e| matches!(e, Event::FrameError { from_servos: false, at, .. } if *at == us(30))), "{events:?}");
    }
}
