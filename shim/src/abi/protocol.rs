//! A followed thread's state, and the only code that changes it.
//!
//! Every controller thread the shim follows has a [`Slot`]; its state says who may act on it.
//! One followed thread runs at a time: climbsim, or a thread that parks, gives the turn to the
//! ready thread whose turn it is ([`Shared::next_turn`]), so that the interleaving of a
//! controller's threads never depends on the host's scheduling. `Slot::state` is private to
//! the `abi` module; the shim and climbsim read it through [`Slot::state`] and change it only
//! through the named transitions below, each a compare-and-swap from the states it is allowed
//! from. A transition that finds the slot in another state changes nothing and says so: the
//! slot was taken from its thread meanwhile (written off, exited with its process).
//!
//! Who: S = the shim (own: the slot's own thread; any: another thread of the controller),
//! C = climbsim.
//!
//! | transition | from | to | who, where |
//! |---|---|---|---|
//! | [`Slot::reserve_unused`] | free, exited (and not handing on) | starting | S any: a thread about to be created, an exec, a trapped clone |
//! | [`Slot::reserve_process`] | free, exited | starting | C: slot 0, for the process it starts |
//! | [`Slot::claim_unused`] | free, exited (and not handing on) | running | S own: a thread's first followed call, with no reservation |
//! | [`Slot::claim_reservation`] | starting | running | S own: the reservation made for this thread or process |
//! | [`Slot::unreserve`] | starting | free | S any: a creation or an exec that failed |
//! | [`Slot::start_in_turn`] | starting, running | ready | S own: a new thread or process waits for its first turn |
//! | [`Slot::park`] | running | blocked, yielded | S own: a wait, or time given up |
//! | [`Slot::park_again`] | running | blocked, yielded | S own: the same wait, after a release that was not for it |
//! | [`Slot::make_ready`] | blocked, yielded | ready | C: at its instant; S any: a waker (futex, peer, child, signal); S own: the kernel woke it |
//! | [`Slot::give_turn`] | ready | running | C, or S any: a thread handing the turn on as it parks |
//! | [`Slot::let_go_at_end`] | blocked, yielded, ready | running | C: the run ended; S own: the run ended or climbsim is gone |
//! | [`Slot::exit`] | starting, running, blocked, yielded, ready, exited | exited | S: a thread's end, its process's end, an exec out of the followed world |
//! | [`Slot::exec_failed`] | exited | the state before | S own: the exec that left returned |
//! | [`Slot::write_off`] | starting, running, blocked, yielded, ready | exited | C: the thread is gone from the host (`/proc`) |
//!
//! Every transition but [`Slot::exec_failed`] publishes with `Release` what the slot's other
//! fields say (a parked thread's deadline and wait, a release's reason), so that whoever sees
//! the new state with `Acquire` sees them.

use core::sync::atomic::Ordering::{AcqRel, Acquire, Relaxed, Release, SeqCst};

use super::layout::{Conn, NEVER, Shared, Slot, timer_state, waits};

/// `Slot::state`.
pub mod state {
    pub const FREE: u32 = 0;
    /// Taken for a thread or process about to start (counts as running: climbsim decides
    /// nothing until it has claimed the slot and parked).
    pub const RESERVED: u32 = 1;
    /// Has the turn (or runs on the wall clock after the run's end).
    pub const RUNNING: u32 = 2;
    /// In an intercepted wait: let go by climbsim at its deadline or when its data is there, or
    /// by the thread that wakes it.
    pub const BLOCKED: u32 = 3;
    /// Gave time up to a due instant (a charge past the horizon, a quantum used up, a spin on an
    /// empty port).
    pub const YIELDED: u32 = 4;
    pub const EXITED: u32 = 5;
    /// Free to run (let go at its instant, or woken by the thread that ran): runs when it is
    /// given the turn.
    pub const READY: u32 = 6;

    pub fn name(state: u32) -> &'static str {
        match state {
            FREE => "free",
            RESERVED => "starting",
            RUNNING => "running",
            BLOCKED => "blocked",
            YIELDED => "yielded",
            EXITED => "exited",
            READY => "ready",
            _ => "?",
        }
    }
}

use state::{BLOCKED, EXITED, FREE, READY, RESERVED, RUNNING, YIELDED};

/// How a running thread parks (see [`Slot::park`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Parked {
    /// In a wait: let go at its deadline, when its data is there, or by a waker.
    Blocked,
    /// Gave time up: let go at its instant.
    Yielded,
}

impl Parked {
    pub fn state(self) -> u32 {
        match self {
            Parked::Blocked => BLOCKED,
            Parked::Yielded => YIELDED,
        }
    }
}

/// What a parked thread waits on besides its deadline (`Slot::deadline_ns`): written with the
/// park ([`Slot::park`]), read back by [`Slot::wait`].
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Wait {
    /// Its deadline only (a sleep, time given up to a due instant).
    Time,
    /// A turn given up after [`super::TURN_QUANTUM_NS`]: when it is ready again, the threads
    /// ready for any other reason run first.
    Turn,
    /// Bytes on the servo port (past `Slot::port_seen`), and/or a response on a sensor
    /// connection that names the slot among its waiters ([`Conn::start_waiting`]).
    Data { port: bool, conns: bool },
    /// A zero-timeout poll of the empty port: it resumes at the next byte due on it (or after
    /// the spin cap if none is).
    Spin,
    /// What the kernel wakes (descriptors climbsim does not model, a signal): only a look tells
    /// whether it is still blocked; and the port and connections among them, as in `Data`.
    Kernel { port: bool, conns: bool },
    /// A child's end, in the kernel's waitpid: the pid (≤ 0: any child of its process).
    Child(i64),
    /// Another thread: a condition's or semaphore's address, or the joined thread's `pthread_t`.
    Peer(u64),
    /// A futex (its address and bitset: `Slot::futex_addr`, `Slot::futex_bitset`) in address
    /// space `space`.
    Futex { space: u64 },
}

impl Wait {
    /// The port, if the wait is for its bytes (a spin on it included).
    pub fn port(self) -> bool {
        matches!(self, Wait::Data { port: true, .. } | Wait::Kernel { port: true, .. } | Wait::Spin)
    }

    /// Whether it waits on sensor connections (those that name the slot among their waiters).
    pub fn conns(self) -> bool {
        match self {
            Wait::Data { conns, .. } | Wait::Kernel { conns, .. } => conns,
            _ => false,
        }
    }
}

