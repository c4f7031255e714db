//! The shared half-duplex bus: routes each instruction to the servos it concerns, collects their
//! replies in the order the protocol prescribes, and schedules them on a modelled wire.
//!
//! Wire model (on by default): an instruction occupies the wire for bytes × bits_per_byte / baud
//! from when it arrived (or when the wire became free); each reply starts Return Delay Time after
//! the end of what preceded it and occupies the wire for its own bytes. With [`Timing::Off`] every
//! reply is due at once.

mod faults;
mod trace;
pub mod wire;

use std::time::Duration;

use thiserror::Error;
use tracing::{debug, trace as trace_event, warn};

use crate::device::{Addressing, FirmwareProfile, Outcome, Plant, Request, Servo};
use crate::protocol::{self, BROADCAST_ID, FastReplyBuilder, Instruction, RawPacket, encode_status};

pub use faults::{BusFaults, FaultCounts};
pub use trace::{TraceWriter, transaction_json};

/// Whether replies are paced like a real wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Timing {
    #[default]
    Wire,
    Off,
}

/// One status packet put on the wire.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply {
    pub bytes: Vec<u8>,
    /// When its first byte starts on the wire.
    pub start: Duration,
    /// When its last byte has been received: the moment to hand it to the controller.
    pub end: Duration,
    /// IDs of the servos that sent it (several for a Fast reply or a collision).
    pub from: Vec<u8>,
}

/// An instruction and what the bus answered.
#[derive(Debug, Clone, PartialEq)]
pub struct Transaction {
    pub packet: RawPacket,
    /// The decoded instruction, or why its parameters did not parse.
    pub instruction: Result<Instruction, protocol::ParamError>,
    pub received_at: Duration,
    /// When the instruction's last byte was on the wire.
    pub instruction_end: Duration,
    pub replies: Vec<Reply>,
    /// Time the instruction and its replies occupy the wire at the line's baud (also with
    /// [`Timing::Off`]: what a real bus would have spent), for bus utilisation.
    pub wire_busy: Duration,
    /// The line's baud differs from every servo's: nobody could decode the packet.
    pub baud_mismatch: bool,
    /// Time one byte took on the line (at its baud, or the bus's default where the transport
    /// has none).
    pub byte_time: Duration,
}

#[derive(Debug, Error)]
pub enum BusError {
    #[error("servo ID {0} is listed twice in the robot description")]
    DuplicateId(u8),
    #[error("servo ID {0} is outside 0..=252")]
    InvalidId(u8),
    #[error("baud rate {bps} bps is not one the firmware profile {profile} offers (it offers {offered} bps)")]
    UnsupportedBaud { bps: u32, profile: String, offered: String },
}

/// Eight (or any number of) servos on one bus.
pub struct Bus {
    servos: Vec<Servo>,
    plant: Box<dyn Plant>,
    timing: Timing,
    bits_per_byte: u32,
    /// Baud assumed when the transport has none (TCP, in-memory).
    default_baud: u32,
    wire_free_at: Duration,
    /// The line baud last reported as matching no servo, so the warning is logged once.
    mismatch_warned_for: Option<u32>,
    faults: BusFaults,
    /// Sees every transaction as it is handled (a recording's bus packets topic).
    tap: Option<TransactionTap>,
}

/// Something that sees every transaction the bus handles.
pub type TransactionTap = Box<dyn FnMut(&Transaction) + Send>;

impl std::fmt::Debug for Bus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bus").field("servos", &self.servos.len()).field("timing", &self.timing).finish_non_exhaustive()
    }
}

impl Bus {
    pub fn new(servos: Vec<Servo>, plant: Box<dyn Plant>, timing: Timing, default_baud: u32) -> Result<Self, BusError> {
        let mut seen = [false; 256];
        for servo in &servos {
            let id = servo.id();
            if id > protocol::MAX_ID {
                return Err(BusError::InvalidId(id));
            }
            if std::mem::replace(&mut seen[usize::from(id)], true) {
                return Err(BusError::DuplicateId(id));
            }
        }
        let bits_per_byte = servos.first().map_or(10, |s| s.profile().model.bits_per_byte);
        Ok(Self { servos, plant, timing, bits_per_byte, default_baud, wire_free_at: Duration::ZERO, mismatch_warned_for: None, faults: BusFaults::default(), tap: None })
    }

