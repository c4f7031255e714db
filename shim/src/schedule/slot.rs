//! A thread's slot in the block: claimed at its first followed call (the slot reserved for it,
//! or a free one), reserved ahead for a thread or program about to start, started in its turn,
//! and given up as the thread ends. Every change of a slot's state goes through
//! `abi::protocol`.

use core::cell::Cell;
use core::ffi::c_void;
use core::sync::atomic::{AtomicU32, Ordering};

use crate::abi::{self, Shared, Slot, state};
use crate::schedule::block::{active, notify_scheduler, pid, refuse, shared};
use crate::schedule::now;
use crate::schedule::turn::{await_turn, forget_charges, hand_on, took_turn};
use crate::{native, sys};

/// The pthread key whose destructor marks a thread's slot exited.
static EXIT_KEY: AtomicU32 = AtomicU32::new(u32::MAX);

const NO_SLOT: u32 = u32::MAX;
/// A thread whose slot was exited at its end: what it still calls (glibc masks every signal
/// after the key destructors) is not followed, and its old slot, which another thread may have
/// taken since, is not touched.
const ENDED: u32 = u32::MAX - 1;

thread_local! {
    /// This thread's slot in the block (NO_SLOT until its first intercepted call).
    static SLOT: Cell<u32> = const { Cell::new(NO_SLOT) };
    /// Set while the shim's pthread_create creates a thread (it reserved its slot already).
    static CREATING_THREAD: Cell<bool> = const { Cell::new(false) };
}

/// The key whose destructor (`thread_exited`, at start) marks a thread's slot exited.
pub(crate) fn set_exit_key(key: u32) {
    EXIT_KEY.store(key, Ordering::Relaxed);
}

/// A forked child is a new process: its threads claim slots of their own.
pub(crate) fn forget_slot() {
    SLOT.with(|s| s.set(NO_SLOT));
}

/// A thread that claims a slot: its signal state starts afresh.
fn slot_claimed(slot: &Slot) {
    slot.signals_due.store(0, Ordering::Relaxed);
    slot.sig_waiting.store(0, Ordering::Relaxed);
    #[cfg(target_arch = "x86_64")]
    slot.sig_blocked.store(crate::handlers::program_mask(), Ordering::Relaxed);
}

/// This thread's slot if it has claimed one (never claims).
pub(crate) fn claimed_slot() -> Option<&'static Slot> {
    let index = SLOT.with(Cell::get);
    if index == NO_SLOT || index == ENDED {
        return None;
    }
    shared()?.slots.get(index as usize)
}

