//! `climbsim check PATH...`: run each scenario and test its `[expect]` thresholds and the run's
//! own verdict (controller, world, pace); JUnit for CI.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::overrides::Override;
use crate::report::junit::{JunitCase, write_junit};
use crate::robot::RobotDescription;
use crate::scenario::{ControllerSection, Scenario};

use super::clock::Pace;
use super::outputs::judge;
use super::process::read_tail;
use super::{Console, During as _, Result, RunnerError, default_out_dir, describe, each_in_parallel, run_scenario};

/// How much of an external controller's log goes into its JUnit case's `<system-out>`.
const SYSTEM_OUT_BYTES: u64 = 64 * 1024;

/// Scenario files named by `paths` (a folder stands for its `*.toml` files with an `[expect]`).
fn scenario_files(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for path in paths {
        if path.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(path)
                .during(|| format!("cannot list {}", path.display()))?
                .filter_map(|entry| entry.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "toml"))
                .filter(|p| std::fs::read_to_string(p).is_ok_and(|text| text.lines().any(|l| l.trim() == "[expect]")))
                .collect();
            found.sort();
            files.extend(found);
        } else {
            files.push(path.clone());
        }
    }
    Ok(files)
}

/// How one scenario's check ended.
enum Checked {
    Passed,
    Failed,
    /// It could not be loaded or run (a broken scenario, a run that could not start).
    Broken,
    Interrupted(String),
}

/// Where and how `check` runs its scenarios.
pub struct CheckOptions<'a> {
    /// Root of the runs' folders: each scenario's is named after its file.
    pub out_root: &'a Path,
    pub junit: Option<&'a Path>,
    pub pace: Pace,
    pub jobs: usize,
    /// `--set` keys of the scenarios (the robot's and profile's are in the description given),
    /// applied to every scenario checked: `world.duration_s=5`, a `controller={ … }` of your own.
    pub overrides: &'a [Override],
}

/// Check every scenario in `paths` (each into its own folder under `out_root`), `jobs` at once,
/// say each verdict as it comes, and write JUnit to `junit` if asked (the cases in the files'
/// order). Ok when all passed; otherwise [`RunnerError::Failed`] (a run failed),
/// [`RunnerError::Interrupted`] (JUnit then holds the cases run and the interrupted ones), or an
/// error for scenarios that could not be loaded or run.
///
/// Runs on virtual time or in lockstep repeat whatever else the machine does, so checking them
/// side by side changes no verdict; wall-clock runs at once compete for the CPU, and their pace
/// shows it.
pub fn check(paths: &[PathBuf], robot: &RobotDescription, options: &CheckOptions, stop: &AtomicBool, console: &dyn Console) -> Result<()> {
    let CheckOptions { junit, jobs, .. } = *options;
    let files = scenario_files(paths)?;
    if files.is_empty() {
        return Err(RunnerError::Invalid(format!("no scenario files with an [expect] section in {}", paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "))));
    }
    // Once a run is interrupted no new one starts (the others under way stop and write).
    let halted = AtomicBool::new(false);
    let results = each_in_parallel(&files, jobs, |file| {
        if stop.load(Ordering::Relaxed) || halted.load(Ordering::Relaxed) {
            return None;
        }
        let (case, checked) = check_one(file, robot, options, stop, console);
        if matches!(checked, Checked::Interrupted(_)) {
            halted.store(true, Ordering::Relaxed);
        }
        Some((case, checked))
    });
    let failed = results.iter().filter(|(case, _)| !case.failure_messages.is_empty()).count();
    let broken = results.iter().filter(|(_, checked)| matches!(checked, Checked::Broken)).count();
    let interrupted = results.iter().find_map(|(_, checked)| match checked {
        Checked::Interrupted(message) => Some(message.clone()),
        _ => None,
    });
    let checked_count = results.len();
    if let Some(path) = junit {
        let cases: Vec<JunitCase> = results.into_iter().map(|(case, _)| case).collect();
        write_junit(path, "climbsim check", &cases)?;
    }
    if stop.load(Ordering::Relaxed) || interrupted.is_some() {
        let message = interrupted.unwrap_or_else(|| "interrupted".to_owned());
        return Err(RunnerError::Interrupted(format!("{message}; {checked_count} of {} scenarios were checked", files.len())));
    }
    if broken > 0 {
        return Err(RunnerError::Invalid(format!("{failed} of {checked_count} scenarios failed, {broken} of them could not be loaded or run")));
    }
    if failed > 0 {
        return Err(RunnerError::Failed(format!("{failed} of {checked_count} scenarios failed")));
    }
    console.say(&format!("all {checked_count} scenarios passed"));
    Ok(())
}

/// Check one scenario file into its folder under `out_root`; its verdict said as it comes.
fn check_one(file: &Path, robot: &RobotDescription, options: &CheckOptions, stop: &AtomicBool, console: &dyn Console) -> (JunitCase, Checked) {
    let CheckOptions { out_root, pace, overrides, .. } = *options;
    let started = Instant::now();
    let name = file.display().to_string();
    let out_dir = out_root.join(default_out_dir(file).file_name().unwrap_or_default());
    let mut system_out = None;
    let (failures, checked) = match Scenario::load_with(file, overrides) {
        Err(error) => (vec![error.to_string()], Checked::Broken),
        Ok(scenario) if scenario.expect.is_empty() => (vec![format!("{name} has no [expect] thresholds")], Checked::Broken),
        Ok(scenario) => {
            let result = run_scenario(&scenario, robot, &out_dir, pace, stop, console);
            if matches!(scenario.controller, ControllerSection::External(_)) {
                system_out = read_tail(&out_dir.join("controller.log"), SYSTEM_OUT_BYTES);
            }
            match result {
                Ok(mut outcome) => match judge(&mut outcome, &scenario, &out_dir) {
                    Ok(found) if found.is_empty() => (found, Checked::Passed),
                    Ok(found) => (found, Checked::Failed),
                    Err(error) => (vec![describe(&error)], Checked::Broken),
                },
                Err(RunnerError::Interrupted(message)) => (vec![describe(&RunnerError::Interrupted(message.clone()))], Checked::Interrupted(message)),
                Err(error) => (vec![describe(&error)], Checked::Broken),
            }
        }
    };
    let verdict = match checked {
        Checked::Passed => "PASS",
        Checked::Failed => "FAIL",
        Checked::Broken => "ERROR",
        Checked::Interrupted(_) => "INTERRUPTED",
    };
    // One call per scenario, so that lines of runs side by side do not interleave.
    let mut lines = format!("{verdict} {name} ({:.1} s)", started.elapsed().as_secs_f64());
    for failure in &failures {
        lines.push_str(&format!("\n    {failure}"));
    }
    console.say(&lines);
    let case = JunitCase { name, time_s: started.elapsed().as_secs_f64(), failure_messages: failures, system_out, broken: matches!(checked, Checked::Broken) };
    (case, checked)
}
