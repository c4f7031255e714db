//! What virtual time cannot follow is a clear error, never a hang. Each running controller
//! thread is judged on its own, from what it does, whatever the others do: one that makes no
//! followed call for a while (wall time) is looked up in /proc. Stopped (SIGSTOP, a debugger):
//! the world waits. Computing (its CPU time grows): allowed up to a generous limit (a model
//! loaded at start). Blocked in a call the shim does not see: the run fails naming it. Gone:
//! its slot is freed. And whatever the threads do, simulated time that stands still while they
//! run (a livelock) fails the run naming every thread.

use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::abi::{self, NEVER, RAW_CLONE_TID, Shared, Slot, call, state};
use super::error::VtError;
use crate::proc_stat::{STATE, cpu_ticks, stat_field};

/// How often running slots are checked for threads that died without saying so (killed).
const LIVENESS_EVERY: Duration = Duration::from_millis(50);
/// Over how long (wall time) a quiet thread's CPU time is compared: longer than the kernel's
/// tick (10 ms), short against the limits.
const CPU_WINDOW: Duration = Duration::from_millis(250);
/// How often (wall time) the running threads are judged at least.
const CHECK_EVERY: Duration = Duration::from_millis(10);

/// The watchdog's limits, in wall time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// A thread blocked in a call the shim does not see, or bytes the controller sent that do
    /// not arrive, or a process that does not load the shim.
    pub stuck_after: Duration,
    /// A thread that computes without a followed call (`--compute-limit-s`).
    pub compute_limit: Duration,
    /// Simulated time standing still while threads run.
    pub livelock_after: Duration,
}

/// What the watchdog knows of one running thread.
struct Quiet {
    tid: i32,
    calls: u64,
    /// The watchdog's check in which it was last seen running (one not seen in the check
    /// before has parked meanwhile: its quiet starts again).
    round: u64,
    /// Since when it has made no followed call.
    since: Instant,
    /// Its CPU time (ns) when last sampled, and when.
    cpu: Option<(u64, Instant)>,
    /// Its CPU time grew while it made no call.
    computing: bool,
}

pub struct Watchdog {
    limits: Limits,
    threads: HashMap<usize, Quiet>,
    round: u64,
    /// Simulated time as last seen, and since when (wall time) it has not moved.
    time: (u64, Instant),
    liveness: Instant,
    checked: Instant,
    /// Since when bytes the controller sent have not reached climbsim.
    held_since: Option<Instant>,
    /// `Header::turns.gave_way` as last seen, and when it last grew.
    gave_way: (u64, Option<Instant>),
}

impl Watchdog {
    pub fn new(limits: Limits) -> Self {
        let now = Instant::now();
        Self { limits, threads: HashMap::new(), round: 0, time: (u64::MAX, now), liveness: now, checked: now, held_since: None, gave_way: (0, None) }
    }

    /// Called while climbsim waits for bytes the shim counted as sent (on the port, on a
    /// sensor connection): they come within microseconds, or never (sent by a path the shim
    /// does not count the same way, such as a child without it, or on a connection the server
    /// had closed).
    pub fn check_held(&mut self, (port, sensors): (bool, bool)) -> Result<(), VtError> {
        let since = *self.held_since.get_or_insert_with(Instant::now);
        if since.elapsed() < self.limits.stuck_after {
            return Ok(());
        }
        let place = if port {
            "the servo port"
        } else if sensors {
            "a sensor-server connection"
        } else {
            return Ok(());
        };
        Err(VtError::Stuck(format!(
            "virtual time: bytes the controller sent on {place} did not reach climbsim within {} s of wall time (written by a process without the shim, or on a connection already closed); simulated time cannot go on",
            self.limits.stuck_after.as_secs_f64()
        )))
    }

    /// Whether a check is due (climbsim's loop calls [`Self::check`] at least this often).
    pub fn due(&self) -> bool {
        self.checked.elapsed() >= CHECK_EVERY
    }