/// This thread's slot, claimed at its first intercepted call: the slot of a program this
/// thread was before an exec, the one climbsim reserved for the process it starts, or a free
/// one. None if all are taken (the thread then runs unfollowed).
pub(crate) fn my_slot() -> Option<&'static Slot> {
    let shared = shared()?;
    let index = SLOT.with(Cell::get);
    if index == ENDED {
        return None;
    }
    if index != NO_SLOT {
        return shared.slots.get(index as usize);
    }
    let (tid, pid) = (sys::gettid(), sys::getpid());
    let claim = |index: usize, slot: &'static Slot| {
        slot.futex_queued.store(0, Ordering::Release);
        slot.pid.store(pid, Ordering::Relaxed);
        slot.tid.store(tid, Ordering::Relaxed);
        slot.parent.store(sys::getppid(), Ordering::Relaxed);
        // SAFETY: pthread_self has no preconditions.
        slot.thread.store(unsafe { sys::pthread_self() } as u64, Ordering::Relaxed);
        slot_claimed(slot);
        SLOT.with(|s| s.set(index as u32));
        took_turn(shared);
        if tid != pid {
            watch_thread_exit();
        }
        Some(slot)
    };
    // After an exec the thread is the same task: its old slot (or the one it reserved before
    // the exec) is still running. A child of posix_spawn finds the one its parent reserved.
    let parent = sys::getppid();
    for (index, slot) in shared.live_slots().iter().enumerate() {
        let held = slot.state();
        let slot_tid = slot.tid.load(Ordering::Relaxed);
        let mine = matches!(held, state::RUNNING | state::RESERVED) && slot_tid == tid;
        let spawned_for_me = held == state::RESERVED && slot_tid == 0 && slot.pid.load(Ordering::Relaxed) == parent;
        if (mine || spawned_for_me) && (held == state::RUNNING || slot.claim_reservation()) {
            let claimed = claim(index, slot);
            // A program a followed process started (posix_spawn, fork, a vfork child's exec)
            // starts in its turn, as a thread does (below).
            if held == state::RESERVED && followed(shared, parent) {
                start_in_turn(slot);
            }
            return claimed;
        }
    }
    if tid != pid
        && shared.header.raw_clones.load(Ordering::Acquire) > 0
        && let Some((index, slot)) = raw_clone_reservation(shared, pid)
    {
        shared.header.raw_clones.fetch_sub(1, Ordering::AcqRel);
        let claimed = claim(index, slot);
        // It starts in its turn, as a thread from the shim's pthread_create does.
        start_in_turn(slot);
        return claimed;
    }
    let first = &shared.slots[0];
    if tid == pid && first.claim_reservation() {
        return claim(0, first);
    }
    // A free slot, or one whose thread has ended (a shell's children come and go).
    let (index, slot) = take_free_slot(shared, Slot::claim_unused)?;
    let claimed = claim(index, slot);
    notify_scheduler(shared);
    // A thread whose creation the shim did not see (libc's own thread creation, such as the
    // thread glibc starts for a SIGEV_THREAD timer's callback; a runtime's raw clone), and a
    // process a followed one started (a forked child, a vfork child's exec), start in their
    // turn: their creator runs on until it parks. Otherwise the two ran at once: the callback's
    // instant, and the order of a parent's and a spawned child's lines, differed from run to
    // run.
    if tid != pid || followed(shared, parent) {
        start_in_turn(slot);
    }
    claimed
}

/// Whether process `pid` is followed (one of its threads has a slot).
fn followed(shared: &Shared, pid: i32) -> bool {
    shared.live_slots().iter().any(|s| s.pid.load(Ordering::Relaxed) == pid && s.is_live())
}

/// A thread that has just claimed `slot` waits, ready, for its turn (without climbsim, or
/// after the run's end, it simply runs).
fn start_in_turn(slot: &Slot) {
    match active() {
        Some(shared) => {
            // Its creator has usually parked by now (in a join, say): the turn is then this
            // thread's at once, without climbsim.
            let hand = hand_on(shared, slot);
            if slot.start_in_turn() {
                hand.finish();
                await_turn(shared, slot);
            }
        }
        None => {
            // A reservation is this thread's (a claimed slot runs already).
            let _ = slot.claim_reservation();
        }
    }
}

/// A trapped clone is about to create a thread whose TLS pointer is `tls` (0: none given): a
/// slot is reserved for it, so that climbsim counts it as running, and decides nothing, until
/// the thread has claimed it (at its first followed call) and waits for its turn. Not for a
/// thread the shim's pthread_create creates, which reserved its own ([`creating_a_thread`]).
pub(crate) fn reserve_raw_clone(tls: u64) {
    let Some(shared) = active() else { return };
    let Some((_, slot)) = take_free_slot(shared, Slot::reserve_unused) else { return };
    slot.pid.store(pid(), Ordering::Relaxed);
    slot.clone_tls.store(tls, Ordering::Relaxed);
    slot.tid.store(abi::RAW_CLONE_TID, Ordering::Release);
    shared.header.raw_clones.fetch_add(1, Ordering::AcqRel);
}

