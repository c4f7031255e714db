//! Timers on simulated time: the pty session's replies and inter-byte gaps wait on them, and
//! the scheduler fires them at their instant (see [`PortLedger::timer`](super::PortLedger::timer)).
//! The wheel knows nothing of the scheduler: the scheduler asks it what is due next and fires
//! it, and a [`Timer`] holds only the wheel.

use std::collections::{BTreeMap, HashSet};
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll};
use std::time::Duration;

use tracing::debug;

use super::abi::NEVER;
use super::error::lock;

/// The timers registered and not yet taken by their futures.
#[derive(Default)]
pub(super) struct TimerWheel(Mutex<Timers>);

#[derive(Default)]
struct Timers {
    /// (due ns, sequence): registered and not fired.
    pending: BTreeMap<(u64, u64), ()>,
    fired: HashSet<u64>,
    next_seq: u64,
}

impl TimerWheel {
    fn timers(&self) -> MutexGuard<'_, Timers> {
        lock(&self.0)
    }

    /// A future that completes when `fire` reaches `due`.
    pub(super) fn timer(self: &Arc<Self>, due: Duration) -> Timer {
        let due = u64::try_from(due.as_nanos()).unwrap_or(NEVER);
        let mut timers = self.timers();
        let seq = timers.next_seq;
        timers.next_seq += 1;
        timers.pending.insert((due, seq), ());
        Timer { wheel: Arc::clone(self), due, seq, done: false }
    }

    /// When the next timer is due ([`NEVER`]: none is).
    pub(super) fn next_due(&self) -> u64 {
        self.timers().pending.keys().next().map_or(NEVER, |&(due, _)| due)
    }

    /// Fire every timer due by `now`; how many.
    pub(super) fn fire(&self, now: u64) -> u64 {
        let mut timers = self.timers();
        let mut fired = 0;
        while let Some(&(due, seq)) = timers.pending.keys().next() {
            if due > now {
                break;
            }
            timers.pending.remove(&(due, seq));
            timers.fired.insert(seq);
            fired += 1;
        }
        fired
    }
}

/// Completes when simulated time reaches its due time (see [`TimerWheel::timer`]).
pub struct Timer {
    wheel: Arc<TimerWheel>,
    due: u64,
    seq: u64,
    done: bool,
}

impl Future for Timer {
    type Output = ();

    fn poll(mut self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<()> {
        let fired = self.wheel.timers().fired.remove(&self.seq);
        if fired {
            self.done = true;
            debug!(due_ns = self.due, "virtual timer fired");
            return Poll::Ready(());
        }
        Poll::Pending
    }
}

impl Drop for Timer {
    fn drop(&mut self) {
        if !self.done {
            let mut timers = self.wheel.timers();
            timers.pending.remove(&(self.due, self.seq));
            timers.fired.remove(&self.seq);
        }
    }
}