/// The states a thread is followed in (a slot that is neither free nor exited).
const LIVE: &[u32] = &[RESERVED, RUNNING, BLOCKED, YIELDED, READY];
const UNUSED: &[u32] = &[FREE, EXITED];
const PARKED: &[u32] = &[BLOCKED, YIELDED];

impl Slot {
    /// The slot's state (see [`state`]).
    pub fn state(&self) -> u32 {
        self.state.load(Acquire)
    }

    /// The slot is followed: neither free nor exited.
    pub fn is_live(&self) -> bool {
        LIVE.contains(&self.state())
    }

    /// Move from any of `from` to `to`; the state found if it was in none of them.
    fn transition(&self, from: &[u32], to: u32) -> Result<u32, u32> {
        let mut found = self.state.load(Acquire);
        loop {
            if !from.contains(&found) {
                return Err(found);
            }
            match self.state.compare_exchange(found, to, AcqRel, Acquire) {
                Ok(was) => return Ok(was),
                Err(now) => found = now,
            }
        }
    }

    /// Take an unused slot (free, or its thread ended) as `to`; not while its thread hands its
    /// turn on as it ends (nor after it died doing so: climbsim then writes the hand-over off
    /// and clears the mark).
    fn take_unused(&self, to: u32) -> bool {
        let taken = self.handing.load(SeqCst) == 0 && self.transition(UNUSED, to).is_ok();
        if taken {
            self.exec_marker_fd.store(0, Relaxed);
            // No thread until one is named (see `joins_live_thread`): not the last one's.
            self.thread.store(0, Release);
        }
        taken
    }

    /// free, exited → starting: reserved for a thread or a program about to start.
    #[must_use]
    pub fn reserve_unused(&self) -> bool {
        self.take_unused(RESERVED)
    }

    /// free, exited → starting: climbsim holds time until the process it is about to start has
    /// loaded the shim and claimed slot 0.
    #[must_use]
    pub fn reserve_process(&self) -> bool {
        self.transition(UNUSED, RESERVED).is_ok()
    }

    /// free, exited → running: taken by a thread that found no reservation for it.
    #[must_use]
    pub fn claim_unused(&self) -> bool {
        self.take_unused(RUNNING)
    }

    /// starting → running: the reservation is this thread's.
    #[must_use]
    pub fn claim_reservation(&self) -> bool {
        self.transition(&[RESERVED], RUNNING).is_ok()
    }

    /// starting → free: what it was reserved for will not start.
    #[must_use]
    pub fn unreserve(&self) -> bool {
        self.transition(&[RESERVED], FREE).is_ok()
    }

    /// starting, running → ready: a new thread or process waits for its first turn.
    #[must_use]
    pub fn start_in_turn(&self) -> bool {
        self.transition(&[RESERVED, RUNNING], READY).is_ok()
    }

    /// running → blocked or yielded, until `deadline` (simulated ns; [`super::NEVER`]) or what
    /// `wait` names; the reason of an earlier release is cleared.
    #[must_use]
    pub fn park(&self, parked: Parked, deadline: u64, wait: Wait) -> bool {
        self.deadline_ns.store(deadline, Relaxed);
        self.set_wait(wait);
        self.release.store(0, Relaxed);
        self.transition(&[RUNNING], parked.state()).is_ok()
    }

    /// running → blocked or yielded again, on the wait and deadline it had (a release that was
    /// not for it, or a signal that interrupted nothing).
    #[must_use]
    pub fn park_again(&self, parked: Parked) -> bool {
        self.release.store(0, Relaxed);
        self.transition(&[RUNNING], parked.state()).is_ok()
    }

    /// What the thread waits on (meaningful while it is parked; [`Wait::Time`] once its wait is
    /// over).
    pub fn wait(&self) -> Wait {
        let bits = self.waits.load(Relaxed);
        let data = |kernel: bool| {
            let (port, conns) = (bits & waits::PORT != 0, bits & waits::CONN != 0);
            if kernel { Wait::Kernel { port, conns } } else { Wait::Data { port, conns } }
        };
        if bits & waits::OTHER != 0 {
            data(true)
        } else if bits & waits::SPIN != 0 {
            Wait::Spin
        } else if bits & waits::CHILD != 0 {
            Wait::Child(self.awaited_child.load(Relaxed))
        } else if bits & waits::PEER != 0 {
            Wait::Peer(self.peer.load(Relaxed))
        } else if bits & waits::FUTEX != 0 {
            Wait::Futex { space: self.futex_space.load(Relaxed) }
        } else if bits & waits::TURN != 0 {
            Wait::Turn
        } else if bits & (waits::PORT | waits::CONN) != 0 {
            data(false)
        } else {
            Wait::Time
        }
    }

    /// The thread is in the kernel's waitpid (a cheaper `matches!(self.wait(), Wait::Child(_))`).
    pub fn in_waitpid(&self) -> bool {
        self.waits.load(Relaxed) & waits::CHILD != 0
    }

    /// The thread's wait is over: it runs, or is about to (its deadline and words stay, unread).
    pub fn wait_over(&self) {
        self.waits.store(0, Relaxed);
    }

    /// Write `wait` (see [`Slot::park`]).
    fn set_wait(&self, wait: Wait) {
        let data = |port: bool, conns: bool| (if port { waits::PORT } else { 0 }) | (if conns { waits::CONN } else { 0 });
        let bits = match wait {
            Wait::Time => 0,
            Wait::Turn => waits::TURN,
            Wait::Data { port, conns } => data(port, conns),
            Wait::Spin => waits::SPIN | waits::PORT,
            Wait::Kernel { port, conns } => waits::OTHER | data(port, conns),
            Wait::Child(pid) => {
                self.awaited_child.store(pid, Relaxed);
                waits::CHILD
            }
            Wait::Peer(peer) => {
                self.peer.store(peer, Relaxed);
                waits::PEER
            }
            Wait::Futex { space } => {
                self.futex_space.store(space, Relaxed);
                waits::FUTEX
            }
        };
        self.waits.store(bits, Relaxed);
    }

    /// blocked, yielded → ready, for reason `why` (`abi::release`, written first even if the
    /// thread is no longer parked: a waker that took it off a queue has woken it, whatever let
    /// it go first); None leaves the reason as it is.
    pub fn make_ready(&self, why: Option<u32>) -> bool {
        if let Some(why) = why {
            self.release.store(why, Release);
        }
        self.transition(PARKED, READY).is_ok()
    }

