//! Futexes on simulated time: every futex system call a followed thread makes (glibc's locks,
//! condition variables, semaphores and joins, libstdc++'s, Rust std's, the JVM's, libuv's)
//! reaches here through the seccomp trap, and none of them is handed to the kernel's futex.
//!
//! A wait publishes the thread as blocked (until its timeout, in simulated time) and queues it
//! on the futex's key; a wake takes waiters off the queue and marks them running *before* it
//! wakes them, so that climbsim never sees every thread blocked while one is about to run. The
//! queues are the slots' futex fields in the shared block, under one lock in the block, so
//! wakers and waiters in different processes meet on a futex in shared memory too.
//!
//! The value check of a wait is the kernel's own: a native FUTEX_WAIT with a zero timeout says
//! whether the word still holds the expected value (and faults for a bad address as a real wait
//! would), under the queue lock, which every wake of that key also takes; so no wake-up can fall
//! between the check and the queueing.
//!
//! Not emulated (run natively, so that their waits are the kernel's): the priority-inheritance
//! operations, which glibc uses only for PTHREAD_PRIO_INHERIT mutexes.

use core::ffi::c_long;
use core::sync::atomic::Ordering;

use crate::abi::{NEVER, Parked, Shared, Slot, Wait, call, release, state};
use crate::native;
use crate::schedule::block::active;
use crate::schedule::park::{charge, note_call};
use crate::schedule::slot::my_slot;
use crate::sys::{self, nr, timespec};
use crate::time::{sim_now, sim_time_of, to_ns};

const FUTEX_WAIT: i32 = 0;
const FUTEX_WAKE: i32 = 1;
const FUTEX_REQUEUE: i32 = 3;
const FUTEX_CMP_REQUEUE: i32 = 4;
const FUTEX_WAKE_OP: i32 = 5;
const FUTEX_WAIT_BITSET: i32 = 9;
const FUTEX_WAKE_BITSET: i32 = 10;
const FUTEX_PRIVATE_FLAG: i32 = 128;
const FUTEX_CLOCK_REALTIME: i32 = 256;
const FUTEX_BITSET_MATCH_ANY: u32 = u32::MAX;

const EINVAL: c_long = 22;
const EINTR: c_long = 4;
const ETIMEDOUT: c_long = 110;

/// Where a futex lives: in this process's memory (`space` = its pid, `offset` = the address),
/// or in a shared file mapping (`space` = the file, `offset` = the offset in it), where another
/// process may wait on the same word at another address.
#[derive(Clone, Copy, PartialEq, Eq)]
struct Key {
    space: u64,
    offset: u64,
}

/// The arguments of futex(2), as the trap saw them.
pub(crate) struct Args {
    pub uaddr: usize,
    pub op: i32,
    pub val: u32,
    /// The timeout pointer, or val2 for the requeue and wake-op operations.
    pub timeout_or_val2: usize,
    pub uaddr2: usize,
    pub val3: u32,
}