/// The slot a trapped clone reserved for this thread (found by its TLS pointer), taken.
fn raw_clone_reservation(shared: &Shared, pid: i32) -> Option<(usize, &Slot)> {
    const ARCH_GET_FS: i64 = 0x1003;
    let mut fs: u64 = 0;
    native::call2(sys::nr::ARCH_PRCTL, ARCH_GET_FS, &mut fs as *mut u64 as i64);
    let reserved = |slot: &Slot, key: u64| {
        slot.state() == state::RESERVED && slot.tid.load(Ordering::Acquire) == abi::RAW_CLONE_TID && slot.pid.load(Ordering::Relaxed) == pid && slot.clone_tls.load(Ordering::Relaxed) == key
    };
    for key in [fs, 0] {
        for (index, slot) in shared.live_slots().iter().enumerate() {
            if reserved(slot, key) && slot.claim_reservation() {
                return Some((index, slot));
            }
        }
    }
    None
}

/// The calling thread is not `claimed`'s, though its thread-locals say so: it shares them with
/// the thread whose slot that is (a thread of the same process made by a clone without a thread
/// pointer of its own). Two system calls: asked only while a trapped clone's thread has not
/// claimed its slot.
pub(crate) fn shares_thread_locals(claimed: &Slot) -> bool {
    // Its thread pointer is its creator's too (a thread whose slot was since given to another
    // has a thread pointer of its own).
    // SAFETY: pthread_self has no preconditions.
    let same_thread_pointer = claimed.thread.load(Ordering::Relaxed) == unsafe { sys::pthread_self() } as u64;
    same_thread_pointer && claimed.tid.load(Ordering::Relaxed) != sys::gettid() && claimed.pid.load(Ordering::Relaxed) == sys::getpid()
}

/// A thread that shares its creator's thread-locals (see [`shares_thread_locals`]) cannot be
/// followed: the run fails saying so, and the slot reserved for it goes, so that climbsim, which
/// waits for every thread to park before it judges a refusal, need not wait for it. (The count of
/// reservations stays up: this thread's calls must still be told from its creator's, which they
/// are while it is.)
pub(crate) fn refuse_shared_thread_locals() {
    refuse(abi::refused::SHARED_TLS);
    let Some(shared) = shared() else { return };
    let pid = sys::getpid();
    let without_tls = |slot: &Slot| {
        slot.state() == state::RESERVED && slot.tid.load(Ordering::Acquire) == abi::RAW_CLONE_TID && slot.pid.load(Ordering::Relaxed) == pid && slot.clone_tls.load(Ordering::Relaxed) == 0
    };
    if let Some(slot) = shared.live_slots().iter().find(|slot| without_tls(slot))
        && slot.unreserve()
    {
        notify_scheduler(shared);
    }
}

/// Whether the shim's pthread_create is creating a thread in this one (its clone then needs no
/// reservation: see `reserve_raw_clone`).
pub(crate) fn creating_a_thread() -> bool {
    CREATING_THREAD.with(Cell::get)
}

/// While the shim's pthread_create creates a thread (see `reserve_raw_clone`).
pub(crate) fn creating_thread<T>(create: impl FnOnce() -> T) -> T {
    CREATING_THREAD.with(|c| c.set(true));
    let result = create();
    CREATING_THREAD.with(|c| c.set(false));
    result
}

/// A slot nobody uses (slot 0 is climbsim's to reserve), taken by `take` (`Slot::reserve_unused`
/// or `Slot::claim_unused`). None if every one is in use: the table is then marked full, which
/// fails the run naming it, rather than leave a thread unfollowed without a word.
pub(crate) fn take_free_slot(shared: &Shared, take: fn(&Slot) -> bool) -> Option<(usize, &Slot)> {
    for (index, slot) in shared.slots.iter().enumerate().skip(1) {
        if slot.is_live() || !crate::marker::exec_over(slot) {
            continue;
        }
        // Scans stop at the high-water mark: it is raised before the slot is taken.
        shared.header.slots_high.fetch_max(index as u32 + 1, Ordering::AcqRel);
        if take(slot) {
            shared.forget_conn_waits(index);
            return Some((index, slot));
        }
    }
    refuse(abi::refused::SLOTS);
    None
}