    /// ready → running: this thread has the turn. Whoever gives it wakes it.
    #[must_use]
    pub fn give_turn(&self) -> bool {
        self.transition(&[READY], RUNNING).is_ok()
    }

    /// blocked, yielded, ready → running: the run is over (or climbsim is gone), and every
    /// thread runs on the wall clock.
    pub fn let_go_at_end(&self) -> bool {
        self.transition(&[BLOCKED, YIELDED, READY], RUNNING).is_ok()
    }

    /// Any state a thread had → exited: it ended, its process ended, or it left the followed
    /// world (an exec of a program that will not load the shim). The caller has written
    /// `exited_ns` first.
    pub fn exit(&self) -> bool {
        self.transition(&[RESERVED, RUNNING, BLOCKED, YIELDED, READY, EXITED], EXITED).is_ok()
    }

    /// exited → `before`: an exec that left the followed world failed, and the task is what it
    /// was (`before` is free for a slot taken only to say it left).
    pub fn exec_failed(&self, before: u32) -> bool {
        self.transition(&[EXITED], before).is_ok()
    }

    /// starting, running, blocked, yielded, ready → exited: climbsim found the thread gone
    /// (killed, or its reservation's creator gone), with no word from its shim.
    pub fn write_off(&self) -> bool {
        self.transition(LIVE, EXITED).is_ok()
    }
}

/// What a thread blocked in the kernel's waitpid is doing, as far as the one who asks can tell
/// (see [`Shared::who_decides`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum ChildWait {
    /// Blocked: a child that can end, and so wake it, lives.
    Blocked,
    /// About to return: no child it waits for lives on, and the kernel is returning it.
    Returning,
    /// Cannot be told without reading `/proc` (the shim does not): climbsim decides.
    Unknown,
}

/// Who decides what happens next (see [`Shared::who_decides`]).
#[derive(Clone, Copy)]
pub enum Decider<'a> {
    /// Another followed thread runs, is being created, or is about to return from the kernel's
    /// waitpid: it decides when it parks or ends.
    AnotherRuns,
    /// climbsim decides, for this reason.
    Climbsim(Why),
    /// Nothing else comes first: the turn goes to this ready thread.
    Turn(&'a Slot),
}

/// How a running thread that climbsim asked to give way does so (see [`Shared::give_way`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum GiveWay {
    /// It made a followed call since it was asked, or is not running: the question is stale.
    Stale,
    /// Other threads are ready: they run first, at this instant; it is ready again after them
    /// (a yield after a quantum, `Wait::Turn`), charged nothing.
    ToReady,
    /// Nothing is ready, and something else waits for an instant to come (a sleeping thread,
    /// a timed wait, a reply due on the port, a signal timer): it is charged up to this instant,
    /// the earliest of those and one quantum of its CPU time from now, at which it is ready
    /// again after whatever else is due then. (At `now` itself when a thread waits on what only
    /// a look at the kernel tells: climbsim looks first.)
    Until(u64),
    /// Nothing else can happen without it (its process's only thread, or every other waits
    /// for it): it runs on, and simulated time holds, as for any computation.
    KeepOn,
}

/// Step 1 of the rule of the turn, as [`Shared::runners`] found it.
enum Runners {
    /// Another thread runs, is being created, or is returning from waitpid.
    Another,
    /// None does; `child_unknown`: a thread is in waitpid with a fate the asker cannot tell.
    Nobody { child_unknown: bool },
}

/// Why climbsim decides (see [`Decider::Climbsim`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Why {
    /// The controller did something virtual time cannot follow: the run fails.
    Refused,
    /// A thread waits on what the kernel wakes: whose turn comes first depends on its look.
    MustLook,
    /// A thread is in the kernel's waitpid, and the one who asks cannot tell whether it returns.
    ChildWait,
    /// No thread is ready: time moves, or a timer fires.
    NoneReady,
}

impl Shared {
    /// The ready thread whose turn it is: the one in the lowest slot, one that gave its turn up
    /// after a quantum after every other (so the order never depends on which thread the host
    /// happened to schedule first). Both climbsim and a thread handing its turn on pick by it.
    pub fn next_turn(&self) -> Option<&Slot> {
        let slots = self.live_slots();
        let ready = |s: &&Slot| s.state() == READY;
        slots.iter().filter(ready).find(|s| s.wait() != Wait::Turn).or_else(|| slots.iter().find(ready))
    }

