//! The servo port's ledger: what the controller wrote and climbsim read, and what climbsim
//! wrote and the controller took. Handed to the pty and its session, which know nothing else of
//! virtual time; the scheduler reads it to decide when a thread waiting on the port may go.
//!
//! Bytes from the controller: the shim copies what it sees written into the block's ring
//! (`abi::Shared::port_tx_ring`), the rest comes through the pty; climbsim counts what it has read
//! of both, and time waits until it has read all the shim counted.
//!
//! Replies written ahead of their time (the shim's side: `shim/src/schedule/held.rs`): under virtual time
//! the pty session writes all the replies of a transaction at once, when it handles the request,
//! and marks each run of bytes with the simulated instant it arrives on the modelled wire
//! ([`PortLedger::hold_bytes`]). The shim hides every byte until its instant. One write and no
//! hand-over per reply: a Sync Read of eight servos used to cost eight round trips between
//! climbsim and the controller.
//!
//! Bytes are counted as a stream: climbsim counts what it writes, the shim what the controller
//! takes. climbsim keeps a copy of what the controller has not taken, so that replies still on
//! their way can be changed (a collision with bytes the controller sent meanwhile): the pty's
//! input is flushed and written again from the controller's position, the stream's offsets
//! unchanged.

use std::collections::VecDeque;
use std::os::fd::RawFd;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tracing::warn;

use super::abi::{self, HELD_RUNS, NEVER, Shared};
use super::block::Block;
use super::error::lock;
use super::timer::{Timer, TimerWheel};

/// How long the run's end waits for writers into the ring that are under way.
const RING_WRITERS_FINISH_WITHIN: Duration = Duration::from_millis(100);

/// The servo port's two ends, as climbsim holds them (owned by the port, which the driven
/// session keeps alive).
#[derive(Debug, Clone, Copy)]
pub(super) struct PortFds {
    pub(super) master: RawFd,
    pub(super) slave: RawFd,
}

/// The servo port's ledger (see the module doc), and the timers its session waits on.
pub struct PortLedger {
    block: Arc<Block>,
    fds: Mutex<Option<PortFds>>,
    held: Mutex<HeldBytes>,
    timers: Arc<TimerWheel>,
    /// Why the run can no longer repeat (reply bytes that did not reach the controller's side
    /// of the pty in time): the scheduler fails the run with it at its next step.
    cannot_repeat: Mutex<Option<String>>,
}

/// climbsim's copy of the stream's bytes the controller has not taken.
#[derive(Debug, Default)]
pub(super) struct HeldBytes {
    /// Stream offset of `copy[0]`.
    copy_start: u64,
    copy: VecDeque<u8>,
}

/// Bytes in `fd`'s input queue (0 if it cannot tell).
fn queued(fd: i32) -> usize {
    let mut pending: libc::c_int = 0;
    // SAFETY: FIONREAD writes one c_int through the pointer, which is valid for the call.
    let rc = unsafe { libc::ioctl(fd, libc::FIONREAD, &mut pending) };
    if rc == 0 { pending.max(0) as usize } else { 0 }
}

/// The most of the stream climbsim keeps a copy of.
const COPY_LIMIT: usize = 64 * 1024;

/// How long bytes climbsim writes to the pty may take to reach the controller's side before it
/// goes on without them. The kernel's pty worker usually hands them over within microseconds,
/// but a kernel thread can be left runnable and unrun for seconds beside busy cores while many
/// threads wake for microseconds every millisecond (docs/performance-virtual-time.md, "A
/// starved pty worker"): the controller's parked threads looking at the kernel, and climbsim's
/// own looks here, both of which look less often the longer nothing happens. A controller let
/// go before the bytes are there loses the replies
/// and the run no longer repeats, so the wait is long: it costs only wall time, and past it the
/// run fails ([`PortLedger::cannot_repeat`]) rather than going on without them. A controller
/// that does not read the port fills the terminal's buffer instead, which is handled apart.
pub const PTY_HAND_OVER_WITHIN: Duration = Duration::from_secs(30);

/// How long the terminal's buffer may stay full before what does not fit is lost (a controller
/// that does not read the port), as an adapter's buffer would lose it.
pub const PTY_FULL_FOR: Duration = Duration::from_millis(100);

/// How long a hand-over is first waited for with yields only (it usually takes microseconds).
const HAND_OVER_SPIN: Duration = Duration::from_micros(50);

