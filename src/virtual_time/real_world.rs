//! Threads waiting on descriptors climbsim does not model (a pipe, an eventfd, a socket of the
//! controller's own) or joining a thread are woken by the kernel, not by climbsim: a write by
//! another followed thread, or its end, makes them ready. So that they wake at the simulated instant of that write, and not
//! whenever the host gets round to it, climbsim asks each of them to look again (the shim's
//! `wait_on_real_world`) after threads ran and before it gives a turn or moves time, and waits
//! until they have. A followed process that has said it exits but is still going away (its
//! last buffered output, the end of its pipes) is waited for the same way, and so is one that
//! execs a program on the wall clock, until the new program has started and the kernel has
//! released what the exec closed (the pipe through which a parent learns that the exec
//! succeeded).

use std::os::unix::ffi::OsStrExt;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::abi::{SLOTS, Shared, Slot, is_exec_marker_link, state};
use super::futex::{futex_wait, futex_wake};

/// A process still going away after this long (wall time) is no longer waited for: something
/// else holds it (a debugger), and the run must not hang on it.
const EXIT_GRACE: Duration = Duration::from_secs(2);

/// How long climbsim sleeps at most between two looks at the waiters' answers.
const ANSWER_WAIT: Duration = Duration::from_millis(1);

/// After this long (wall time) without an answer, a waiter is looked up: gone, its slot is
/// freed. (One stopped by a debugger or SIGSTOP is waited for, as a running one is.)
const UNANSWERED: Duration = Duration::from_millis(50);

pub(super) struct RealWorld {
    /// `Header::turns.sched_word` when the check epoch was last bumped: threads ran since, if it moved.
    epoch_for_sched: Option<u32>,
    /// Per slot: the thread id last seen gone for good (its slot is not looked at again).
    gone: Vec<i32>,
    /// Per slot: the thread seen going away, and since when.
    exiting_since: Vec<Option<(i32, Instant)>>,
    /// Since when climbsim waits for waiters to look (wall time).
    asked_since: Option<Instant>,
}

impl RealWorld {
    pub(super) fn new() -> Self {
        Self { epoch_for_sched: None, gone: vec![0; SLOTS], exiting_since: vec![None; SLOTS], asked_since: None }
    }

    /// Whether every thread waiting on the real world has looked at it since threads last ran,
    /// and no followed process is still going away. If not, those that have not are asked to,
    /// and climbsim waits a moment for their answers.
    pub(super) fn settled(&mut self, shared: &Shared) -> bool {
        let header = &shared.header;
        let waiting = || shared.live_slots().iter().filter(|s| shared.must_look(s));
        if waiting().next().is_none() {
            return true;
        }
        // First the threads going away: what they leave (the end of a pipe, a join's wake-up)
        // is there only once they are gone, and the looks must come after.
        if self.any_exiting(shared) {
            self.epoch_for_sched = None;
            std::thread::sleep(Duration::from_micros(50));
            return false;
        }
        let sched = header.turns.sched_word.load(Ordering::Acquire);
        if self.epoch_for_sched != Some(sched) {
            self.epoch_for_sched = Some(sched);
            header.looks.check_epoch.fetch_add(1, Ordering::AcqRel);
        }
        let epoch = header.looks.check_epoch.load(Ordering::Acquire);
        let answers = header.looks.checks_word.load(Ordering::Acquire);
        let mut looked = true;
        for slot in waiting().filter(|s| s.checked_epoch.load(Ordering::Acquire) != epoch) {
            looked = false;
            slot.wake_word.fetch_add(1, Ordering::AcqRel);
            futex_wake(&slot.wake_word);
        }
        if !looked {
            let asked = *self.asked_since.get_or_insert_with(Instant::now);
            futex_wait(&header.looks.checks_word, answers, ANSWER_WAIT);
            if asked.elapsed() > UNANSWERED {
                // One that never answers may have been killed (SIGKILL runs no clean-up).
                for slot in waiting().filter(|s| s.checked_epoch.load(Ordering::Acquire) != epoch && !alive(s)) {
                    slot.write_off();
                }
            }
            return false;
        }
        self.asked_since = None;
        true
    }

    /// A followed thread that has said it exits still lives (not yet a zombie, nor reaped).
    fn any_exiting(&mut self, shared: &Shared) -> bool {
        let mut exiting = false;
        for (index, slot) in shared.live_slots().iter().enumerate() {
            if slot.state() != state::EXITED {
                self.exiting_since[index] = None;
                continue;
            }
            let tid = slot.tid.load(Ordering::Relaxed);
            if tid <= 0 || self.gone[index] == tid {
                continue;
            }
            let marker = slot.exec_marker_fd.load(Ordering::Acquire);
            // An exec's end counts once climbsim has taken the marker from the slot: an exec that
            // failed takes it back itself (before it closes the marker), and its task, followed
            // again, is not to be written off as gone.
            let left = if marker > 0 {
                exec_over(tid, marker) && slot.exec_marker_fd.compare_exchange(marker, 0, Ordering::AcqRel, Ordering::Acquire).is_ok()
            } else {
                !alive(slot) || followed_elsewhere(shared, index, tid)
            };
            if left {
                self.gone[index] = tid;
                self.exiting_since[index] = None;
                continue;
            }
            let since = match self.exiting_since[index] {
                Some((seen, since)) if seen == tid => since,
                _ => self.exiting_since[index].insert((tid, Instant::now())).1,
            };
            if since.elapsed() > EXIT_GRACE {
                if marker > 0 {
                    tracing::warn!(
                        tid,
                        "a controller process's exec of a program without climbsim's clock has not finished within {} s (a statically linked program, or one that ignores LD_PRELOAD, never says it has); no longer waited for",
                        EXIT_GRACE.as_secs()
                    );
                } else {
                    tracing::warn!(tid, "a controller thread has been exiting for {} s; no longer waited for", EXIT_GRACE.as_secs());
                }
                self.gone[index] = tid;
                continue;
            }
            exiting = true;
        }
        exiting
    }
}

/// The exec of task `tid` into a program on the wall clock, whose marker is descriptor `fd`
/// (`Slot::exec_marker_fd`), is over: the new program's shim has closed the marker as it
/// started (or the task is gone).
fn exec_over(tid: i32, fd: i32) -> bool {
    std::fs::read_link(format!("/proc/{tid}/fd/{fd}")).map_or(true, |link| !is_exec_marker_link(link.as_os_str().as_bytes()))
}

/// The slot's thread exists and is not a zombie.
fn alive(slot: &Slot) -> bool {
    super::watchdog::stat_path(slot).is_some_and(|task| super::watchdog::lives(&format!("{task}/stat")))
}

/// The thread also holds another slot that is in use (one it moved to, as a thread created
/// with explicit scheduling does).
fn followed_elsewhere(shared: &Shared, index: usize, tid: i32) -> bool {
    shared.live_slots().iter().enumerate().any(|(other, s)| other != index && s.tid.load(Ordering::Relaxed) == tid && s.is_live())
}