    pub fn servos(&self) -> &[Servo] {
        &self.servos
    }

    /// The plant, if it is a `P` (e.g. the rapier world).
    pub fn plant<P: 'static>(&self) -> Option<&P> {
        self.plant.as_any().downcast_ref()
    }

    pub fn plant_mut<P: 'static>(&mut self) -> Option<&mut P> {
        self.plant.as_any_mut().downcast_mut()
    }

    /// The rate of a servo that was never told one (`--baud`'s default).
    pub fn default_baud(&self) -> u32 {
        self.default_baud
    }

    pub fn timing(&self) -> Timing {
        self.timing
    }

    /// The inter-byte timeout of the servos' firmware (for the decoder).
    pub fn inter_byte_timeout(&self) -> Duration {
        Duration::from_micros(self.servos.first().map_or(1500, |s| s.profile().model.inter_byte_timeout_us))
    }

    /// Time `bytes` take on the wire at `baud`.
    pub fn wire_time(&self, bytes: usize, baud: u32) -> Duration {
        Duration::from_secs_f64(bytes as f64 * f64::from(self.bits_per_byte) / f64::from(baud.max(1)))
    }

    /// Time one byte takes on the line (`line_baud`, or the bus's default where the transport has
    /// no baud).
    pub fn byte_time(&self, line_baud: Option<u32>) -> Duration {
        self.wire_time(1, line_baud.unwrap_or(self.default_baud))
    }

    /// Advance the servos' physics to `now` without any packet (e.g. on a timer).
    pub fn advance(&mut self, now: Duration) {
        self.apply_faults_until(now);
        self.plant.advance(&mut self.servos, now);
    }

    /// Handle one packet that finished arriving at `received_at`. `line_baud` is the baud the
    /// controller's port is set to, where the transport knows it (a pty): servos set to another
    /// baud do not hear the packet, exactly as on a real bus.
    pub fn handle(&mut self, packet: RawPacket, received_at: Duration, line_baud: Option<u32>) -> Transaction {
        self.handle_on(packet, received_at, line_baud, false)
    }

    /// Like [`Bus::handle`] for a packet that came over a physical wire (a serial device): the
    /// host saw its last byte at `received_at`, after its real wire time, so none is modelled,
    /// and each reply's `start` is when to write it (the device's UART takes the wire time).
    pub fn handle_from_physical_wire(&mut self, packet: RawPacket, received_at: Duration, line_baud: Option<u32>) -> Transaction {
        self.handle_on(packet, received_at, line_baud, true)
    }

    /// Let `tap` see every transaction from now on (None: stop).
    pub fn set_transaction_tap(&mut self, tap: Option<TransactionTap>) {
        self.tap = tap;
    }

    fn handle_on(&mut self, packet: RawPacket, received_at: Duration, line_baud: Option<u32>, physical_wire: bool) -> Transaction {
        let transaction = self.transact(packet, received_at, line_baud, physical_wire);
        if let Some(tap) = &mut self.tap {
            tap(&transaction);
        }
        transaction
    }

    fn transact(&mut self, packet: RawPacket, received_at: Duration, line_baud: Option<u32>, physical_wire: bool) -> Transaction {
        let baud = line_baud.unwrap_or(self.default_baud);
        let (instruction_end, reply_base) = match self.timing {
            Timing::Wire if physical_wire => (received_at, received_at),
            Timing::Wire => {
                let end = received_at.max(self.wire_free_at) + self.wire_time(packet.wire_len, baud);
                (end, end)
            }
            Timing::Off => (received_at, received_at),
        };
        self.apply_faults_until(instruction_end);
        self.plant.advance(&mut self.servos, instruction_end);
        let instruction = Instruction::parse(packet.instruction, &packet.params);
        let wire_busy = self.wire_time(packet.wire_len, baud);
        let byte_time = self.wire_time(1, baud);
        let mut transaction = Transaction { packet, instruction, received_at, instruction_end, replies: Vec::new(), wire_busy, baud_mismatch: false, byte_time };
        if self.faults.instruction_corrupted(transaction.packet.wire_len, self.bits_per_byte) {
            return transaction; // bit errors: every servo's CRC check fails, nobody answers
        }
        if transaction.packet.instruction == protocol::STATUS_INSTRUCTION {
            return transaction; // another device's status packet: nothing to do
        }
        let Ok(instruction) = &transaction.instruction else {
            // Chosen (reference §7 unverified): ROBOTIS's own slave code drops a packet whose
            // parameters do not fit, without a reply.
            debug!(error = ?transaction.instruction, "malformed parameters, dropped");
            return transaction;
        };
        let hearing: Vec<usize> = (0..self.servos.len())
            .filter(|&i| {
                let servo = &self.servos[i];
                !servo.is_booting(instruction_end) && servo.speaks_protocol_2() && line_baud.is_none_or(|bps| servo.baud_bps() == Some(bps))
            })
            .filter(|&i| !self.faults.is_silent(self.servos[i].id()))
            .collect();
        if hearing.len() < self.servos.len() && line_baud.is_some() {
            trace_event!(hearing = hearing.len(), baud, "some servos do not hear this baud or are booting");
        }
        if let Some(bps) = line_baud {
            transaction.baud_mismatch = self.note_baud_mismatch(bps);
        }
        let pending = self.route(transaction.packet.id, instruction, &hearing, instruction_end);
        transaction.replies = self.schedule(pending, reply_base, baud);
        self.faults.on_replies(&mut transaction.replies);
        transaction.wire_busy += transaction.replies.iter().map(|r| self.wire_time(r.bytes.len(), baud)).sum::<Duration>();
        if let Some(last) = transaction.replies.last() {
            self.wire_free_at = last.end;
        } else {
            self.wire_free_at = instruction_end;
        }
        transaction
    }

    /// Whether no servo listens at `line_bps`. A real servo's UART samples such a packet as
    /// garbage and never answers; the controller sees only timeouts, so say why, once per baud.
    fn note_baud_mismatch(&mut self, line_bps: u32) -> bool {
        // Every packet passes here: the usual answer without allocating.
        if self.servos.iter().any(|s| s.baud_bps() == Some(line_bps)) {
            self.mismatch_warned_for = None;
            return false;
        }
        if self.mismatch_warned_for != Some(line_bps) {
            self.mismatch_warned_for = Some(line_bps);
            let mut bauds: Vec<u32> = self.servos.iter().filter_map(Servo::baud_bps).collect();
            bauds.sort_unstable();
            bauds.dedup();
            warn!(
                controller_bps = line_bps,
                servo_bps = ?bauds,
                "baud mismatch: the controller's port is at {line_bps} bps but the servos listen at {bauds:?} bps; \
                 as on hardware they hear garbage and do not answer (set the port to the servos' baud)"
            );
        }
        true
    }

    /// Execute the instruction on every servo it concerns; return the replies (unscheduled).
    fn route(&mut self, id: u8, instruction: &Instruction, hearing: &[usize], now: Duration) -> Vec<PendingReply> {
        let mut replies = Vec::new();
        if id == BROADCAST_ID {
            self.route_broadcast(instruction, hearing, now, &mut replies);
            return replies;
        }
        let Some(request) = unicast_request(instruction) else {
            return replies; // Sync/Bulk instructions must go to the broadcast ID
        };
        let primary_taken = hearing.iter().any(|&i| self.servos[i].id() == id);
        for &index in hearing {
            let servo = &self.servos[index];
            let via_secondary = servo.id() != id && servo.secondary_id() == Some(id) && !primary_taken;
            if servo.id() != id && !via_secondary {
                continue;
            }
            let addressing = Addressing { broadcast: false, via_secondary_id: via_secondary };
            let reply_id = servo.id();
            let answers = !via_secondary && replies_at_level(&request, servo.status_return_level());
            let outcome = self.execute(index, request, addressing, now);
            if answers {
                replies.push(self.status_reply(index, reply_id, &outcome));
            }
            self.finish(index, &outcome, now);
        }
        replies
    }

    fn route_broadcast(&mut self, instruction: &Instruction, hearing: &[usize], now: Duration, replies: &mut Vec<PendingReply>) {
        let addressing = Addressing { broadcast: true, via_secondary_id: false };
        match instruction {
            Instruction::Ping => {
                let mut order: Vec<usize> = hearing.to_vec();
                order.sort_by_key(|&i| self.servos[i].id());
                for index in order {
                    let outcome = self.execute(index, Request::Ping, addressing, now);
                    replies.push(self.status_reply(index, self.servos[index].id(), &outcome));
                }
            }
            Instruction::SyncRead { address, length, ids } => {
                for &id in ids {
                    self.read_slot(id, *address, *length, hearing, now, replies);
                }
            }
            Instruction::BulkRead { entries } => {
                for entry in entries {
                    self.read_slot(entry.id, entry.address, entry.length, hearing, now, replies);
                }
            }
            Instruction::FastSyncRead { address, length, ids } => {
                let reads: Vec<(u8, u16, u16)> = ids.iter().map(|&id| (id, *address, *length)).collect();
                replies.extend(self.fast_read(&reads, hearing, now));
            }
            Instruction::FastBulkRead { entries } => {
                let reads: Vec<(u8, u16, u16)> = entries.iter().map(|e| (e.id, e.address, e.length)).collect();
                replies.extend(self.fast_read(&reads, hearing, now));
            }
            Instruction::SyncWrite { address, entries, .. } => {
                for entry in entries {
                    self.write_slot(entry.id, Request::Write { address: *address, data: &entry.data }, hearing, now);
                }
            }
            Instruction::BulkWrite { entries } => {
                for entry in entries {
                    self.write_slot(entry.id, Request::Write { address: entry.address, data: &entry.data }, hearing, now);
                }
            }
            // Read to broadcast is not executed (reference §4); unknown codes get no reply.
            Instruction::Read { .. } | Instruction::Unknown { .. } => {}
            other => {
                if let Some(request) = unicast_request(other) {
                    for &index in hearing {
                        let outcome = self.execute(index, request, addressing, now);
                        self.finish(index, &outcome, now);
                    }
                }
            }
        }
    }

    /// The servos (primary ID match) that answer a slot of a Sync/Bulk instruction.
    fn slot_servos(&self, id: u8, hearing: &[usize]) -> Vec<usize> {
        hearing.iter().copied().filter(|&i| self.servos[i].id() == id).collect()
    }

    fn read_slot(&mut self, id: u8, address: u16, length: u16, hearing: &[usize], now: Duration, replies: &mut Vec<PendingReply>) {
        let addressing = Addressing { broadcast: true, via_secondary_id: false };
        for index in self.slot_servos(id, hearing) {
            let outcome = self.execute(index, Request::Read { address, length }, addressing, now);
            if self.servos[index].status_return_level() >= 1 {
                replies.push(self.status_reply(index, id, &outcome));
            }
        }
    }

    /// The normal status packet servo `index` sends as `id` for `outcome`.
    fn status_reply(&self, index: usize, id: u8, outcome: &Outcome) -> PendingReply {
        let error = self.servos[index].status_error_byte(&outcome.reply);
        let params = outcome.reply.as_deref().unwrap_or_default();
        PendingReply::single(index, id, encode_status(id, error, params))
    }

    fn write_slot(&mut self, id: u8, request: Request<'_>, hearing: &[usize], now: Duration) {
        let addressing = Addressing { broadcast: true, via_secondary_id: false };
        for index in self.slot_servos(id, hearing) {
            let outcome = self.execute(index, request, addressing, now);
            self.finish(index, &outcome, now);
        }
    }

    /// Fast Sync/Bulk Read: one packet, each listed servo adds its block in order. The chain
    /// stops at the first listed servo that is absent or silent, leaving the packet short of its
    /// LEN, as a real bus would (the SDK then reports a corrupt or timed-out reply).
    fn fast_read(&mut self, reads: &[(u8, u16, u16)], hearing: &[usize], now: Duration) -> Option<PendingReply> {
        let addressing = Addressing { broadcast: true, via_secondary_id: false };
        let Some(mut builder) = FastReplyBuilder::new(reads.iter().map(|&(_, _, len)| usize::from(len))) else {
            // Chosen: a combined reply too long for the LEN field is never started.
            debug!(devices = reads.len(), "Fast read reply would exceed the LEN field; no reply");
            return None;
        };
        let mut senders = Vec::new();
        for &(id, address, length) in reads {
            let Some(&index) = self.slot_servos(id, hearing).first() else { break };
            if self.servos[index].status_return_level() < 1 {
                break;
            }
            let outcome = self.execute(index, Request::Read { address, length }, addressing, now);
            let error = self.servos[index].status_error_byte(&outcome.reply);
            // A servo that cannot read still fills its slot so the packet keeps its length.
            let data = outcome.reply.unwrap_or_else(|_| vec![0; usize::from(length)]);
            builder.push_block(error, id, &data);
            senders.push(index);
        }
        let first = *senders.first()?;
        let ids = senders.iter().map(|&i| self.servos[i].id()).collect();
        Some(PendingReply { first_sender: first, from: ids, bytes: builder.into_bytes() })
    }

    fn execute(&mut self, index: usize, request: Request<'_>, addressing: Addressing, now: Duration) -> Outcome {
        let servo = &mut self.servos[index];
        servo.note_packet(now);
        let outcome = servo.handle(now, request, addressing);
        if let Err(error) = &outcome.reply {
            debug!(id = servo.id(), ?request, %error, "servo refused");
        }
        outcome
    }

    fn finish(&mut self, index: usize, outcome: &Outcome, now: Duration) {
        if let Some(after) = outcome.after_reply {
            self.servos[index].finish(now, after);
        }
    }

    /// Give each reply its slot on the wire. Replies from servos with the same ID land in the
    /// same slot and collide.
    fn schedule(&self, pending: Vec<PendingReply>, base: Duration, baud: u32) -> Vec<Reply> {
        let mut scheduled: Vec<Reply> = Vec::with_capacity(pending.len());
        let mut cursor = base;
        for reply in pending {
            if let Some(previous) = scheduled.last_mut()
                && reply.from.len() == 1
                && previous.from.len() == 1
                && previous.from[0] == reply.from[0]
            {
                warn!(id = reply.from[0], "two servos answered with the same ID: collision on the wire");
                wire::overlay(&mut previous.bytes, &reply.bytes);
                continue;
            }
            let (start, end) = match self.timing {
                Timing::Wire => {
                    let start = cursor + self.servos[reply.first_sender].return_delay();
                    (start, start + self.wire_time(reply.bytes.len(), baud))
                }
                Timing::Off => (base, base),
            };
            cursor = end;
            scheduled.push(Reply { bytes: reply.bytes, start, end, from: reply.from });
        }
        scheduled
    }
}

