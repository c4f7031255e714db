//! Preemption: a controller thread that computes without a followed call (a spin on a flag
//! another thread sets, a lock-free queue polled in a loop) is asked to give way once it has
//! used [`abi::COMPUTE_QUANTUM_NS`] of its own CPU time since its last call, as the kernel's
//! scheduler would preempt it. climbsim measures (it already reads each running thread's CPU
//! time from /proc) and asks, with a signal the shim keeps ([`abi::GIVE_WAY_SIGNAL`]); the
//! thread decides how, by the one rule `Shared::give_way`, in its turn.
//!
//! Anchors: Shadow's native preemption (a CPU-time timer in its shim moves simulated time on
//! by a fixed amount), and Hermit's, which counts retired conditional branches on the PMU so
//! that a preemption lands at the same instruction in every run. This host has no PMU (its
//! `perf_event_open` of a hardware counter fails), so a preemption lands wherever the quantum
//! ends: a thread that only spins (no effect but its wait) still repeats exactly; one that
//! computes and does something else meanwhile may not (docs/virtual-time.md says so, and
//! `summary.json` records that threads gave way).

use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::abi::{self, Shared, state};
use super::watchdog::cpu_ns;

/// How often (wall time) the running threads' CPU times are compared: a fifth of the default
/// quantum. A thread's CPU time is first read at the look after its last call, so that one that
/// makes calls is never read from /proc: it is asked after 1 to 1.4 quanta and one check more
/// (10 to 16 ms by default; a quantum shorter than a check is measured no finer).
const CHECK_EVERY: Duration = Duration::from_nanos(abi::COMPUTE_QUANTUM_NS / 5);

/// A running thread, as last seen: it has made no call and not given way since `cpu_from`.
struct Computing {
    tid: i32,
    calls: u64,
    gave_way: u64,
    /// Its CPU time (ns) when first seen so: None until the second look (one that makes calls
    /// is never read from /proc).
    cpu_from: Option<u64>,
}

#[derive(Default)]
pub(super) struct Preempter {
    threads: HashMap<usize, Computing>,
    checked: Option<Instant>,
    /// Threads asked to give way.
    pub asked: u64,
}

impl Preempter {
    /// Whether a look is due (climbsim's scheduler calls [`Self::check`] at least this often
    /// while threads run).
    pub fn due(&self) -> bool {
        self.checked.is_none_or(|at| at.elapsed() >= CHECK_EVERY)
    }

    /// How long climbsim's scheduler may sleep while threads run: until the next look, or
    /// 10 ms with preemption off.
    pub fn sleep_at_most(&self, shared: &Shared) -> Duration {
        if shared.header.clock.give_way_after_ns.load(Ordering::Relaxed) == 0 { Duration::from_millis(10) } else { CHECK_EVERY }
    }

    /// Ask every running thread that has computed for a quantum without a call to give way.
    pub fn check(&mut self, shared: &Shared) {
        self.checked = Some(Instant::now());
        let quantum = shared.header.clock.give_way_after_ns.load(Ordering::Relaxed);
        // Never (`--preempt-after-ms 0`); or where the shim does not follow signals, and a
        // SIGWINCH would reach only the program's own handler.
        if quantum == 0 || cfg!(not(target_arch = "x86_64")) {
            return;
        }
        let running: Vec<usize> = shared.live_slots().iter().enumerate().filter(|(_, s)| s.state() == state::RUNNING).map(|(i, _)| i).collect();
        self.threads.retain(|index, _| running.contains(index));
        for index in running {
            let slot = &shared.live_slots()[index];
            let (tid, calls, gave_way) = (slot.tid.load(Ordering::Relaxed), slot.calls.load(Ordering::Acquire), slot.gave_way.load(Ordering::Acquire));
            let seen = Computing { tid, calls, gave_way, cpu_from: None };
            let thread = self.threads.entry(index).or_insert(seen);
            if (thread.tid, thread.calls, thread.gave_way) != (tid, calls, gave_way) {
                *thread = Computing { tid, calls, gave_way, cpu_from: None };
                continue;
            }
            let Some(cpu) = cpu_ns(slot) else { continue };
            let Some(from) = thread.cpu_from else {
                thread.cpu_from = Some(cpu);
                continue;
            };
            if cpu.saturating_sub(from) < quantum {
                continue;
            }
            // Asked again after another quantum if it runs on (its rule may say so).
            thread.cpu_from = Some(cpu);
            slot.give_way_asked.store(calls + 1, Ordering::Release);
            let pid = slot.pid.load(Ordering::Relaxed);
            // SAFETY: tgkill takes plain integers; a thread gone meanwhile makes it fail (ESRCH),
            // which the watchdog sees on its own.
            unsafe { libc::syscall(libc::SYS_tgkill, pid, tid, abi::GIVE_WAY_SIGNAL) };
            self.asked += 1;
        }
    }
}
