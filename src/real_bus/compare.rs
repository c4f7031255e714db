//! The real servos against the world, register by register: what each read reply of a real
//! session says next to what the world answered to the same read at the same instant, and how
//! far apart they are (bias, RMS, largest difference, and the lag that best lines them up).
//! Sans-IO: `runner::compare` re-enacts the session and feeds the pairs here.

use std::collections::{BTreeMap, BTreeSet};

use serde::Serialize;

use crate::device::{FirmwareProfile, decode_item};
use crate::protocol::{BROADCAST_ID, Instruction, RawPacket};

/// The largest shift (in samples, each way) tried when looking for the lag.
const MAX_LAG_SAMPLES: usize = 25;

/// One register of one servo over the session, in its unit (the profile's scale applied).
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterSeries {
    pub id: u8,
    pub key: String,
    pub unit: Option<String>,
    /// (time of the real reply in s, real value, simulated value).
    pub samples: Vec<(f64, f64, f64)>,
}

/// How far the world is from the robot in one register.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RegisterStats {
    pub id: u8,
    pub key: String,
    pub unit: Option<String>,
    pub samples: usize,
    /// Mean of simulated − real.
    pub bias: f64,
    pub rms: f64,
    pub max_abs: f64,
    /// The shift of the simulated series that fits the real one best (ms; > 0: the world lags
    /// the robot), within ±25 samples.
    pub lag_ms: f64,
    /// The real signal's span (max − min): what the relative tolerance is a fraction of.
    pub real_span: f64,
    /// The RMS allowed, and whether it held.
    pub tolerance: f64,
    pub passed: bool,
}

/// What a register may differ by: `abs` per key (`present_velocity`, or `3.present_velocity`
/// for one servo) in the register's unit, else `rel` × the real signal's span, and never less
/// than two steps of the register.
#[derive(Debug, Clone, PartialEq)]
pub struct Tolerances {
    pub abs: BTreeMap<String, f64>,
    pub rel: f64,
}

impl Default for Tolerances {
    fn default() -> Self {
        Self { abs: BTreeMap::new(), rel: 0.05 }
    }
}

impl Tolerances {
    fn for_register(&self, id: u8, key: &str, real_span: f64, step: f64) -> f64 {
        self.abs.get(&format!("{id}.{key}")).or_else(|| self.abs.get(key)).copied().unwrap_or((self.rel * real_span).max(2.0 * step))
    }
}

/// Which registers each reply to `instruction` carries: (servo, first address, length). A Fast
/// Sync or Bulk Read's one combined reply carries them all, in this order ([`fast_blocks`]).
pub fn read_spans(packet: &RawPacket) -> Vec<(u8, u16, u16)> {
    match Instruction::parse(packet.instruction, &packet.params) {
        Ok(Instruction::Read { address, length }) if packet.id != BROADCAST_ID => vec![(packet.id, address, length)],
        Ok(Instruction::SyncRead { address, length, ids } | Instruction::FastSyncRead { address, length, ids }) => ids.into_iter().map(|id| (id, address, length)).collect(),
        Ok(Instruction::BulkRead { entries } | Instruction::FastBulkRead { entries }) => entries.into_iter().map(|e| (e.id, e.address, e.length)).collect(),
        _ => Vec::new(),
    }
}

/// Whether `instruction` is answered by one combined status packet (Fast Sync/Bulk Read).
pub fn is_fast_read(instruction: &RawPacket) -> bool {
    matches!(Instruction::parse(instruction.instruction, &instruction.params), Ok(Instruction::FastSyncRead { .. } | Instruction::FastBulkRead { .. }))
}