/// A reply before it has a slot on the wire.
struct PendingReply {
    first_sender: usize,
    from: Vec<u8>,
    bytes: Vec<u8>,
}

impl PendingReply {
    fn single(index: usize, id: u8, bytes: Vec<u8>) -> Self {
        Self { first_sender: index, from: vec![id], bytes }
    }
}

/// The per-servo request for a unicast (or plain broadcast) instruction.
fn unicast_request(instruction: &Instruction) -> Option<Request<'_>> {
    Some(match instruction {
        Instruction::Ping => Request::Ping,
        Instruction::Read { address, length } => Request::Read { address: *address, length: *length },
        Instruction::Write { address, data } => Request::Write { address: *address, data },
        Instruction::RegWrite { address, data } => Request::RegWrite { address: *address, data },
        Instruction::Action => Request::Action,
        Instruction::FactoryReset { option } => Request::FactoryReset { option: *option },
        Instruction::Reboot => Request::Reboot,
        Instruction::Clear { params } => Request::Clear { params },
        Instruction::ControlTableBackup { params } => Request::ControlTableBackup { params },
        Instruction::Unknown { code } => Request::Unknown { code: *code },
        _ => return None,
    })
}

/// Status Return Level (reference §6): 0 answers Ping only, 1 also the Read family, 2 everything.
fn replies_at_level(request: &Request<'_>, level: u8) -> bool {
    match request {
        Request::Ping => true,
        Request::Read { .. } => level >= 1,
        _ => level >= 2,
    }
}

/// Build the servos of a bus from one profile.
pub fn servos_from_profile(profile: &std::sync::Arc<FirmwareProfile>, ids: &[u8], baud_bps: u32, supply_voltage_v: f64) -> Result<Vec<Servo>, BusError> {
    let code = profile.baud_code(baud_bps).ok_or_else(|| BusError::UnsupportedBaud {
        bps: baud_bps,
        profile: profile.path.display().to_string(),
        offered: profile.baud_rates.iter().map(|b| b.bps.to_string()).collect::<Vec<_>>().join(", "),
    })?;
    Ok(ids.iter().map(|&id| Servo::new(std::sync::Arc::clone(profile), id, code, supply_voltage_v)).collect())
}
