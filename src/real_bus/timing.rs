//! The timing report of a real bus: per servo, how long it took to answer (the request's last
//! byte handed to the servos' side to the reply's first byte read back, so the adapter's USB
//! latency is in it, as a controller sees it), how often it did not, and its failed CRCs.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Duration;

use serde::Serialize;

use super::pairing::{Event, Seen};
use crate::protocol::FrameError;
use crate::transport::stats::LogHistogram;

/// What one servo did over a session.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ServoTiming {
    pub id: u8,
    /// Instructions it should have answered.
    pub expected: u64,
    pub replies: u64,
    pub missed: u64,
    /// Status packets from it that failed their CRC.
    pub crc_errors: u64,
    /// Reply latency in microseconds (None without replies).
    pub latency_us: Option<Latency>,
}

/// Exact minimum and maximum; the quantiles from a fixed-size log histogram, within 1.2 % (a
/// day-long session costs the memory of a short one).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Latency {
    pub min: f64,
    pub median: f64,
    pub p90: f64,
    pub p99: f64,
    pub max: f64,
}

/// The whole session's report (`<transcript>.timing.json`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TimingReport {
    pub transactions: u64,
    pub servos: Vec<ServoTiming>,
    /// Status packets that answered nothing pending.
    pub unpaired: u64,
    /// Bytes in no packet, from the controller and from the servos.
    pub raw_bytes_from_controller: u64,
    pub raw_bytes_from_servos: u64,
    /// Framing errors from the servos' side that name no servo (a bad length, a cut packet).
    pub other_frame_errors: u64,
}

/// Gathers the report as events come.
#[derive(Debug, Default)]
pub struct TimingTally {
    latencies: BTreeMap<u8, LatencyTally>,
    servos: BTreeMap<u8, ServoTiming>,
    report: TimingReport,
}

impl TimingTally {
    pub fn add(&mut self, event: &Event) {
        match event {
            Event::Transaction(seen) => self.transaction(seen),
            Event::Raw { from_servos: true, bytes, .. } => self.report.raw_bytes_from_servos += bytes.len() as u64,
            Event::Raw { from_servos: false, bytes, .. } => self.report.raw_bytes_from_controller += bytes.len() as u64,
            Event::Unpaired { .. } => self.report.unpaired += 1,
            Event::FrameError { from_servos: true, error: FrameError::BadCrc { id, .. }, .. } => self.servo(*id).crc_errors += 1,
            Event::FrameError { from_servos: true, .. } => self.report.other_frame_errors += 1,
            Event::FrameError { from_servos: false, .. } => {}
        }
    }

    fn servo(&mut self, id: u8) -> &mut ServoTiming {
        self.servos.entry(id).or_insert_with(|| ServoTiming { id, ..ServoTiming::default() })
    }

    fn transaction(&mut self, seen: &Seen) {
        self.report.transactions += 1;
        for reply in &seen.replies {
            let latency = reply.first.saturating_sub(seen.end);
            self.servo(reply.id).replies += 1;
            self.servo(reply.id).expected += 1;
            self.latencies.entry(reply.id).or_default().record(latency);
        }
        for id in &seen.missed {
            let servo = self.servo(*id);
            servo.missed += 1;
            servo.expected += 1;
        }
    }

    pub fn report(&self) -> TimingReport {
        let mut report = self.report.clone();
        report.servos = self
            .servos
            .values()
            .map(|servo| {
                let mut servo = servo.clone();
                servo.latency_us = self.latencies.get(&servo.id).and_then(LatencyTally::latency);
                servo
            })
            .collect();
        report
    }
}

/// One servo's reply latencies so far.
#[derive(Debug, Clone)]
struct LatencyTally {
    histogram: LogHistogram,
    min_us: f64,
}

impl Default for LatencyTally {
    fn default() -> Self {
        Self { histogram: LogHistogram::default(), min_us: f64::INFINITY }
    }
}

impl LatencyTally {
    fn record(&mut self, latency: Duration) {
        self.histogram.record(latency);
        self.min_us = self.min_us.min(latency.as_secs_f64() * 1e6);
    }

    fn latency(&self) -> Option<Latency> {
        let at = |q: f64| self.histogram.quantile_us(q);
        let max = self.histogram.quantiles()?.max_us;
        Some(Latency { min: self.min_us, median: at(0.5)?, p90: at(0.9)?, p99: at(0.99)?, max })
    }
}

impl TimingReport {
    /// A table for the terminal.
    pub fn table(&self) -> String {
        let mut out = format!("{} transactions; reply latency (request's last byte to reply's first), µs:\n", self.transactions);
        out.push_str("   ID  replies  missed  CRC  median     p90     p99     max\n");
        for servo in &self.servos {
            let _ = write!(out, "  {:>3}  {:>7}  {:>6}  {:>3}", servo.id, servo.replies, servo.missed, servo.crc_errors);
            match servo.latency_us {
                Some(l) => {
                    let _ = writeln!(out, "  {:>6.0}  {:>6.0}  {:>6.0}  {:>6.0}", l.median, l.p90, l.p99, l.max);
                }
                None => out.push_str("       -       -       -       -\n"),
            }
        }
        if self.unpaired + self.raw_bytes_from_controller + self.raw_bytes_from_servos + self.other_frame_errors > 0 {
            let _ = writeln!(
                out,
                "  {} unpaired replies; bytes in no packet: {} from the controller, {} from the servos; {} other framing errors",
                self.unpaired, self.raw_bytes_from_controller, self.raw_bytes_from_servos, self.other_frame_errors
            );
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::RawPacket;
    use crate::real_bus::pairing::SeenReply;

    fn seen(end_us: u64, replies: &[(u8, u64)], missed: &[u8]) -> Event {
        let instruction = RawPacket { id: 0xFE, instruction: 0x82, params: vec![], wire_len: 0, bytes: vec![] };
        let replies = replies.iter().map(|(id, at)| SeenReply { id: *id, first: Duration::from_micros(*at), last: Duration::from_micros(*at + 150), bytes: vec![] }).collect();
        Event::Transaction(Seen { t: Duration::ZERO, end: Duration::from_micros(end_us), baud: 1_000_000, instruction, replies, missed: missed.to_vec() })
    }

    #[test]
    fn latency_missed_and_crc_errors_are_counted_per_servo() {
        let mut tally = TimingTally::default();
        tally.add(&seen(100, &[(1, 350), (2, 500)], &[]));
        tally.add(&seen(1000, &[(1, 1260)], &[2]));
        tally.add(&seen(2000, &[(1, 2240)], &[2]));
        tally.add(&Event::FrameError { from_servos: true, at: Duration::ZERO, error: FrameError::BadCrc { id: 2, received: 1, computed: 2 } });
        let report = tally.report();
        assert_eq!(report.transactions, 3);
        let one = &report.servos[0];
        assert_eq!((one.id, one.replies, one.missed, one.expected), (1, 3, 0, 3));
        let l = one.latency_us.expect("latency");
        assert_eq!((l.min.round(), l.max.round()), (240.0, 260.0), "exact");
        assert!((l.median / 250.0 - 1.0).abs() < 0.012, "within a bin: {l:?}");
        let two = &report.servos[1];
        assert_eq!((two.replies, two.missed, two.crc_errors), (1, 2, 1));
        assert!(report.table().contains("    2        1       2    1"), "{}", report.table());
    }
}
