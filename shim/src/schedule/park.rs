//! A thread's charges and its parks: how a followed thread meets climbsim's scheduler (its turn
//! is turn.rs's). What a thread does costs simulated time (charges, applied in batches, moving
//! the clock up to climbsim's horizon, else yielding); a wait publishes the thread as parked and
//! sleeps until climbsim (or a waker) lets it go.

use core::cell::Cell;
use core::sync::atomic::{AtomicU64, Ordering};

use crate::abi::{self, Parked, Shared, Slot, Wait, release, state};
use crate::schedule::block::{active, climbsim_gone, notify_scheduler};
use crate::schedule::delivery::take_due;
use crate::schedule::held;
use crate::schedule::now::{sim_now, thread_cpu_ns};
use crate::schedule::slot::my_slot;
use crate::schedule::turn::{add_charge, forget_charges, hand_on, resume_after_kernel_wake, run_over, sleep_on_wake_word, spin_while_not_running, took_turn, turn_began};
use crate::sys;

/// Charges a thread may run up while climbsim has not read its bytes yet, before it yields.
const HELD_CHARGE_LIMIT_NS: u64 = 50_000;

thread_local! {
    /// This thread's CPU time (real, ns) when its computation was last charged
    /// (`--controller-cpu`); 0: not yet read.
    static CPU_SEEN: Cell<u64> = const { Cell::new(0) };
    /// The check epoch when this thread last began to wait on what the kernel wakes (see
    /// [`look_at_kernel`]).
    static WAIT_EPOCH: Cell<u32> = const { Cell::new(0) };
}

/// With `--controller-cpu F`: the CPU time this thread used since it was last charged, × F.
/// Time spent parked (spinning for climbsim) is not the controller's and is skipped.
pub(crate) fn charge_computation(shared: &Shared) {
    let ns = take_computation(shared);
    if ns > 0 {
        charge(shared, ns);
    }
}

/// With `--controller-cpu F`: the simulated time (ns) the CPU time this thread used since it
/// was last charged costs, taken (0: none, or no factor).
pub(crate) fn take_computation(shared: &Shared) -> u64 {
    let factor = shared.header.clock.cpu_factor_ppm.load(Ordering::Relaxed);
    if factor == 0 {
        return 0;
    }
    let now = thread_cpu_ns();
    let seen = CPU_SEEN.with(|c| c.replace(now));
    if seen == 0 || now <= seen {
        return 0;
    }
    u64::try_from(u128::from(now - seen) * u128::from(factor) / 1_000_000).unwrap_or(u64::MAX)
}

/// Forget the CPU time used until now (after a park: the spin was not the controller's work).
pub(crate) fn reset_computation(shared: &Shared) {
    if shared.header.clock.cpu_factor_ppm.load(Ordering::Relaxed) != 0 {
        CPU_SEEN.with(|c| c.set(thread_cpu_ns()));
    }
}

/// Count an intercepted call (the watchdog's sign of life) and remember what it was.
pub(crate) fn note_call(shared: &Shared, call: u32) {
    shared.header.calls.fetch_add(1, Ordering::Relaxed);
    charge_computation(shared);
    if let Some(slot) = my_slot() {
        slot.calls.fetch_add(1, Ordering::Relaxed);
        slot.last_call.store(call, Ordering::Relaxed);
        slot.last_call_ns.store(shared.header.clock.now_ns.load(Ordering::Relaxed), Ordering::Relaxed);
    }
}

/// Bytes the controller sent that climbsim has not time-stamped yet: simulated time must not
/// move until it has, or their arrival would be stamped late.
pub(crate) fn held(shared: &Shared) -> bool {
    let header = &shared.header;
    header.port.tx_total.load(Ordering::Acquire) != header.port.tx_read.load(Ordering::Acquire) || shared.requests_unread()
}

