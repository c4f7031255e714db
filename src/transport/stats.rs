//! Line timing statistics for the timing report (`--report`): what a logic analyser on the bus
//! would tell a firmware developer. Fixed-size log histograms, so a 30-minute soak at thousands
//! of transactions per second uses the same memory as a ten-second run.

use std::collections::BTreeMap;
use std::time::Duration;

use serde::Serialize;

/// Histogram bins per decade: neighbouring bins differ by 2.3 %.
const BINS_PER_DECADE: f64 = 100.0;
/// Smallest value kept apart (µs); anything smaller lands in the first bin.
const FLOOR_US: f64 = 0.1;
/// 0.1 µs … 1000 s.
const DECADES: f64 = 10.0;

/// Log-spaced histogram of durations.
#[derive(Debug, Clone)]
pub struct LogHistogram {
    counts: Vec<u64>,
    total: u64,
    max_us: f64,
    sum_us: f64,
}

impl Default for LogHistogram {
    fn default() -> Self {
        Self { counts: vec![0; (BINS_PER_DECADE * DECADES) as usize + 1], total: 0, max_us: 0.0, sum_us: 0.0 }
    }
}

/// Count and quantiles of a histogram (µs; quantiles are bin centres, within 1.2 %).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Quantiles {
    pub count: u64,
    pub p1_us: f64,
    pub p50_us: f64,
    pub p99_us: f64,
    pub max_us: f64,
    pub mean_us: f64,
}

impl LogHistogram {
    pub fn record(&mut self, value: Duration) {
        let us = value.as_secs_f64() * 1e6;
        let bin = ((us.max(FLOOR_US) / FLOOR_US).log10() * BINS_PER_DECADE).round() as usize;
        let last = self.counts.len() - 1;
        self.counts[bin.min(last)] += 1;
        self.total += 1;
        self.max_us = self.max_us.max(us);
        self.sum_us += us;
    }

    pub fn count(&self) -> u64 {
        self.total
    }

    fn bin_centre_us(bin: usize) -> f64 {
        FLOOR_US * 10f64.powf(bin as f64 / BINS_PER_DECADE)
    }

    /// The value below which a fraction `q` of the samples lie.
    pub fn quantile_us(&self, q: f64) -> Option<f64> {
        if self.total == 0 {
            return None;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.total as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (bin, &count) in self.counts.iter().enumerate() {
            seen += count;
            if seen >= rank {
                return Some(Self::bin_centre_us(bin).min(self.max_us));
            }
        }
        Some(self.max_us)
    }

    pub fn quantiles(&self) -> Option<Quantiles> {
        Some(Quantiles {
            count: self.total,
            p1_us: self.quantile_us(0.01)?,
            p50_us: self.quantile_us(0.5)?,
            p99_us: self.quantile_us(0.99)?,
            max_us: self.max_us,
            mean_us: self.sum_us / self.total as f64,
        })
    }

    /// The cumulative distribution: (value µs, fraction ≤ value) at every occupied bin.
    pub fn cdf(&self) -> Vec<(f64, f64)> {
        let mut seen = 0;
        let mut points = Vec::new();
        for (bin, &count) in self.counts.iter().enumerate() {
            if count > 0 {
                seen += count;
                points.push((Self::bin_centre_us(bin), seen as f64 / self.total as f64));
            }
        }
        points
    }
}

/// Which packets mark one turn of a controller's loop: same instruction to the same ID.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct LoopKey {
    pub instruction: u8,
    pub id: u8,
}

#[derive(Debug, Clone, Default)]
struct Period {
    first_seen: u64,
    last_at: Option<Duration>,
    histogram: LogHistogram,
}

/// Everything the transports observe on the line.
#[derive(Debug, Clone, Default)]
pub struct LineStats {
    first_at: Option<Duration>,
    last_at: Duration,
    requests: u64,
    replies: u64,
    wire_busy: Duration,
    periods: BTreeMap<LoopKey, Period>,
    latency: BTreeMap<&'static str, LogHistogram>,
    lateness: LogHistogram,
    unread_replies: u64,
    unread_bytes: u64,
    collisions: u64,
    collided_bytes: u64,
    inter_byte_gaps: u64,
    frame_errors: u64,
    baud_mismatch_packets: u64,
    over_timeouts: MasterTimeouts,
}

/// Transactions that took longer than common masters wait for them: what the controller would
/// have reported as a timeout, had it been one of these. Counted from the request's last byte to
/// the last reply's last byte at the controller.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct MasterTimeouts {
    /// Dynamixel2Arduino's 10 ms for a whole transaction.
    pub dynamixel2arduino_10ms: u64,
    /// The official DynamixelSDK's packet timeout: twice its 16 ms latency-timer allowance plus
    /// 2 ms, plus the wire time of the reply (`PortHandler.setPacketTimeout`).
    pub dynamixel_sdk_34ms_plus_wire: u64,
}

