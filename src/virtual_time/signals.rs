//! Signal timers on simulated time (`alarm`, `setitimer`, `timer_create`): the shim of the
//! controller's process creates and arms them in the block (`abi::SigTimer`); the scheduler
//! fires them at their instant here, with every controller thread parked. It picks the thread
//! that takes the signal, as the kernel would (the one that waits for it in sigtimedwait, else
//! the main thread unless it blocks it, else the first that does not), counts the expiration
//! and lets that thread go: the thread sends itself the signal (shim `signals.rs`), so that it
//! arrives in its turn.

use std::sync::atomic::Ordering;

use tracing::debug;

use super::VirtualTime;
use super::abi::{NEVER, release, state, timer_state};
use super::error::lock;

impl VirtualTime {
    /// The next armed signal timer's instant.
    pub(super) fn next_signal_timer(&self) -> u64 {
        self.shared().live_sig_timers().iter().filter(|t| t.state.load(Ordering::Acquire) == timer_state::ARMED).map(|t| t.deadline_ns.load(Ordering::Relaxed)).min().unwrap_or(NEVER)
    }

    /// Fire every signal timer due by `now`; whether a thread was let go for one.
    pub(super) fn fire_signal_timers(&self, now: u64) -> bool {
        let shared = self.shared();
        let mut released = false;
        for timer in shared.live_sig_timers() {
            let deadline = timer.deadline_ns.load(Ordering::Relaxed);
            if deadline > now || timer.state.compare_exchange(timer_state::ARMED, timer_state::BUSY, Ordering::AcqRel, Ordering::Relaxed).is_err() {
                continue;
            }
            let interval = timer.interval_ns.load(Ordering::Relaxed);
            // A period shorter than the time since the deadline: the missed expirations are
            // the signal's overrun, as on a kernel.
            let expirations = (now - deadline).checked_div(interval).map_or(1, |missed| missed.saturating_add(1));
            let next = if interval == 0 { NEVER } else { deadline.saturating_add(interval.saturating_mul(expirations)) };
            timer.deadline_ns.store(next, Ordering::Relaxed);
            let (pid, tid, signo) = (timer.pid.load(Ordering::Relaxed), timer.tid.load(Ordering::Relaxed), timer.signo.load(Ordering::Relaxed));
            let target = if signo == 0 { None } else { shared.signal_taker(pid, tid, signo) };
            if let Some(slot) = target {
                timer.deliver_tid.store(slot.tid.load(Ordering::Relaxed), Ordering::Relaxed);
                let added = u32::try_from(expirations).unwrap_or(u32::MAX);
                timer.fired.fetch_update(Ordering::AcqRel, Ordering::Relaxed, |f| Some(f.saturating_add(added))).ok();
                slot.signals_due.fetch_add(1, Ordering::AcqRel);
                lock(&self.stats).signals_fired += 1;
                debug!(pid, tid = slot.tid.load(Ordering::Relaxed), signo, now_s = now as f64 / 1e9, "signal timer fired");
                if matches!(slot.state(), state::BLOCKED | state::YIELDED) && !slot.in_waitpid() {
                    slot.make_ready(Some(release::SIGNAL));
                    released = true;
                }
            }
            let gone = signo != 0 && target.is_none() && shared.signal_taker(pid, 0, signo).is_none();
            let after = if gone {
                timer_state::FREE
            } else if next == NEVER {
                timer_state::DISARMED
            } else {
                timer_state::ARMED
            };
            timer.state.store(after, Ordering::Release);
        }
        released
    }
}