    /// Called while climbsim waits for running controller threads (or for their looks).
    pub fn check(&mut self, shared: &Shared) -> Result<(), VtError> {
        self.checked = Instant::now();
        if running(shared).next().is_some() {
            // Threads run: whatever was held is theirs to send on (a wait for it starts anew).
            self.held_since = None;
        }
        let now = shared.header.clock.now_ns.load(Ordering::Acquire);
        if now != self.time.0 {
            self.time = (now, Instant::now());
        }
        if self.liveness.elapsed() >= LIVENESS_EVERY {
            self.liveness = Instant::now();
            for (_, slot) in running(shared) {
                if matches!(task_state(slot), TaskState::Gone) || reserved_thread_orphaned(slot) {
                    slot.write_off();
                    write_off_gone_threads_of(shared, slot.pid.load(Ordering::Relaxed));
                }
            }
        }
        let mut computing = false;
        // A thread that started since the last round: the controller is creating threads (4000
        // of them take seconds on a loaded machine before the first one's sleep can move time),
        // which is progress, not a livelock.
        let mut started = false;
        self.round += 1;
        let round = self.round;
        for (index, slot) in running(shared) {
            let (calls, tid) = (slot.calls.load(Ordering::Relaxed), slot.tid.load(Ordering::Relaxed));
            let fresh = || Quiet { tid, calls, round, since: Instant::now(), cpu: None, computing: false };
            started |= self.threads.get(&index).is_none_or(|known| known.tid != tid);
            let thread = self.threads.entry(index).or_insert_with(fresh);
            let seen_before = std::mem::replace(&mut thread.round, round) + 1 == round;
            if thread.tid != tid || thread.calls != calls || !seen_before {
                *thread = fresh();
                continue;
            }
            let quiet = thread.since.elapsed();
            if quiet < self.limits.stuck_after {
                computing |= thread.computing;
                continue;
            }
            if slot.state() == state::RESERVED {
                return Err(VtError::Stuck(describe(slot, Judged::NoShim, quiet)));
            }
            match task_state(slot) {
                // A debugger or SIGSTOP: the world waits for it, however long. Unless its
                // tracer is one of the controller's own processes (strace as its command): that
                // one waits for its turn, which the stopped thread holds, for ever.
                TaskState::Stopped => {
                    if let Some(tracer) = followed_tracer(shared, slot) {
                        return Err(VtError::Stuck(format!(
                            "virtual time: {} is stopped by its tracer, pid {tracer}, which is one of the controller's own processes (strace or a debugger started as the controller's command): the tracer cannot run while the thread it stopped holds the turn. Trace the controller from outside instead (strace -f -p PID; gdb with `set environment`, see docs/virtual-time.md)",
                            thread_name(slot).0
                        )));
                    }
                    self.waited_for_stopped();
                    return Ok(());
                }
                TaskState::Gone => continue,
                state => {
                    let Some(cpu) = cpu_ns(slot) else {
                        // No CPU time to read: judged as before, quiet means stuck.
                        return Err(VtError::Stuck(describe(slot, Judged::Blocked, quiet)));
                    };
                    let Some((before, sampled)) = thread.cpu else {
                        thread.cpu = Some((cpu, Instant::now()));
                        continue;
                    };
                    if sampled.elapsed() < CPU_WINDOW {
                        computing |= thread.computing;
                        continue;
                    }
                    // Computing (its CPU time grew), runnable but waiting for a CPU (a loaded
                    // machine), or reading a disk (a large file at start): working.
                    let working = cpu > before || matches!(state, TaskState::Other('R' | 'D'));
                    if !working {
                        return Err(VtError::Stuck(describe(slot, Judged::Blocked, quiet)));
                    }
                    if quiet >= self.limits.compute_limit {
                        return Err(VtError::Stuck(describe(slot, Judged::Computing(self.limits.compute_limit), quiet)));
                    }
                    thread.computing = true;
                    thread.cpu = Some((cpu, Instant::now()));
                    computing = true;
                }
            }
        }
        // Threads that give way to one another (preempt.rs) compute without moving time, as a
        // thread that computes between calls does: allowed up to the compute limit (a spin that
        // waits for itself never ends).
        let gave_way = shared.header.turns.gave_way.load(Ordering::Relaxed);
        if gave_way != self.gave_way.0 {
            self.gave_way = (gave_way, Some(Instant::now()));
        }
        let giving_way = self.gave_way.1.is_some_and(|at| at.elapsed() < Duration::from_secs(1));
        let limit = if giving_way { self.limits.compute_limit.max(self.limits.livelock_after) } else { self.limits.livelock_after };
        if computing || started {
            // A computing thread holds simulated time where it is, rightly.
            self.time.1 = Instant::now();
        } else if self.time.1.elapsed() >= limit {
            return Err(VtError::Stuck(livelock(shared, limit, now)));
        }
        Ok(())
    }