    /// Who decides what happens next, once the asker has published its own state: the one
    /// rule of the turn, for the shim's thread that parks or ends (it hands the turn on itself
    /// when the answer is [`Decider::Turn`], else tells climbsim). climbsim's scheduler waits
    /// while step 1 holds ([`Shared::another_runs`]), then settles the rest itself: the looks,
    /// the refusal, the turns. In order:
    ///
    /// 1. another thread runs (running, starting, or `child_wait` says it is returning from
    ///    waitpid): it decides later;
    /// 2. climbsim, if the controller did something that cannot be followed, or a thread waits
    ///    on what only a look at the kernel tells ([`Shared::must_look`]), or one is in waitpid
    ///    and `child_wait` cannot tell its fate;
    /// 3. the turn, to the ready thread whose turn it is ([`Shared::next_turn`]);
    /// 4. climbsim, with no thread ready.
    pub fn who_decides(&self, child_wait: impl Fn(&[Slot], &Slot) -> ChildWait) -> Decider<'_> {
        let Runners::Nobody { child_unknown } = self.runners(child_wait) else { return Decider::AnotherRuns };
        if self.header.refused.load(Acquire) != 0 {
            return Decider::Climbsim(Why::Refused);
        }
        if self.live_slots().iter().any(|slot| self.must_look(slot)) {
            return Decider::Climbsim(Why::MustLook);
        }
        if child_unknown {
            return Decider::Climbsim(Why::ChildWait);
        }
        self.next_turn().map_or(Decider::Climbsim(Why::NoneReady), Decider::Turn)
    }

    /// Step 1 of the rule of the turn ([`Shared::who_decides`]): another thread runs, is being
    /// created, or is returning from the kernel's waitpid (as `child_wait` tells).
    pub fn another_runs(&self, child_wait: impl Fn(&[Slot], &Slot) -> ChildWait) -> bool {
        matches!(self.runners(child_wait), Runners::Another)
    }

    fn runners(&self, child_wait: impl Fn(&[Slot], &Slot) -> ChildWait) -> Runners {
        let slots = self.live_slots();
        let mut child_unknown = false;
        for slot in slots {
            match slot.state() {
                RUNNING | RESERVED => return Runners::Another,
                BLOCKED if slot.in_waitpid() => match child_wait(slots, slot) {
                    ChildWait::Returning => return Runners::Another,
                    ChildWait::Unknown => child_unknown = true,
                    ChildWait::Blocked => {}
                },
                _ => {}
            }
        }
        Runners::Nobody { child_unknown }
    }

    /// The rule of preemption, for the thread `me`, which climbsim asked to give way (it had
    /// computed for a quantum, `Clock::give_way_after_ns`, of CPU time without a followed call,
    /// at simulated time `now`): other ready threads run first; else a thread waiting on what
    /// only a look at the kernel tells is looked at, at this instant; else, if anything else
    /// waits for a later instant, time moves to the first such instant (at most a quantum on),
    /// as the kernel would have let those threads run while this one spins; else it runs on,
    /// and simulated time holds (computation is free: a model loaded at start costs no
    /// simulated time). While a thread or process is being created it runs on: the creation
    /// may be its own, half done.
    pub fn give_way(&self, me: &Slot, now: u64) -> GiveWay {
        let asked = me.give_way_asked.load(Acquire);
        if asked == 0 || asked - 1 != me.calls.load(Relaxed) || me.state() != RUNNING {
            return GiveWay::Stale;
        }
        let others = || self.live_slots().iter().filter(|s| !core::ptr::eq(*s, me));
        // A thread or process being created (by this thread, perhaps half-way through
        // pthread_create or fork): nothing is decided until it has claimed its slot.
        if others().any(|s| s.state() == RESERVED) {
            return GiveWay::KeepOn;
        }
        if others().any(|s| s.state() == READY) {
            return GiveWay::ToReady;
        }
        if others().any(|s| self.must_look(s) || (s.state() == BLOCKED && s.in_waitpid())) {
            return GiveWay::Until(now);
        }
        // (climbsim asks only with a quantum set: `--preempt-after-ms 0` asks nothing.)
        let mut until = now.saturating_add(self.header.clock.give_way_after_ns.load(Relaxed));
        let mut waits_for_time = false;
        for slot in others().filter(|s| matches!(s.state(), BLOCKED | YIELDED)) {
            let (deadline, wait) = (slot.deadline_ns.load(Relaxed), slot.wait());
            if deadline != NEVER {
                until = until.min(deadline);
                waits_for_time = true;
            }
            if wait.port() {
                until = until.min(self.header.port.next_due_ns.load(Relaxed));
                waits_for_time = true;
            }
            waits_for_time |= wait.conns();
        }
        for timer in self.live_sig_timers().iter().filter(|t| t.state.load(Acquire) == timer_state::ARMED) {
            until = until.min(timer.deadline_ns.load(Relaxed));
            waits_for_time = true;
        }
        if waits_for_time { GiveWay::Until(until.max(now)) } else { GiveWay::KeepOn }
    }

    /// `waiter` joins a thread that is followed and has not ended: it is blocked until that
    /// thread ends, which marks it ready as it goes (so nobody need look at the kernel for it).
    pub fn joins_live_thread(&self, waiter: &Slot) -> bool {
        let Wait::Peer(thread) = waiter.wait() else { return false };
        let pid = waiter.pid.load(Relaxed);
        self.live_slots().iter().any(|s| {
            // A reserved slot's thread has not claimed it yet: it names the thread once its
            // creator knows it (the joiner's `pthread_create` has returned), none before.
            // (Only a reservation for a thread, whose creator has written its marks: between its
            // taking and those, a slot holds its last thread's.)
            let state = s.state();
            let live = matches!(state, RUNNING | BLOCKED | YIELDED | READY) || (state == RESERVED && s.tid.load(Acquire) == super::layout::RESERVED_THREAD_TID);
            live && s.thread.load(Acquire) == thread && thread != 0 && s.pid.load(Relaxed) == pid && !core::ptr::eq(s, waiter)
        })
    }

    /// The thread `thread` (a `pthread_t`) of process `pid` was created for slot `slot`, which
    /// it may not have claimed yet: a join of it waits for its end from now (see
    /// [`Shared::joins_live_thread`]). Only a slot that names no thread yet, still this
    /// process's: whatever the slot's thread wrote since is the same value or newer.
    pub fn name_created_thread(&self, slot: usize, pid: i32, thread: u64) {
        if let Some(slot) = self.slots.get(slot)
            && slot.pid.load(Relaxed) == pid
            && slot.is_live()
        {
            let _ = slot.thread.compare_exchange(0, thread, AcqRel, Relaxed);
        }
    }

    /// `slot` waits on what the kernel wakes (a descriptor climbsim does not model, a thread
    /// that is not followed or is going away): only a look tells whether it is still blocked.
    pub fn must_look(&self, slot: &Slot) -> bool {
        slot.state() == BLOCKED && matches!(slot.wait(), Wait::Kernel { .. } | Wait::Peer(_)) && !self.joins_live_thread(slot)
    }

    /// The index of `slot` in the table (None: not one of this block's slots).
    pub fn slot_index(&self, slot: &Slot) -> Option<usize> {
        let offset = (slot as *const Slot as usize).checked_sub(self.slots.as_ptr() as usize)?;
        let index = offset / core::mem::size_of::<Slot>();
        (offset % core::mem::size_of::<Slot>() == 0 && index < self.slots.len()).then_some(index)
    }

    /// A response waits (written by climbsim, not yet taken by the controller) on a sensor
    /// connection that the thread in slot `slot` waits on ([`Conn::start_waiting`]).
    /// Only a connection of the slot's own process: a bit a thread left as it died in its wait
    /// (its process killed) lets go no thread of another.
    pub fn response_waiting_for(&self, slot: usize) -> bool {
        let Some(pid) = self.slots.get(slot).map(|s| s.pid.load(Relaxed)) else { return false };
        self.live_conns().iter().any(|conn| conn.is_followed() && conn.pid.load(Relaxed) == pid && conn.waited_by(slot) && conn.resp_written.load(Acquire) > conn.resp_taken.load(Acquire))
    }

    /// Slot `slot` is taken by a new thread: no connection names it among its waiters (one
    /// left by a thread that died in its wait, or left it by a `siglongjmp` from a handler,
    /// would let the new thread go for another's response).
    pub fn forget_conn_waits(&self, slot: usize) {
        for conn in self.live_conns() {
            conn.stop_waiting(slot);
        }
    }
}

