//! One controller's session on a byte stream ([`serve_stream`]): bytes in, packets framed,
//! transactions on the bus, replies out at their due time (a timer, then a spin); the same for
//! every transport.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tracing::{Instrument, debug, info_span, trace};

use crate::bus::{Bus, Reply, Timing, Transaction, wire};
use crate::protocol::{DEFAULT_MAX_LEN, Decoder, FrameError, RawPacket};
use crate::virtual_time::PortLedger;

use super::stats::{Answered, LineStats};
use super::{AdapterModel, BusHandle, Clock, LineSettings, TransportError};

/// The timer wheel has 1 ms resolution: sleep to this much before a deadline, spin the rest.
const SPIN_MARGIN: Duration = Duration::from_micros(1500);
/// With a precise timer (a transport's own `wait_for_controller`), the spin that absorbs its
/// wake-up latency.
const FINAL_SPIN: Duration = Duration::from_micros(200);

/// Sleep until `deadline` with microsecond precision: the timer wheel gets us close, a spin
/// finishes the job.
pub async fn sleep_until_precise(deadline: Instant) {
    let now = Instant::now();
    if deadline > now + SPIN_MARGIN {
        tokio::time::sleep_until((deadline - SPIN_MARGIN).into()).await;
    }
    while Instant::now() < deadline {
        std::hint::spin_loop();
    }
}

/// Serve one controller connection until it closes: decode instructions, hand them to the bus,
/// write the replies when the wire model says they have arrived. While a reply is still on the
/// (modelled) half-duplex wire the line is watched: bytes the controller sends then collide
/// with it, and both arrive corrupted, as on hardware.
pub async fn serve_stream<S>(stream: S, handle: Arc<BusHandle>, line: &dyn LineSettings) -> Result<(), TransportError>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    serve_stream_through(stream, handle, line, None).await
}

/// [`serve_stream`] with the controller behind a modelled USB adapter (see [`adapter`]).
pub async fn serve_stream_through<S>(stream: S, handle: Arc<BusHandle>, line: &dyn LineSettings, adapter: Option<AdapterModel>) -> Result<(), TransportError>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let (servos_gap, timing) = handle.with_bus(|bus| (bus.inter_byte_timeout(), bus.timing()));
    // A line's own timeout (TCP's) is wall time, for wall-clock causes (delayed ACKs, an
    // emulator's UART); the session's gaps are simulated time, N x the wall at --speed N.
    let gap = line.inter_byte_timeout().map_or(servos_gap, |wall| wall.mul_f64(handle.clock().speed()));
    let mut session = Session {
        stream,
        clock: handle.clock(),
        handle: Arc::clone(&handle),
        line,
        timing,
        gap,
        decoder: Decoder::new(gap, DEFAULT_MAX_LEN),
        buf: vec![0u8; 4096],
        out: Vec::new(),
        decoded: VecDeque::new(),
        last_reply_lens: Vec::new(),
        replies_since_unread_check: false,
        baud: line.baud(),
        controller_tx_free_at: Duration::ZERO,
        physical_wire: line.physical_wire(),
        servo_bauds: Vec::new(),
        adapter,
        ahead: None,
    };
    if session.physical_wire {
        session.servo_bauds = session.handle.with_bus(servo_bauds);
    }
    session.run().await
}