/// Charge `ns` of simulated time to this thread; once the charges reach a batch they move the
/// clock: by the thread itself up to climbsim's horizon, else by yielding to climbsim.
pub(crate) fn charge(shared: &Shared, ns: u64) {
    let total = add_charge(ns);
    if total < shared.header.clock.batch_ns.load(Ordering::Relaxed) {
        return;
    }
    // Bytes in flight: the clock cannot move until climbsim has them, but yielding for a
    // microsecond's charge would cost a round trip per write; the thread's next wait yields anyway.
    if total < HELD_CHARGE_LIMIT_NS && held(shared) {
        return;
    }
    forget_charges();
    let header = &shared.header;
    loop {
        let now = header.clock.now_ns.load(Ordering::Acquire);
        let target = now.saturating_add(total);
        // A thread that keeps the turn (a loop that polls what is already ready, a spin on the
        // clock) gives it up after a quantum, as the kernel's scheduler would: the threads
        // ready meanwhile run first (climbsim puts it after them), whoever they are.
        if target.saturating_sub(turn_began()) >= abi::TURN_QUANTUM_NS {
            park(shared, Parked::Yielded, target, Wait::Turn);
            return;
        }
        if advance_within_horizon(shared, now, target) {
            return;
        }
        if header.clock.now_ns.load(Ordering::Acquire) == now {
            park(shared, Parked::Yielded, target, Wait::Time);
            return;
        }
    }
}

/// sched_yield on simulated time: it costs what a call does, and the threads ready at this
/// instant run first, as the kernel's run queue would have them (a loop that yields while it
/// waits for a lock's holder then lets the holder run, and moves the clock meanwhile).
pub(crate) fn yield_turn(shared: &Shared) {
    note_call(shared, abi::call::YIELD);
    charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
    if shared.live_slots().iter().any(|slot| slot.state() == state::READY) {
        park(shared, Parked::Yielded, sim_now(shared), Wait::Turn);
    }
}

/// Move the clock from `now` to `target` without climbsim, if that passes nothing climbsim
/// has due (the horizon) and climbsim has every byte the controller sent; whether it did.
pub(crate) fn advance_within_horizon(shared: &Shared, now: u64, target: u64) -> bool {
    let header = &shared.header;
    target <= header.clock.horizon_ns.load(Ordering::Acquire) && !held(shared) && header.clock.now_ns.compare_exchange(now, target, Ordering::AcqRel, Ordering::Acquire).is_ok()
}

/// A thread about to wait on what the kernel wakes (a descriptor climbsim does not model, a
/// thread's end): climbsim waits for its first look before it decides anything (see
/// `wait::wait_on_real_world`).
pub(crate) fn expect_look(shared: &Shared, slot: &Slot) {
    let epoch = shared.header.looks.check_epoch.load(Ordering::Acquire);
    WAIT_EPOCH.with(|e| e.set(epoch));
    slot.checked_epoch.store(epoch.wrapping_sub(1), Ordering::Relaxed);
}

/// Publish this thread as blocked on what the kernel wakes until `deadline` (simulated ns),
/// waiting on `wait` (a `Wait::Kernel` or `Wait::Peer`), and tell climbsim, which first waits
/// for its look (see [`expect_look`]).
pub(crate) fn publish_waiting_on_kernel(shared: &Shared, slot: &Slot, deadline: u64, wait: Wait) {
    let hand = hand_on(shared, slot);
    expect_look(shared, slot);
    publish_state(slot, Parked::Blocked, deadline, wait);
    hand.finish();
}

/// What a look at the kernel found (see [`look_at_kernel`]).
pub(crate) enum Look<T> {
    /// Nothing ready.
    Nothing,
    /// Something is ready, and was left there.
    Peeked,
    /// This, taken (a join that succeeded, an epoll wait's events).
    Took(T),
}

impl<T> Look<T> {
    /// A look that takes nothing (poll, select, pending signals) and found `found`: taken only
    /// when the look may `take`.
    pub(crate) fn taking_nothing(found: Option<T>, take: bool) -> Self {
        match (found, take) {
            (None, _) => Look::Nothing,
            (Some(_), false) => Look::Peeked,
            (Some(found), true) => Look::Took(found),
        }
    }
}