/// The longest pause between two looks at a hand-over in progress.
const HAND_OVER_LOOK_AT_MOST_EVERY: Duration = Duration::from_millis(16);

/// Wait until `handed_over` says the kernel's pty worker has handed bytes climbsim wrote over
/// to the controller's side, up to [`PTY_HAND_OVER_WITHIN`]; whether it did. After a short spin
/// the looks come with growing pauses (20 µs doubling to 16 ms): each look (FIONREAD) takes the
/// terminal's termios lock for writing, which the worker needs to hand the bytes over, and each
/// wake-up of climbsim's is one more short sleeper for the kernel's scheduler (see
/// [`PTY_HAND_OVER_WITHIN`]).
pub fn await_pty_hand_over(mut handed_over: impl FnMut() -> bool) -> bool {
    let started = Instant::now();
    let mut pause = Duration::from_micros(20);
    while !handed_over() {
        if started.elapsed() > PTY_HAND_OVER_WITHIN {
            return false;
        }
        if started.elapsed() < HAND_OVER_SPIN {
            std::thread::yield_now();
        } else {
            std::thread::sleep(pause);
            pause = (pause * 2).min(HAND_OVER_LOOK_AT_MOST_EVERY);
        }
    }
    true
}

impl std::fmt::Debug for PortLedger {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PortLedger").field("block", &self.block.path()).field("now", &self.now()).finish()
    }
}

impl PortLedger {
    pub(super) fn new(block: Arc<Block>, timers: Arc<TimerWheel>) -> Self {
        Self { block, fds: Mutex::default(), held: Mutex::default(), timers, cannot_repeat: Mutex::default() }
    }

    fn shared(&self) -> &Shared {
        self.block.shared()
    }

    fn now_ns(&self) -> u64 {
        self.shared().header.clock.now_ns.load(Ordering::Acquire)
    }

    /// Simulated time now.
    pub fn now(&self) -> Duration {
        Duration::from_nanos(self.now_ns())
    }

    /// A future that completes when simulated time reaches `due` (the scheduler fires it).
    pub fn timer(&self, due: Duration) -> Timer {
        self.timers.timer(due)
    }

    /// What each followed thread is doing now, for a diagnostic.
    pub fn threads_now(&self) -> String {
        super::watchdog::threads_now(self.shared())
    }

    /// The port's two ends, once attached.
    pub(super) fn fds(&self) -> Option<PortFds> {
        *lock(&self.fds)
    }

    /// Whether bytes the controller wrote wait for climbsim (by the shim's count).
    pub(super) fn unread_by_climbsim(&self) -> bool {
        let port = &self.shared().header.port;
        port.tx_read.load(Ordering::Acquire) != port.tx_total.load(Ordering::Acquire)
    }

    /// The run can no longer repeat, for `why` (the first reason is kept): it fails at the
    /// scheduler's next step, rather than going on with what the controller did not see.
    pub fn cannot_repeat(&self, why: String) {
        lock(&self.cannot_repeat).get_or_insert(why);
    }

    /// Why the run can no longer repeat, if it cannot (taken once).
    pub(super) fn take_cannot_repeat(&self) -> Option<String> {
        lock(&self.cannot_repeat).take()
    }

    /// The servo port the controller opens: its writes are counted, its reads waited for.
    pub fn attach(&self, master: RawFd, slave: RawFd) {
        let mut stat: libc::stat = unsafe { std::mem::zeroed() };
        // SAFETY: fstat of climbsim's own descriptor into a valid struct.
        if unsafe { libc::fstat(slave, &mut stat) } == 0 {
            self.shared().header.port.rdev.store(stat.st_rdev, Ordering::Release);
        }
        *lock(&self.fds) = Some(PortFds { master, slave });
    }

    /// climbsim has read `bytes` more from the port (and so time-stamped them).
    pub fn read(&self, bytes: usize) {
        self.shared().header.port.tx_read.fetch_add(bytes as u64, Ordering::AcqRel);
    }

