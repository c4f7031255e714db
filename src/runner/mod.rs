//! The run library: everything between a parsed command line and the layers below it. A run of
//! a scenario — the built-in controller in lockstep ([`lockstep`]), an external controller's
//! process on the wall clock ([`external`]), a recorded session re-enacted ([`replay`]) — and
//! `serve`'s world ([`serve`]) are one tick loop ([`ticks::run_ticks`]) over a [`Clock`]
//! ([`clock`]): what differs between them is the clock and what ticks with the world.
//! [`check`] and [`sweep`] run many; [`outputs`] writes what a run leaves behind.
//!
//! Nothing here prints: what a person should see goes through a [`Console`], which the command
//! line implements.

pub mod capped_log;
pub mod check;
pub mod clock;
pub mod compare;
pub mod error;
pub mod external;
pub mod feed;
pub mod fit;
pub mod lockstep;
pub mod observe;
pub mod outputs;
pub mod process;
pub mod recording;
pub mod replay;
pub mod serve;
pub mod signals;
pub mod sweep;
pub mod tap;
pub mod tap_view;
pub mod tap_world;
pub mod ticks;
pub mod time_base;
pub mod view;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Mutex, PoisonError};

use crate::bus::Timing;
use crate::robot::RobotDescription;
use crate::scenario::{ControllerSection, Scenario};

pub use clock::{Clock, ClockStop, LockstepClock, Pace, TimeBase, VirtualClock, WallClock};
pub use error::{During, Result, RunError, RunnerError};
pub use observe::Observer;
pub use outputs::{RunOutcome, write_outputs};

/// `work` on each of `items`, `jobs` at once: scoped threads each take the next item until none
/// is left. The results in the items' order; an item `work` returns `None` for is left out.
fn each_in_parallel<T: Sync, R: Send>(items: &[T], jobs: usize, work: impl Fn(&T) -> Option<R> + Sync) -> Vec<R> {
    let next = AtomicUsize::new(0);
    let done: Mutex<Vec<(usize, R)>> = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..jobs.clamp(1, items.len().max(1)) {
            scope.spawn(|| {
                loop {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    let Some(item) = items.get(index) else { break };
                    if let Some(result) = work(item) {
                        done.lock().unwrap_or_else(PoisonError::into_inner).push((index, result));
                    }
                }
            });
        }
    });
    let mut done = done.into_inner().unwrap_or_else(PoisonError::into_inner);
    done.sort_by_key(|(index, _)| *index);
    done.into_iter().map(|(_, result)| result).collect()
}

/// Where a run tells a person what is happening. The library decides what is said; the command
/// line decides where it goes (stdout for what scripts read, stderr for notes). Shared by the
/// runs of a parallel sweep, so it takes `&self`.
pub trait Console: Sync {
    /// A line for stdout: addresses to connect to, verdicts, summaries.
    fn say(&self, line: &str);
    /// A line for stderr: notes, timing summaries, where files were written.
    fn note(&self, line: &str);
}

/// Fail now, not after minutes of simulation, if `dir` cannot be created or written.
pub fn preflight_dir(dir: &Path, flag: &str) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        return Err(RunnerError::Invalid(format!("{flag} {}: exists and is not a folder", dir.display())));
    }
    std::fs::create_dir_all(dir).during(|| format!("{flag} {}: cannot create the folder", dir.display()))?;
    let probe = dir.join(format!(".climbsim-write-check-{}", std::process::id()));
    std::fs::OpenOptions::new().write(true).create(true).truncate(true).open(&probe).during(|| format!("{flag} {}: cannot write in the folder", dir.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Fail now if the file `path` could not be written at the end: its folder must exist (or be
/// creatable) and be writable, and the path must not be a folder.
pub fn preflight_file(path: &Path, flag: &str) -> Result<()> {
    if path.is_dir() {
        return Err(RunnerError::Invalid(format!("{flag} {}: is a folder, not a file", path.display())));
    }
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    preflight_dir(parent, flag)
}

/// Run `scenario` with whichever controller it names (an external one quietly, on its own port)
/// into `out_dir`: what `check` and `sweep` do with each scenario.
pub fn run_scenario(scenario: &Scenario, robot: &RobotDescription, out_dir: &Path, pace: Pace, stop: &AtomicBool, console: &dyn Console) -> Result<RunOutcome> {
    match &scenario.controller {
        ControllerSection::Builtin(_) => lockstep::run_builtin(scenario, robot, out_dir, stop, None),
        ControllerSection::External(controller) => {
            let options = external::ExternalRun { timing: Timing::Wire, link: None, record: None, pace, announce: false, live: None };
            external::run_external(scenario, controller, robot, &options, out_dir, stop, console)
        }
    }
}

/// An error and its causes on one line, without repeating a cause its parent already quotes
/// (for the command line's `climbsim: …`, a JUnit message, a sweep table).
pub fn describe(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut cause = error.source();
    while let Some(inner) = cause {
        let inner_text = inner.to_string();
        if !text.contains(&inner_text) {
            text.push_str(": ");
            text.push_str(&inner_text);
        }
        cause = inner.source();
    }
    text
}

/// Where a run's outputs go without `--out`: `results/<scenario stem>`.
pub fn default_out_dir(scenario: &Path) -> PathBuf {
    let stem = scenario.file_stem().map_or_else(|| "run".into(), |s| s.to_string_lossy().into_owned());
    PathBuf::from("results").join(stem)
}
