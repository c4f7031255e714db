//! `climbsim check PATH...`: run each scenario and test its `[expect]` thresholds and the run's
//! own verdict (controller, world, pace); JUnit for CI.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::report::junit::{JunitCase, write_junit};
use crate::robot::RobotDescription;
use crate::scenario::{ControllerSection, Scenario};

use super::clock::Pace;
use super::outputs::judge;
use super::process::read_tail;
use super::{Console, During as _, Result, RunnerError, default_out_dir, describe, run_scenario};

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

/// Check every scenario in `paths` (each into its own folder under `out_root`), say each
/// verdict as it comes, and write JUnit to `junit` if asked. Ok when all passed; otherwise
/// [`RunnerError::Failed`] (a run failed), [`RunnerError::Interrupted`] (JUnit then holds the
/// cases run and the interrupted one), or an error for scenarios that could not be loaded or run.
pub fn check(paths: &[PathBuf], robot: &RobotDescription, out_root: &Path, junit: Option<&Path>, pace: Pace, stop: &AtomicBool, console: &dyn Console) -> Result<()> {
    let files = scenario_files(paths)?;
    if files.is_empty() {
        return Err(RunnerError::Invalid(format!("no scenario files with an [expect] section in {}", paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "))));
    }
    let mut cases = Vec::new();
    let (mut broken, mut interrupted) = (0, None);
    for file in &files {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let started = Instant::now();
        let name = file.display().to_string();
        let out_dir = out_root.join(default_out_dir(file).file_name().unwrap_or_default());
        let mut system_out = None;
        let broken_before = broken;
        let failures = match Scenario::load(file) {
            Err(error) => {
                broken += 1;
                vec![error.to_string()]
            }
            Ok(scenario) if scenario.expect.is_empty() => {
                broken += 1;
                vec![format!("{name} has no [expect] thresholds")]
            }
            Ok(scenario) => {
                let result = run_scenario(&scenario, robot, &out_dir, pace, stop, console);
                if matches!(scenario.controller, ControllerSection::External(_)) {
                    system_out = read_tail(&out_dir.join("controller.log"), SYSTEM_OUT_BYTES);
                }
                match result {
                    Ok(mut outcome) => match judge(&mut outcome, &scenario, &out_dir) {
                        Ok(found) => found,
                        Err(error) => {
                            broken += 1;
                            vec![describe(&error)]
                        }
                    },
                    Err(error) => {
                        match &error {
                            RunnerError::Interrupted(message) => interrupted = Some(message.clone()),
                            _ => broken += 1,
                        }
                        vec![describe(&error)]
                    }
                }
            }
        };
        let verdict = if failures.is_empty() { "PASS" } else if interrupted.is_some() { "INTERRUPTED" } else if broken > broken_before { "ERROR" } else { "FAIL" };
        console.say(&format!("{verdict} {name} ({:.1} s)", started.elapsed().as_secs_f64()));
        for failure in &failures {
            console.say(&format!("    {failure}"));
        }
        cases.push(JunitCase { name, time_s: started.elapsed().as_secs_f64(), failure_messages: failures, system_out, broken: broken > broken_before });
        if interrupted.is_some() {
            break;
        }
    }
    if let Some(path) = junit {
        write_junit(path, "climbsim check", &cases)?;
    }
    let failed = cases.iter().filter(|c| !c.failure_messages.is_empty()).count();
    if stop.load(Ordering::Relaxed) {
        let message = interrupted.unwrap_or_else(|| "interrupted".to_owned());
        return Err(RunnerError::Interrupted(format!("{message}; {} of {} scenarios were checked", cases.len(), files.len())));
    }
    if broken > 0 {
        return Err(RunnerError::Invalid(format!("{failed} of {} scenarios failed, {broken} of them could not be loaded or run", cases.len())));
    }
    if failed > 0 {
        return Err(RunnerError::Failed(format!("{failed} of {} scenarios failed", cases.len())));
    }
    console.say(&format!("all {} scenarios passed", cases.len()));
    Ok(())
}