    /// Take what the controller wrote to the port through the block's ring (see
    /// `abi::Shared::port_tx_ring`) into `out`, counted as read; how many bytes (0: none is
    /// there, the pty may have some).
    pub fn take_ring(&self, out: &mut [u8]) -> usize {
        let shared = self.shared();
        let header = &shared.header;
        let start = header.port.tx_ring_read.load(Ordering::Acquire);
        // Never more than a ring's worth: the count is the shim's, which climbsim does not trust.
        let unread = shared.port_tx_ring_unread().min(abi::PORT_TX_RING as u64);
        let count = usize::try_from(unread).unwrap_or(usize::MAX).min(out.len());
        for (index, byte) in out[..count].iter_mut().enumerate() {
            *byte = shared.port_tx_ring_at(start.wrapping_add(index as u64)).load(Ordering::Relaxed);
        }
        header.port.tx_ring_read.store(start.wrapping_add(count as u64), Ordering::Release);
        self.read(count);
        count
    }

    /// Everything left in the port's ring once the run has ended (the shim writes to the pty
    /// then), counted as read. Writers already under way finish first (a few microseconds; at
    /// most [`RING_WRITERS_FINISH_WITHIN`], for one killed in its write).
    pub fn take_ring_rest(&self) -> Vec<u8> {
        let shared = self.shared();
        let since = std::time::Instant::now();
        while shared.header.port.tx_ring_writers.load(Ordering::SeqCst) != 0 && since.elapsed() < RING_WRITERS_FINISH_WITHIN {
            std::thread::yield_now();
        }
        let unread = shared.port_tx_ring_unread().min(abi::PORT_TX_RING as u64);
        let mut rest = vec![0; usize::try_from(unread).unwrap_or(abi::PORT_TX_RING)];
        let taken = self.take_ring(&mut rest);
        rest.truncate(taken);
        rest
    }

    /// Bytes of the port's stream the controller has taken (read or flushed), as the shim counts.
    pub fn taken_total(&self) -> u64 {
        self.shared().header.port.rx_taken.load(Ordering::Acquire)
    }

    /// Bytes written to the port so far (the stream offset of the next byte).
    pub fn written_total(&self) -> u64 {
        self.shared().header.port.rx_written.load(Ordering::Acquire)
    }

    /// climbsim wrote `bytes` to the port (all of them now visible to the kernel).
    pub fn written(&self, bytes: &[u8]) {
        let header = &self.shared().header;
        let mut held = lock(&self.held);
        let taken = header.port.rx_taken.load(Ordering::Acquire);
        let consumed = usize::try_from(taken.saturating_sub(held.copy_start)).unwrap_or(usize::MAX).min(held.copy.len());
        held.copy.drain(..consumed);
        held.copy_start += consumed as u64;
        if held.copy.is_empty() {
            held.copy_start = header.port.rx_written.load(Ordering::Acquire);
        }
        held.copy.extend(bytes);
        // A controller that reads the port where the shim cannot count it never takes: keep
        // the copy bounded (replies that far back are long visible, never rewritten).
        let excess = held.copy.len().saturating_sub(COPY_LIMIT);
        held.copy.drain(..excess);
        held.copy_start += excess as u64;
        header.port.rx_written.fetch_add(bytes.len() as u64, Ordering::AcqRel);
    }

    /// Whether `runs` more held runs fit in the block.
    pub fn holds_room_for(&self, runs: usize) -> bool {
        self.prune_held_runs(self.now_ns());
        let used = self.shared().header.port.held_runs.iter().filter(|r| r.due_ns.load(Ordering::Relaxed) != 0).count();
        used + runs <= HELD_RUNS
    }

    /// The bytes about to be written from stream offset `start` on become visible at `due`
    /// (each run until the next one's start). Published before the bytes are written.
    pub fn hold_bytes(&self, runs: &[(u64, Duration)]) {
        let now = self.now_ns();
        self.prune_held_runs(now);
        self.edit_held_runs(|shared| {
            let mut free = shared.header.port.held_runs.iter().filter(|r| r.due_ns.load(Ordering::Relaxed) == 0);
            for &(start, due) in runs {
                let due = u64::try_from(due.as_nanos()).unwrap_or(NEVER);
                if due <= now {
                    continue;
                }
                let Some(run) = free.next() else {
                    // The caller asked for room first; seen anyway, the bytes show at once.
                    warn!("more held reply runs than the block has room for: shown early");
                    break;
                };
                run.start.store(start, Ordering::Relaxed);
                run.due_ns.store(due, Ordering::Relaxed);
            }
        });
    }

