//! Threads, and joins.
//!
//! A new thread gets a slot reserved by its creator before it exists, so that no simulated time
//! passes while it starts. Locks, condition variables and semaphores need nothing here: their
//! futex calls are emulated (`futex.rs`). A join is the exception, because the kernel itself
//! wakes it when the thread's id is cleared at its exit: a joining thread counts as blocked,
//! the ending thread marks it ready before it goes, and the joiner looks at the thread again
//! whenever climbsim asks (climbsim first waits until an ending thread is gone) and every
//! 200 µs of wall time, so that time cannot move between the two.

use core::cell::Cell;
use core::ffi::{c_int, c_void};
use core::sync::atomic::{AtomicU32, AtomicUsize, Ordering};

use crate::abi::{NEVER, Shared, Wait, call, release, state};
use crate::schedule::block::{active, pid};
use crate::schedule::park::{note_call, reset_computation};
use crate::schedule::slot::my_slot;
use crate::sys::{self, clockid_t, real, timespec};
use crate::time::sim_now;

/// One slice of a real wait (wall time).
const SLICE_NS: u64 = 200_000;
const ETIMEDOUT: c_int = 110;

/// Where glibc keeps a thread's id, which the kernel clears (and wakes as a futex) when the
/// thread ends: as an offset from its `pthread_t` (0: not known yet). A join waits on that word
/// itself, with the shim's own untrapped calls and a spin first, instead of in glibc's futex
/// wait, which traps (about 4 µs a trap) twice a join.
static CLEAR_TID_OFFSET: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    /// The word the clone of the thread being created clears at its end (see `pthread_create`).
    static CLONE_CLEAR_TID: Cell<usize> = const { Cell::new(0) };
}

/// The trapped clone of the shim's pthread_create named `clear_tid` as the word the new thread's
/// end clears.
pub(crate) fn note_clone_clear_tid(clear_tid: usize) {
    CLONE_CLEAR_TID.with(|c| c.set(clear_tid));
}

/// A thread was created as `thread`: where its id word lies from it tells the offset for every
/// thread of this libc (glibc's `struct pthread` and its `tid` field).
fn learn_clear_tid(thread: usize) {
    let clear_tid = CLONE_CLEAR_TID.with(|c| c.replace(0));
    if let Some(offset) = clear_tid.checked_sub(thread).filter(|&o| o > 0 && o < 4096 && o % 4 == 0) {
        CLEAR_TID_OFFSET.store(offset, Ordering::Relaxed);
    }
}

/// The id word of `thread` that its end clears, once the offset is known.
fn clear_tid_word(thread: usize) -> Option<&'static AtomicU32> {
    let offset = CLEAR_TID_OFFSET.load(Ordering::Relaxed);
    // SAFETY: the word lies inside the caller's live pthread_t (a join of a thread that is not
    // joinable is undefined behaviour already), 4-aligned (checked when it was learned).
    (offset != 0 && thread != 0).then(|| unsafe { &*((thread + offset) as *const AtomicU32) })
}

/// Wait (wall time, until the monotonic `until`) for `word`, a thread's id, to be cleared by its
/// end, on the kernel's futex, which the kernel wakes when it clears the word. Whether it was
/// cleared. (Not a spin first: the thread ending needs a CPU to end on, and climbsim spins on
/// one while a thread runs; on two CPUs a spin here made a thread's create and join cost a
/// fifth more wall time.)
fn wait_cleared(word: &AtomicU32, until: &timespec) -> bool {
    let deadline = crate::time::to_ns(until);
    loop {
        let tid = word.load(Ordering::Acquire);
        if tid == 0 {
            return true;
        }
        let now = crate::time::real_monotonic_ns();
        if now >= deadline {
            return false;
        }
        sys::futex_wait(word, tid, deadline - now);
    }
}

fn real_deadline_after(ns: u64) -> timespec {
    crate::time::from_ns(crate::time::real_monotonic_ns().saturating_add(ns))
}