/// One look at what the kernel wakes, as climbsim asks: if nothing is ready, say so for the
/// epoch the look was made in, and sleep until climbsim asks again (it bumps the wake word) or
/// for `slice_ns` of wall time. `look(take)` says what is ready; with `take` false it should
/// only peek where it can (an epoll wait's look would take its edge-triggered events).
///
/// Only a look climbsim asked for, with every thread parked (an epoch begun since this wait
/// began, not yet answered), makes this thread ready: its instant is then the same in every
/// run. A look of its own (the first after the thread parked, or one after a slice of wall
/// time) may come while another thread runs: had it taken that thread's events, or made this
/// one ready there (the other's next yield, or the turn it hands on as it parks, depends on who
/// is ready), the run would have depended on the host (docs/performance-virtual-time.md
/// measured it). Such a look peeks, and if something is there, climbsim is told
/// (once: `told`) and asks every waiter once all threads have parked. What a look had to take
/// (a join) is `held`, returned when climbsim asks (or the wait ends otherwise).
pub(crate) fn look_at_kernel<T>(shared: &Shared, slot: &Slot, slice_ns: u64, told: &mut bool, held: &mut Option<T>, look: impl FnOnce(bool) -> Look<T>) -> Option<T> {
    let epoch = shared.header.looks.check_epoch.load(Ordering::Acquire);
    let seen = slot.wake_word.load(Ordering::Acquire);
    let asked = epoch != WAIT_EPOCH.with(Cell::get) && slot.checked_epoch.load(Ordering::Acquire) != epoch;
    if asked {
        if held.is_some() {
            return held.take();
        }
        if let Look::Took(found) = look(true) {
            return Some(found);
        }
        *told = false;
    } else if !*told && held.is_none() {
        match look(false) {
            Look::Nothing => {}
            Look::Peeked => *told = true,
            Look::Took(found) => {
                *held = Some(found);
                *told = true;
            }
        }
        if *told {
            // As when a thread has run: climbsim asks every waiter again before it decides
            // (told before this look is answered, so that it cannot decide on the answer alone).
            notify_scheduler(shared);
        }
    }
    if slot.checked_epoch.swap(epoch, Ordering::AcqRel) != epoch {
        shared.header.looks.checks_word.fetch_add(1, Ordering::AcqRel);
        sys::futex_wake(&shared.header.looks.checks_word);
    }
    sys::futex_wait(&slot.wake_word, seen, slice_ns);
    None
}

/// How a wait on what the kernel wakes ended (see [`wait_looking`]).
pub(crate) enum Looked<T> {
    /// climbsim (or a waker) let the thread go, for this reason (`abi::release`).
    Released(u32),
    /// The run is over, or climbsim is gone: the thread runs on the wall clock.
    Ended,
    /// A look found this; the thread has its turn again.
    Found(T),
}