    /// Forget the runs that are visible by `now`.
    fn prune_held_runs(&self, now: u64) {
        let runs = &self.shared().header.port.held_runs;
        if runs.iter().all(|r| r.due_ns.load(Ordering::Relaxed) == 0 || r.due_ns.load(Ordering::Relaxed) > now) {
            return;
        }
        self.edit_held_runs(|shared| {
            for run in &shared.header.port.held_runs {
                let due = run.due_ns.load(Ordering::Relaxed);
                if due != 0 && due <= now {
                    run.due_ns.store(0, Ordering::Relaxed);
                    run.start.store(0, Ordering::Relaxed);
                }
            }
        });
    }

    /// Change the runs under the sequence lock the shim reads them with.
    fn edit_held_runs(&self, edit: impl FnOnce(&Shared)) {
        let shared = self.shared();
        let seq = &shared.header.port.held_seq;
        seq.fetch_add(1, Ordering::AcqRel);
        std::sync::atomic::fence(Ordering::Release);
        edit(shared);
        seq.fetch_add(1, Ordering::Release);
    }

    /// When the next held reply becomes visible ([`NEVER`]: none is held).
    pub(super) fn next_held_due(&self, now: u64) -> u64 {
        self.prune_held_runs(now);
        self.shared().header.port_visible_at(self.written_total(), now).1
    }

    /// Visible bytes on the port the controller has not read (by the counts; the kernel's own
    /// count caps it, for a controller that reads the port in a way the shim does not see): what
    /// a thread waiting on the port is let go for, and what a new request finds unread.
    pub fn unread_visible(&self) -> usize {
        self.unread_and_visible().0
    }

    /// [`Self::unread_visible`], and how far into the port's stream bytes are visible.
    pub(super) fn unread_and_visible(&self) -> (usize, u64) {
        let taken = self.shared().header.port.rx_taken.load(Ordering::Acquire);
        let (visible, _) = self.shared().header.port_visible_at(self.written_total(), self.now_ns());
        if visible <= taken {
            return (0, visible);
        }
        let counted = usize::try_from(visible - taken).unwrap_or(usize::MAX);
        let unread = match *lock(&self.fds) {
            Some(port) => counted.min(queued(port.slave)),
            None => 0,
        };
        (unread, visible)
    }

    /// `bytes` of `what` climbsim wrote to the port never reached the controller's side within
    /// [`PTY_HAND_OVER_WITHIN`]: the run fails ([`PortLedger::cannot_repeat`]).
    pub fn hand_over_never_came(&self, bytes: usize, what: &str) {
        self.cannot_repeat(format!(
            "the kernel did not hand {bytes} {what} bytes over to the controller's side of the pty within {} s (a starved machine: its pty worker did not run); the run cannot repeat, so it fails",
            PTY_HAND_OVER_WITHIN.as_secs()
        ));
    }

    /// Replace held bytes from stream offset `start` with `bytes` (a reply corrupted on its
    /// way). Called with every controller thread parked: the pty's input is flushed and written
    /// again from the controller's position.
    pub fn rewrite_held_bytes(&self, start: u64, bytes: &[u8]) {
        let Some(port) = *lock(&self.fds) else { return };
        let mut held = lock(&self.held);
        let taken = self.shared().header.port.rx_taken.load(Ordering::Acquire);
        let Some(from) = start.checked_sub(held.copy_start).and_then(|o| usize::try_from(o).ok()) else { return };
        for (index, &byte) in bytes.iter().enumerate() {
            if let Some(slot) = held.copy.get_mut(from + index) {
                *slot = byte;
            }
        }
        let resume = usize::try_from(taken.saturating_sub(held.copy_start)).unwrap_or(usize::MAX).min(held.copy.len());
        let rest: Vec<u8> = held.copy.iter().skip(resume).copied().collect();
        // SAFETY: tcflush of climbsim's own slave descriptor.
        unsafe { libc::tcflush(port.slave, libc::TCIFLUSH) };
        let mut written = 0;
        let deadline = Instant::now() + PTY_FULL_FOR;
        while written < rest.len() && Instant::now() < deadline {
            // SAFETY: a write of our own buffer to climbsim's master descriptor.
            let n = unsafe { libc::write(port.master, rest[written..].as_ptr().cast(), rest.len() - written) };
            if n > 0 {
                written += n as usize;
            } else {
                std::thread::yield_now();
            }
        }
        if !await_pty_hand_over(|| queued(port.slave) >= written) {
            warn!(written, queued = queued(port.slave), "rewritten reply bytes not visible to the controller after {PTY_HAND_OVER_WITHIN:?}");
            self.hand_over_never_came(written, "rewritten reply");
        }
    }
}
