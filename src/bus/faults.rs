//! Scheduled faults on the bus: the schedule, the bus-level faults themselves
//! (bit errors, dropped, late and missing replies), and the hand-off of servo and plant faults to
//! [`Servo`] and [`Plant`] at the firmware tick they start or end.
//!
//! Every random choice comes from one generator seeded by the scenario's seed, so a run replays
//! exactly. Without faults every hook here is a no-op and draws nothing.

use std::time::Duration;

use serde_json::{Value, json};
use tracing::{info, warn};

use crate::device::{Plant, Servo};
use crate::fault::{Fault, ScheduledFault, SplitMix64};

use super::{Bus, Reply};

/// A fault starting or ending.
#[derive(Debug, Clone, Copy)]
struct Transition {
    at: Duration,
    index: usize,
    start: bool,
}

/// What the bus-level faults did so far (for the time series and the summary).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FaultCounts {
    /// Instructions that bit errors corrupted (no servo executed them).
    pub instructions_corrupted: u64,
    /// Replies with at least one flipped bit.
    pub replies_corrupted: u64,
    /// Replies dropped by `drop_replies`.
    pub replies_dropped: u64,
    /// Replies delayed by `late_replies`.
    pub replies_delayed: u64,
    /// Instructions a `silent` servo did not hear.
    pub instructions_unheard: u64,
}

/// The faults of one bus: schedule, which are active, and the generator.
#[derive(Debug, Clone)]
pub struct BusFaults {
    faults: Vec<ScheduledFault>,
    active: Vec<bool>,
    transitions: Vec<Transition>,
    next: usize,
    seed: u64,
    rng: SplitMix64,
    /// Each servo's supply before any sag (captured when the schedule is installed).
    nominal_v: Vec<f64>,
    counts: FaultCounts,
}

impl Default for BusFaults {
    fn default() -> Self {
        Self::new(Vec::new(), 0)
    }
}

impl BusFaults {
    /// `faults` (already validated) with every random choice drawn from `seed`.
    pub fn new(faults: Vec<ScheduledFault>, seed: u64) -> Self {
        let mut transitions = Vec::new();
        for (index, f) in faults.iter().enumerate() {
            transitions.push(Transition { at: Duration::from_secs_f64(f.at_s), index, start: true });
            if let Some(until) = f.until_s {
                transitions.push(Transition { at: Duration::from_secs_f64(until), index, start: false });
            }
        }
        // Ends before starts at the same instant, so a fault can hand over to the next one.
        transitions.sort_by_key(|t| (t.at, t.start));
        let active = vec![false; faults.len()];
        Self { faults, active, transitions, next: 0, seed, rng: SplitMix64::new(seed ^ 0xFA17_5EED), nominal_v: Vec::new(), counts: FaultCounts::default() }
    }

    pub fn is_empty(&self) -> bool {
        self.faults.is_empty()
    }

    /// The whole schedule.
    pub fn scheduled(&self) -> &[ScheduledFault] {
        &self.faults
    }

    /// Whether each scheduled fault (in [`BusFaults::scheduled`] order) is acting now.
    pub fn acting(&self) -> &[bool] {
        &self.active
    }

    /// The faults acting now.
    pub fn active(&self) -> impl Iterator<Item = &ScheduledFault> {
        self.faults.iter().zip(&self.active).filter(|(_, on)| **on).map(|(f, _)| f)
    }

    pub fn counts(&self) -> FaultCounts {
        self.counts
    }

    /// The schedule and the counts, for `settings.json` / `summary.json`.
    pub fn to_json(&self) -> Value {
        json!({
            "scheduled": self.faults,
            "instructions_corrupted": self.counts.instructions_corrupted,
            "replies_corrupted": self.counts.replies_corrupted,
            "replies_dropped": self.counts.replies_dropped,
            "replies_delayed": self.counts.replies_delayed,
            "instructions_unheard": self.counts.instructions_unheard,
        })
    }

    fn active_faults(&self) -> impl Iterator<Item = &Fault> {
        self.active().map(|f| &f.fault)
    }