/// Which threads wait on a sensor connection: each names itself before it parks with
/// `Wait::Data { conns: true }` (or `Kernel`), and takes its name back once the wait is over;
/// a table as long as the slots', so that any number of threads may wait on any number of
/// connections, each let go by a response on its own.
impl Conn {
    /// The thread in slot `slot` waits on this connection (before it parks).
    pub fn start_waiting(&self, slot: usize) {
        if let Some(word) = self.waiters.get(slot / 64) {
            word.fetch_or(1 << (slot % 64), Release);
        }
    }

    /// Its wait is over.
    pub fn stop_waiting(&self, slot: usize) {
        if let Some(word) = self.waiters.get(slot / 64) {
            word.fetch_and(!(1 << (slot % 64)), Release);
        }
    }

    /// Whether the thread in slot `slot` waits on this connection.
    pub fn waited_by(&self, slot: usize) -> bool {
        self.waiters.get(slot / 64).is_some_and(|word| word.load(Acquire) & (1 << (slot % 64)) != 0)
    }

    /// The entry follows a connection: taken, and filled in (`u32::MAX` while it is being).
    pub fn is_followed(&self) -> bool {
        !matches!(self.client_port.load(Acquire), 0 | u32::MAX)
    }

    /// The entry is taken for a new connection: nobody waits on it yet (a thread that ended in
    /// a wait on the one before left its name).
    pub fn no_waiters(&self) {
        for word in &self.waiters {
            word.store(0, Relaxed);
        }
    }
}

/// Compiled into climbsim's tests (the shim itself is never built as a test: its symbols would
/// stand in for libc's in the test binary).
#[cfg(test)]
mod tests {
    use super::super::layout::COMPUTE_QUANTUM_NS;
    use super::*;

    const ALL: [u32; 7] = [FREE, RESERVED, RUNNING, BLOCKED, YIELDED, EXITED, READY];

    /// A slot in `state`, the rest zero (a valid, empty slot).
    fn slot_in(state: u32) -> Slot {
        // SAFETY: every field of a slot is an atomic integer, for which zero is a valid value.
        let slot: Slot = unsafe { core::mem::zeroed() };
        slot.state.store(state, Release);
        slot
    }

    /// `transition` moves a slot from each state in `from` to `to`, and from every other state
    /// changes nothing and says it did not.
    fn check(name: &str, transition: impl Fn(&Slot) -> bool, from: &[u32], to: impl Fn(u32) -> u32) {
        for state in ALL {
            let slot = slot_in(state);
            let moved = transition(&slot);
            if from.contains(&state) {
                assert!(moved, "{name} from {}", state::name(state));
                assert_eq!(slot.state(), to(state), "{name} from {}", state::name(state));
            } else {
                assert!(!moved, "{name} is not allowed from {}", state::name(state));
                assert_eq!(slot.state(), state, "{name} from {} changed it", state::name(state));
            }
        }
    }

    #[test]
    fn reserve_unused_takes_a_free_or_exited_slot() {
        check("reserve_unused", Slot::reserve_unused, &[FREE, EXITED], |_| RESERVED);
    }

    #[test]
    fn reserve_process_takes_a_free_or_exited_slot() {
        check("reserve_process", Slot::reserve_process, &[FREE, EXITED], |_| RESERVED);
    }

    #[test]
    fn claim_unused_takes_a_free_or_exited_slot_running() {
        check("claim_unused", Slot::claim_unused, &[FREE, EXITED], |_| RUNNING);
    }

    /// A slot whose thread hands its turn on as it ends (or died doing so) is not taken, and a
    /// slot taken forgets the exec marker of the task that had it.
    #[test]
    fn an_unused_slot_is_not_taken_while_its_thread_hands_on_and_forgets_its_marker() {
        for take in [Slot::reserve_unused as fn(&Slot) -> bool, Slot::claim_unused] {
            let slot = slot_in(EXITED);
            slot.handing.store(1, SeqCst);
            assert!(!take(&slot));
            assert_eq!(slot.state(), EXITED);
            slot.handing.store(0, SeqCst);
            slot.exec_marker_fd.store(1023, Relaxed);
            assert!(take(&slot));
            assert_eq!(slot.exec_marker_fd.load(Relaxed), 0);
        }
        // climbsim's own reservation of slot 0 does not look at the mark (no thread of the
        // controller has it before the process starts).
        let slot = slot_in(FREE);
        slot.handing.store(1, SeqCst);
        assert!(slot.reserve_process());
    }

    #[test]
    fn claim_reservation_runs_a_starting_slot() {
        check("claim_reservation", Slot::claim_reservation, &[RESERVED], |_| RUNNING);
    }

    #[test]
    fn unreserve_frees_a_starting_slot() {
        check("unreserve", Slot::unreserve, &[RESERVED], |_| FREE);
    }

    #[test]
    fn start_in_turn_makes_a_starting_or_running_thread_ready() {
        check("start_in_turn", Slot::start_in_turn, &[RESERVED, RUNNING], |_| READY);
    }

    #[test]
    fn park_blocks_or_yields_a_running_thread() {
        check("park blocked", |s| s.park(Parked::Blocked, 5, Wait::Time), &[RUNNING], |_| BLOCKED);
        check("park yielded", |s| s.park(Parked::Yielded, 5, Wait::Turn), &[RUNNING], |_| YIELDED);
        check("park again blocked", |s| s.park_again(Parked::Blocked), &[RUNNING], |_| BLOCKED);
        check("park again yielded", |s| s.park_again(Parked::Yielded), &[RUNNING], |_| YIELDED);
    }

    /// A park writes its deadline and wait, and clears the last release's reason; a park again
    /// keeps the wait and deadline.
    #[test]
    fn a_park_publishes_its_deadline_and_wait_and_clears_the_release() {
        let slot = slot_in(RUNNING);
        slot.release.store(2, Relaxed);
        assert!(slot.park(Parked::Blocked, 42, Wait::Peer(7)));
        assert_eq!((slot.deadline_ns.load(Relaxed), slot.wait(), slot.release.load(Relaxed)), (42, Wait::Peer(7), 0));
        slot.state.store(RUNNING, Release);
        slot.release.store(4, Relaxed);
        assert!(slot.park_again(Parked::Blocked));
        assert_eq!((slot.deadline_ns.load(Relaxed), slot.wait(), slot.release.load(Relaxed)), (42, Wait::Peer(7), 0));
    }