/// One controller connection.
struct Session<'a, S> {
    stream: S,
    handle: Arc<BusHandle>,
    clock: Clock,
    line: &'a dyn LineSettings,
    timing: Timing,
    gap: Duration,
    decoder: Decoder,
    buf: Vec<u8>,
    /// Reply bytes gathered for one write (when there is no wire timing to follow).
    out: Vec<u8>,
    /// Framed packets (or framing errors) not handled yet, with when their bytes arrived.
    decoded: VecDeque<(Result<RawPacket, FrameError>, Duration)>,
    /// Lengths of the replies last delivered, to count unread ones.
    last_reply_lens: Vec<usize>,
    /// Replies were handed over since [`Session::count_unread`] last looked.
    replies_since_unread_check: bool,
    /// The controller's baud, read when its bytes arrive (once per read, not per packet: the
    /// packets of one read were all sent before it).
    baud: Option<u32>,
    /// When the controller's own transmitter has shifted out everything it was given: a UART
    /// sends a second packet only after the first, however soon the program wrote it.
    controller_tx_free_at: Duration,
    /// The line is a real wire (see [`LineSettings::physical_wire`]).
    physical_wire: bool,
    /// Each servo's baud after the last transaction, on a physical wire (whose device follows).
    servo_bauds: Vec<(u8, Option<u32>)>,
    /// The USB adapter in front of the controller (`--adapter`), if not an ideal one.
    adapter: Option<AdapterModel>,
    /// Under virtual time: the last transaction's replies, written ahead of their time.
    ahead: Option<Ahead>,
}

/// Bytes of one reply handed to the controller at `due`.
struct HandOver {
    due: Duration,
    reply: usize,
    bytes: std::ops::Range<usize>,
}

/// Replies written to the port before they are due, each hand-over shown by the shim at its
/// instant (see [`Session::deliver_ahead`]). Until the last is due, bytes the controller sends
/// may still collide with those on their way.
struct Ahead {
    replies: Vec<Reply>,
    /// Each hand-over with its offset in the port's stream.
    plan: Vec<(u64, HandOver)>,
    last_due: Duration,
}

fn servo_bauds(bus: &mut Bus) -> Vec<(u8, Option<u32>)> {
    bus.servos().iter().map(|servo| (servo.id(), servo.baud_bps())).collect()
}