/// Blocked, as [`publish_waiting_on_kernel`] published it (`publish` does it again), until
/// climbsim lets this thread go, or a look (`look`, made whenever climbsim asks and every
/// millisecond of wall time, see [`look_at_kernel`]) finds what the kernel has woken: a pipe,
/// an eventfd, a signal. A signal climbsim let it go for that interrupts nothing is sent, and
/// the wait goes on.
pub(crate) fn wait_looking<T>(shared: &Shared, slot: &Slot, publish: &dyn Fn(), mut look: impl FnMut(bool) -> Look<T>) -> Looked<T> {
    const SLICE_NS: u64 = 1_000_000;
    let mut slices = 0u32;
    let (mut told, mut held) = (false, None);
    // The pause between looks of its own: 1 ms, doubling while climbsim neither asks nor lets
    // the thread go (see [`OWN_LOOKS_AT_MOST_EVERY_NS`]).
    let mut pause_ns = SLICE_NS;
    loop {
        slices = slices.wrapping_add(1);
        if slices.is_multiple_of(100) || pause_ns == OWN_LOOKS_AT_MOST_EVERY_NS {
            climbsim_gone(shared);
        }
        if slot.state() == state::RUNNING {
            let why = slot.release.load(Ordering::Acquire);
            if why == release::SIGNAL && !take_due(slot) {
                publish();
                continue;
            }
            return held.map_or(Looked::Released(why), Looked::Found);
        }
        if active().is_none() {
            slot.let_go_at_end();
            return held.map_or(Looked::Ended, Looked::Found);
        }
        if slot.state() == state::READY {
            // Let go, waiting for its turn: it looks no more (a look now would race the thread
            // that runs).
            let seen = slot.wake_word.load(Ordering::Acquire);
            if slot.state() == state::READY {
                sys::futex_wait(&slot.wake_word, seen, SLICE_NS);
            }
            continue;
        }
        let word = slot.wake_word.load(Ordering::Acquire);
        if let Some(found) = look_at_kernel(shared, slot, pause_ns, &mut told, &mut held, &mut look) {
            // Woken by the kernel: this thread runs again in its turn.
            resume_after_kernel_wake(shared, slot);
            return Looked::Found(found);
        }
        pause_ns = if slot.wake_word.load(Ordering::Acquire) == word { (pause_ns * 2).min(OWN_LOOKS_AT_MOST_EVERY_NS) } else { SLICE_NS };
    }
}

/// The longest pause between a waiting thread's looks of its own at the kernel, reached by
/// doubling from 1 ms while nothing happens (climbsim asks whenever it matters, with every
/// thread parked; these looks only catch what wakes a thread from outside, on the wall clock).
/// Each look wakes the thread for microseconds, and many threads doing so every millisecond
/// beside busy cores can starve other tasks, among them the kernel's pty worker that carries
/// the replies to the controller (docs/performance-virtual-time.md, "A starved pty worker";
/// `hil/bench/short-sleepers.sh` shows it).
const OWN_LOOKS_AT_MOST_EVERY_NS: u64 = 64_000_000;

/// Publish this thread as blocked or yielded until `deadline` (simulated ns), waiting on
/// `wait`, and sleep until climbsim releases it; why it did (`abi::release`). A thread without
/// a slot cannot be followed: it returns at once, as if its deadline had come.
pub(crate) fn park(shared: &Shared, parked: Parked, deadline: u64, wait: Wait) -> u32 {
    let Some(slot) = my_slot() else { return release::DEADLINE };
    // A signal fired for this thread while it ran: taken before it waits.
    if slot.signals_due.load(Ordering::Acquire) != 0 && take_due(slot) {
        return release::SIGNAL;
    }
    let hand = hand_on(shared, slot);
    publish_parked(slot, parked, deadline, wait);
    hand.finish();
    await_release(shared, slot, parked, deadline)
}

/// The longest jump of a spin on the port while a reply is due on it.
const REPLY_JUMP_NS: u64 = 1_000_000;

/// Block until `deadline` or data on what `wait` names (see `park`).
pub(crate) fn park_blocked(shared: &'static Shared, deadline: u64, wait: Wait) -> u32 {
    if wait.port() {
        held::bound_horizon(shared);
    }
    park(shared, Parked::Blocked, deadline, wait)
}

