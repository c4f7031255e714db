//! System V semaphores and POSIX message queues on simulated time: `semop`, `semtimedop`,
//! `mq_timedreceive` and `mq_timedsend` (glibc's `mq_receive` and `mq_send` are the last two
//! with no timeout), trapped wherever they are made. Their waits are the kernel's (a post or a
//! message may come from any process), so a call that would wait is made without waiting, and
//! the thread waits as a pipe's reader does: blocked on simulated time until its timeout, looking
//! at the kernel whenever climbsim asks (threads ran) and every millisecond of wall time, and
//! making the call again only in its own turn. A post by another followed thread so wakes the
//! waiter at the post's instant, and a timeout ends at its simulated instant, not on the host's
//! clock (where a relative timeout would wait in real time while simulated time held, and an
//! absolute one, read from the simulated clock, would end at once or years late).
//!
//! `futex_waitv` (Linux 5.16, used by Wine and some game engines, never by glibc) waits on
//! futexes the shim's own futex queues wake, which the kernel cannot see: it answers ENOSYS, as
//! a kernel without it does, so that a program falls back to futex(2), which is followed.

use core::ffi::c_long;
use core::sync::atomic::Ordering;

use crate::abi::{NEVER, Shared, Wait, call, release};
use crate::native;
use crate::schedule::block::active;
use crate::schedule::park::{Look, Looked, charge, note_call};
use crate::sys::{self, nr, timespec, timespec_ns};
use crate::time::{sim_now, sim_time_of};

const EFAULT: c_long = 14;
const EAGAIN: c_long = 11;
const EINTR: c_long = 4;
const EINVAL: c_long = 22;
const EIDRM: c_long = 43;
const ENOSYS: c_long = 38;
const ETIMEDOUT: c_long = 110;

/// A semaphore operation's flag: fail with EAGAIN rather than wait.
const IPC_NOWAIT: i16 = 0o4000;
/// semctl's command for one semaphore's value.
const GETVAL: c_long = 12;
/// The most operations one call is followed with: the kernel's default limit (SEMOPM). A call
/// with more is the kernel's (E2BIG, unless the limit was raised).
const MOST_OPERATIONS: usize = 500;

/// One `struct sembuf`.
#[repr(C)]
#[derive(Clone, Copy)]
struct SemOp {
    num: u16,
    op: i16,
    flags: i16,
}

/// `semop` (`timeout` 0) or `semtimedop` (a relative timeout) on simulated time; None: the
/// kernel's, as the program made it (the run is over, no slot, operations the kernel refuses
/// or that the program asked not to wait for).
pub(crate) fn semtimedop(semid: c_long, operations: usize, count: c_long, timeout: usize) -> Option<c_long> {
    let shared = active()?;
    let count = usize::try_from(count).ok().filter(|&n| (1..=MOST_OPERATIONS).contains(&n))?;
    let mut ops = [SemOp { num: 0, op: 0, flags: 0 }; MOST_OPERATIONS];
    if !sys::copy_from_program(operations as *const u8, ops.as_mut_ptr().cast(), count * core::mem::size_of::<SemOp>()) {
        return Some(-EFAULT);
    }
    let ops = &mut ops[..count];
    if ops.iter().any(|op| op.flags & IPC_NOWAIT != 0) {
        return None;
    }
    for op in ops.iter_mut() {
        op.flags |= IPC_NOWAIT;
    }
    note_call(shared, call::IPC);
    // The kernel checks the timeout (EFAULT, EINVAL) before it tries the operations.
    let attempt = || match native::call4(nr::SEMTIMEDOP, semid, ops.as_ptr() as c_long, count as c_long, timeout as c_long) {
        rc if rc == -EAGAIN => None,
        rc => Some(rc),
    };
    if let Some(rc) = attempt() {
        charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
        return Some(rc);
    }
    let deadline = match timeout {
        0 => NEVER,
        // Readable and valid: the attempt would have said otherwise.
        _ => sim_now(shared).saturating_add(sys::read_from_program(timeout as *const timespec).and_then(|t| timespec_ns(&t))?),
    };
    match wait_for_kernel(shared, deadline, || could_go_on(semid, ops), attempt) {
        // The set was there when the wait began: gone since, it was removed (Linux wakes its
        // sleepers with EIDRM; a new call would say EINVAL).
        Ok(rc) if rc == -EINVAL => Some(-EIDRM),
        Ok(rc) => Some(rc),
        Err(release::DEADLINE) => Some(-EAGAIN),
        // System V's calls are never restarted after a handler, whatever SA_RESTART says.
        Err(release::SIGNAL) => Some(-EINTR),
        Err(_) => None,
    }
}