/// Run one futex call for a followed thread: what the system call returns (negative errno), or
/// None for a call that goes to the kernel as it is (after the run, a thread without a slot,
/// the priority-inheritance operations).
pub(crate) fn emulate(args: &Args) -> Option<c_long> {
    let (Some(shared), Some(slot)) = (active(), my_slot()) else { return None };
    let private = args.op & FUTEX_PRIVATE_FLAG != 0;
    let command = args.op & !(FUTEX_PRIVATE_FLAG | FUTEX_CLOCK_REALTIME);
    let key = |addr: usize| key_of(addr, private);
    Some(match command {
        FUTEX_WAIT => {
            // A relative timeout on CLOCK_MONOTONIC.
            let deadline = if args.timeout_or_val2 == 0 {
                NEVER
            } else {
                // SAFETY: the caller's timespec (the kernel would fault on a bad one; so do we).
                sim_now(shared).saturating_add(to_ns(unsafe { &*(args.timeout_or_val2 as *const timespec) }))
            };
            wait(shared, slot, args, key(args.uaddr), deadline, FUTEX_BITSET_MATCH_ANY)
        }
        FUTEX_WAIT_BITSET => {
            if args.val3 == 0 {
                return Some(-EINVAL);
            }
            // An absolute timeout on CLOCK_MONOTONIC, or CLOCK_REALTIME with the flag.
            let deadline = if args.timeout_or_val2 == 0 {
                NEVER
            } else {
                let clock = if args.op & FUTEX_CLOCK_REALTIME != 0 { sys::CLOCK_REALTIME } else { sys::CLOCK_MONOTONIC };
                // SAFETY: the caller's timespec.
                let at = to_ns(unsafe { &*(args.timeout_or_val2 as *const timespec) });
                sim_time_of(shared, clock, at).unwrap_or(0)
            };
            wait(shared, slot, args, key(args.uaddr), deadline, args.val3)
        }
        FUTEX_WAKE => counted(shared, wake(shared, key(args.uaddr), args.val, FUTEX_BITSET_MATCH_ANY)),
        FUTEX_WAKE_BITSET => {
            if args.val3 == 0 {
                return Some(-EINVAL);
            }
            counted(shared, wake(shared, key(args.uaddr), args.val, args.val3))
        }
        FUTEX_REQUEUE | FUTEX_CMP_REQUEUE => {
            let expected = (command == FUTEX_CMP_REQUEUE).then_some(args.val3);
            counted(shared, requeue(shared, args, key(args.uaddr), key(args.uaddr2), expected))
        }
        FUTEX_WAKE_OP => counted(shared, wake_op(shared, args, key(args.uaddr), key(args.uaddr2))),
        _ => return None,
    })
}

/// A wake-up is counted but costs no simulated time: it is part of the lock or queue operation
/// that made it (glibc's unlock, a condition variable's signal), as it was when those were
/// followed through their symbols; charging it would let a thread that wakes another run past
/// instants it used to keep.
fn counted(shared: &Shared, result: c_long) -> c_long {
    note_call(shared, call::FUTEX);
    result
}

/// Whether the word at `uaddr` holds `val`, asked of the kernel (0 if so, else -EAGAIN, -EFAULT
/// or -EINVAL as a real wait would return).
fn word_holds(uaddr: usize, val: u32, private: bool) -> c_long {
    let zero = timespec { tv_sec: 0, tv_nsec: 0 };
    let op = FUTEX_WAIT | if private { FUTEX_PRIVATE_FLAG } else { 0 };
    match native::call4(nr::FUTEX, uaddr as c_long, op as c_long, val as c_long, &zero as *const timespec as c_long) {
        rc if rc == -ETIMEDOUT => 0,
        rc => rc,
    }
}

fn wait(shared: &'static Shared, slot: &'static Slot, args: &Args, key: Key, deadline: u64, bitset: u32) -> c_long {
    note_call(shared, call::FUTEX);
    let header = &shared.header;
    // A wait costs what a call does, whether it blocks or not, and before it blocks: so that
    // threads that only hand a lock or a condition back and forth move the clock (a charge is
    // applied in whole batches, and a parking thread's remainder is dropped), while a waiter is
    // still woken at its waker's very instant. The charge may yield (past the horizon) before
    // the word is checked, as a thread preempted on its way into the kernel would.
    charge(shared, header.clock.syscall_ns.load(Ordering::Relaxed));
    let hand = crate::schedule::turn::hand_on(shared, slot);
    lock(shared);
    let holds = word_holds(args.uaddr, args.val, args.op & FUTEX_PRIVATE_FLAG != 0);
    if holds != 0 {
        unlock(shared);
        return holds;
    }
    if deadline <= sim_now(shared) {
        unlock(shared);
        return -ETIMEDOUT;
    }
    slot.futex_addr.store(key.offset, Ordering::Relaxed);
    slot.futex_space.store(key.space, Ordering::Relaxed);
    slot.futex_bitset.store(bitset, Ordering::Relaxed);
    slot.futex_ticket.store(header.futex_tickets.fetch_add(1, Ordering::Relaxed), Ordering::Relaxed);
    slot.futex_queued.store(1, Ordering::Release);
    // Published blocked under the lock: a waker that takes this thread off the queue finds it
    // blocked and makes it ready, whenever it comes.
    crate::schedule::park::publish_parked(slot, Parked::Blocked, deadline, Wait::Futex { space: key.space });
    unlock(shared);
    hand.finish();
    let why = crate::schedule::park::await_release(shared, slot, Parked::Blocked, deadline);
    lock(shared);
    let still_queued = slot.futex_queued.swap(0, Ordering::AcqRel) == 1;
    unlock(shared);
    slot.wait_over();
    if !still_queued {
        return 0;
    }
    match why {
        release::DEADLINE => -ETIMEDOUT,
        // Its handler runs as the trap returns.
        release::SIGNAL => -EINTR,
        // The run ended (or climbsim is gone): a spurious wake-up, which every futex user
        // handles; its next wait goes to the kernel.
        _ => 0,
    }
}