/// Dynamixel2Arduino's default transaction timeout.
const DYNAMIXEL2ARDUINO_TIMEOUT: Duration = Duration::from_millis(10);
/// The official SDK's packet timeout, less the reply's wire time.
const DYNAMIXEL_SDK_TIMEOUT: Duration = Duration::from_millis(34);

/// One transaction's replies handed over.
#[derive(Debug, Clone, Copy)]
pub struct Answered {
    pub instruction: &'static str,
    pub replies: usize,
    /// Request's last byte → last reply handed over.
    pub latency: Duration,
    /// How late the last reply was handed over against its due time.
    pub late: Duration,
    pub at: Duration,
    /// Request's last byte → the last reply's last byte at the controller.
    pub complete: Duration,
    /// The replies' own wire time.
    pub replies_wire: Duration,
}

impl LineStats {
    /// A packet arrived at `at`; `wire_busy` is what it and its replies occupy on the wire.
    pub fn request(&mut self, at: Duration, key: LoopKey, wire_busy: Duration, baud_mismatch: bool) {
        self.first_at.get_or_insert(at);
        self.last_at = self.last_at.max(at);
        let order = self.requests;
        self.requests += 1;
        self.wire_busy += wire_busy;
        self.baud_mismatch_packets += u64::from(baud_mismatch);
        let period = self.periods.entry(key).or_insert_with(|| Period { first_seen: order, ..Period::default() });
        if let Some(previous) = period.last_at.replace(at) {
            period.histogram.record(at.saturating_sub(previous));
        }
    }

    /// The last reply to an instruction was handed to the controller `latency` after the
    /// instruction arrived, `late` after the wire model's due time.
    pub fn answered(&mut self, answer: Answered) {
        self.replies += answer.replies as u64;
        self.latency.entry(answer.instruction).or_default().record(answer.latency);
        self.lateness.record(answer.late);
        self.last_at = self.last_at.max(answer.at);
        self.over_timeouts.dynamixel2arduino_10ms += u64::from(answer.complete > DYNAMIXEL2ARDUINO_TIMEOUT);
        self.over_timeouts.dynamixel_sdk_34ms_plus_wire += u64::from(answer.complete > DYNAMIXEL_SDK_TIMEOUT + answer.replies_wire);
    }

    /// A new request came while `bytes` of earlier replies (`replies` packets) were unread.
    pub fn unread(&mut self, replies: u64, bytes: u64) {
        self.unread_replies += replies;
        self.unread_bytes += bytes;
    }

    /// The controller sent while replies were on the wire; `bytes` pairs overlapped.
    pub fn collision(&mut self, bytes: usize) {
        self.collisions += 1;
        self.collided_bytes += bytes as u64;
    }

    /// A packet's bytes stopped for longer than the firmware's inter-byte timeout.
    pub fn inter_byte_gap(&mut self) {
        self.inter_byte_gaps += 1;
    }

    /// Bytes that did not frame as a packet (bad CRC, garbage, truncated).
    pub fn frame_error(&mut self) {
        self.frame_errors += 1;
    }

    pub fn collisions(&self) -> u64 {
        self.collisions
    }

    pub fn requests(&self) -> u64 {
        self.requests
    }

    /// The report, with what only the caller knows (servo watchdogs, the physics pacer).
    pub fn report(&self, extra: ReportExtras) -> TimingReport {
        let span = self.first_at.map_or(Duration::ZERO, |first| self.last_at.saturating_sub(first));
        // The loop marker: the instruction/ID pair seen most often (ties: the one seen first).
        let marker = self.periods.iter().max_by_key(|(_, p)| (p.histogram.count(), std::cmp::Reverse(p.first_seen)));
        let controller_loop = marker.and_then(|(key, period)| {
            let q = period.histogram.quantiles()?;
            Some(LoopReport {
                marker: format!("instruction 0x{:02X} to ID {}", key.instruction, key.id),
                period_ms: q.into(),
                jitter_ms: (q.p99_us - q.p50_us) / 1000.0,
                cdf_ms: period.histogram.cdf().into_iter().map(|(us, f)| (us / 1000.0, f)).collect(),
            })
        });
        TimingReport {
            duration_s: span.as_secs_f64(),
            requests: self.requests,
            replies: self.replies,
            controller_loop,
            latency_us: self.latency.iter().filter_map(|(name, h)| Some(((*name).to_owned(), LatencyReport { summary: h.quantiles()?, cdf_us: h.cdf() }))).collect(),
            delivery_lateness_us: self.lateness.quantiles(),
            bus_utilisation_pct: if span.is_zero() { 0.0 } else { 100.0 * self.wire_busy.as_secs_f64() / span.as_secs_f64() },
            unread_replies: self.unread_replies,
            unread_bytes: self.unread_bytes,
            collisions: self.collisions,
            collided_bytes: self.collided_bytes,
            inter_byte_gaps: self.inter_byte_gaps,
            frame_errors: self.frame_errors,
            baud_mismatch_packets: self.baud_mismatch_packets,
            over_master_timeouts: self.over_timeouts,
            watchdog_expiries: extra.watchdog_expiries,
            speed: if extra.pace.speed > 0.0 { extra.pace.speed } else { 1.0 },
            physics_ticks: extra.pace.ticks,
            physics_overruns: extra.pace.overruns,
            physics_lateness_us: extra.pace.lateness.quantiles(),
        }
    }
}