    /// Every wait reads back as written, whatever was written before it; a wait that is over
    /// reads as time only.
    #[test]
    fn every_wait_reads_back_as_written() {
        let all = [
            Wait::Time,
            Wait::Turn,
            Wait::Data { port: true, conns: false },
            Wait::Data { port: false, conns: true },
            Wait::Data { port: true, conns: true },
            Wait::Spin,
            Wait::Kernel { port: false, conns: false },
            Wait::Kernel { port: true, conns: true },
            Wait::Kernel { port: false, conns: true },
            Wait::Child(-1),
            Wait::Child(4242),
            Wait::Peer(0xdead_beef),
            Wait::Futex { space: 77 },
        ];
        let slot = slot_in(RUNNING);
        for before in all {
            for wait in all {
                slot.set_wait(before);
                slot.set_wait(wait);
                assert_eq!(slot.wait(), wait, "after {before:?}");
                assert_eq!(slot.in_waitpid(), matches!(wait, Wait::Child(_)));
            }
        }
        // What the port and the connections are, whichever wait holds them.
        assert!(Wait::Spin.port() && Wait::Kernel { port: true, conns: false }.port() && !Wait::Child(1).port());
        assert!(Wait::Kernel { port: false, conns: true }.conns() && !Wait::Data { port: true, conns: false }.conns() && !Wait::Spin.conns());
        // Data on nothing is a wait on time (a poll of timerfds alone).
        slot.set_wait(Wait::Data { port: false, conns: false });
        assert_eq!(slot.wait(), Wait::Time);
        slot.set_wait(Wait::Child(3));
        slot.wait_over();
        assert_eq!(slot.wait(), Wait::Time);
    }

    #[test]
    fn make_ready_lets_a_parked_thread_go_and_writes_its_reason_whatever_it_found() {
        check("make_ready", |s| s.make_ready(None), &[BLOCKED, YIELDED], |_| READY);
        check("make_ready with a reason", |s| s.make_ready(Some(7)), &[BLOCKED, YIELDED], |_| READY);
        for state in ALL {
            let slot = slot_in(state);
            slot.release.store(3, Relaxed);
            slot.make_ready(Some(2));
            assert_eq!(slot.release.load(Relaxed), 2, "from {}", state::name(state));
            slot.make_ready(None);
            assert_eq!(slot.release.load(Relaxed), 2, "None keeps the reason, from {}", state::name(state));
        }
    }

    #[test]
    fn give_turn_runs_a_ready_thread() {
        check("give_turn", Slot::give_turn, &[READY], |_| RUNNING);
    }

    #[test]
    fn let_go_at_end_runs_every_parked_or_ready_thread() {
        check("let_go_at_end", Slot::let_go_at_end, &[BLOCKED, YIELDED, READY], |_| RUNNING);
    }

    #[test]
    fn exit_ends_a_thread_in_any_state_but_free() {
        check("exit", Slot::exit, &[RESERVED, RUNNING, BLOCKED, YIELDED, READY, EXITED], |_| EXITED);
    }

    #[test]
    fn exec_failed_gives_an_exited_slot_back_its_state() {
        for before in [FREE, RESERVED, RUNNING] {
            check("exec_failed", |s| s.exec_failed(before), &[EXITED], |_| before);
        }
    }

    #[test]
    fn write_off_ends_a_followed_thread() {
        check("write_off", Slot::write_off, &[RESERVED, RUNNING, BLOCKED, YIELDED, READY], |_| EXITED);
    }

    /// The states the table calls followed.
    #[test]
    fn a_slot_is_live_unless_free_or_exited() {
        for state in ALL {
            assert_eq!(slot_in(state).is_live(), !matches!(state, FREE | EXITED), "{}", state::name(state));
        }
    }

    /// Two takers of one slot (two threads after the same free slot, a waker and climbsim
    /// after the same parked thread): exactly one succeeds.
    #[test]
    fn of_two_racing_transitions_exactly_one_succeeds() {
        for _ in 0..200 {
            let slot = slot_in(FREE);
            let wins = std::thread::scope(|scope| {
                let takers: Vec<_> = (0..2).map(|_| scope.spawn(|| slot.claim_unused() as u32)).collect();
                takers.into_iter().map(|t| t.join().expect("a taker")).sum::<u32>()
            });
            assert_eq!(wins, 1);
            let slot = slot_in(READY);
            let wins = std::thread::scope(|scope| {
                let givers: Vec<_> = (0..2).map(|_| scope.spawn(|| slot.give_turn() as u32)).collect();
                givers.into_iter().map(|t| t.join().expect("a giver")).sum::<u32>()
            });
            assert_eq!(wins, 1);
        }
    }

    /// A block with `states` in its first slots (zeroed on the heap: it is megabytes).
    fn block_with(states: &[u32]) -> Box<Shared> {
        let layout = std::alloc::Layout::new::<Shared>();
        // SAFETY: every field of the block is an atomic integer (or an array of them), for
        // which zero is valid; the allocation has the block's layout, and the Box takes it.
        let shared = unsafe { Box::from_raw(std::alloc::alloc_zeroed(layout).cast::<Shared>()) };
        for (slot, &state) in shared.slots.iter().zip(states) {
            slot.state.store(state, Release);
        }
        shared.header.slots_high.store(states.len() as u32, Release);
        shared
    }