/// Take up to `count` waiters on `key` whose bitset meets `bitset` off the queue, oldest first,
/// and make them ready to run; how many. The caller holds the lock.
fn wake_locked(shared: &Shared, key: Key, count: u32, bitset: u32) -> u32 {
    let mut woken = 0;
    while woken < count {
        let Some(slot) = oldest_waiter(shared, key, bitset) else { break };
        slot.futex_queued.store(0, Ordering::Release);
        // Ready, not running: it runs when climbsim gives it the turn (after this thread parks).
        slot.make_ready(Some(release::DATA));
        woken += 1;
    }
    woken
}

fn oldest_waiter(shared: &Shared, key: Key, bitset: u32) -> Option<&Slot> {
    shared
        .live_slots()
        .iter()
        .filter(|s| {
            s.futex_queued.load(Ordering::Acquire) == 1
                // A waiter is blocked while queued; one whose process died is not.
                && s.state() == state::BLOCKED
                && s.futex_addr.load(Ordering::Relaxed) == key.offset
                && s.futex_space.load(Ordering::Relaxed) == key.space
                && s.futex_bitset.load(Ordering::Relaxed) & bitset != 0
        })
        .min_by_key(|s| s.futex_ticket.load(Ordering::Relaxed))
}

fn wake(shared: &Shared, key: Key, count: u32, bitset: u32) -> c_long {
    lock(shared);
    let woken = wake_locked(shared, key, count, bitset);
    unlock(shared);
    c_long::from(woken)
}

/// FUTEX_REQUEUE and FUTEX_CMP_REQUEUE: wake `val` waiters on `from`, move up to `val2` of the
/// rest to `to` (after checking that `from` still holds `expected`).
fn requeue(shared: &Shared, args: &Args, from: Key, to: Key, expected: Option<u32>) -> c_long {
    let (wake_count, move_count) = (args.val, args.timeout_or_val2 as u32);
    if (wake_count as i32) < 0 || (move_count as i32) < 0 {
        return -EINVAL;
    }
    lock(shared);
    if let Some(expected) = expected {
        let holds = word_holds(args.uaddr, expected, args.op & FUTEX_PRIVATE_FLAG != 0);
        if holds != 0 {
            unlock(shared);
            return holds;
        }
    }
    let woken = wake_locked(shared, from, wake_count, FUTEX_BITSET_MATCH_ANY);
    let mut moved = 0;
    // Onto the same futex the waiters stay where they are (and in the same order).
    while moved < move_count && from != to {
        let Some(slot) = oldest_waiter(shared, from, FUTEX_BITSET_MATCH_ANY) else { break };
        slot.futex_addr.store(to.offset, Ordering::Relaxed);
        slot.futex_space.store(to.space, Ordering::Relaxed);
        moved += 1;
    }
    unlock(shared);
    // The kernel's count: woken, plus requeued for the CMP variant.
    c_long::from(woken) + if expected.is_some() { c_long::from(moved) } else { 0 }
}