    /// A stopped thread: nothing is judged while the world waits for it.
    fn waited_for_stopped(&mut self) {
        let now = Instant::now();
        self.time.1 = now;
        for thread in self.threads.values_mut() {
            thread.since = now;
            thread.cpu = None;
        }
    }
}

/// A running thread of process `pid` is gone without a word from its shim: its process may have
/// ended with it (a raw `exit_group`, as Go ends; a fatal signal), and then its parked threads
/// are gone too. They are written off now, at the instant the process ended, not found gone at
/// their deadlines.
fn write_off_gone_threads_of(shared: &Shared, pid: i32) {
    for slot in shared.live_slots().iter().filter(|s| s.is_live() && s.pid.load(Ordering::Relaxed) == pid) {
        if matches!(task_state(slot), TaskState::Gone) {
            slot.write_off();
        }
    }
}

/// What each followed thread (not free nor exited) is doing now, for a diagnostic: its
/// slot, thread id, state, what it waits on and until when, and its last call.
pub(super) fn threads_now(shared: &Shared) -> String {
    let threads: Vec<String> = shared
        .live_slots()
        .iter()
        .enumerate()
        .filter(|(_, s)| s.is_live())
        .map(|(i, s)| {
            let deadline = s.deadline_ns.load(Ordering::Relaxed);
            let until = if deadline == NEVER { "never".to_owned() } else { format!("{:.6}", deadline as f64 / 1e9) };
            let (tid, wait, last) = (s.tid.load(Ordering::Relaxed), s.wait(), abi::call::name(s.last_call.load(Ordering::Relaxed)));
            format!("#{i} tid {tid} {} waits {wait:?} until {until} last {last}", state::name(s.state()))
        })
        .collect();
    threads.join("; ")
}

fn running(shared: &Shared) -> impl Iterator<Item = (usize, &Slot)> {
    shared.live_slots().iter().enumerate().filter(|(_, s)| matches!(s.state(), state::RUNNING | state::RESERVED))
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
    Ok(stat_field(&stat, STATE).and_then(|state| state.chars().next()))
}

/// The task whose `stat` file is at `path` exists and is neither a zombie nor dead.
pub(super) fn lives(path: &str) -> bool {
    state_letter(path).is_ok_and(|letter| letter.is_some_and(|state| state != 'Z' && state != 'X'))
}

/// A slot reserved for a thread to come (by `pthread_create` or a trapped `clone`) whose
/// process has ended: the thread never starts (the process exited while creating it: a Go
/// program that ends at once does), and its slot would be judged a process that never loaded
/// the shim.
fn reserved_thread_orphaned(slot: &Slot) -> bool {
    let (pid, tid) = (slot.pid.load(Ordering::Relaxed), slot.tid.load(Ordering::Relaxed));
    slot.state() == state::RESERVED && tid < 0 && pid > 0 && !lives(&format!("/proc/{pid}/stat"))
}