/// Wait for `addr` (a thread, to join it) until simulated `deadline` ([`NEVER`]: none), one
/// `slice` at a time (`slice(d)` waits for real until the monotonic `d`, returning 0 when
/// woken, ETIMEDOUT at `d`, or another error). Returns what the wait returns: 0 when woken,
/// ETIMEDOUT at the deadline.
fn peer_wait(shared: &Shared, addr: usize, deadline: u64, slice: &mut dyn FnMut(&timespec) -> c_int) -> c_int {
    note_call(shared, call::PEER);
    let Some(slot) = my_slot() else {
        return slice_until(shared, deadline, slice);
    };
    if deadline <= sim_now(shared) {
        // A zero timeout: one look, no block.
        // (ETIMEDOUT if the thread runs on; glibc's other answers, ESRCH, EINVAL, EDEADLK, as
        // they are.)
        return slice(&real_deadline_after(0));
    }
    let publish = || crate::schedule::park::publish_waiting_on_kernel(shared, slot, deadline, Wait::Peer(addr as u64));
    shared.header.peer_waiters.fetch_add(1, Ordering::AcqRel);
    publish();
    let (mut told, mut held) = (false, None);
    let result = loop {
        if slot.state() == state::RUNNING {
            match slot.release.load(Ordering::Acquire) {
                // (A join a look of its own made is the wait's result.)
                release::DEADLINE => break held.unwrap_or(ETIMEDOUT),
                release::ENDING => break slice_until(shared, deadline, slice),
                // A signal's handler runs (the thread sends it to itself); the wait goes on.
                release::SIGNAL => {
                    crate::schedule::delivery::take_due(slot);
                    publish();
                    continue;
                }
                // Marked running by a thread about to wake it: take the wake-up (or, if it
                // went to another waiter, wait on).
                _ => {
                    let rc = slice(&real_deadline_after(SLICE_NS));
                    if rc != ETIMEDOUT {
                        break rc;
                    }
                    publish();
                    continue;
                }
            }
        }
        if active().is_none() {
            slot.let_go_at_end();
            if let Some(rc) = held {
                break rc;
            }
            break slice_until(shared, deadline, slice);
        }
        if slot.state() == state::READY || shared.joins_live_thread(slot) {
            // Marked ready by the thread joined as it ended, or that thread is followed and has
            // not ended (nothing else can wake this one): nothing to look at until the turn
            // comes.
            let seen = slot.wake_word.load(Ordering::Acquire);
            if slot.state() != state::RUNNING {
                sys::futex_wait(&slot.wake_word, seen, SLICE_NS);
            }
            continue;
        }
        // A look whenever climbsim asks (threads ran: the one joined may have ended), and one
        // every slice of wall time.
        // (A look that finds the thread ended has joined it.)
        let look = crate::schedule::park::look_at_kernel(shared, slot, SLICE_NS, &mut told, &mut held, |_| match slice(&real_deadline_after(0)) {
            ETIMEDOUT => crate::schedule::park::Look::Nothing,
            rc => crate::schedule::park::Look::Took(rc),
        });
        if let Some(rc) = look {
            crate::schedule::turn::resume_after_kernel_wake(shared, slot);
            break rc;
        }
    };
    slot.wait_over();
    shared.header.peer_waiters.fetch_sub(1, Ordering::AcqRel);
    reset_computation(shared);
    result
}

/// After the run's end (or for a thread without a slot): slices until woken or the deadline.
fn slice_until(shared: &Shared, deadline: u64, slice: &mut dyn FnMut(&timespec) -> c_int) -> c_int {
    loop {
        let rc = slice(&real_deadline_after(SLICE_NS));
        if rc != ETIMEDOUT {
            return rc;
        }
        if deadline != NEVER && sim_now(shared) >= deadline {
            return ETIMEDOUT;
        }
    }
}

/// A thread is about to wake waiters on `addr`: they run from now (before the wake-up lands).
fn wake_peers(addr: usize) {
    let Some(shared) = active() else { return };
    if shared.header.peer_waiters.load(Ordering::Acquire) == 0 {
        return;
    }
    let me = pid();
    for slot in shared.live_slots() {
        if slot.state() == state::BLOCKED && slot.wait() == Wait::Peer(addr as u64) && slot.pid.load(Ordering::Relaxed) == me {
            slot.make_ready(None);
        }
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_join(thread: usize, result: *mut *mut c_void) -> c_int {
    let Some(shared) = active() else {
        let next = real!(pthread_join: fn(usize, *mut *mut c_void) -> c_int);
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(thread, result) };
    };
    join(shared, thread, result, NEVER)
}

/// A join with a deadline on the simulated CLOCK_REALTIME (glibc's futex wait on the thread's
/// id, which the kernel wakes as the thread ends, would not see that end on simulated time).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_timedjoin_np(thread: usize, result: *mut *mut c_void, at: *const timespec) -> c_int {
    let Some(shared) = active() else {
        let next = real!(pthread_timedjoin_np: fn(usize, *mut *mut c_void, *const timespec) -> c_int);
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(thread, result, at) };
    };
    timed_join(shared, thread, result, sys::CLOCK_REALTIME, at)
}

/// A join with a deadline on `clock` (CLOCK_MONOTONIC or CLOCK_REALTIME), on simulated time.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_clockjoin_np(thread: usize, result: *mut *mut c_void, clock: clockid_t, at: *const timespec) -> c_int {
    let Some(shared) = active() else {
        let next = real!(pthread_clockjoin_np: fn(usize, *mut *mut c_void, clockid_t, *const timespec) -> c_int);
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(thread, result, clock, at) };
    };
    timed_join(shared, thread, result, clock, at)
}