/// FUTEX_WAKE_OP: change the word at `uaddr2` atomically, wake `val` waiters on `uaddr`, and
/// `val2` on `uaddr2` if the word's old value met the condition.
fn wake_op(shared: &Shared, args: &Args, first: Key, second: Key) -> c_long {
    // Decoded as the kernel does: op in bits 28-30 (bit 31: the argument is a shift), the
    // comparison in 24-27, two sign-extended 12-bit arguments.
    let encoded = args.val3;
    let sign12 = |v: u32| ((v << 20) as i32) >> 20;
    let op = (encoded >> 28) & 7;
    let cmp = (encoded >> 24) & 15;
    let mut oparg = sign12((encoded >> 12) & 0xfff) as u32;
    let cmparg = sign12(encoded & 0xfff);
    if encoded & (8 << 28) != 0 {
        oparg = 1 << (oparg & 31);
    }
    if !args.uaddr2.is_multiple_of(4) || args.uaddr2 == 0 {
        return -EINVAL;
    }
    // The word is changed under the queue lock, which every followed process shares: a fault
    // there would kill this process holding it. The kernel checks it first (adding 0, waking
    // nobody), and a bad address is the EFAULT a real call returns.
    const ADD_ZERO_NEVER_MET: c_long = (1 << 28) | (6 << 24);
    let probe = native::call6(nr::FUTEX, args.uaddr2 as c_long, (FUTEX_WAKE_OP | FUTEX_PRIVATE_FLAG) as c_long, 0, 0, args.uaddr2 as c_long, ADD_ZERO_NEVER_MET);
    if probe < 0 && probe != -38 {
        return probe;
    }
    lock(shared);
    // SAFETY: the caller's futex word (aligned, checked above); the kernel would fault too.
    let word = unsafe { &*(args.uaddr2 as *const core::sync::atomic::AtomicU32) };
    let old = match op {
        0 => word.swap(oparg, Ordering::AcqRel),
        1 => word.fetch_add(oparg, Ordering::AcqRel),
        2 => word.fetch_or(oparg, Ordering::AcqRel),
        3 => word.fetch_and(!oparg, Ordering::AcqRel),
        4 => word.fetch_xor(oparg, Ordering::AcqRel),
        _ => {
            unlock(shared);
            return -38; // ENOSYS, as the kernel answers an unknown op
        }
    };
    let (old_signed, arg_signed) = (old as i32, cmparg);
    let met = match cmp {
        0 => old_signed == arg_signed,
        1 => old_signed != arg_signed,
        2 => old_signed < arg_signed,
        3 => old_signed <= arg_signed,
        4 => old_signed > arg_signed,
        5 => old_signed >= arg_signed,
        _ => {
            unlock(shared);
            return -38;
        }
    };
    let mut woken = wake_locked(shared, first, args.val, FUTEX_BITSET_MATCH_ANY);
    if met {
        woken += wake_locked(shared, second, args.timeout_or_val2 as u32, FUTEX_BITSET_MATCH_ANY);
    }
    unlock(shared);
    c_long::from(woken)
}

/// The robust mutex protocol's bits of a futex word (set_robust_list(2)).
const FUTEX_WAITERS: u32 = 0x8000_0000;
const FUTEX_OWNER_DIED: u32 = 0x4000_0000;
const FUTEX_TID_MASK: u32 = 0x3fff_ffff;
/// The most entries of a robust list the kernel walks.
const ROBUST_LIST_LIMIT: usize = 2048;

/// This followed thread ends (the shim's thread-end callback, or its process's end): the
/// robust mutexes it still holds are handed on as the kernel hands them on at its exit (see
/// set_robust_list(2)): each word that names this thread is marked FUTEX_OWNER_DIED, its owner
/// cleared, and one waiter woken. Here, because the waiters are in the shim's queues, which the
/// kernel cannot see: a thread waiting for a robust mutex whose owner died waited for ever. (The
/// kernel, walking the list again as the thread exits, finds the words no longer this
/// thread's.) Priority-inheritance mutexes (an entry's low bit) are left to the kernel, whose
/// queues hold their waiters.
pub(crate) fn robust_list_ends() {
    robust_list_of_thread_ends(sys::gettid());
}

