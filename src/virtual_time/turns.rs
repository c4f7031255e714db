//! Whose turn it is: one followed thread runs at a time, the ready one in the lowest slot
//! first (a thread that gave up its quantum after the others), so that the interleaving of a
//! controller's threads never depends on the host's scheduling; and which parked threads go at
//! an instant (their deadline, data for them, a timer's signal), and how far the ones that run
//! may move the clock (the horizon).

use std::sync::atomic::Ordering;

use super::abi::protocol::ChildWait;
use super::abi::{NEVER, Slot, Wait, release, state};
use super::error::lock;
use super::futex::wake;
use super::{VirtualTime, watchdog};

impl VirtualTime {
    /// Give the turn to the ready thread in the lowest slot, if there is one (and no thread
    /// runs): the order does not depend on which the host happened to schedule first. A
    /// thread that gave its turn up after a quantum comes after every other ready one.
    pub(super) fn give_turn(&self) -> bool {
        let ready = self.shared().next_turn();
        if let Some(slot) = ready
            && slot.give_turn()
        {
            lock(&self.stats).turns += 1;
            self.shared().header.turns.given.fetch_add(1, Ordering::Release);
            wake(slot);
        }
        ready.is_some()
    }

    /// At trace level (`RUST_LOG=climbsim::virtual_time=trace`): a jump of simulated time to
    /// `to`, with every followed thread's state, to find which wait a run that does not repeat
    /// waited on.
    pub(super) fn trace_jump(&self, to: u64) {
        if tracing::enabled!(tracing::Level::TRACE) {
            tracing::trace!(from_s = self.now_ns() as f64 / 1e9, to_s = to as f64 / 1e9, "jump; {}", watchdog::threads_now(self.shared()));
        }
    }

    /// A thread runs, or may: one is being created, is in a waitpid the kernel is about to
    /// return from, or is handing its turn on (`Header::turns.hand_ons_begun`: climbsim decides
    /// nothing on a look that such a hand-over overlapped).
    pub(super) fn any_running(&self) -> bool {
        let header = &self.shared().header;
        let ended = header.turns.hand_ons_ended.load(Ordering::SeqCst);
        // In waitpid: blocked only while a child it waits for lives; else the kernel is about
        // to return it (its child has just ended).
        let child_wait = |slots: &[Slot], s: &Slot| {
            if waits_on_live_child(slots, s) || watchdog::has_unfollowed_child(slots, s) { ChildWait::Blocked } else { ChildWait::Returning }
        };
        let running = self.shared().another_runs(child_wait);
        running || {
            let begun = header.turns.hand_ons_begun.load(Ordering::SeqCst);
            let mut hand_ons = lock(&self.hand_ons);
            begun != ended.wrapping_add(hand_ons.written_off) && !hand_ons.write_off_dead(self.shared(), begun, ended)
        }
    }
}

/// `parent`, in waitpid, has a followed child that can end (and so wake it).
pub(super) fn waits_on_live_child(slots: &[Slot], parent: &Slot) -> bool {
    let pid = parent.pid.load(Ordering::Relaxed);
    let Wait::Child(awaited) = parent.wait() else { return false };
    slots.iter().any(|child| {
        let live = child.is_live();
        live && child.parent.load(Ordering::Relaxed) == pid && (awaited <= 0 || i64::from(child.pid.load(Ordering::Relaxed)) == awaited)
    })
}

/// Which parked threads go at an instant.
impl VirtualTime {
    /// Fire the port session's timers and the controller's signal timers due by `now`; a thread
    /// let go for a signal takes the turn.
    pub(super) fn fire_all(&self, now: u64) {
        self.fire_timers(now);
        if self.fire_signal_timers(now) {
            self.give_turn();
        }
    }

    /// Let go every parked thread whose instant is `now` (its deadline, its spin's next byte, or
    /// data for it), and set the horizon for those that run. `next_reply`: the next timer or
    /// held reply.
    pub(super) fn let_go_at(&self, now: u64, next_timer: u64, next_reply: u64) -> LetGo {
        let header = &self.shared().header;
        let mut unread = None;
        let mut due_now = Vec::new();
        let mut next_thread = NEVER;
        let mut blocked_on_port = false;
        // A thread that found by itself what woke it (its look at the kernel saw the port's
        // reply shown at this instant) is ready at this instant, as one let go here would be.
        // Skipped, time would move on while it waits for its turn (an epoll woken by its own
        // look at a reply's instant would then see that reply and the next together).
        let mut ready_already = false;
        for (index, slot) in self.shared().live_slots().iter().enumerate() {
            let parked = slot.state();
            ready_already |= parked == state::READY;
            if parked != state::BLOCKED && parked != state::YIELDED {
                continue;
            }
            let wait = slot.wait();
            let response = wait.conns() && self.sensors.response_waiting(index);
            let on_port = wait.port();
            // An edge-triggered epoll registration waits for bytes past those it has reported.
            let port_ready = on_port && {
                let (unread, visible) = *unread.get_or_insert_with(|| self.port.unread_and_visible());
                unread > 0 && visible > slot.port_seen.load(Ordering::Relaxed)
            };
            if port_ready || response {
                due_now.push((slot, release::DATA));
                continue;
            }
            blocked_on_port |= on_port && wait != Wait::Spin;
            let mut at = slot.deadline_ns.load(Ordering::Relaxed);
            if wait == Wait::Spin {
                // A spin on the port goes on to the next byte due on it (its own deadline
                // bounds the jump).
                at = at.min(next_reply);
            }
            if at <= now {
                due_now.push((slot, release::DEADLINE));
            } else {
                next_thread = next_thread.min(at);
            }
        }
        // Not the world's next tick: a thread may run past it (the world catches up). Nor a
        // held reply's instant, unless a thread blocked on the port must be let go then.
        let horizon = next_thread.min(next_timer).min(if blocked_on_port { next_reply } else { NEVER });
        header.clock.horizon_ns.store(horizon, Ordering::Release);
        header.port.next_due_ns.store(next_timer, Ordering::Release);
        let released = !due_now.is_empty() || ready_already;
        if released {
            let mut stats = lock(&self.stats);
            for (slot, why) in due_now {
                match why {
                    release::DATA => stats.released_for_data += 1,
                    _ => stats.released_at_deadline += 1,
                }
                slot.make_ready(Some(why));
            }
            drop(stats);
            // Every thread is parked here: the first of them runs at once, while the world
            // catches up or ticks (it sees the world only through replies made at their
            // instants); the others get their turns as it parks.
            self.give_turn();
        }
        LetGo { released, next: next_thread.min(next_reply) }
    }
}