/// A Fast Sync/Bulk Read's combined reply split per servo: (ID, first address, data) for each
/// block whose error byte is clear, in the order of `spans` ([`read_spans`] of the
/// instruction). Per block the reply holds its error byte, the servo's ID, the data and, except
/// after the last, a CRC (the e-manual's Fast Sync Read); a servo that stopped answering ends
/// the packet early, so only whole blocks are returned, and a block whose ID is not the one
/// expected there ends the split.
pub fn fast_blocks<'a>(status: &'a RawPacket, spans: &[(u8, u16, u16)]) -> Vec<(u8, u16, &'a [u8])> {
    let mut out = Vec::new();
    let mut rest = status.params.as_slice();
    for (index, &(id, address, length)) in spans.iter().enumerate() {
        let length = usize::from(length);
        let Some((&[error, block_id], after)) = rest.split_first_chunk::<2>() else { break };
        if block_id != id || after.len() < length {
            break;
        }
        if error & !crate::protocol::ALERT_BIT == 0 {
            out.push((id, address, &after[..length]));
        }
        let crc = if index + 1 < spans.len() { 2 } else { 0 };
        rest = after.get(length + crc..).unwrap_or_default();
    }
    out
}

/// The whole items in `data`, read from `address` on: (item index, raw value).
pub fn items_in(profile: &FirmwareProfile, address: u16, data: &[u8]) -> Vec<(usize, i64)> {
    let mut out = Vec::new();
    let mut offset = 0usize;
    while offset < data.len() {
        let at = address.saturating_add(offset as u16);
        match profile.item_index_at(at).map(|index| (index, &profile.items[index])) {
            Some((index, item)) if item.address() == at && offset + item.size() <= data.len() => {
                out.push((index, decode_item(&data[offset..offset + item.size()], item.spec.signed)));
                offset += item.size();
            }
            _ => offset += 1,
        }
    }
    out
}

/// The whole items in `data` by key, read from `address` on: (key, raw value).
pub fn registers_in<'p>(profile: &'p FirmwareProfile, address: u16, data: &[u8]) -> Vec<(&'p str, i64)> {
    items_in(profile, address, data).into_iter().map(|(index, value)| (profile.items[index].spec.key.as_str(), value)).collect()
}

/// The register whose value [`Comparison::new`]'s servos count from the session's start.
const POSITION: &str = "present_position";

/// Gathers the pairs of a session, register by register.
#[derive(Debug, Default)]
pub struct Comparison {
    series: BTreeMap<(u8, usize), RegisterSeries>,
    /// Servos whose Present Position each side counts from its own first reading.
    position_from_start: BTreeSet<u8>,
    /// Those servos' first readings: (real, world).
    origins: BTreeMap<u8, (f64, f64)>,
}

impl Comparison {
    /// `position_from_start`: servos whose Present Position is compared as the distance turned
    /// since the session's first reading, on each side. A wheel's absolute position says where
    /// its shaft happened to be when the servo was powered (and how far the robot rolled before
    /// the session: down a wall, with the torque off), which the world cannot know; a magnet
    /// shaft's is its angle, and is compared as it is.
    pub fn new(position_from_start: impl IntoIterator<Item = u8>) -> Self {
        Self { position_from_start: position_from_start.into_iter().collect(), ..Self::default() }
    }

    /// A real reply's data and the world's to the same read of `address` from servo `id`.
    pub fn add(&mut self, profile: &FirmwareProfile, id: u8, address: u16, t_s: f64, real: &[u8], sim: &[u8]) {
        let simulated: BTreeMap<usize, i64> = items_in(profile, address, sim).into_iter().collect();
        for (index, real_value) in items_in(profile, address, real) {
            let Some(sim_value) = simulated.get(&index) else { continue };
            let spec = &profile.items[index].spec;
            let scale = spec.scale.unwrap_or(1.0);
            let (mut real, mut sim) = (real_value as f64 * scale, *sim_value as f64 * scale);
            if spec.key == POSITION && self.position_from_start.contains(&id) {
                let (real_origin, sim_origin) = *self.origins.entry(id).or_insert((real, sim));
                (real, sim) = (real - real_origin, sim - sim_origin);
            }
            let series = self.series.entry((id, index)).or_insert_with(|| RegisterSeries { id, key: spec.key.clone(), unit: spec.unit.clone(), samples: Vec::new() });
            series.samples.push((t_s, real, sim));
        }
    }

    pub fn series(&self) -> impl Iterator<Item = &RegisterSeries> {
        self.series.values()
    }