/// What the line cannot see.
#[derive(Debug, Clone, Default)]
pub struct ReportExtras {
    pub watchdog_expiries: u64,
    pub pace: PhysicsPace,
}

/// How well a world on the wall clock kept its pace: firmware ticks run, ticks handled more
/// than one tick late (overruns), and how late each tick was handled, in simulated time.
#[derive(Debug, Clone, Default)]
pub struct PhysicsPace {
    /// Simulated seconds per wall-clock second (`--speed`); 1 when the world ran at real time.
    pub speed: f64,
    pub ticks: u64,
    pub overruns: u64,
    pub lateness: LogHistogram,
}

/// p1/p50/p99/max/mean in milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Milliseconds {
    pub count: u64,
    pub p1: f64,
    pub p50: f64,
    pub p99: f64,
    pub max: f64,
    pub mean: f64,
}

impl From<Quantiles> for Milliseconds {
    fn from(q: Quantiles) -> Self {
        Self { count: q.count, p1: q.p1_us / 1000.0, p50: q.p50_us / 1000.0, p99: q.p99_us / 1000.0, max: q.max_us / 1000.0, mean: q.mean_us / 1000.0 }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopReport {
    /// The packets whose spacing is the loop period.
    pub marker: String,
    pub period_ms: Milliseconds,
    /// p99 − p50 of the period.
    pub jitter_ms: f64,
    pub cdf_ms: Vec<(f64, f64)>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LatencyReport {
    #[serde(flatten)]
    pub summary: Quantiles,
    pub cdf_us: Vec<(f64, f64)>,
}

/// The `--report` file.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TimingReport {
    /// From the first to the last packet.
    pub duration_s: f64,
    pub requests: u64,
    pub replies: u64,
    pub controller_loop: Option<LoopReport>,
    /// Request (last byte received) → last reply handed to the controller, per instruction.
    pub latency_us: BTreeMap<String, LatencyReport>,
    /// How late replies were handed over against the wire model's due time (scheduling error).
    pub delivery_lateness_us: Option<Quantiles>,
    pub bus_utilisation_pct: f64,
    pub unread_replies: u64,
    pub unread_bytes: u64,
    pub collisions: u64,
    pub collided_bytes: u64,
    pub inter_byte_gaps: u64,
    pub frame_errors: u64,
    pub baud_mismatch_packets: u64,
    /// Transactions slower than common masters' timeouts.
    pub over_master_timeouts: MasterTimeouts,
    pub watchdog_expiries: u64,
    /// Simulated seconds per wall-clock second; every time in this report is simulated time.
    pub speed: f64,
    pub physics_ticks: u64,
    pub physics_overruns: u64,
    /// How late the world's firmware ticks were handled against their deadlines.
    pub physics_lateness_us: Option<Quantiles>,
}

impl TimingReport {
    /// Why this session did not keep its pace, if it did not: the world's ticks or the replies
    /// were handed over later than `tolerance` (simulated time) at the 99th percentile. A run that
    /// could not keep up is not the run the scenario describes, whatever its metrics say.
    pub fn pace_problems(&self, tolerance: Duration) -> Vec<String> {
        let limit_us = tolerance.as_secs_f64() * 1e6;
        let mut problems = Vec::new();
        if let Some(q) = self.physics_lateness_us.filter(|q| q.p99_us > limit_us) {
            problems.push(format!(
                "pace: the world's ticks ran p99 {:.2} ms (max {:.2} ms) behind their deadlines at {}x, over the {:.2} ms tolerance: this machine could not keep up",
                q.p99_us / 1000.0,
                q.max_us / 1000.0,
                self.speed,
                limit_us / 1000.0
            ));
        }
        if let Some(q) = self.delivery_lateness_us.filter(|q| q.p99_us > limit_us) {
            problems.push(format!(
                "pace: replies reached the controller p99 {:.2} ms (max {:.2} ms) later than the wire model at {}x, over the {:.2} ms tolerance: this machine could not keep up",
                q.p99_us / 1000.0,
                q.max_us / 1000.0,
                self.speed,
                limit_us / 1000.0
            ));
        }
        problems
    }

    /// A few lines for the terminal.
    pub fn human_summary(&self) -> String {
        let mut out = format!("timing: {} requests, {} replies in {:.1} s; bus {:.1} % busy\n", self.requests, self.replies, self.duration_s, self.bus_utilisation_pct);
        if let Some(l) = &self.controller_loop {
            out += &format!("  controller loop ({}): period p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms; jitter {:.3} ms\n", l.marker, l.period_ms.p50, l.period_ms.p99, l.period_ms.max, l.jitter_ms);
        }
        for (name, latency) in &self.latency_us {
            let q = &latency.summary;
            out += &format!("  {name}: {} answered, request→reply p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs\n", q.count, q.p50_us, q.p99_us, q.max_us);
        }
        out += &format!(
            "  collisions {}, unread replies {}, inter-byte gaps {}, frame errors {}, baud mismatches {}, watchdog expiries {}, physics overruns {} of {} ticks",
            self.collisions, self.unread_replies, self.inter_byte_gaps, self.frame_errors, self.baud_mismatch_packets, self.watchdog_expiries, self.physics_overruns, self.physics_ticks
        );
        let over = self.over_master_timeouts;
        if over != MasterTimeouts::default() {
            out += &format!(
                "\n  slower than masters wait: {} transactions over Dynamixel2Arduino's 10 ms, {} over the official SDK's 34 ms + wire time",
                over.dynamixel2arduino_10ms, over.dynamixel_sdk_34ms_plus_wire
            );
        }
        if let Some(q) = &self.physics_lateness_us {
            out += &format!("\n  world at {}x: ticks handled p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs after their deadlines (simulated time)", self.speed, q.p50_us, q.p99_us, q.max_us);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_come_within_a_bin_of_the_samples() {
        let mut h = LogHistogram::default();
        for us in 1..=1000u64 {
            h.record(Duration::from_micros(us));
        }
        let q = h.quantiles().expect("samples");
        assert_eq!(q.count, 1000);
        assert!((q.p50_us - 500.0).abs() / 500.0 < 0.012, "{q:?}");
        assert!((q.p99_us - 990.0).abs() / 990.0 < 0.012, "{q:?}");
        assert_eq!(q.max_us, 1000.0);
        assert!((q.mean_us - 500.5).abs() < 1e-6);
    }

    #[test]
    fn transactions_slower_than_masters_wait_are_counted_against_each_timeout() {
        let mut stats = LineStats::default();
        let answer = |complete_ms: u64| Answered {
            instruction: "Read",
            replies: 1,
            latency: Duration::from_millis(complete_ms),
            late: Duration::ZERO,
            at: Duration::ZERO,
            complete: Duration::from_millis(complete_ms),
            replies_wire: Duration::from_millis(2),
        };
        for ms in [1, 9, 11, 35, 37] {
            stats.answered(answer(ms));
        }
        let over = stats.report(ReportExtras::default()).over_master_timeouts;
        // 11, 35 and 37 ms exceed 10 ms; only 37 exceeds 34 ms + 2 ms of wire.
        assert_eq!(over, MasterTimeouts { dynamixel2arduino_10ms: 3, dynamixel_sdk_34ms_plus_wire: 1 });
        assert!(stats.report(ReportExtras::default()).human_summary().contains("3 transactions over Dynamixel2Arduino's 10 ms"));
    }

    #[test]
    fn an_empty_histogram_has_no_quantiles() {
        assert!(LogHistogram::default().quantiles().is_none());
    }

    #[test]
    fn the_loop_marker_is_the_most_frequent_packet_and_its_spacing_the_period() {
        let mut stats = LineStats::default();
        let sync_read = LoopKey { instruction: 0x82, id: 0xFE };
        let sync_write = LoopKey { instruction: 0x83, id: 0xFE };
        let ping = LoopKey { instruction: 0x01, id: 1 };
        stats.request(Duration::ZERO, ping, Duration::ZERO, false);
        for i in 0..100u64 {
            let t = Duration::from_millis(5 + 4 * i);
            stats.request(t, sync_read, Duration::from_micros(500), false);
            stats.request(t + Duration::from_millis(1), sync_write, Duration::from_micros(500), false);
        }
        let report = stats.report(ReportExtras::default());
        let l = report.controller_loop.expect("a loop");
        assert!(l.marker.contains("0x82"), "{}", l.marker);
        assert!((l.period_ms.p50 - 4.0).abs() < 0.05, "{:?}", l.period_ms);
        // 200 packets × 0.5 ms of wire over 397 ms.
        assert!((report.bus_utilisation_pct - 100.0 * 0.1 / 0.397).abs() < 0.5, "{}", report.bus_utilisation_pct);
    }
}
