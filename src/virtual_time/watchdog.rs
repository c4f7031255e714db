//! What virtual time cannot follow is a clear error, never a hang: a controller thread that
//! makes no intercepted call for a while (wall time) is looked up in /proc. Stopped (SIGSTOP, a
//! debugger): the world waits. Computing, or blocked in a call the shim does not see: the run
//! fails naming the thread and the last call seen. Gone: its slot is freed.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::VtError;
use super::abi::{Shared, Slot, call, state};

/// How often running slots are checked for threads that died without saying so (killed).
const LIVENESS_EVERY: Duration = Duration::from_millis(50);

pub struct Watchdog {
    stuck_after: Duration,
    calls: u64,
    progress: Instant,
    liveness: Instant,
    /// Since when bytes the controller sent have not reached climbsim.
    held_since: Option<Instant>,
}

impl Watchdog {
    pub fn new(stuck_after: Duration) -> Self {
        let now = Instant::now();
        Self { stuck_after, calls: u64::MAX, progress: now, liveness: now, held_since: None }
    }

    /// Called while climbsim waits for bytes the shim counted as sent (on the port, on a
    /// sensor connection): they come within microseconds, or never (sent by a path the shim
    /// does not count the same way, such as a child without it, or on a connection the server
    /// had closed).
    pub fn check_held(&mut self, (port, sensors): (bool, bool)) -> Result<(), VtError> {
        let since = *self.held_since.get_or_insert_with(Instant::now);
        if since.elapsed() < self.stuck_after {
            return Ok(());
        }
        let place = if port { "the servo port" } else if sensors { "a sensor-server connection" } else { return Ok(()) };
        Err(VtError::Stuck(format!(
            "virtual time: bytes the controller sent on {place} did not reach climbsim within {} s of wall time (written by a process without the shim, or on a connection already closed); simulated time cannot go on",
            self.stuck_after.as_secs_f64()
        )))
    }

    /// Called while climbsim waits for running controller threads.
    pub fn check(&mut self, shared: &Shared) -> Result<(), VtError> {
        self.held_since = None;
        let calls = shared.header.calls.load(Ordering::Relaxed);
        if calls != self.calls {
            self.calls = calls;
            self.progress = Instant::now();
        }
        if self.liveness.elapsed() >= LIVENESS_EVERY {
            self.liveness = Instant::now();
            for slot in running(shared) {
                if matches!(task_state(slot), TaskState::Gone) {
                    slot.state.store(state::EXITED, Ordering::Release);
                }
            }
        }
        if self.progress.elapsed() < self.stuck_after {
            return Ok(());
        }
        let stuck: Vec<&Slot> = running(shared).collect();
        if stuck.iter().any(|slot| matches!(task_state(slot), TaskState::Stopped)) {
            // A debugger or SIGSTOP: the world waits for it, however long.
            self.progress = Instant::now();
            return Ok(());
        }
        let Some(slot) = stuck.first() else { return Ok(()) };
        Err(VtError::Stuck(describe(slot, self.stuck_after)))
    }
}

fn running(shared: &Shared) -> impl Iterator<Item = &Slot> {
    shared.live_slots().iter().filter(|s| matches!(s.state.load(Ordering::Acquire), state::RUNNING | state::RESERVED))
}

enum TaskState {
    Gone,
    Stopped,
    /// The state letter of /proc/…/stat (R, S, D, …).
    Other(char),
    Unknown,
}

/// The slot's thread's folder in /proc, if the slot names one.
pub(super) fn stat_path(slot: &Slot) -> Option<String> {
    let (pid, tid) = (slot.pid.load(Ordering::Relaxed), slot.tid.load(Ordering::Relaxed));
    (pid > 0 && tid > 0).then(|| format!("/proc/{pid}/task/{tid}"))
}

/// The state letter (R, S, D, Z, …) of the task whose `stat` file is at `path`: Err if there is
/// no such task, Ok(None) if the file does not parse.
fn state_letter(path: &str) -> Result<Option<char>, std::io::Error> {
    let stat = std::fs::read_to_string(path)?;
    // The state is the field after the command's closing parenthesis (the command may hold any byte).
    Ok(stat.rfind(')').and_then(|at| stat[at + 1..].trim_start().chars().next()))
}