    /// Each register's statistics against `tolerances`; `steps` gives a register's step (its
    /// scale) by key.
    pub fn stats(&self, profile: &FirmwareProfile, tolerances: &Tolerances) -> Vec<RegisterStats> {
        self.series
            .iter()
            .map(|((_, index), series)| {
                let step = profile.items[*index].spec.scale.unwrap_or(1.0).abs();
                stats_of(series, tolerances, step)
            })
            .collect()
    }
}

fn stats_of(series: &RegisterSeries, tolerances: &Tolerances, step: f64) -> RegisterStats {
    let samples = &series.samples;
    let n = samples.len().max(1) as f64;
    let diffs: Vec<f64> = samples.iter().map(|(_, real, sim)| sim - real).collect();
    let bias = diffs.iter().sum::<f64>() / n;
    let rms = (diffs.iter().map(|d| d * d).sum::<f64>() / n).sqrt();
    let max_abs = diffs.iter().fold(0.0f64, |m, d| m.max(d.abs()));
    let (lo, hi) = samples.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (_, real, _)| (lo.min(*real), hi.max(*real)));
    let real_span = if samples.is_empty() { 0.0 } else { hi - lo };
    let tolerance = tolerances.for_register(series.id, &series.key, real_span, step);
    RegisterStats {
        id: series.id,
        key: series.key.clone(),
        unit: series.unit.clone(),
        samples: samples.len(),
        bias,
        rms,
        max_abs,
        lag_ms: lag_ms(samples),
        real_span,
        tolerance,
        passed: rms <= tolerance,
    }
}