/// Reserve a slot for a thread about to be created (the creator runs on meanwhile).
pub(crate) fn reserve_thread_slot() -> Option<usize> {
    let shared = shared()?;
    let (index, slot) = take_free_slot(shared, Slot::reserve_unused)?;
    slot.pid.store(pid(), Ordering::Relaxed);
    // Not 0, which marks a process's reservation (see `my_slot`).
    slot.tid.store(abi::RESERVED_THREAD_TID, Ordering::Release);
    Some(index)
}

pub(crate) fn unreserve_slot(index: usize) {
    if let Some(shared) = shared()
        && let Some(slot) = shared.slots.get(index)
        && slot.unreserve()
    {
        // A thread that parked meanwhile left the decision to this one (see `turn::HandOn`).
        notify_scheduler(shared);
    }
}

/// A new thread's first act: the slot its creator reserved is its own.
pub(crate) fn claim_reserved(index: usize) {
    let Some(slot) = shared().and_then(|s| s.slots.get(index)) else { return };
    // A thread that made a followed call before its start routine (glibc's "stopped start",
    // for explicit scheduling attributes, waits on a lock first) claimed a slot of its own
    // then: that one goes, or it would count as running for ever.
    let before = SLOT.with(Cell::get);
    if before != NO_SLOT
        && before as usize != index
        && let Some(old) = shared().and_then(|s| s.slots.get(before as usize))
    {
        old.futex_queued.store(0, Ordering::Release);
        old.exit();
    }
    slot.futex_queued.store(0, Ordering::Release);
    let tid = sys::gettid();
    slot.pid.store(pid(), Ordering::Relaxed);
    slot.tid.store(tid, Ordering::Relaxed);
    slot.parent.store(sys::getppid(), Ordering::Relaxed);
    // SAFETY: pthread_self has no preconditions.
    slot.thread.store(unsafe { sys::pthread_self() } as u64, Ordering::Relaxed);
    slot_claimed(slot);
    SLOT.with(|s| s.set(index as u32));
    forget_charges();
    watch_thread_exit();
    // It starts in its turn: its creator runs on until it parks.
    start_in_turn(slot);
}

/// This thread's end runs `thread_exited` (the exit key's destructor runs only for a thread
/// that set a value for it).
fn watch_thread_exit() {
    let key = EXIT_KEY.load(Ordering::Relaxed);
    if key != u32::MAX {
        // SAFETY: a key from pthread_key_create; the value only has to be non-null.
        unsafe { sys::pthread_setspecific(key, core::ptr::dangling::<c_void>()) };
    }
}

/// A new program in this process (its shim's start, after an exec, before its main thread
/// claims its slot): the slots of the threads of its earlier image are theirs no longer, but
/// for the one the main thread takes on (running under the process's id: the exec'ing
/// thread's, see `spawn::exec_with`). An exec ends every other thread of the process
/// (one from a thread other than the main one ends the main one too, and takes its id) without
/// any of the shim's code running in them: they are exited now, or climbsim would wait for ever
/// for a blocked main thread's look, or a running thread's park.
pub(crate) fn exit_earlier_image() {
    let Some(shared) = shared() else { return };
    let pid = sys::getpid();
    for slot in shared.live_slots() {
        // Kept: the one taken on, and reservations (climbsim's for the first process, whose
        // thread id it may not have written yet).
        let held = slot.state();
        let kept = held == state::RESERVED || (held == state::RUNNING && slot.tid.load(Ordering::Relaxed) == pid);
        if slot.pid.load(Ordering::Relaxed) == pid && slot.is_live() && !kept {
            exit_slot(slot);
        }
    }
}

/// This thread has ended, its slot exited (see [`ENDED`]).
pub(crate) fn forget_ended_slot() {
    SLOT.with(|s| s.set(ENDED));
}

pub(crate) fn exit_slot(slot: &Slot) {
    let Some(shared) = shared() else {
        slot.exit();
        return;
    };
    let hand = hand_on(shared, slot);
    slot.exited_ns.store(now::sim_now(shared), Ordering::Relaxed);
    slot.exit();
    hand.finish();
}
