//! A model of the USB–serial adapter in front of the controller (`serve --adapter NAME`): when
//! the servos' bytes reach the controller's program, not just its adapter.
//!
//! FTDI chips (the U2D2 is an FT232H) send received bytes to the host in USB packets of up to 62
//! data bytes plus 2 status bytes. A packet goes out when 62 bytes have arrived, or when the
//! latency timer expires (16 ms by default on Linux, `latency_timer` in sysfs); an expiry with no
//! data sends a status-only packet, and every packet restarts the timer, so while the line is
//! idle the timer runs freely and new data waits for its next expiry (FTDI application note
//! AN232B-04, "Data Throughput, Latency and Handshaking"). Modelled as exactly that, with the
//! host's USB polling (125 µs microframes on a high-speed FT232H) and the kernel's own delivery
//! taken as instant. Unverified against a real U2D2: whether a full packet restarts the timer
//! (assumed, as the note describes), and the timer's phase against the controller's writes
//! (free-running here from when the port opened).

use std::time::Duration;

/// Data bytes in one full USB packet of an FTDI chip (64 less 2 modem-status bytes).
const FTDI_PACKET_DATA: usize = 62;

/// Which adapter the controller sits behind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Adapter {
    /// Bytes reach the controller as they arrive (a perfect adapter; the default).
    Ideal,
    /// An FTDI chip with this latency timer.
    Ftdi { latency_timer: Duration },
}

impl Adapter {
    /// A U2D2 (FT232H) at Linux's default latency timer, or `latency_timer_ms` if given.
    pub fn u2d2(latency_timer_ms: Option<u32>) -> Self {
        Self::Ftdi { latency_timer: Duration::from_millis(u64::from(latency_timer_ms.unwrap_or(16))) }
    }
}

/// The adapter's state between transactions: when it last sent the host a packet.
#[derive(Debug, Clone)]
pub struct AdapterModel {
    latency_timer: Duration,
    last_packet: Duration,
}

impl AdapterModel {
    /// A model of `adapter`; None for [`Adapter::Ideal`], which needs none.
    pub fn new(adapter: Adapter) -> Option<Self> {
        match adapter {
            Adapter::Ideal => None,
            Adapter::Ftdi { latency_timer } => Some(Self { latency_timer: latency_timer.max(Duration::from_millis(1)), last_packet: Duration::ZERO }),
        }
    }

    /// The latest timer expiry at or before `t`.
    fn expiry_at_or_before(&self, t: Duration) -> Duration {
        let periods = (t.saturating_sub(self.last_packet).as_nanos() / self.latency_timer.as_nanos()) as u32;
        self.last_packet + self.latency_timer * periods
    }

    /// Bytes reach the adapter at `arrivals` (in order): when the controller gets them, as
    /// `(at, bytes)` hand-overs in order, every byte in exactly one.
    pub fn deliver(&mut self, arrivals: &[Duration]) -> Vec<(Duration, usize)> {
        let mut out = Vec::new();
        let mut buffered = 0usize;
        for &arrival in arrivals {
            let expiry = self.expiry_at_or_before(arrival);
            if expiry > self.last_packet {
                // The timer expired since the last packet: what was buffered went out then (an
                // empty buffer sent a status-only packet; either way the timer restarted).
                if buffered > 0 {
                    out.push((self.last_packet + self.latency_timer, buffered));
                    buffered = 0;
                    self.last_packet += self.latency_timer;
                }
                self.last_packet = self.expiry_at_or_before(arrival);
            }
            buffered += 1;
            if buffered == FTDI_PACKET_DATA {
                out.push((arrival, buffered));
                buffered = 0;
                self.last_packet = arrival;
            }
        }
        if buffered > 0 {
            self.last_packet += self.latency_timer;
            out.push((self.last_packet, buffered));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn bytes_at(start: Duration, count: usize, byte_time: Duration) -> Vec<Duration> {
        (1..=count).map(|i| start + byte_time * i as u32).collect()
    }

    #[test]
    fn a_short_reply_waits_for_the_next_timer_expiry() {
        let mut model = AdapterModel::new(Adapter::u2d2(None)).expect("ftdi");
        // A 14-byte ping reply at 1 Mbps (10 µs a byte) arriving at 20.5 ms: the timer, free
        // running from 0, next expires at 32 ms.
        let arrivals = bytes_at(20 * MS + Duration::from_micros(500), 14, Duration::from_micros(10));
        assert_eq!(model.deliver(&arrivals), vec![(32 * MS, 14)]);
        // The next reply right after (the controller answered at once) waits a whole period.
        let arrivals = bytes_at(32 * MS + Duration::from_micros(700), 14, Duration::from_micros(10));
        assert_eq!(model.deliver(&arrivals), vec![(48 * MS, 14)]);
    }

    #[test]
    fn full_packets_go_at_once_and_restart_the_timer() {
        let mut model = AdapterModel::new(Adapter::u2d2(Some(1))).expect("ftdi");
        // 130 bytes arriving from 0.25 ms, 10 µs apart (so no timer expiry passes between two
        // full packets): 62 at 0.87 ms, 62 at 1.49 ms, the last 6 at the expiry after 1.49 ms.
        let arrivals = bytes_at(Duration::from_micros(250), 130, Duration::from_micros(10));
        let out = model.deliver(&arrivals);
        assert_eq!(out.iter().map(|&(_, n)| n).collect::<Vec<_>>(), [62, 62, 6]);
        assert_eq!(out[0].0, arrivals[61]);
        assert_eq!(out[1].0, arrivals[123]);
        assert_eq!(out[2].0, arrivals[123] + MS);
    }

    #[test]
    fn bytes_spread_over_expiries_go_out_at_each() {
        let mut model = AdapterModel::new(Adapter::u2d2(Some(1))).expect("ftdi");
        // Two bytes 1.5 ms apart: the first at the expiry after it (1 ms), the second at 2 ms.
        let out = model.deliver(&[Duration::from_micros(400), Duration::from_micros(1900)]);
        assert_eq!(out, vec![(MS, 1), (2 * MS, 1)]);
    }

    #[test]
    fn the_ideal_adapter_has_no_model() {
        assert!(AdapterModel::new(Adapter::Ideal).is_none());
    }
}