/// The shift of the simulated series (in samples, ±[`MAX_LAG_SAMPLES`]) with the smallest RMS
/// against the real one, as milliseconds at the median sample interval.
fn lag_ms(samples: &[(f64, f64, f64)]) -> f64 {
    if samples.len() < 3 {
        return 0.0;
    }
    let max = MAX_LAG_SAMPLES.min(samples.len() / 2) as isize;
    let mut best = (f64::INFINITY, 0isize);
    for shift in -max..=max {
        let pairs = (0..samples.len() as isize).filter_map(|i| {
            let j = i + shift;
            (j >= 0 && (j as usize) < samples.len()).then(|| samples[j as usize].2 - samples[i as usize].1)
        });
        let (sum, count) = pairs.fold((0.0, 0usize), |(s, c), d| (s + d * d, c + 1));
        let rms = (sum / count.max(1) as f64).sqrt();
        // Ties go to the smaller shift: a flat signal has no lag.
        if rms < best.0 - 1e-12 || (rms <= best.0 + 1e-12 && shift.abs() < best.1.abs()) {
            best = (rms, shift);
        }
    }
    let mut intervals: Vec<f64> = samples.windows(2).map(|w| w[1].0 - w[0].0).collect();
    intervals.sort_by(f64::total_cmp);
    best.1 as f64 * intervals[intervals.len() / 2] * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::encode_instruction;
    use crate::protocol::{Decoder, RawPacket};
    use std::time::Duration;

    fn profile() -> FirmwareProfile {
        FirmwareProfile::load(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profiles/xm540-w270-r.toml")).expect("the shipped profile")
    }

    fn packet(bytes: &[u8]) -> RawPacket {
        Decoder::default().push(Duration::ZERO, bytes).remove(0).expect("one packet")
    }

    #[test]
    fn a_sync_read_of_velocity_and_position_splits_into_registers() {
        let profile = profile();
        let request = packet(&encode_instruction(BROADCAST_ID, 0x82, &[128, 0, 8, 0, 1, 5]));
        assert_eq!(read_spans(&request), vec![(1, 128, 8), (5, 128, 8)]);
        // Present Velocity -3 (signed), Present Position 4096.
        let data = [0xFD, 0xFF, 0xFF, 0xFF, 0x00, 0x10, 0x00, 0x00];
        let keys: Vec<(String, i64)> = items_in(&profile, 128, &data).into_iter().map(|(i, v)| (profile.items[i].spec.key.clone(), v)).collect();
        assert_eq!(keys, vec![("present_velocity".to_owned(), -3), ("present_position".to_owned(), 4096)]);
    }

    #[test]
    fn a_fast_sync_read_reply_splits_per_servo_as_the_e_manual_lays_it_out() {
        // The e-manual's Fast Sync Read of Present Position (132, 4 B) from IDs 3, 7 and 4.
        let request = packet(&encode_instruction(BROADCAST_ID, 0x8A, &[132, 0, 4, 0, 3, 7, 4]));
        assert!(is_fast_read(&request));
        let spans = read_spans(&request);
        assert_eq!(spans, vec![(3, 132, 4), (7, 132, 4), (4, 132, 4)]);
        let reply = packet(&[
            0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x19, 0x00, 0x55, 0x00, 0x03, 0xA6, 0x00, 0x00, 0x00, 0x84, 0x08, 0x00, 0x07, 0x1F, 0x08, 0x00, 0x00, 0x16, 0xCA, 0x00, 0x04, 0xFF, 0x03, 0x00, 0x00, 0xD1,
            0x9E,
        ]);
        let blocks = fast_blocks(&reply, &spans);
        assert_eq!(blocks, vec![(3, 132, &[0xA6, 0, 0, 0][..]), (7, 132, &[0x1F, 0x08, 0, 0][..]), (4, 132, &[0xFF, 0x03, 0, 0][..])]);
        // Cut after the second block (the third servo did not answer), or a block out of order.
        assert_eq!(fast_blocks(&reply, &[(3, 132, 4), (7, 132, 4), (9, 132, 4)]).len(), 2);
        assert!(fast_blocks(&reply, &[(7, 132, 4)]).is_empty());
        assert!(!is_fast_read(&packet(&encode_instruction(BROADCAST_ID, 0x82, &[132, 0, 4, 0, 3]))));
    }

    #[test]
    fn bias_rms_lag_and_the_tolerance_come_out_per_register() {
        let profile = profile();
        let mut comparison = Comparison::default();
        // The world reads 10 steps more, one sample late, of a ramp sampled every 20 ms.
        for i in 0..100i32 {
            let real = (i * 100).to_le_bytes();
            let sim = ((i - 1) * 100 + 10).to_le_bytes();
            comparison.add(&profile, 3, 132, f64::from(i) * 0.02, &real, &sim);
        }
        let stats = comparison.stats(&profile, &Tolerances::default());
        assert_eq!(stats.len(), 1);
        // Counted from the first reading on each side, the 10 steps' offset is gone.
        let mut from_start = Comparison::new([3]);
        for i in 0..100i32 {
            from_start.add(&profile, 3, 132, f64::from(i) * 0.02, &(5000 + i * 100).to_le_bytes(), &(-20 + i * 100).to_le_bytes());
            from_start.add(&profile, 5, 132, f64::from(i) * 0.02, &2060i32.to_le_bytes(), &2048i32.to_le_bytes());
        }
        let turned = from_start.stats(&profile, &Tolerances::default());
        assert_eq!((turned[0].id, turned[0].bias, turned[0].rms), (3, 0.0, 0.0), "{turned:?}");
        assert!(turned[1].id == 5 && turned[1].bias < 0.0, "a magnet shaft's position is compared as it is: {turned:?}");
        let s = &stats[0];
        assert_eq!((s.id, s.key.as_str(), s.samples), (3, "present_position", 100));
        let step = profile.items[profile.index("present_position")].spec.scale.unwrap_or(1.0);
        assert!((s.bias - (-90.0 * step)).abs() < 1e-9, "{s:?}");
        assert!((s.lag_ms - 20.0).abs() < 1e-6, "one sample late: {s:?}");
        assert!(s.passed, "90 steps in a 9900-step span is within 5 %: {s:?}");
        let strict = Tolerances { abs: BTreeMap::from([("3.present_position".to_owned(), 1.0)]), rel: 0.05 };
        assert!(!comparison.stats(&profile, &strict)[0].passed);
    }
}