    /// Any number of threads wait on any number of connections, and each is let go by a
    /// response on its own only: threads 64 slots apart, connections 64 entries apart (a mask
    /// of 64 bits, as the table once had, mixed each pair up), a connection two threads wait on.
    #[test]
    fn a_response_lets_go_the_threads_waiting_on_its_connection_and_no_other() {
        let shared = block_with(&[RUNNING; 200]);
        shared.header.conns_high.store(130, Release);
        for conn in &shared.live_conns()[..130] {
            conn.client_port.store(40_000, Release);
        }
        let (conn, other_conn) = (&shared.conns[70], &shared.conns[6]);
        conn.start_waiting(3);
        conn.start_waiting(67);
        other_conn.start_waiting(131);
        assert!((0..200).all(|slot| !shared.response_waiting_for(slot)), "nothing written yet");
        other_conn.resp_written.store(100, Release);
        assert_eq!((0..200).filter(|&slot| shared.response_waiting_for(slot)).collect::<Vec<_>>(), [131]);
        other_conn.resp_taken.store(100, Release);
        conn.resp_written.store(1, Release);
        assert_eq!((0..200).filter(|&slot| shared.response_waiting_for(slot)).collect::<Vec<_>>(), [3, 67]);
        // A wait that is over names the thread no longer; a connection that ended (its entry
        // free) lets nobody go; an entry taken again starts with no waiters.
        conn.stop_waiting(3);
        assert_eq!((0..200).filter(|&slot| shared.response_waiting_for(slot)).collect::<Vec<_>>(), [67]);
        conn.client_port.store(0, Release);
        assert!(!shared.response_waiting_for(67));
        conn.no_waiters();
        conn.client_port.store(40_001, Release);
        assert!(!conn.waited_by(67) && !shared.response_waiting_for(67));
        // Past the high-water mark nothing is looked at (nor trusted past the table).
        shared.conns[140].client_port.store(1, Release);
        shared.conns[140].start_waiting(5);
        shared.conns[140].resp_written.store(1, Release);
        assert!(!shared.response_waiting_for(5));
        shared.header.conns_high.store(u32::MAX, Release);
        assert!(shared.response_waiting_for(5));
        // A connection of another process lets nobody go (a bit its thread left as it died);
        // nor does an entry being filled in; and a slot taken again names no connection.
        let other = &shared.conns[100];
        other.start_waiting(9);
        other.resp_written.store(1, Release);
        assert!(shared.response_waiting_for(9));
        other.pid.store(4242, Release);
        assert!(!shared.response_waiting_for(9), "another process's connection");
        other.pid.store(0, Release);
        other.client_port.store(u32::MAX, Release);
        assert!(!shared.response_waiting_for(9), "an entry being filled in");
        other.client_port.store(40_002, Release);
        shared.forget_conn_waits(9);
        assert!(!shared.response_waiting_for(9) && !other.waited_by(9), "the slot taken again");
        // Slots past the table are nobody's.
        conn.start_waiting(super::super::layout::SLOTS);
        assert!(!conn.waited_by(super::super::layout::SLOTS));
        assert_eq!(shared.slot_index(&shared.slots[199]), Some(199));
        assert_eq!(shared.slot_index(&block_with(&[]).slots[0]), None);
    }

    #[test]
    fn the_next_turn_is_the_lowest_ready_slot_and_a_thread_that_used_its_quantum_goes_last() {
        let shared = block_with(&[BLOCKED, READY, RUNNING, READY]);
        assert!(core::ptr::eq(shared.next_turn().expect("one is ready"), &shared.slots[1]));
        shared.slots[1].set_wait(Wait::Turn);
        assert!(core::ptr::eq(shared.next_turn().expect("one is ready"), &shared.slots[3]));
        shared.slots[3].set_wait(Wait::Turn);
        assert!(core::ptr::eq(shared.next_turn().expect("one is ready"), &shared.slots[1]), "all gave their quantum up: the lowest");
        let none = block_with(&[BLOCKED, RUNNING, YIELDED]);
        assert!(none.next_turn().is_none());
    }

    /// A running thread asked to give way (slot 1, asked at 7 calls, at 100 ms): stale once it
    /// made a call; to the ready threads first; else up to the first instant anything else
    /// waits for, at most a quantum on; else (nothing but it can move anything) on.
    #[test]
    fn a_thread_asked_to_give_way_yields_to_the_ready_then_to_the_next_instant_then_runs_on() {
        const NOW: u64 = 100_000_000;
        let shared = block_with(&[BLOCKED, RUNNING, BLOCKED]);
        let me = &shared.slots[1];
        let never = |slot: &Slot| {
            slot.deadline_ns.store(NEVER, Release);
            slot.set_wait(Wait::Futex { space: 1 });
        };
        never(&shared.slots[0]);
        never(&shared.slots[2]);
        me.calls.store(7, Release);
        shared.header.clock.give_way_after_ns.store(COMPUTE_QUANTUM_NS, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::Stale, "not asked");
        me.give_way_asked.store(8, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::KeepOn, "every other thread waits for another thread");
        me.calls.store(8, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::Stale, "a call since it was asked");
        me.calls.store(7, Release);
        shared.slots[2].deadline_ns.store(NOW + 3_000_000, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::Until(NOW + 3_000_000), "a timed wait's instant");
        shared.slots[2].deadline_ns.store(NOW + 300_000_000, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::Until(NOW + COMPUTE_QUANTUM_NS), "at most a quantum on");
        shared.slots[2].deadline_ns.store(NEVER, Release);
        shared.slots[2].set_wait(Wait::Data { port: true, conns: false });
        shared.header.port.next_due_ns.store(NOW + 1_000, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::Until(NOW + 1_000), "a reply due on the port");
        never(&shared.slots[2]);
        shared.header.sig_timers_high.store(1, Release);
        shared.sig_timers[0].state.store(timer_state::ARMED, Release);
        shared.sig_timers[0].deadline_ns.store(NOW + 2_000, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::Until(NOW + 2_000), "a signal timer");
        shared.slots[0].state.store(READY, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::ToReady, "the ready first, whatever is due");
        shared.slots[2].state.store(RESERVED, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::KeepOn, "a thread being created, perhaps by it");
        shared.slots[2].state.store(BLOCKED, Release);
        shared.slots[0].state.store(BLOCKED, Release);
        shared.slots[0].set_wait(Wait::Kernel { port: false, conns: false });
        assert_eq!(shared.give_way(me, NOW), GiveWay::Until(NOW), "a wait on the kernel is looked at first");
        never(&shared.slots[0]);
        shared.sig_timers[0].state.store(timer_state::FREE, Release);
        shared.header.clock.give_way_after_ns.store(4_000, Release);
        shared.slots[2].deadline_ns.store(NOW + 300_000_000, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::Until(NOW + 4_000), "the quantum as climbsim set it");
        me.state.store(BLOCKED, Release);
        assert_eq!(shared.give_way(me, NOW), GiveWay::Stale, "not running");
    }

