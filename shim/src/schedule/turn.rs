//! A thread's turn: waiting for it, handing it on as the thread parks or ends, and what the
//! thread has been charged since it got it. Below the slots (a thread that claims one starts in
//! its turn) and the parks (park.rs), which use it.

use core::cell::Cell;
use core::sync::atomic::Ordering;

use crate::abi::protocol::{ChildWait, Decider};
use crate::abi::{self, Shared, Slot, mode, state};
use crate::schedule::block::{ORPHANED, active, climbsim_gone, notify_scheduler};
use crate::schedule::now::{SpinLimit, real_monotonic_ns, sim_now};
use crate::sys;

thread_local! {
    /// Simulated time charged to this thread and not yet applied (ns).
    static UNAPPLIED: Cell<u64> = const { Cell::new(0) };
    /// Simulated time when this thread last got the turn (see `park::charge`).
    static TURN_FROM: Cell<u64> = const { Cell::new(0) };
}

/// A new thread or process starts with no charges (a forked child's copy is its parent's), and
/// a parked one drops them (a blocked thread costs nothing).
pub(crate) fn forget_charges() {
    UNAPPLIED.with(|u| u.set(0));
}

/// Charge `ns` more to this thread; what it has been charged and not applied, in all.
pub(crate) fn add_charge(ns: u64) -> u64 {
    UNAPPLIED.with(|u| {
        let total = u.get().saturating_add(ns);
        u.set(total);
        total
    })
}

/// Simulated time when this thread last got the turn.
pub(crate) fn turn_began() -> u64 {
    TURN_FROM.with(Cell::get)
}

/// Wait, ready to run (and climbsim told, or the turn handed: see [`HandOn`]), until climbsim
/// or a parking thread gives this thread the turn (it marks it running). After the run's end
/// (or without climbsim) every thread simply runs.
pub(crate) fn await_turn(shared: &Shared, slot: &Slot) {
    spin_while_not_running(shared, slot);
    loop {
        let seen = slot.wake_word.load(Ordering::Acquire);
        if slot.state() != state::READY {
            took_turn(shared);
            return;
        }
        if run_over(shared) {
            slot.let_go_at_end();
            return;
        }
        sleep_on_wake_word(shared, slot, seen);
    }
}

/// This thread runs from now: its quantum starts (see [`charge`]).
pub(crate) fn took_turn(shared: &Shared) {
    TURN_FROM.with(|t| t.set(sim_now(shared)));
}

/// climbsim usually lets a parked (or ready) thread run within a few hundred microseconds: a
/// spin saves the futex's sleep and wake-up, which on a VM whose idle vCPUs halt costs tens of
/// them. How long is climbsim's call (none on one CPU, nor where the machine is busy); not
/// once climbsim has given another thread the turn (this one's CPU is that thread's then).
pub(crate) fn spin_while_not_running(shared: &Shared, slot: &Slot) {
    let header = &shared.header;
    let now = real_monotonic_ns();
    let spin = header.spin.park_spin_ns.load(Ordering::Relaxed);
    let mut spin_until = now.saturating_add(spin);
    // One thread at a time spins longer (see `abi::LONG_PARK_SPIN_NS`): several would take the
    // CPUs from climbsim and from the thread that has the turn.
    let long_until = now.saturating_add(abi::LONG_PARK_SPIN_NS);
    let taken = header.spin.long_spin_until.load(Ordering::Acquire);
    let long = spin > 0 && taken <= now && header.spin.long_spin_until.compare_exchange(taken, long_until, Ordering::AcqRel, Ordering::Relaxed).is_ok();
    if long {
        spin_until = long_until;
    }
    let turns = header.turns.given.load(Ordering::Acquire);
    let mut limit = SpinLimit::until(spin_until, now);
    while slot.state() != state::RUNNING && !limit.passed() && header.turns.given.load(Ordering::Acquire) == turns {
        core::hint::spin_loop();
    }
    if long {
        let _ = header.spin.long_spin_until.compare_exchange(long_until, 0, Ordering::AcqRel, Ordering::Relaxed);
    }
}

/// Sleep until climbsim bumps the slot's wake word past `seen`; the timeout only notices a
/// climbsim that went away without waking us.
pub(crate) fn sleep_on_wake_word(shared: &Shared, slot: &Slot, seen: u32) {
    sys::futex_wait(&slot.wake_word, seen, 100_000_000);
    if slot.wake_word.load(Ordering::Acquire) == seen {
        climbsim_gone(shared);
    }
}