/// Whether the semaphores' values would let every operation of `ops` through now (as the
/// kernel applies them, in order): a peek that changes nothing. An error (the set removed)
/// counts as yes: the call itself then says it.
fn could_go_on(semid: c_long, ops: &[SemOp]) -> bool {
    ops.iter().enumerate().all(|(index, op)| {
        let value = native::call4(nr::SEMCTL, semid, c_long::from(op.num), GETVAL, 0);
        if value < 0 {
            return true;
        }
        let value = value + ops[..index].iter().filter(|earlier| earlier.num == op.num).map(|earlier| c_long::from(earlier.op)).sum::<c_long>();
        match op.op {
            taken if taken < 0 => value >= -c_long::from(taken),
            0 => value == 0,
            _ => true,
        }
    })
}

/// `mq_timedreceive` or `mq_timedsend` (`number`) with the trap's arguments, on simulated time:
/// the absolute timeout (argument 5) is on the simulated CLOCK_REALTIME. None: the kernel's.
pub(crate) fn mq_timed(number: i64, a: [i64; 6]) -> Option<c_long> {
    let shared = active()?;
    // Linux's order: the timeout (EFAULT, then EINVAL), then the descriptor.
    let at = match a[4] {
        0 => None,
        at => match sys::read_from_program(at as *const timespec) {
            None => return Some(-EFAULT),
            // (Not a time: the kernel's EINVAL.)
            Some(at) => Some(timespec_ns(&at)?),
        },
    };
    if !sys::blocking(a[0] as i32) {
        // Not a descriptor (the kernel says EBADF), or one that never waits.
        return None;
    }
    note_call(shared, call::IPC);
    let expired = timespec { tv_sec: 0, tv_nsec: 0 };
    let attempt = || match native::call6(number, a[0], a[1], a[2], a[3], &expired as *const timespec as c_long, 0) {
        rc if rc == -ETIMEDOUT => None,
        rc => Some(rc),
    };
    if let Some(rc) = attempt() {
        charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
        return Some(rc);
    }
    let deadline = at.map_or(NEVER, |at| sim_time_of(shared, sys::CLOCK_REALTIME, at).unwrap_or(0));
    // A queue's descriptor polls readable while it holds a message, writable while it has room.
    let events = if number == nr::MQ_TIMEDRECEIVE { sys::POLLIN } else { sys::POLLOUT };
    let peek = || {
        let mut entry = sys::pollfd { fd: a[0] as i32, events, revents: 0 };
        native::call3(nr::POLL, &mut entry as *mut sys::pollfd as c_long, 1, 0) != 0
    };
    match wait_for_kernel(shared, deadline, peek, attempt) {
        Ok(rc) => Some(rc),
        Err(release::DEADLINE) => Some(-ETIMEDOUT),
        // A handler with SA_RESTART: the call is made again once it has run (it runs only as
        // the trap returns), as the kernel restarts it, with the same absolute timeout.
        Err(release::SIGNAL) => Some(match crate::schedule::delivery::interrupted_by() {
            Some(signal) if crate::handlers::restarts(signal) => sys::RESTART_CALL,
            _ => -EINTR,
        }),
        Err(_) => None,
    }
}

/// `futex_waitv`: see the module's comment.
pub(crate) fn futex_waitv() -> Option<c_long> {
    active().map(|_| -ENOSYS)
}

/// Blocked on simulated time until `deadline`, for a call that only the kernel can finish:
/// `attempt` makes it without waiting (`None`: it would still wait), `peek` says, changing
/// nothing, whether it could go on now. A look (see `park::wait_looking`) may come while
/// another thread runs, so it only peeks; the call is made in the thread's own turn, and if
/// another thread took what the look saw, the wait goes on. `Err`: why climbsim let the thread
/// go (`abi::release`: its deadline, a signal, the run's end).
fn wait_for_kernel(shared: &Shared, deadline: u64, peek: impl Fn() -> bool, attempt: impl Fn() -> Option<c_long>) -> Result<c_long, u32> {
    if deadline <= sim_now(shared) {
        charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
        return Err(release::DEADLINE);
    }
    let Some(slot) = crate::schedule::slot::my_slot() else { return Err(release::ENDING) };
    let publish = || crate::schedule::park::publish_waiting_on_kernel(shared, slot, deadline, Wait::Kernel { port: false, conns: false });
    publish();
    let result = loop {
        match crate::schedule::park::wait_looking(shared, slot, &publish, |take| Look::taking_nothing(peek().then_some(()), take)) {
            Looked::Released(why) => break Err(why),
            Looked::Ended => break Err(release::ENDING),
            Looked::Found(()) => match attempt() {
                Some(rc) => break Ok(rc),
                // Taken by a thread that ran first.
                None => publish(),
            },
        }
    };
    slot.wait_over();
    result
}