/// The task whose `stat` file is at `path` exists and is neither a zombie nor dead.
pub(super) fn lives(path: &str) -> bool {
    state_letter(path).is_ok_and(|letter| letter.is_some_and(|state| state != 'Z' && state != 'X'))
}

fn task_state(slot: &Slot) -> TaskState {
    let Some(task) = stat_path(slot) else { return TaskState::Unknown };
    let Ok(letter) = state_letter(&format!("{task}/stat")) else { return TaskState::Gone };
    let Some(letter) = letter else { return TaskState::Unknown };
    match letter {
        'Z' | 'X' => TaskState::Gone,
        'T' | 't' => TaskState::Stopped,
        other => TaskState::Other(other),
    }
}

fn describe(slot: &Slot, after: Duration) -> String {
    let (pid, tid) = (slot.pid.load(Ordering::Relaxed), slot.tid.load(Ordering::Relaxed));
    let task = stat_path(slot).unwrap_or_default();
    let comm = std::fs::read_to_string(format!("{task}/comm")).map(|c| c.trim().to_owned()).unwrap_or_else(|_| "?".to_owned());
    let secs = after.as_secs_f64();
    if slot.state.load(Ordering::Acquire) == state::RESERVED {
        return format!(
            "virtual time: the controller process `{comm}` (pid {pid}) did not load climbsim's shim within {secs} s of wall time: \
             a statically linked program, or one that drops LD_PRELOAD, cannot run on virtual time (run it with --clock wall)"
        );
    }
    let last = call::name(slot.last_call.load(Ordering::Relaxed));
    let at = slot.last_call_ns.load(Ordering::Relaxed) as f64 / 1e9;
    let thread = format!("controller thread `{comm}` (pid {pid}, tid {tid})");
    match task_state(slot) {
        TaskState::Other('R') => format!(
            "virtual time: {thread} has computed for {secs} s of wall time without a call climbsim follows (last: {last} at t = {at:.6} s): \
             a loop that neither reads a clock nor waits cannot run on virtual time"
        ),
        _ => {
            let syscall = std::fs::read_to_string(format!("{task}/syscall")).ok().and_then(|s| s.split_whitespace().next().and_then(|n| n.parse::<i64>().ok()));
            let inside = syscall.map_or_else(|| "a system call".to_owned(), |n| format!("system call {n}{}", syscall_name(n).map(|s| format!(" ({s})")).unwrap_or_default()));
            format!(
                "virtual time: {thread} has been blocked for {secs} s of wall time in {inside}, which climbsim does not follow \
                 (last followed call: {last} at t = {at:.6} s); nothing can wake it on virtual time"
            )
        }
    }
}

/// The slot's process has a child that is not followed (it dropped the shim) and has not
/// ended: its waitpid waits on the real world, like a wait on a descriptor climbsim does not
/// model, and time may move meanwhile. A followed child (one with a slot, even one already
/// marked exited, which the kernel may still be taking down for a while) is no such child: its
/// parent is about to be woken.
pub fn has_unfollowed_child(slots: &[Slot], slot: &Slot) -> bool {
    let pid = slot.pid.load(Ordering::Relaxed);
    let followed = |child: i32| slots.iter().any(|s| s.state.load(Ordering::Acquire) != state::FREE && s.pid.load(Ordering::Relaxed) == child);
    // Each thread's own children (another thread may have started the one waited for).
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return false };
    tasks.filter_map(|task| std::fs::read_to_string(task.ok()?.path().join("children")).ok()).any(|children| {
        children.split_whitespace().filter_map(|child| child.parse::<i32>().ok()).any(|child| {
            !followed(child) && lives(&format!("/proc/{child}/stat"))
        })
    })
}

/// Names of the blocking calls one meets (x86-64 numbers).
fn syscall_name(number: i64) -> Option<&'static str> {
    #[cfg(target_arch = "x86_64")]
    return Some(match number {
        0 => "read",
        7 => "poll",
        23 => "select",
        34 => "pause",
        35 => "nanosleep",
        43 => "accept",
        45 => "recvfrom",
        47 => "recvmsg",
        61 => "wait4",
        128 => "rt_sigtimedwait",
        202 => "futex",
        230 => "clock_nanosleep",
        232 => "epoll_wait",
        270 => "pselect6",
        271 => "ppoll",
        281 => "epoll_pwait",
        288 => "accept4",
        _ => return None,
    });
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = number;
        None
    }
}