/// glibc's answers, then the join until `at` on `clock` (NULL: none): EINVAL for a clock other
/// than CLOCK_MONOTONIC and CLOCK_REALTIME, ETIMEDOUT once the deadline has passed.
fn timed_join(shared: &'static Shared, thread: usize, result: *mut *mut c_void, clock: clockid_t, at: *const timespec) -> c_int {
    const EINVAL: c_int = 22;
    if clock != sys::CLOCK_MONOTONIC && clock != sys::CLOCK_REALTIME {
        return EINVAL;
    }
    let deadline = if at.is_null() {
        NEVER
    } else {
        match sys::read_from_program(at) {
            // A negative second is a deadline that has passed (glibc's ETIMEDOUT, if the
            // thread still runs).
            Some(at) if at.tv_sec < 0 => 0,
            // A nanosecond field out of range is no deadline: glibc's wait answers EINVAL, which
            // its join takes for a spurious wake-up and waits on until the thread ends.
            Some(at) => sys::timespec_ns(&at).map_or(NEVER, |at| crate::time::sim_time_of(shared, clock, at).unwrap_or(0)),
            // (glibc would fault.)
            None => return EINVAL,
        }
    };
    join(shared, thread, result, deadline)
}

/// Join `thread` until simulated `deadline`: the kernel's join in slices of wall time (see
/// `peer_wait`).
fn join(shared: &'static Shared, thread: usize, result: *mut *mut c_void, deadline: u64) -> c_int {
    let clockjoin = real!(pthread_clockjoin_np: fn(usize, *mut *mut c_void, clockid_t, *const timespec) -> c_int);
    let cleared = clear_tid_word(thread);
    let mut slice = |until: &timespec| {
        // Once the id word is clear, glibc's join returns at once, with no futex call.
        if let Some(word) = cleared
            && !wait_cleared(word, until)
        {
            return ETIMEDOUT;
        }
        // The slice's futex wait is the kernel's (its deadline is on the wall clock, and the
        // kernel wakes a join itself when the thread's id is cleared at its exit).
        let _own = crate::sys::OwnCalls::enter();
        // SAFETY: the caller's thread and result pointer.
        unsafe { clockjoin(thread, result, sys::CLOCK_MONOTONIC, until) }
    };
    peer_wait(shared, thread, deadline, &mut slice)
}

/// What a new thread needs to claim the slot its creator reserved.
struct Start {
    slot: usize,
    routine: unsafe extern "C" fn(*mut c_void) -> *mut c_void,
    arg: *mut c_void,
}

unsafe extern "C" fn trampoline(start: *mut c_void) -> *mut c_void {
    // SAFETY: the Box pthread_create leaked for this thread.
    let start = unsafe { Box::from_raw(start.cast::<Start>()) };
    crate::schedule::slot::claim_reserved(start.slot);
    // SAFETY: the program's own start routine and argument.
    unsafe { (start.routine)(start.arg) }
}

/// The thread is ending: whoever joins it runs from now.
pub(crate) fn thread_ending() {
    // SAFETY: pthread_self has no preconditions.
    wake_peers(unsafe { sys::pthread_self() });
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pthread_create(thread: *mut usize, attr: *const c_void, routine: unsafe extern "C" fn(*mut c_void) -> *mut c_void, arg: *mut c_void) -> c_int {
    let next = real!(pthread_create: fn(*mut usize, *const c_void, unsafe extern "C" fn(*mut c_void) -> *mut c_void, *mut c_void) -> c_int);
    let Some(slot) = active().and_then(|_| crate::schedule::slot::reserve_thread_slot()) else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(thread, attr, routine, arg) };
    };
    let start = Box::into_raw(Box::new(Start { slot, routine, arg }));
    // SAFETY: our trampoline, with the start it frees.
    let rc = crate::schedule::slot::creating_thread(|| unsafe { next(thread, attr, trampoline, start.cast()) });
    if rc == 0 {
        // SAFETY: the real pthread_create succeeded and wrote the new thread's id there.
        let created = unsafe { *thread };
        // A join of it from now waits for its end, as for a thread that runs, even before it
        // has claimed its slot: not a look at the kernel in every slice.
        if let Some(shared) = active() {
            shared.name_created_thread(slot, pid(), created as u64);
        }
        if CLEAR_TID_OFFSET.load(Ordering::Relaxed) == 0 {
            learn_clear_tid(created);
        }
    }
    if rc != 0 {
        // SAFETY: not handed to any thread.
        drop(unsafe { Box::from_raw(start) });
        crate::schedule::slot::unreserve_slot(slot);
    }
    rc
}