    /// The combined bit error rate of the active `bit_errors` faults.
    fn bit_error_rate(&self) -> f64 {
        1.0 - self.active_faults().fold(1.0, |pass, f| if let Fault::BitErrors { rate } = f { pass * (1.0 - rate) } else { pass })
    }

    /// Whether servo `id` is cut off the bus.
    pub(super) fn is_silent(&mut self, id: u8) -> bool {
        let silent = self.active_faults().any(|f| matches!(f, Fault::Silent { id: s } if *s == id));
        self.counts.instructions_unheard += u64::from(silent);
        silent
    }

    /// Whether bit errors corrupt an instruction of `wire_len` bytes. Every bit on the wire
    /// counts (start and stop bits too: a flipped one is a framing error). All servos hear the
    /// same corrupted bytes, and CRC-16 catches all errors of up to three bits and all but 2⁻¹⁶
    /// of the others, so a corrupted instruction is taken as dropped by every servo (reference
    /// §3: a packet whose CRC fails is discarded without a reply).
    pub(super) fn instruction_corrupted(&mut self, wire_len: usize, bits_per_byte: u32) -> bool {
        let rate = self.bit_error_rate();
        if rate <= 0.0 {
            return false;
        }
        let bits = (wire_len as f64) * f64::from(bits_per_byte);
        let corrupted = self.rng.next_f64() < 1.0 - (1.0 - rate).powf(bits);
        self.counts.instructions_corrupted += u64::from(corrupted);
        corrupted
    }

    /// Apply reply faults to one transaction's scheduled replies: drop, delay, flip bits.
    pub(super) fn on_replies(&mut self, replies: &mut Vec<Reply>) {
        if !self.active.iter().any(|&a| a) {
            return;
        }
        let single = |reply: &Reply| (reply.from.len() == 1).then(|| reply.from[0]);
        // Dropped: the servo executed the instruction but its packet never reaches the wire. A
        // Fast Sync/Bulk Read reply (several senders) is left whole (chosen simplification).
        let mut kept = Vec::with_capacity(replies.len());
        for reply in replies.drain(..) {
            let p = single(&reply).map_or(0.0, |id| self.drop_probability(id));
            if p > 0.0 && self.rng.next_f64() < p {
                self.counts.replies_dropped += 1;
                continue;
            }
            kept.push(reply);
        }
        *replies = kept;
        // Late: the reply and everything queued behind it on the half-duplex wire move later.
        let mut shift = Duration::ZERO;
        for reply in replies.iter_mut() {
            if let Some(delay) = reply.from.iter().map(|&id| self.delay(id)).max().filter(|d| !d.is_zero()) {
                shift += delay;
                self.counts.replies_delayed += 1;
            }
            reply.start += shift;
            reply.end += shift;
        }
        let rate = self.bit_error_rate();
        if rate > 0.0 {
            for reply in replies.iter_mut() {
                if flip_bits(&mut reply.bytes, rate, &mut self.rng) {
                    self.counts.replies_corrupted += 1;
                }
            }
        }
    }

    fn drop_probability(&self, id: u8) -> f64 {
        1.0 - self.active_faults().fold(1.0, |keep, f| match f {
            Fault::DropReplies { id: d, probability } if *d == id => keep * (1.0 - probability),
            _ => keep,
        })
    }

    fn delay(&self, id: u8) -> Duration {
        self.active_faults()
            .map(|f| match f {
                Fault::LateReplies { id: d, delay_ms } if *d == id => Duration::from_secs_f64(delay_ms / 1000.0),
                _ => Duration::ZERO,
            })
            .sum()
    }

    /// The next start or end at or before `until`.
    fn next_due(&self, until: Duration) -> Option<Duration> {
        self.transitions.get(self.next).map(|t| t.at).filter(|&at| at <= until)
    }