/// The process ends (exit, `_exit`): every followed thread of it hands on the robust mutexes
/// it holds, as [`robust_list_ends`] does for one (the kernel walks each thread's list as the
/// process dies; a mutex another thread than the exiting one held was left to waiters in other
/// processes for ever).
pub(crate) fn robust_lists_of_process_end(pid: i32) {
    let Some(shared) = active() else { return };
    for slot in shared.live_slots().iter().filter(|s| s.pid.load(Ordering::Relaxed) == pid && s.is_live()) {
        let tid = slot.tid.load(Ordering::Relaxed);
        if tid > 0 {
            robust_list_of_thread_ends(tid);
        }
    }
}

/// Thread `tid` of this process ends: see [`robust_list_ends`].
fn robust_list_of_thread_ends(tid: i32) {
    let Some(shared) = active() else { return };
    let (mut head, mut length) = (0usize, 0usize);
    if native::call3(nr::GET_ROBUST_LIST, c_long::from(tid), &mut head as *mut usize as c_long, &mut length as *mut usize as c_long) != 0 || head == 0 {
        return;
    }
    // struct robust_list_head: the list's first entry, the offset of an entry's futex word,
    // and the entry being taken or released (list_op_pending), read at once.
    let word = |at: usize| sys::read_from_program(at as *const usize);
    let Some([first, offset, pending]) = sys::read_from_program(head as *const [usize; 3]) else { return };
    let tid = tid as u32;
    let mut entry = first;
    for _ in 0..ROBUST_LIST_LIMIT {
        if entry == head || entry == 0 {
            break;
        }
        let Some(next) = word(entry & !1) else { break };
        if entry & 1 == 0 {
            hand_on_robust(shared, (entry & !1).wrapping_add(offset), tid);
        }
        entry = next;
    }
    if pending != 0 && pending & 1 == 0 {
        hand_on_robust(shared, pending.wrapping_add(offset), tid);
    }
}

/// The robust mutex word at `addr`, if thread `tid` holds it: marked as its owner's death
/// marks it, and one waiter woken.
fn hand_on_robust(shared: &Shared, addr: usize, tid: u32) {
    if !addr.is_multiple_of(4) || sys::read_from_program(addr as *const u32).is_none() {
        return;
    }
    // SAFETY: an aligned word of the program's memory that could be read just now; futex
    // words are written atomically by every party.
    let word = unsafe { &*(addr as *const core::sync::atomic::AtomicU32) };
    let mut value = word.load(Ordering::Acquire);
    loop {
        if value & FUTEX_TID_MASK != tid {
            return;
        }
        match word.compare_exchange(value, (value & FUTEX_WAITERS) | FUTEX_OWNER_DIED, Ordering::AcqRel, Ordering::Acquire) {
            Ok(_) => break,
            Err(found) => value = found,
        }
    }
    if value & FUTEX_WAITERS != 0 {
        // A process-private mutex's waiters wait on its address; a shared one's on its file.
        if wake(shared, key_of(addr, true), 1, FUTEX_BITSET_MATCH_ANY) == 0 {
            wake(shared, key_of(addr, false), 1, FUTEX_BITSET_MATCH_ANY);
        }
    }
}

/// The queue lock (Drepper's three-state mutex on a shared word).
fn lock(shared: &Shared) {
    let word = &shared.header.futex_lock;
    if word.compare_exchange(0, 1, Ordering::Acquire, Ordering::Relaxed).is_ok() {
        return;
    }
    while word.swap(2, Ordering::Acquire) != 0 {
        sys::futex_wait(word, 2, 100_000_000);
    }
}

fn unlock(shared: &Shared) {
    let word = &shared.header.futex_lock;
    if word.swap(0, Ordering::Release) == 2 {
        sys::futex_wake(word);
    }
}

/// The key of the futex at `addr`: process-private unless the call says it may be shared and
/// the word lies in a shared file mapping (a POSIX semaphore in /dev/shm, say).
fn key_of(addr: usize, private: bool) -> Key {
    let own = Key { space: crate::schedule::block::pid() as u64, offset: addr as u64 };
    if private {
        return own;
    }
    crate::maps::shared_file_offset(addr).map_or(own, |(file, offset)| Key { space: file | 1 << 63, offset })
}
