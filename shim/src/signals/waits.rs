//! The waits for a signal: `pause`, `sigsuspend`, `sigtimedwait`, on simulated time.

use core::ffi::{c_int, c_long, c_void};
use core::sync::atomic::Ordering;

use crate::abi::{NEVER, Shared, Wait, call, release};
use crate::native;
use crate::schedule::now::sim_now;
use crate::schedule::park::Looked;
use crate::sys::{self, nr, timespec, timespec_ns};

use super::{EAGAIN, EINTR, EINVAL};
use crate::handlers::program_mask;

/// Wait until a signal ends this wait, or `deadline`; why it ended (`release::SIGNAL`: a
/// signal is pending for it). Signals come two ways: climbsim lets this thread go for a timer's
/// or a followed thread's signal (which it then sends itself), and the kernel raises others (a
/// child's SIGCHLD, a `kill` from a process climbsim does not follow), which wait pending while
/// the trap handler blocks them. For those it waits as a thread on a pipe does: looking at what
/// is pending (`ends`) whenever climbsim asks, and every millisecond of wall time.
fn wait_for_signal(shared: &Shared, deadline: u64, ends: impl Fn(u64) -> bool) -> u32 {
    let Some(slot) = crate::schedule::slot::my_slot() else { return release::ENDING };
    let publish = || crate::schedule::park::publish_waiting_on_kernel(shared, slot, deadline, Wait::Kernel { port: false, conns: false });
    publish();
    loop {
        match crate::schedule::park::wait_looking(shared, slot, &publish, |take| crate::schedule::park::Look::taking_nothing(ends(sys::pending_signals()).then_some(()), take)) {
            // Let go before its deadline for a wait it had ended itself: it waits on.
            Looked::Released(release::DEADLINE) if sim_now(shared) < deadline => publish(),
            Looked::Released(why) => return why,
            Looked::Ended => return release::ENDING,
            // Raised by the kernel.
            Looked::Found(()) => return release::SIGNAL,
        }
    }
}

pub(super) fn pause(shared: &Shared) -> Option<c_long> {
    crate::schedule::park::note_call(shared, call::SIGNAL_WAIT);
    let program_mask = program_mask();
    match wait_for_signal(shared, NEVER, |pending| pending & !program_mask != 0) {
        release::SIGNAL => Some(-EINTR),
        _ => None,
    }
}

pub(super) fn sigsuspend(shared: &Shared, mask: *const u64, size: i64, program_mask: u64) -> Option<c_long> {
    if mask.is_null() || size != 8 {
        return Some(-EINVAL);
    }
    crate::schedule::park::note_call(shared, call::SIGNAL_WAIT);
    // SAFETY: the caller's sigset (8 bytes, as size says).
    let suspended = unsafe { *mask } & !crate::handlers::kept_signals();
    let slot = crate::schedule::slot::my_slot();
    if let Some(slot) = slot {
        slot.sig_blocked.store(suspended, Ordering::Relaxed);
    }
    let why = if sys::pending_signals() & !suspended != 0 { release::SIGNAL } else { wait_for_signal(shared, NEVER, |pending| pending & !suspended != 0) };
    if let Some(slot) = slot {
        slot.sig_blocked.store(program_mask, Ordering::Relaxed);
    }
    if why != release::SIGNAL {
        return None;
    }
    // The signal is pending and the suspended mask lets it through: the kernel's own
    // sigsuspend runs its handler with that mask, puts the program's back and returns EINTR
    // at once.
    let suspended = suspended as c_long;
    Some(native::call2(nr::RT_SIGSUSPEND, &suspended as *const c_long as c_long, 8))
}