    /// Start or end every fault due at `at`.
    fn apply_due(&mut self, at: Duration, servos: &mut [Servo], plant: &mut dyn Plant) {
        if self.nominal_v.len() != servos.len() {
            self.nominal_v = servos.iter().map(Servo::supply_voltage).collect();
        }
        while let Some(&t) = self.transitions.get(self.next).filter(|t| t.at <= at) {
            self.next += 1;
            self.active[t.index] = t.start;
            let fault = self.faults[t.index].fault.clone();
            let _span = tracing::info_span!("fault", kind = fault.kind(), t_s = at.as_secs_f64()).entered();
            info!(start = t.start, ?fault, "fault {}", if t.start { "starts" } else { "ends" });
            match &fault {
                Fault::Overload { id } => {
                    for servo in servos.iter_mut().filter(|s| s.id() == *id) {
                        let bit = servo.profile().hardware_error_bits.overload;
                        servo.raise_hardware_error(1 << bit);
                    }
                }
                Fault::EncoderNoise { id, position_std_pulses, velocity_std } => {
                    let seed = SplitMix64::new(self.seed ^ (u64::from(*id) << 32) ^ t.index as u64).next_u64();
                    for servo in servos.iter_mut().filter(|s| s.id() == *id) {
                        servo.set_encoder_noise(t.start.then_some((*position_std_pulses, *velocity_std)), seed);
                    }
                }
                Fault::MagnetFailure { .. } | Fault::SlipPatch { .. } if !plant.inject_fault(t.index, &fault, t.start) => {
                    warn!(kind = fault.kind(), "this plant has no world: the fault has no effect");
                }
                _ => {}
            }
            self.refresh_supply_and_air(servos);
        }
    }

    /// Supply voltage (the lowest active sag) and ambient air (the hottest active overheating)
    /// of every servo, from the active faults: overlapping faults end cleanly.
    fn refresh_supply_and_air(&self, servos: &mut [Servo]) {
        for (servo, &nominal) in servos.iter_mut().zip(&self.nominal_v) {
            let id = servo.id();
            let mut volts = nominal;
            let mut ambient: Option<f64> = None;
            for fault in self.active_faults() {
                match *fault {
                    Fault::VoltageSag { id: target, volts: v } if target.is_none_or(|t| t == id) => volts = volts.min(v),
                    Fault::Overheating { id: target, ambient_c } if target == id => ambient = Some(ambient.map_or(ambient_c, |a: f64| a.max(ambient_c))),
                    _ => {}
                }
            }
            servo.set_supply_voltage(volts);
            servo.set_ambient_temperature(ambient);
        }
    }
}

/// Flip each data bit of `bytes` with probability `rate` (start and stop bits are not in the
/// byte: a framing error there is counted with the instruction, not modelled in replies). Draws
/// the gaps between flips from the geometric distribution, so a low rate costs one draw per reply.
fn flip_bits(bytes: &mut [u8], rate: f64, rng: &mut SplitMix64) -> bool {
    let total = bytes.len() * 8;
    let mut flipped = false;
    let mut position = 0usize;
    loop {
        let gap = if rate >= 1.0 { 0 } else { ((1.0 - rng.next_f64()).ln() / (1.0 - rate).ln()).floor() as usize };
        position = position.saturating_add(gap);
        if position >= total {
            return flipped;
        }
        bytes[position / 8] ^= 1 << (position % 8);
        flipped = true;
        position += 1;
    }
}

impl Bus {
    /// Install a fault schedule (replacing any). Servo and plant faults take effect at the firmware
    /// tick they are due; bus faults on the packets handled from then on.
    pub fn set_faults(&mut self, faults: BusFaults) {
        self.faults = faults;
    }

    pub fn faults(&self) -> &BusFaults {
        &self.faults
    }

    /// Advance the plant to each fault start or end up to `until` and apply it there.
    pub(super) fn apply_faults_until(&mut self, until: Duration) {
        while let Some(at) = self.faults.next_due(until) {
            self.plant.advance(&mut self.servos, at);
            self.faults.apply_due(at, &mut self.servos, self.plant.as_mut());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flip_bits_hits_the_rate() {
        let mut rng = SplitMix64::new(1);
        let mut bytes = vec![0u8; 100_000];
        flip_bits(&mut bytes, 1e-3, &mut rng);
        let ones: u32 = bytes.iter().map(|b| b.count_ones()).sum();
        assert!((700..1300).contains(&ones), "{ones} flips in 800000 bits at 1e-3");
        let mut all = vec![0u8; 4];
        flip_bits(&mut all, 1.0, &mut rng);
        assert_eq!(all, [0xFF; 4]);
    }
}