/// The pid of the process tracing the slot's thread, if it is a followed one (it has a live
/// slot).
fn followed_tracer(shared: &Shared, slot: &Slot) -> Option<i32> {
    let status = std::fs::read_to_string(format!("{}/status", stat_path(slot)?)).ok()?;
    let tracer: i32 = status.lines().find_map(|line| line.strip_prefix("TracerPid:"))?.trim().parse().ok()?;
    let followed = shared.live_slots().iter().any(|s| s.pid.load(Ordering::Relaxed) == tracer && s.is_live());
    (tracer > 0 && followed).then_some(tracer)
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

/// What the watchdog found a quiet thread doing.
enum Judged {
    /// A process that never loaded the shim.
    NoShim,
    /// Computing past the limit.
    Computing(Duration),
    /// Blocked in a call the shim does not see.
    Blocked,
}

/// `controller thread `comm` (pid P, tid T)`, and its /proc folder.
fn thread_name(slot: &Slot) -> (String, String) {
    let (pid, tid) = (slot.pid.load(Ordering::Relaxed), slot.tid.load(Ordering::Relaxed));
    let task = stat_path(slot).unwrap_or_default();
    (format!("controller thread `{}` (pid {pid}, tid {tid})", comm(&task)), task)
}

/// The command name of the task whose /proc folder is `task` ("?" if it cannot be read).
fn comm(task: &str) -> String {
    std::fs::read_to_string(format!("{task}/comm")).map(|c| c.trim().to_owned()).unwrap_or_else(|_| "?".to_owned())
}

/// The slot's last followed call and its simulated time.
fn last_call(slot: &Slot) -> String {
    let last = call::name(slot.last_call.load(Ordering::Relaxed));
    let at = slot.last_call_ns.load(Ordering::Relaxed) as f64 / 1e9;
    format!("{last} at t = {at:.6} s")
}

fn describe(slot: &Slot, judged: Judged, quiet: Duration) -> String {
    let (thread, task) = thread_name(slot);
    let secs = quiet.as_secs_f64().round();
    let last = last_call(slot);
    match judged {
        Judged::NoShim if slot.tid.load(Ordering::Relaxed) == RAW_CLONE_TID => {
            let pid = slot.pid.load(Ordering::Relaxed);
            let comm = comm(&format!("/proc/{pid}"));
            format!(
                "virtual time: a thread the controller process `{comm}` (pid {pid}) made with a raw clone has made no followed call of its own \
                 within {secs} s of wall time, and time waits for its first: a thread that computes that long before its first system call, \
                 or one that shares its creator's thread-local storage (a clone without CLONE_SETTLS), cannot run on virtual time \
                 (create it with pthread_create, or run with --clock wall)"
            )
        }
        Judged::NoShim => {
            let (pid, comm) = (slot.pid.load(Ordering::Relaxed), comm(&task));
            format!(
                "virtual time: the controller process `{comm}` (pid {pid}) did not load climbsim's shim within {secs} s of wall time: \
                 a statically linked program, or one that drops LD_PRELOAD, cannot run on virtual time (run it with --clock wall)"
            )
        }
        Judged::Computing(limit) => format!(
            "virtual time: {thread} has computed for {secs} s of wall time without a call climbsim follows (last: {last}), past --compute-limit-s {}: \
             a loop that neither reads a clock nor waits cannot run on virtual time (a longer computation, such as loading a model, needs a higher limit)",
            limit.as_secs_f64()
        ),
        Judged::Blocked => {
            let inside = syscall_inside(&task);
            format!(
                "virtual time: {thread} has been blocked for {secs} s of wall time in {inside}, which climbsim does not follow \
                 (last followed call: {last}); nothing can wake it on virtual time"
            )
        }
    }
}

/// The system call a task is in, from /proc/…/syscall, in words.
fn syscall_inside(task: &str) -> String {
    let syscall = std::fs::read_to_string(format!("{task}/syscall")).ok();
    match syscall.as_deref().map(str::trim) {
        Some("running") => "no system call (running)".to_owned(),
        Some(text) => match text.split_whitespace().next().and_then(|n| n.parse::<i64>().ok()) {
            Some(n) => format!("system call {n}{}", syscall_name(n).map(|s| format!(" ({s})")).unwrap_or_default()),
            None => "a system call".to_owned(),
        },
        None => "a system call".to_owned(),
    }
}

/// Simulated time stood still at `now` for `after` of wall time while threads ran: every
/// thread that is not parked on a deadline, with what it was doing.
fn livelock(shared: &Shared, after: Duration, now: u64) -> String {
    let threads: Vec<String> = shared
        .live_slots()
        .iter()
        .filter(|s| s.is_live())
        .map(|slot| {
            let (thread, task) = thread_name(slot);
            let followed = state::name(slot.state());
            let kernel = match task_state(slot) {
                TaskState::Other(letter) => format!("{letter}, in {}", syscall_inside(&task)),
                TaskState::Stopped => "stopped".to_owned(),
                TaskState::Gone => "gone".to_owned(),
                TaskState::Unknown => "unknown".to_owned(),
            };
            format!("{thread}: {followed} (kernel: {kernel}), {} calls, last {}", slot.calls.load(Ordering::Relaxed), last_call(slot))
        })
        .collect();
    format!(
        "virtual time: simulated time has stood still at t = {:.6} s for {} s of wall time while the controller ran: \
         its threads make calls that do not move time, or wait on each other in a way climbsim cannot end (a livelock). Threads: {}",
        now as f64 / 1e9,
        after.as_secs_f64(),
        threads.join("; ")
    )
}

/// The task's CPU time so far (ns): /proc's schedstat, else stat's utime and stime (in the
/// kernel's 100 Hz ticks).
pub(super) fn cpu_ns(slot: &Slot) -> Option<u64> {
    let task = stat_path(slot)?;
    if let Some(ns) = std::fs::read_to_string(format!("{task}/schedstat")).ok().and_then(|s| s.split_whitespace().next()?.parse().ok()) {
        return Some(ns);
    }
    let ticks = cpu_ticks(&std::fs::read_to_string(format!("{task}/stat")).ok()?)?;
    Some(ticks.saturating_mul(10_000_000))
}

/// The slot's process has a child that is not followed (it dropped the shim) and has not
/// ended: its waitpid waits on the real world, like a wait on a descriptor climbsim does not
/// model, and time may move meanwhile. A followed child (one with a slot, even one already
/// marked exited, which the kernel may still be taking down for a while) is no such child: its
/// parent is about to be woken.
pub fn has_unfollowed_child(slots: &[Slot], slot: &Slot) -> bool {
    let pid = slot.pid.load(Ordering::Relaxed);
    let followed = |child: i32| slots.iter().any(|s| s.state() != state::FREE && s.pid.load(Ordering::Relaxed) == child);
    // Each thread's own children (another thread may have started the one waited for).
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return false };
    tasks
        .filter_map(|task| std::fs::read_to_string(task.ok()?.path().join("children")).ok())
        .any(|children| children.split_whitespace().filter_map(|child| child.parse::<i32>().ok()).any(|child| !followed(child) && lives(&format!("/proc/{child}/stat"))))
}

/// Names of the blocking calls one meets (x86-64 numbers).
fn syscall_name(number: i64) -> Option<&'static str> {
    #[cfg(target_arch = "x86_64")]
    return Some(match number {
        0 => "read",
        1 => "write",
        2 => "open",
        7 => "poll",
        23 => "select",
        34 => "pause",
        35 => "nanosleep",
        43 => "accept",
        44 => "sendto",
        45 => "recvfrom",
        46 => "sendmsg",
        47 => "recvmsg",
        61 => "wait4",
        65 => "semop",
        72 => "fcntl",
        73 => "flock",
        128 => "rt_sigtimedwait",
        202 => "futex",
        230 => "clock_nanosleep",
        232 => "epoll_wait",
        257 => "openat",
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
