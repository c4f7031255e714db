//! Timers on simulated time: the pty session's replies and inter-byte gaps wait on them, and
//! the scheduler fires them at their instant (see [`VirtualTime::timer`]).

use std::collections::{BTreeMap, HashSet};
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use tracing::debug;

use super::abi::NEVER;
use super::{Serves, VirtualTime, lock};

#[derive(Default)]
pub(super) struct Timers {
    /// (due ns, sequence): registered and not fired.
    pending: BTreeMap<(u64, u64), ()>,
    fired: HashSet<u64>,
    next_seq: u64,
}

impl VirtualTime {
    /// A future that completes when simulated time reaches `due`.
    pub fn timer(self: &Arc<Self>, due: Duration) -> Timer {
        let due = u64::try_from(due.as_nanos()).unwrap_or(NEVER);
        let mut timers = lock(&self.timers);
        let seq = timers.next_seq;
        timers.next_seq += 1;
        timers.pending.insert((due, seq), ());
        Timer { vt: Arc::clone(self), due, seq, done: false }
    }

    pub(super) fn next_timer(&self) -> u64 {
        lock(&self.timers).pending.keys().next().map_or(NEVER, |&(due, _)| due)
    }

    /// Fire every timer due by `now`, then let the driven futures act on them.
    pub(super) fn fire_timers(&self, now: u64) {
        {
            let mut timers = lock(&self.timers);
            while let Some(&(due, seq)) = timers.pending.keys().next() {
                if due > now {
                    break;
                }
                timers.pending.remove(&(due, seq));
                timers.fired.insert(seq);
                lock(&self.stats).timers_fired += 1;
            }
        }
        // Timers are the port session's (its replies and its inter-byte gaps).
        self.poll_driven(Some(Serves::Port));
    }
}

/// Completes when simulated time reaches its due time (see [`VirtualTime::timer`]).
pub struct Timer {
    vt: Arc<VirtualTime>,
    due: u64,
    seq: u64,
    done: bool,
}

impl Future for Timer {
    type Output = ();

    fn poll(mut self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<()> {
        let fired = lock(&self.vt.timers).fired.remove(&self.seq);
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
            let mut timers = lock(&self.vt.timers);
            timers.pending.remove(&(self.due, self.seq));
            timers.fired.remove(&self.seq);
        }
    }
}