impl<S: AsyncRead + AsyncWrite + Unpin> Session<'_, S> {
    async fn run(&mut self) -> Result<(), TransportError> {
        loop {
            // A partial packet waits for at most the inter-byte gap: if the line stays quiet that
            // long, drop it (and find any packet that was hidden behind a false header).
            let read = if self.decoder.pending() > 0 {
                match self.clock.virtual_port() {
                    Some(port) => {
                        let quiet = port.timer(self.clock.now() + self.gap);
                        tokio::select! {
                            biased;
                            read = self.stream.read(&mut self.buf) => Some(read),
                            () = quiet => None,
                        }
                    }
                    None => tokio::time::timeout(self.clock.wall(self.gap), self.stream.read(&mut self.buf)).await.ok(),
                }
            } else {
                Some(self.stream.read(&mut self.buf).await)
            };
            let now = self.clock.now();
            match read {
                // Counted where the decoder drops the partial packet (in `handle_decoded`).
                None => {
                    let flushed = self.decoder.flush();
                    self.decoded.extend(flushed.into_iter().map(|r| (r, now)));
                }
                Some(read) => match read? {
                    0 => return Ok(()),
                    n if self.ahead_still_due(now) => self.early_bytes_ahead(n),
                    n => {
                        self.line.read_done();
                        self.baud = self.line.baud();
                        let framed = self.decoder.push(now, &self.buf[..n]);
                        self.decoded.extend(framed.into_iter().map(|r| (r, now)));
                    }
                },
            }
            if self.handle_decoded().await? {
                return Ok(());
            }
        }
    }

    /// Handle every framed packet in order; true if the controller closed meanwhile.
    async fn handle_decoded(&mut self) -> Result<bool, TransportError> {
        while let Some((result, at)) = self.decoded.pop_front() {
            match result {
                Ok(packet) => {
                    self.count_unread();
                    let span = info_span!("packet", id = packet.id, instruction = packet.instruction);
                    let transaction = span.in_scope(|| self.handle.handle(packet, at, self.baud, self.physical_wire));
                    self.controller_tx_free_at = self.controller_tx_free_at.max(transaction.instruction_end);
                    if self.deliver(transaction).instrument(span).await? {
                        return Ok(true);
                    }
                    if self.physical_wire {
                        self.follow_baud_changes();
                    }
                }
                // A bad CRC gets no reply (no error 0x03): ROBOTIS's own slave code drops such
                // packets; unverified on XM firmware (reference §7), listed in docs/serve-and-bus.md.
                Err(error) => {
                    // A packet cut by a quiet line is both: lost to framing, and by a gap.
                    if let FrameError::InterByteTimeout(_) = error {
                        self.handle.with_stats(LineStats::inter_byte_gap);
                    }
                    self.handle.with_stats(LineStats::frame_error);
                    log_frame_error(&error);
                }
            }
        }
        Ok(false)
    }

    /// A servo switches its baud after its reply: so does a device, once the reply is out.
    fn follow_baud_changes(&mut self) {
        let now = self.handle.with_bus(servo_bauds);
        if now != self.servo_bauds {
            self.line.servo_bauds_changed(&now);
            self.servo_bauds = now;
            self.baud = self.line.baud();
        }
    }

    /// A request while earlier replies sit unread: the controller moved on without them.
    fn count_unread(&mut self) {
        // Nothing written since the last look: nothing new can be unread (and the ioctl is saved).
        if !std::mem::take(&mut self.replies_since_unread_check) {
            return;
        }
        // Under virtual time replies still on their way sit in the pty too: only visible ones count.
        let unread = match self.clock.virtual_port() {
            Some(port) => Some(port.unread_visible()),
            None => self.line.unread_by_controller(),
        };
        let Some(bytes) = unread.filter(|&b| b > 0) else { return };
        let mut left = bytes;
        let mut replies = 0;
        for &len in self.last_reply_lens.iter().rev() {
            if left == 0 {
                break;
            }
            replies += 1;
            left = left.saturating_sub(len);
        }
        self.handle.with_stats(|stats| stats.unread(replies.max(1), bytes as u64));
        debug!(bytes, "request sent while earlier replies were unread");
    }

    /// Hand the transaction's replies over when the wire model says they have arrived, watching
    /// for bytes the controller sends meanwhile. True if the controller closed.
    async fn deliver(&mut self, mut transaction: Transaction) -> Result<bool, TransportError> {
        let mut replies = std::mem::take(&mut transaction.replies);
        if replies.is_empty() {
            return Ok(false);
        }
        // On a physical wire collisions happen on the wire itself, not in a model.
        let modelled_wire = self.timing == Timing::Wire && !self.physical_wire;
        if modelled_wire {
            self.collide_queued(&mut replies);
        }
        let byte_time = transaction.byte_time;
        let plan = self.hand_over_plan(&replies, byte_time);
        if self.timing == Timing::Wire
            && let Some(port) = self.clock.virtual_port().cloned()
            && port.holds_room_for(plan.len())
        {
            return self.deliver_ahead(&port, &transaction, replies, plan).await;
        }
        let mut closed = false;
        let (last_reply, last_due) = plan.last().map_or((0, Duration::ZERO), |h| (h.reply, h.due));
        for (index, hand_over) in plan.iter().enumerate() {
            if self.timing == Timing::Wire {
                closed |= self.wait_watching(&mut replies[hand_over.reply..], hand_over.due).await?;
            }
            if index == plan.len() - 1 {
                // Counted just before the hand-over (a write to the kernel takes microseconds):
                // once written, the controller may act on it, even end the session.
                self.count_answer(&transaction, &replies, self.clock.now(), last_reply, last_due);
            }
            let reply = &replies[hand_over.reply];
            let bytes = &reply.bytes[hand_over.bytes.clone()];
            if self.timing == Timing::Wire || !self.line.batches_replies() {
                self.stream.write_all(bytes).await?;
            } else {
                // Nothing to wait for between them: one write for all the replies. Each write to a
                // pty wakes the kernel's flush worker and then the reader; a Sync Read's eight
                // replies written one by one cost eight (measured: docs/performance.md, loop rate).
                self.out.extend_from_slice(bytes);
            }
            trace!(from = ?reply.from, bytes = hand_over.bytes.len(), "reply bytes handed over");
        }
        if !self.out.is_empty() {
            let written = self.stream.write_all(&self.out).await;
            self.out.clear();
            written?;
        }
        self.stream.flush().await?;
        Ok(closed)
    }

    /// The transaction's replies handed over, the last at `at` (due at `last_due`).
    fn count_answer(&mut self, transaction: &Transaction, replies: &[Reply], at: Duration, last_reply: usize, last_due: Duration) {
        let byte_time = transaction.byte_time;
        let name = transaction.instruction.as_ref().map_or("Malformed", |i| i.name());
        let (latency, late) = (at.saturating_sub(transaction.received_at), at.saturating_sub(last_due));
        let replies_wire = byte_time * replies.iter().map(|r| r.bytes.len() as u32).sum::<u32>();
        // Handed over at its start on a physical wire, its bytes still have to cross it.
        let complete = if self.physical_wire { latency + byte_time * replies[last_reply].bytes.len() as u32 } else { latency };
        let answer = Answered { instruction: name, replies: replies.len(), latency, late, at, complete, replies_wire };
        self.handle.with_stats(|stats| stats.answered(answer));
        self.last_reply_lens = replies.iter().map(|r| r.bytes.len()).collect();
        self.replies_since_unread_check = true;
    }

    /// Under virtual time: write every reply now, in one write, each hand-over marked with its
    /// instant; the shim shows each byte only from then on (src/virtual_time/port.rs). Exact as
    /// the timed writes, without a hand-over between climbsim and the controller per reply.
    async fn deliver_ahead(&mut self, port: &Arc<PortLedger>, transaction: &Transaction, replies: Vec<Reply>, plan: Vec<HandOver>) -> Result<bool, TransportError> {
        let (last_reply, last_due) = plan.last().map_or((0, Duration::ZERO), |h| (h.reply, h.due));
        self.count_answer(transaction, &replies, last_due.max(self.clock.now()), last_reply, last_due);
        let base = port.written_total();
        let mut offset = base;
        let mut runs = Vec::with_capacity(plan.len());
        let mut out = std::mem::take(&mut self.out);
        out.clear();
        for hand_over in &plan {
            runs.push((offset, hand_over.due));
            let bytes = &replies[hand_over.reply].bytes[hand_over.bytes.clone()];
            out.extend_from_slice(bytes);
            offset += bytes.len() as u64;
            trace!(from = ?replies[hand_over.reply].from, bytes = bytes.len(), due = ?hand_over.due, "reply bytes written ahead");
        }
        port.hold_bytes(&runs);
        let written = self.stream.write_all(&out).await;
        out.clear();
        self.out = out;
        written?;
        self.stream.flush().await?;
        let plan = runs.into_iter().map(|(start, _)| start).zip(plan).collect();
        self.ahead = Some(Ahead { replies, plan, last_due });
        Ok(false)
    }

    /// Replies written ahead are still on their way at `now`.
    fn ahead_still_due(&mut self, now: Duration) -> bool {
        if self.ahead.as_ref().is_some_and(|ahead| now >= ahead.last_due) {
            self.ahead = None;
        }
        self.ahead.is_some()
    }

    /// `n` bytes arrived while replies written ahead were still on their way: as
    /// [`Session::early_bytes`], and what the collision changed of the replies not shown yet is
    /// written again.
    fn early_bytes_ahead(&mut self, n: usize) {
        let at = self.clock.now();
        let (Some(mut ahead), Some(port)) = (self.ahead.take(), self.clock.virtual_port().cloned()) else {
            self.early_bytes(n, &mut []);
            return;
        };
        let first = ahead.plan.iter().position(|(_, h)| h.due > at).unwrap_or(ahead.plan.len());
        let first_reply = ahead.plan.get(first).map_or(ahead.replies.len(), |(_, h)| h.reply);
        let before: Vec<Vec<u8>> = ahead.replies[first_reply..].iter().map(|r| r.bytes.clone()).collect();
        self.early_bytes(n, &mut ahead.replies[first_reply..]);
        let changed = ahead.replies[first_reply..].iter().zip(&before).any(|(reply, was)| reply.bytes != *was);
        if changed && let Some(&(start, _)) = ahead.plan.get(first) {
            let rest: Vec<u8> = ahead.plan[first..].iter().flat_map(|(_, h)| ahead.replies[h.reply].bytes[h.bytes.clone()].iter().copied()).collect();
            port.rewrite_held_bytes(start, &rest);
        }
        self.ahead = Some(ahead);
    }

    /// When each part of the replies goes to the controller. A modelled wire hands a reply over
    /// when its last byte has arrived; a physical one needs it written when its first byte
    /// starts; an adapter model hands bytes over as the adapter would pass them to the host.
    fn hand_over_plan(&mut self, replies: &[Reply], byte_time: Duration) -> Vec<HandOver> {
        let whole = |(reply, r): (usize, &Reply)| HandOver { due: if self.physical_wire { r.start } else { r.end }, reply, bytes: 0..r.bytes.len() };
        let Some(adapter) = self.adapter.as_mut().filter(|_| self.timing == Timing::Wire && !self.physical_wire) else {
            return replies.iter().enumerate().map(whole).collect();
        };
        let mut arrivals = Vec::with_capacity(replies.iter().map(|r| r.bytes.len()).sum());
        let mut owner = Vec::with_capacity(arrivals.capacity());
        for (index, reply) in replies.iter().enumerate() {
            for byte in 0..reply.bytes.len() {
                arrivals.push(reply.start + byte_time * (byte as u32 + 1));
                owner.push((index, byte));
            }
        }
        // Each adapter packet, split where it spans two replies.
        let mut plan = Vec::new();
        let mut next = 0;
        for (due, count) in adapter.deliver(&arrivals) {
            let end = next + count;
            while next < end {
                let (reply, first) = owner[next];
                let in_reply = (replies[reply].bytes.len() - first).min(end - next);
                plan.push(HandOver { due, reply, bytes: first..first + in_reply });
                next += in_reply;
            }
        }
        plan
    }

    /// Wait until `due`, reading whatever the controller sends meanwhile: bytes that overlap
    /// `undelivered` replies on the wire collide with them. True if the controller closed.
    async fn wait_watching(&mut self, undelivered: &mut [Reply], due: Duration) -> Result<bool, TransportError> {
        if let Some(port) = self.clock.virtual_port().cloned() {
            return self.wait_watching_virtual(&port, undelivered, due).await;
        }
        loop {
            let now = self.clock.now();
            if now >= due {
                return Ok(false);
            }
            let remaining = due - now;
            // The spin margins are wall-clock time (they absorb wake-up latency); `remaining` is
            // simulated time.
            let remaining = self.clock.wall(remaining);
            // Faster than real time the pace tolerance is in simulated milliseconds, far coarser on
            // the wall clock than a timer's wake-up latency; spinning there would only take the
            // core the controller needs (eight replies of a Sync Read spun 1.6 ms of every 4 ms
            // loop at 5x).
            let final_spin = if self.clock.speed() > 1.0 { Duration::ZERO } else { FINAL_SPIN };
            let precise_wait = if remaining > final_spin { self.line.wait_for_controller(remaining - final_spin) } else { None };
            let read = if let Some(ready) = precise_wait {
                if ready { Some(self.stream.read(&mut self.buf).await?) } else { None }
            } else if remaining > SPIN_MARGIN {
                let wake = self.clock.instant(due) - SPIN_MARGIN;
                tokio::select! {
                    _ = tokio::time::sleep_until(wake.into()) => None,
                    read = self.stream.read(&mut self.buf) => Some(read?),
                }
            } else {
                match self.line.waiting_from_controller() {
                    Some(0) => {
                        std::hint::spin_loop();
                        None
                    }
                    Some(_) => Some(self.stream.read(&mut self.buf).await?),
                    // No cheap readiness check: poll the stream once without waiting.
                    None => tokio::time::timeout(Duration::ZERO, self.stream.read(&mut self.buf)).await.ok().transpose()?,
                }
            };
            match read {
                None => {}
                Some(0) => return Ok(true),
                Some(n) => self.early_bytes(n, undelivered),
            }
        }
    }

    /// [`Session::wait_watching`] under virtual time: the scheduler fires the timer at `due`
    /// exactly, with the controller parked; whatever it sends before then is read at its
    /// simulated instant (no spin, no wake-up margin).
    async fn wait_watching_virtual(&mut self, port: &Arc<PortLedger>, undelivered: &mut [Reply], due: Duration) -> Result<bool, TransportError> {
        while self.clock.now() < due {
            let reached = port.timer(due);
            let read = tokio::select! {
                biased;
                read = self.stream.read(&mut self.buf) => Some(read?),
                () = reached => None,
            };
            match read {
                None => {}
                Some(0) => return Ok(true),
                Some(n) => self.early_bytes(n, undelivered),
            }
        }
        Ok(false)
    }

    /// Packets that arrived in the same read as the one just handled were written before its
    /// replies came back: on the wire they follow it out of the controller's transmitter and
    /// may meet the replies. Those that do are corrupted and framed again.
    fn collide_queued(&mut self, replies: &mut [Reply]) {
        let mut reframed = VecDeque::with_capacity(self.decoded.len());
        while let Some((result, at)) = self.decoded.pop_front() {
            let Ok(packet) = result else {
                reframed.push_back((result, at));
                continue;
            };
            let mut bytes = packet.bytes.clone();
            if self.put_on_wire(&mut bytes, at, replies) == 0 {
                reframed.push_back((Ok(packet), at));
                continue;
            }
            let mut decoder = Decoder::new(self.gap, DEFAULT_MAX_LEN);
            let mut framed = decoder.push(at, &bytes);
            framed.extend(decoder.flush());
            // What a collision left of the packet is garbage on the wire, not a gap in it: the
            // flush's "interrupted by an inter-byte gap" is the collision's, counted as such.
            let framed = framed.into_iter().map(|r| match r {
                Err(FrameError::InterByteTimeout(n)) => Err(FrameError::Garbage(n)),
                other => other,
            });
            reframed.extend(framed.map(|r| (r, at)));
        }
        self.decoded = reframed;
    }

    /// `n` bytes in the buffer arrived while replies were still due.
    fn early_bytes(&mut self, n: usize, undelivered: &mut [Reply]) {
        let at = self.clock.now();
        self.baud = self.line.baud();
        // A copy: rare (only a controller that does not wait), and `put_on_wire` needs `self`.
        let mut sent = self.buf[..n].to_vec();
        if !self.physical_wire {
            self.put_on_wire(&mut sent, at, undelivered);
        }
        let framed = self.decoder.push(at, &sent);
        self.decoded.extend(framed.into_iter().map(|r| (r, at)));
    }

    /// The controller wrote `bytes` at `at`: its transmitter sends them once it has sent what it
    /// was given before; where they meet `replies` on the wire both are corrupted. Returns how
    /// many byte pairs collided.
    fn put_on_wire(&mut self, bytes: &mut [u8], at: Duration, replies: &mut [Reply]) -> usize {
        let byte_time = self.handle.with_bus(|bus| bus.byte_time(self.baud));
        let on_wire = at.max(self.controller_tx_free_at);
        self.controller_tx_free_at = on_wire + byte_time * bytes.len() as u32;
        let collided = wire::collide_in_time(bytes, on_wire, replies, byte_time);
        if collided > 0 {
            self.handle.with_stats(|stats| stats.collision(collided));
            debug!(bytes = bytes.len(), collided, "controller sent while a reply was on the wire: both corrupted");
        }
        collided
    }
}

fn log_frame_error(error: &FrameError) {
    match error {
        FrameError::Garbage(_) => trace!(%error, "framing"),
        _ => debug!(%error, "framing"),
    }
}