pub(super) fn sigtimedwait(shared: &Shared, set: *const u64, info: i64, timeout: *const timespec, size: i64) -> Option<c_long> {
    if set.is_null() || size != 8 {
        return Some(-EINVAL);
    }
    crate::schedule::park::note_call(shared, call::SIGNAL_WAIT);
    // SAFETY: the caller's sigset.
    let set_bits = unsafe { *set };
    let zero = timespec { tv_sec: 0, tv_nsec: 0 };
    let take = || native::call4(nr::RT_SIGTIMEDWAIT, set as c_long, info as c_long, &zero as *const timespec as c_long, 8);
    let taken = take();
    if taken != -EAGAIN {
        return Some(taken);
    }
    let deadline = if timeout.is_null() {
        NEVER
    } else {
        // SAFETY: the caller's timespec.
        let Some(ns) = timespec_ns(unsafe { &*timeout }) else { return Some(-EINVAL) };
        if ns == 0 {
            crate::schedule::park::charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
            return Some(-EAGAIN);
        }
        sim_now(shared).saturating_add(ns)
    };
    let slot = crate::schedule::slot::my_slot()?;
    slot.sig_waiting.store(set_bits, Ordering::Relaxed);
    let why = wait_for_signal(shared, deadline, |pending| pending & set_bits != 0);
    slot.sig_waiting.store(0, Ordering::Relaxed);
    match why {
        // One of the set, or another signal whose handler runs when this call returns.
        release::SIGNAL => Some(match take() {
            taken if taken > 0 => taken,
            _ => -EINTR,
        }),
        release::DEADLINE => Some(-EAGAIN),
        _ => None,
    }
}

/// The signal mask a wait of the pselect family asks for (`pselect`, `ppoll`, `epoll_pwait`:
/// its `sigmask`), in force while it waits on simulated time, as the kernel puts it in force
/// while the thread sleeps: the signals it lets through are those climbsim may pick this thread
/// for and that interrupt the wait, and the handler of one that does runs with it before the
/// wait returns EINTR; then the program's mask is back. (The wait's real calls are made with it
/// too, by the caller.)
pub(crate) struct WaitMask(Option<Masks>);

#[derive(Clone, Copy)]
struct Masks {
    during: u64,
    program: u64,
}

impl WaitMask {
    /// The caller's `sigmask` (NULL: none, the wait keeps the program's), in force from now; or
    /// Linux's answer to it (EFAULT).
    pub(crate) fn enter(sigmask: *const c_void) -> Result<Self, c_int> {
        if sigmask.is_null() {
            return Ok(WaitMask(None));
        }
        // (SIGSYS and the shim's other signals stay deliverable, as in every mask the program sets.)
        let during = sys::read_from_program(sigmask.cast::<u64>()).ok_or(sys::EFAULT)? & !crate::handlers::kept_signals();
        let program = program_mask();
        if let Some(slot) = crate::schedule::slot::my_slot() {
            slot.sig_blocked.store(during, Ordering::Relaxed);
        }
        Ok(WaitMask(Some(Masks { during, program })))
    }

    /// The wait ended with `rc` (and errno): the program's mask is back, and if a signal
    /// interrupted the wait (EINTR) its handler runs first, with the wait's mask, as the kernel's
    /// own sigsuspend runs it (see `sigsuspend`). Only for a signal that is not discarded on
    /// arrival: sigsuspend would discard an ignored one and sleep on.
    pub(crate) fn leave(self, rc: c_int) -> c_int {
        let Some(masks) = self.0 else { return rc };
        if let Some(slot) = crate::schedule::slot::my_slot() {
            slot.sig_blocked.store(masks.program, Ordering::Relaxed);
        }
        // (Looked at only for a wait a signal ended: the pending set and the actions are
        // system calls.)
        let acted_on = || {
            let let_through = sys::pending_signals() & !masks.during;
            (1..=64).filter(|signo| let_through & (1u64 << (signo - 1)) != 0).any(|signo| !crate::schedule::delivery::ignored(signo))
        };
        if rc == -1 && sys::errno() == sys::EINTR && acted_on() {
            let during = masks.during as c_long;
            native::call2(nr::RT_SIGSUSPEND, &during as *const c_long as c_long, 8);
            sys::set_errno(sys::EINTR);
        }
        rc
    }
}