    /// A thread blocked on what the kernel wakes must be looked at, unless it joins a followed
    /// thread that has not ended (that thread's end makes it ready).
    #[test]
    fn a_blocked_wait_on_the_kernel_must_be_looked_at_unless_it_joins_a_live_followed_thread() {
        let shared = block_with(&[BLOCKED, RUNNING]);
        let (waiter, joined) = (&shared.slots[0], &shared.slots[1]);
        waiter.set_wait(Wait::Kernel { port: false, conns: false });
        assert!(shared.must_look(waiter));
        waiter.set_wait(Wait::Data { port: true, conns: false });
        assert!(!shared.must_look(waiter));
        waiter.set_wait(Wait::Peer(0xabc));
        joined.thread.store(0xabc, Relaxed);
        assert!(shared.joins_live_thread(waiter) && !shared.must_look(waiter));
        joined.tid.store(super::super::layout::RESERVED_THREAD_TID, Release);
        for (state, live) in [(RESERVED, true), (EXITED, false), (READY, true), (BLOCKED, true)] {
            joined.state.store(state, Release);
            assert_eq!(shared.joins_live_thread(waiter), live, "joined {}", state::name(state));
            assert_eq!(shared.must_look(waiter), !live, "joined {}", state::name(state));
        }
        // A slot taken again names no thread (a reservation holds nothing of its last thread's)
        // until its creator names the one it made; then only that one, of that process.
        joined.state.store(EXITED, Release);
        joined.tid.store(777, Release);
        assert!(joined.reserve_unused());
        assert!(!shared.joins_live_thread(waiter), "a reservation with its last thread's name");
        joined.thread.store(0xabc, Relaxed);
        assert!(!shared.joins_live_thread(waiter), "a reservation its creator has not marked as a thread's");
        joined.thread.store(0, Relaxed);
        joined.tid.store(super::super::layout::RESERVED_THREAD_TID, Release);
        shared.name_created_thread(1, 4242, 0xabc);
        assert!(!shared.joins_live_thread(waiter), "named by another process");
        shared.name_created_thread(1, 0, 0xabc);
        assert!(shared.joins_live_thread(waiter), "named by its creator");
        shared.name_created_thread(1, 0, 0xdef);
        assert_eq!(joined.thread.load(Relaxed), 0xabc, "a name is given once");
        waiter.set_wait(Wait::Peer(0));
        assert!(!shared.joins_live_thread(waiter), "a join of no thread");
        waiter.state.store(READY, Release);
        assert!(!shared.must_look(waiter), "a waiter already let go is not looked at");
    }

    /// The rule of the turn, case by case, in its order.
    #[test]
    fn who_decides_another_runner_first_then_climbsim_then_the_turn() {
        let never = |_: &[Slot], _: &Slot| -> ChildWait { panic!("no thread is in waitpid") };
        let is = |decider: Decider<'_>, slot: &Slot| matches!(decider, Decider::Turn(s) if core::ptr::eq(s, slot));
        // Nobody ready: climbsim moves time.
        let shared = block_with(&[BLOCKED, YIELDED, EXITED, FREE]);
        assert!(matches!(shared.who_decides(never), Decider::Climbsim(Why::NoneReady)));
        // The lowest ready thread has the turn.
        let shared = block_with(&[BLOCKED, READY, READY]);
        assert!(is(shared.who_decides(never), &shared.slots[1]));
        assert!(!shared.another_runs(never), "ready threads wait for the turn: none runs");
        // A thread that runs, or one being created, decides later, whatever else waits.
        for runner in [RUNNING, RESERVED] {
            let shared = block_with(&[READY, BLOCKED, runner]);
            shared.slots[1].set_wait(Wait::Kernel { port: false, conns: false });
            shared.header.refused.store(1, Relaxed);
            assert!(matches!(shared.who_decides(never), Decider::AnotherRuns), "{}", state::name(runner));
            assert!(shared.another_runs(never), "{}", state::name(runner));
        }
        // A wait on the kernel: climbsim asks for a look before any turn.
        let shared = block_with(&[READY, BLOCKED]);
        shared.slots[1].set_wait(Wait::Kernel { port: true, conns: false });
        assert!(matches!(shared.who_decides(never), Decider::Climbsim(Why::MustLook)));
        // A refusal comes before the look: the run fails.
        shared.header.refused.store(1, Relaxed);
        assert!(matches!(shared.who_decides(never), Decider::Climbsim(Why::Refused)));
        // A thread in waitpid, as the asker tells it.
        let shared = block_with(&[READY, BLOCKED]);
        shared.slots[1].set_wait(Wait::Child(-1));
        assert!(matches!(shared.who_decides(|_, _| ChildWait::Returning), Decider::AnotherRuns));
        assert!(shared.another_runs(|_, _| ChildWait::Returning));
        assert!(!shared.another_runs(|_, _| ChildWait::Unknown) && !shared.another_runs(|_, _| ChildWait::Blocked));
        assert!(matches!(shared.who_decides(|_, _| ChildWait::Unknown), Decider::Climbsim(Why::ChildWait)));
        assert!(is(shared.who_decides(|_, _| ChildWait::Blocked), &shared.slots[0]));
        // The asker is seen as it published itself: parked, exited or ready, never running.
        let shared = block_with(&[EXITED, READY]);
        assert!(is(shared.who_decides(never), &shared.slots[1]));
    }

    /// `Slot::state` is written here only: the field is private to `abi` (the compiler keeps
    /// the rest of both crates off it), and nothing else in `abi` writes it.
    #[test]
    fn a_slots_state_is_written_in_this_file_only() {
        let abi = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shim/src/abi");
        let layout = std::fs::read_to_string(abi.join("layout.rs")).expect("layout.rs");
        let slot = &layout[layout.find("pub struct Slot {").expect("the slot's layout")..];
        let slot = &slot[..slot.find("\n}").expect("its end")];
        assert!(slot.contains("    pub(super) state: AtomicU32,"), "Slot::state must stay private to abi");
        let mut files = 0;
        for entry in std::fs::read_dir(&abi).expect("shim/src/abi") {
            let path = entry.expect("an entry").path();
            if path.file_name().is_some_and(|name| name == "protocol.rs") {
                continue;
            }
            let text = std::fs::read_to_string(&path).expect("a source file");
            for write in ["state.store", "state.compare_exchange", "state.swap", "state.fetch_"] {
                assert!(!text.contains(write), "{} writes a state ({write}): only protocol.rs may", path.display());
            }
            files += 1;
        }
        assert!(files >= 2, "read layout.rs and mod.rs");
    }
}
