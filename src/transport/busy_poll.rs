//! When a transport's thread should spin for the controller's next request instead of sleeping.
//!
//! A controller in a tight request/reply loop answers a reply within tens of microseconds. A
//! thread that sleeps in poll(2) meanwhile pays a scheduler wake-up for every request, and on a VM
//! whose idle vCPUs halt that wake-up costs more than the emulator's own work (measured:
//! docs/performance.md, pty latency). So the port's thread spins for a while after each reply, but
//! only as long as this controller's recent turnarounds (reply written → next request read) say
//! the request is about to come: a controller paced at a millisecond or more never makes it spin.
//! It spins after request bytes that drew no reply too (a Sync Write, a broadcast, half a packet):
//! a tight loop's next packet follows them within microseconds (a Sync Write then a Sync Read is
//! the usual control cycle), and sleeping between the two cost a wake-up per cycle (measured:
//! docs/performance.md, loop rate).

use std::time::{Duration, Instant};

/// Turnarounds above this count as this much: one slow reply must not dominate the average.
const TURNAROUND_CAP: Duration = Duration::from_millis(1);
/// A controller whose average turnaround is longer than this is not in a tight loop: no spin.
const TIGHT_LOOP: Duration = Duration::from_micros(150);
/// The longest spin after one reply.
const MAX_SPIN: Duration = Duration::from_micros(250);
/// Spin this long beyond twice the average turnaround (its spread).
const SPIN_MARGIN: Duration = Duration::from_micros(20);

/// Tracks one connection's turnarounds and says how long to spin after a reply.
#[derive(Debug, Clone)]
pub struct BusyPoll {
    /// When the last reply was written, if no request has been read since.
    reply_written: Option<Instant>,
    /// When request bytes were last read, if no reply has been written since.
    request_read: Option<Instant>,
    /// Exponential average (weight 1/8) of the capped turnaround, in nanoseconds.
    average_ns: u64,
}

impl Default for BusyPoll {
    fn default() -> Self {
        // Until a controller has shown a tight loop, it is assumed slow.
        Self { reply_written: None, request_read: None, average_ns: nanos(TURNAROUND_CAP) }
    }
}

impl BusyPoll {
    /// A reply went out at `at`.
    pub fn reply_written(&mut self, at: Instant) {
        self.reply_written = Some(at);
        self.request_read = None;
    }

    /// Bytes from the controller were read at `at`.
    pub fn request_read(&mut self, at: Instant) {
        if let Some(written) = self.reply_written.take() {
            let turnaround = nanos(at.saturating_duration_since(written).min(TURNAROUND_CAP));
            self.average_ns = (self.average_ns * 7 + turnaround) / 8;
        }
        self.request_read = Some(at);
    }

    /// Until when to spin for the controller's next bytes (None: sleep straight away): from the
    /// last reply written or, if none since, from the last request bytes read.
    pub fn spin_until(&self) -> Option<Instant> {
        let last_activity = self.reply_written.or(self.request_read)?;
        let average = Duration::from_nanos(self.average_ns);
        (average <= TIGHT_LOOP).then(|| last_activity + (2 * average + SPIN_MARGIN).min(MAX_SPIN))
    }
}

fn nanos(duration: Duration) -> u64 {
    u64::try_from(duration.as_nanos()).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn after(start: Instant, us: u64) -> Instant {
        start + Duration::from_micros(us)
    }

    /// 64 cycles of a controller answering each reply in 30 µs, 10 µs apart; the time (µs after
    /// `start`) at their end.
    fn tight_loop(busy: &mut BusyPoll, start: Instant) -> u64 {
        let mut t = 0;
        for _ in 0..64 {
            busy.reply_written(after(start, t));
            t += 30;
            busy.request_read(after(start, t));
            t += 10;
        }
        t
    }

    #[test]
    fn a_new_connection_does_not_spin() {
        let mut busy = BusyPoll::default();
        assert_eq!(busy.spin_until(), None, "no reply written yet");
        busy.reply_written(Instant::now());
        assert_eq!(busy.spin_until(), None, "no turnaround seen yet: assumed slow");
    }

    #[test]
    fn a_tight_loop_spins_about_twice_its_turnaround() {
        let start = Instant::now();
        let mut busy = BusyPoll::default();
        let t = tight_loop(&mut busy, start);
        busy.reply_written(after(start, t));
        let until = busy.spin_until().expect("a 30 µs loop spins");
        let spin = until - after(start, t);
        assert!(spin >= Duration::from_micros(70) && spin <= Duration::from_micros(90), "spin {spin:?} for a 30 µs turnaround");
    }

    #[test]
    fn a_paced_controller_never_spins_and_the_spin_is_bounded() {
        let start = Instant::now();
        let mut busy = BusyPoll::default();
        let mut t = 0;
        for _ in 0..64 {
            busy.reply_written(after(start, t));
            t += 900; // a 1 kHz loop
            busy.request_read(after(start, t));
            t += 100;
        }
        busy.reply_written(after(start, t));
        assert_eq!(busy.spin_until(), None);

        // A loop just inside the limit spins at most MAX_SPIN.
        for _ in 0..64 {
            busy.reply_written(after(start, t));
            t += 140;
            busy.request_read(after(start, t));
        }
        busy.reply_written(after(start, t));
        let spin = busy.spin_until().expect("140 µs is a tight loop") - after(start, t);
        assert_eq!(spin, MAX_SPIN);
    }

    #[test]
    fn one_stall_does_not_stop_the_spinning() {
        let start = Instant::now();
        let mut busy = BusyPoll::default();
        let mut t = 0;
        for turnaround in std::iter::repeat_n(20, 64).chain([50_000]) {
            busy.reply_written(after(start, t));
            t += turnaround;
            busy.request_read(after(start, t));
        }
        busy.reply_written(after(start, t));
        assert!(busy.spin_until().is_some(), "a 50 ms stall counts as 1 ms, once");
    }

    #[test]
    fn bytes_without_a_reply_before_them_change_nothing() {
        let mut busy = BusyPoll::default();
        let now = Instant::now();
        busy.request_read(now);
        busy.request_read(now + Duration::from_micros(5));
        assert_eq!(busy.average_ns, nanos(TURNAROUND_CAP));
        assert_eq!(busy.spin_until(), None, "no tight loop seen: bytes alone never make it spin");
    }

    #[test]
    fn a_tight_loop_spins_after_a_request_that_drew_no_reply() {
        let start = Instant::now();
        let mut busy = BusyPoll::default();
        let mut t = tight_loop(&mut busy, start);
        // The controller's Sync Write was read; no reply goes out for it. Its Sync Read is due
        // within microseconds: spin from the read, as long as after a reply.
        busy.request_read(after(start, t));
        let spin = busy.spin_until().expect("a tight loop spins after a write without reply") - after(start, t);
        assert!(spin >= Duration::from_micros(70) && spin <= Duration::from_micros(90), "spin {spin:?}");
        // A reply written later counts from the reply.
        t += 5;
        busy.reply_written(after(start, t));
        assert_eq!(busy.spin_until().map(|until| until - after(start, t)), Some(spin));
    }
}