/// The run has ended, or climbsim is gone: nobody gives turns or releases any more.
pub(crate) fn run_over(shared: &Shared) -> bool {
    shared.header.mode.load(Ordering::Acquire) != mode::VIRTUAL || ORPHANED.load(Ordering::Relaxed)
}

/// This thread, which the kernel woke (a descriptor, a child's end, a join), runs again: in its
/// turn, unless climbsim or a waker let it go already.
pub(crate) fn resume_after_kernel_wake(shared: &Shared, slot: &Slot) {
    if active().is_none() {
        slot.let_go_at_end();
        return;
    }
    slot.make_ready(None);
    notify_scheduler(shared);
    await_turn(shared, slot);
}

/// A hand-over of the turn this running thread may make as it parks or ends, begun before it
/// publishes that (so that climbsim, which sees it begun, decides nothing meanwhile) and ended
/// by [`HandOn::finish`] after. Without it, every park is two hand-overs through climbsim (this
/// thread to climbsim, climbsim to the next), each a futex wake-up: most of what a thread's
/// start and end, or a lock passed between threads, costs in wall time.
pub(crate) struct HandOn<'a> {
    shared: &'a Shared,
    me: &'a Slot,
    ended: bool,
}

/// Begin a hand-over by this thread (`me`, see [`HandOn`]): before it publishes itself parked
/// or ended. Its slot is marked first, so that climbsim can tell a hand-over that will never
/// end (its thread was killed in it) from one under way.
pub(crate) fn hand_on<'a>(shared: &'a Shared, me: &'a Slot) -> HandOn<'a> {
    me.handing.store(1, Ordering::SeqCst);
    shared.header.turns.hand_ons_begun.fetch_add(1, Ordering::SeqCst);
    HandOn { shared, me, ended: false }
}

impl HandOn<'_> {
    /// This thread (`me`) has published itself parked or ended: the next ready thread takes the
    /// turn at once, if that is what climbsim would do now; else climbsim is told, and decides.
    pub(crate) fn finish(mut self) {
        let outcome = self.hand_to_next();
        self.end();
        if outcome == Handing::ClimbsimDecides {
            notify_scheduler(self.shared);
        }
    }

    /// Give the turn to the ready thread whose turn it is, if the rule of the turn
    /// (`Shared::who_decides`) says so: no other thread runs, and climbsim has nothing to decide
    /// first.
    fn hand_to_next(&self) -> Handing {
        let shared = self.shared;
        // Against a thread publishing itself at the same moment (a new one ready, say, while this
        // one parks): with a full fence between each one's store of its state and its look at
        // the other's, at least one of the two sees the other, so they never both leave it to
        // the other (see `Handing::OtherRuns`).
        core::sync::atomic::fence(Ordering::SeqCst);
        if active().is_none() {
            return Handing::ClimbsimDecides;
        }
        // The shim does not read /proc: whether a thread in waitpid returns is climbsim's call.
        let next = match shared.who_decides(|_, _| ChildWait::Unknown) {
            Decider::AnotherRuns => return Handing::OtherRuns,
            Decider::Climbsim(_) => return Handing::ClimbsimDecides,
            Decider::Turn(next) => next,
        };
        if !next.give_turn() {
            return Handing::ClimbsimDecides;
        }
        let header = &shared.header;
        header.turns.given.fetch_add(1, Ordering::Release);
        header.turns.handed.fetch_add(1, Ordering::Relaxed);
        next.wake_word.fetch_add(1, Ordering::AcqRel);
        sys::futex_wake(&next.wake_word);
        Handing::Handed
    }

    fn end(&mut self) {
        if !self.ended {
            self.ended = true;
            self.shared.header.turns.hand_ons_ended.fetch_add(1, Ordering::SeqCst);
            self.me.handing.store(0, Ordering::SeqCst);
        }
    }
}

/// How [`HandOn::hand_to_next`] went.
#[derive(PartialEq, Eq)]
enum Handing {
    /// The next ready thread has the turn.
    Handed,
    /// Another thread runs, or is being created: it parks (or starts) later, and hands the turn
    /// on or tells climbsim then; climbsim, woken now, could only spin meanwhile, on a CPU
    /// those threads need. (A reservation that is given up tells climbsim.)
    OtherRuns,
    /// climbsim decides what comes next: it is told.
    ClimbsimDecides,
}

impl Drop for HandOn<'_> {
    /// Ended without a hand-over (the park did not happen after all).
    fn drop(&mut self) {
        self.end();
    }
}