/// A look at the port that found nothing, at simulated time `now`: time goes on to the next
/// byte due on it.
pub(crate) fn spin_on_port(shared: &'static Shared, now: u64) {
    // Pyserial's select also watches its own abort pipe; the C++ SDK reads the port without
    // blocking. On to the next byte due on the port, at most 1 ms at a time; with none due (an
    // absent servo), by the cap. A timeout the program checks between its looks is so overshot
    // by at most the cap, or 1 ms while a reply is on its way. Within the horizon the thread
    // moves the clock itself; a reply due now, or anything beyond, is climbsim's.
    // Replies climbsim wrote ahead show at their instants without it: within the horizon the
    // thread moves on to the next itself.
    let held_due = held::stream_at(shared, now).next_due;
    let next_due = shared.header.port.next_due_ns.load(Ordering::Acquire).min(held_due);
    let target = if next_due == crate::abi::NEVER { now.saturating_add(shared.header.clock.spin_cap_ns.load(Ordering::Relaxed)) } else { next_due.min(now.saturating_add(REPLY_JUMP_NS)) };
    if target <= now || !advance_within_horizon(shared, now, target) {
        park(shared, Parked::Yielded, target.max(now), Wait::Spin);
    }
}

/// Publish this thread (whose slot is `slot`) as parked until `deadline` on `wait`; nobody is
/// told yet (see [`park`]). Its unapplied charges are dropped: a blocked thread costs nothing.
pub(crate) fn publish_parked(slot: &Slot, parked: Parked, deadline: u64, wait: Wait) {
    forget_charges();
    publish_state(slot, parked, deadline, wait);
}

thread_local! {
    /// While an epoll wait over an edge-triggered registration of the port runs: where that
    /// registration has seen the port's stream to (epoll.rs).
    static PORT_SEEN: Cell<*const AtomicU64> = const { Cell::new(core::ptr::null()) };
}

/// Marks this thread's waits on the port, while it lives, as for bytes past `seen` only.
pub(crate) struct PortSeen;

impl PortSeen {
    pub(crate) fn watch(seen: Option<&'static AtomicU64>) -> Self {
        PORT_SEEN.with(|p| p.set(seen.map_or(core::ptr::null(), |s| s as *const AtomicU64)));
        PortSeen
    }
}

impl Drop for PortSeen {
    fn drop(&mut self) {
        PORT_SEEN.with(|p| p.set(core::ptr::null()));
    }
}

/// The slot's wait (until `deadline`, on `wait`), then its state, which makes it seen.
pub(crate) fn publish_state(slot: &Slot, parked: Parked, deadline: u64, wait: Wait) {
    let seen = PORT_SEEN.with(Cell::get);
    // SAFETY: a registration's entry in epoll.rs's static table.
    slot.port_seen.store(if seen.is_null() { 0 } else { unsafe { (*seen).load(Ordering::Relaxed) } }, Ordering::Relaxed);
    // A slot taken from its thread meanwhile (exited with its process) stays so: its wait
    // lasts until the run ends, or the process does.
    let _ = slot.park(parked, deadline, wait);
}

/// Sleep, parked as [`publish_parked`] published, until climbsim (or a waker) lets this thread
/// go; why (`abi::release`).
pub(crate) fn await_release(shared: &Shared, slot: &Slot, parked: Parked, deadline: u64) -> u32 {
    spin_while_not_running(shared, slot);
    loop {
        let seen = slot.wake_word.load(Ordering::Acquire);
        if slot.state() == state::RUNNING {
            let why = slot.release.load(Ordering::Acquire);
            // A signal timer fired for this thread: it sends itself the signal, and waits on
            // unless the signal interrupts the wait.
            if why == release::SIGNAL && !take_due(slot) {
                let _ = slot.park_again(parked);
                notify_scheduler(shared);
                continue;
            }
            // A release meant for an earlier wait of this thread (it had woken by itself, from
            // a real descriptor or a peer, before climbsim's decision landed): wait on.
            if why != release::DATA && why != release::ENDING && why != release::SIGNAL && deadline != abi::NEVER && sim_now(shared) < deadline {
                let _ = slot.park_again(parked);
                notify_scheduler(shared);
                continue;
            }
            reset_computation(shared);
            took_turn(shared);
            return why;
        }
        if run_over(shared) {
            slot.let_go_at_end();
            return release::ENDING;
        }
        sleep_on_wake_word(shared, slot, seen);
    }
}