/// What [`VirtualTime::let_go_at`] did.
pub(super) struct LetGo {
    /// Some thread was let go, or is ready to run at this instant already.
    pub(super) released: bool,
    /// The next instant a parked thread is due, or a reply ([`NEVER`]: none).
    pub(super) next: u64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    use super::super::abi::Parked;
    use super::super::hand_ons::HAND_ON_STALL;
    use crate::virtual_time::VtSettings;

    /// A thread whose own look at the kernel found what woke it marks itself ready; if
    /// climbsim's look at the same instant passed it over, time moved on while it waited for
    /// its turn, and it saw a later instant than a run where climbsim let it go.
    #[test]
    fn a_thread_ready_by_its_own_look_runs_before_time_moves_on() {
        let vt = VirtualTime::create(VtSettings::default()).expect("a block");
        let shared = vt.shared();
        shared.header.slots_high.store(2, Ordering::Release);
        let (ready, blocked) = (&shared.slots[0], &shared.slots[1]);
        assert!(ready.claim_unused() && ready.park(Parked::Blocked, NEVER, Wait::Time) && ready.make_ready(None));
        assert!(blocked.claim_unused() && blocked.park(Parked::Blocked, 9_000, Wait::Time));
        let plan = vt.let_go_at(5_000, NEVER, 7_000);
        assert!(plan.released, "a ready thread runs at this instant: no jump to {}", plan.next);
        assert_eq!(ready.state(), state::RUNNING, "it has the turn");
        assert_eq!(blocked.state(), state::BLOCKED, "the other waits on");
    }

    /// Reply bytes that never reached the controller's side of the pty make the run fail at
    /// the scheduler's next step, with the reason, instead of going on without them (the run
    /// would no longer repeat); the first reason is the one given.
    #[test]
    fn a_run_that_cannot_repeat_fails_at_the_next_step_with_its_reason() {
        let vt = VirtualTime::create(VtSettings::default()).expect("a block");
        let stop = std::sync::atomic::AtomicBool::new(false);
        vt.port().cannot_repeat("the reply did not reach the controller".to_owned());
        vt.port().cannot_repeat("a later reason".to_owned());
        match vt.advance_to(Duration::from_millis(2), &stop) {
            Err(crate::virtual_time::VtError::Stuck(why)) => assert_eq!(why, "the reply did not reach the controller"),
            other => panic!("the run went on: {other:?}"),
        }
        assert!(vt.advance_to(Duration::from_millis(2), &stop).is_ok(), "said once; with no thread, time then reaches the tick");
    }

    /// A thread killed inside a hand-over (between its mark and its count, on either side)
    /// leaves counts that never meet: once they have stood apart for a while with no live
    /// thread marked, the difference is written off, and nothing runs. A live thread's mark
    /// keeps it under way however long it takes.
    #[test]
    fn hand_overs_of_killed_threads_are_written_off_and_a_live_ones_is_not() {
        let vt = VirtualTime::create(VtSettings::default()).expect("a block");
        let header = &vt.shared().header;
        header.turns.hand_ons_begun.store(7, Ordering::SeqCst);
        header.turns.hand_ons_ended.store(5, Ordering::SeqCst);
        let slot = &vt.shared().slots[0];
        slot.pid.store(std::process::id() as i32, Ordering::Relaxed);
        // SAFETY: gettid has no arguments and cannot fail.
        slot.tid.store(unsafe { libc::gettid() }, Ordering::Relaxed);
        assert!(slot.claim_unused() && slot.park(Parked::Blocked, NEVER, Wait::Time));
        slot.handing.store(1, Ordering::SeqCst);
        for _ in 0..3 {
            assert!(vt.any_running(), "a live thread is handing its turn on");
            std::thread::sleep(HAND_ON_STALL + Duration::from_millis(5));
        }
        // The thread dies: its mark stays, and the counts stay apart.
        slot.pid.store(i32::MAX, Ordering::Relaxed);
        let mut running = vt.any_running();
        for _ in 0..2 {
            if !running {
                break;
            }
            std::thread::sleep(HAND_ON_STALL + Duration::from_millis(5));
            running = vt.any_running();
        }
        assert!(!running, "written off within two stalls");
        assert_eq!(slot.handing.load(Ordering::SeqCst), 0, "the dead thread's mark is cleared");
        header.turns.hand_ons_begun.store(8, Ordering::SeqCst);
        assert!(vt.any_running(), "a new hand-over is under way");
        header.turns.hand_ons_ended.store(6, Ordering::SeqCst);
        assert!(!vt.any_running(), "and has ended");
    }
}
