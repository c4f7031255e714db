//! `climbsim fit`: the parameter values that make the world answer a real session as the robot
//! did ([`crate::real_bus::fit`] searches; each evaluation is a `compare` re-enactment, run
//! `--jobs` at a time), how well the session determines each, and the files to use them.

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde_json::json;
use tracing::warn;

use super::compare::{COMPARE_MCAP, CompareError, CompareOptions, CompareReport, reenact, write_report};
use super::each_in_parallel;
use super::sweep::Progress;
use crate::overrides::{Override, PROFILE_PREFIX, ROBOT_PREFIX};
use crate::real_bus::RealTranscript;
use crate::real_bus::fit::{Determination, FitParam, Stop, search};
use crate::robot::{RobotDescription, RobotError, RobotOverrides};
use crate::source_location::load_toml_with;

/// One real session to fit against: its transcript, the file it was read from, and its
/// comparison's options (its scenario and output folder; the robot, the fixed keys and the
/// tolerances are the same for every session of a fit).
#[derive(Debug, Clone)]
pub struct Session {
    pub transcript: RealTranscript,
    pub path: PathBuf,
    pub compare: CompareOptions,
}

/// What to fit, against what.
#[derive(Debug, Clone)]
pub struct FitOptions {
    /// One or more: a parameter one session cannot tell from another (the tread's friction from
    /// the magnets' pull on a floor) may be told by two (a floor and a wall). The first one's
    /// output folder is the fit's.
    pub sessions: Vec<Session>,
    pub params: Vec<FitParam>,
    pub jobs: usize,
    pub stop: Stop,
}

/// One fitted parameter.
#[derive(Debug, Clone, Serialize)]
pub struct Fitted {
    #[serde(flatten)]
    pub param: FitParam,
    pub value: f64,
    #[serde(flatten)]
    pub determination: Determination,
}

/// `compare` of one session with the parameters as the files have them, and with the fitted
/// values.
#[derive(Debug, Clone)]
pub struct SessionOutcome {
    pub before: CompareReport,
    pub after: CompareReport,
}

/// The fit's result.
#[derive(Debug, Clone)]
pub struct FitOutcome {
    pub fitted: Vec<Fitted>,
    pub evaluations: usize,
    /// In the order of [`FitOptions::sessions`].
    pub sessions: Vec<SessionOutcome>,
    /// The error (the mean over sessions) before and after.
    pub error_before: f64,
    pub error_after: f64,
}

/// The error the fit minimises: the mean over registers of (RMS / tolerance)², so that every
/// register counts in units of what it may differ by (the tolerances come from the real signals
/// and the flags, so they do not move with the parameters).
pub fn fit_error(report: &CompareReport) -> f64 {
    let terms: Vec<f64> = report.registers.iter().filter(|r| r.tolerance > 0.0).map(|r| (r.rms / r.tolerance).powi(2)).collect();
    if terms.is_empty() { f64::INFINITY } else { terms.iter().sum::<f64>() / terms.len() as f64 }
}

/// The `--set` for `param` at `unit` of its range: an integer where the range was given in
/// integers (an encoder offset), else a float.
fn set_for(param: &FitParam, unit: f64) -> Override {
    let value = param.value(unit);
    let value = if param.integer { toml::Value::Integer(value.round() as i64) } else { toml::Value::Float(value) };
    Override { key: param.key.clone(), value }
}

/// The error of several sessions' comparisons: the mean of each one's [`fit_error`].
fn sessions_error<'a>(reports: impl ExactSizeIterator<Item = &'a CompareReport>) -> f64 {
    let count = reports.len();
    if count == 0 { f64::INFINITY } else { reports.map(fit_error).sum::<f64>() / count as f64 }
}

/// The output folder of a fit's session `index` (0-based) when the fit writes into `out`: `out`
/// itself for the first, `out/session-N` for the others. Each session's `compare.out`.
pub fn session_out(out: &Path, index: usize) -> PathBuf {
    if index == 0 { out.to_owned() } else { out.join(format!("session-{}", index + 1)) }
}

/// Search, probe, and write `fit.json`, `fitted.sets`, `fitted-robot.toml` (when robot or
/// profile keys were fitted) into the first session's output folder, and each session's
/// compare reports before and after into its own ([`session_out`]).
pub fn fit(options: &FitOptions, progress: &dyn Progress) -> Result<FitOutcome, CompareError> {
    let params = &options.params;
    let Some(first) = options.sessions.first() else {
        return Err(CompareError::NoSession);
    };
    let with = |session: &Session, unit: &[f64]| {
        let mut sets = session.compare.overrides.clone();
        sets.extend(params.iter().zip(unit).map(|(param, u)| set_for(param, *u)));
        CompareOptions { overrides: sets, ..session.compare.clone() }
    };
    // The files' own values are the baseline, and a session the world cannot re-enact at all
    // fails here, clearly, rather than as an infinite error.
    let mut before = Vec::new();
    for session in &options.sessions {
        before.push(reenact(&session.transcript, &session.path, &session.compare, Some(&recording_in(&session.compare.out.join("before"))?))?);
    }
    // Every point is evaluated; one the world cannot be built for (a value its checks refuse)
    // counts as infinitely far.
    let mut evaluate = |points: &[Vec<f64>]| -> Vec<f64> {
        each_in_parallel(points, options.jobs, |unit| {
            let reports: Result<Vec<CompareReport>, CompareError> = options.sessions.iter().map(|session| reenact(&session.transcript, &session.path, &with(session, unit), None)).collect();
            let error = match reports {
                Ok(reports) => sessions_error(reports.iter()),
                Err(error) => {
                    warn!(%error, "an evaluation failed; it counts as infinitely far");
                    f64::INFINITY
                }
            };
            progress.done_one();
            Some(error)
        })
    };
    let probes = 1 + 2 * params.len() * params.len();
    progress.start(options.stop.max_evaluations + probes);
    let (minimum, determinations) = search(params, options.stop, options.jobs > 1, &mut evaluate);
    progress.finish();
    let mut sessions = Vec::new();
    for (session, before) in options.sessions.iter().zip(before) {
        let after = reenact(&session.transcript, &session.path, &with(session, &minimum.unit), Some(&recording_in(&session.compare.out.join("after"))?))?;
        sessions.push(SessionOutcome { before, after });
    }
    let fitted: Vec<Fitted> =
        params.iter().zip(&minimum.unit).zip(determinations).map(|((param, unit), determination)| Fitted { param: param.clone(), value: set_value(&set_for(param, *unit)), determination }).collect();
    let error_before = sessions_error(sessions.iter().map(|s| &s.before));
    let error_after = sessions_error(sessions.iter().map(|s| &s.after));
    let outcome = FitOutcome { fitted, evaluations: minimum.evaluations, sessions, error_before, error_after };
    write_outputs(&outcome, options, first, &with(first, &minimum.unit))?;
    Ok(outcome)
}

/// `compare.mcap` in `dir`, made first.
fn recording_in(dir: &Path) -> Result<PathBuf, CompareError> {
    std::fs::create_dir_all(dir).map_err(|source| CompareError::Write { path: dir.to_owned(), source })?;
    Ok(dir.join(COMPARE_MCAP))
}

fn set_value(set: &Override) -> f64 {
    set.value.as_float().or_else(|| set.value.as_integer().map(|i| i as f64)).unwrap_or(f64::NAN)
}

fn write(path: PathBuf, text: String) -> Result<(), CompareError> {
    std::fs::write(&path, text).map_err(|source| CompareError::Write { path, source })
}

fn write_outputs(outcome: &FitOutcome, options: &FitOptions, first: &Session, after: &CompareOptions) -> Result<(), CompareError> {
    let base = &first.compare;
    let out = &base.out;
    for (session, reports) in options.sessions.iter().zip(&outcome.sessions) {
        write_report(&reports.before, &session.compare.out.join("before"))?;
        write_report(&reports.after, &session.compare.out.join("after"))?;
    }
    let sessions: Vec<serde_json::Value> = options
        .sessions
        .iter()
        .zip(&outcome.sessions)
        .map(|(session, reports)| {
            json!({
                "transcript": session.path,
                "scenario": session.compare.scenario,
                "out": session.compare.out,
                "error_before": fit_error(&reports.before),
                "error_after": fit_error(&reports.after),
            })
        })
        .collect();
    let summary = json!({
        "transcript": first.path,
        "scenario": base.scenario,
        "sessions": sessions,
        "robot": base.robot,
        "fixed_sets": base.overrides.iter().map(ToString::to_string).collect::<Vec<_>>(),
        "evaluations": outcome.evaluations,
        "error_before": outcome.error_before,
        "error_after": outcome.error_after,
        "parameters": outcome.fitted,
    });
    write(out.join("fit.json"), serde_json::to_string_pretty(&summary).unwrap_or_default() + "\n")?;
    // One `--set` per line, for `run --set`, `compare --set` and the like.
    let fitted_sets = &after.overrides[base.overrides.len()..];
    let mut sets: String = fitted_sets.iter().map(|s| format!("{s}\n")).collect();
    sets.insert_str(0, "# climbsim fit: the fitted keys, one KEY=VALUE per line (pass each as --set)\n");
    write(out.join("fitted.sets"), sets)?;
    let (_, robot_sets) = RobotOverrides::split(fitted_sets);
    if !robot_sets.is_empty() {
        // A fitted profile key (the gearbox's friction) goes into a copy of the profile beside
        // the description, which names it: `--robot fitted-robot.toml` then carries them all.
        let profile = if robot_sets.profile.is_empty() {
            None
        } else {
            let original = RobotDescription::load(&base.robot)?.profile_path();
            write(out.join(FITTED_PROFILE), fitted_profile(&original, &robot_sets.profile)?)?;
            Some(FITTED_PROFILE)
        };
        write(out.join("fitted-robot.toml"), fitted_robot(&base.robot, &robot_sets.robot, profile)?)?;
    }
    Ok(())
}

/// The fitted firmware profile's name, beside `fitted-robot.toml`.
const FITTED_PROFILE: &str = "fitted-profile.toml";

/// A data file (`what` at `path`) with the fitted `sets` (keys under `prefix`) set.
fn fitted_table(what: &'static str, path: &Path, prefix: &str, sets: &[Override]) -> Result<toml::Table, CompareError> {
    Ok(load_toml_with(what, path, prefix, sets).map_err(RobotError::from)?)
}

/// `table` as TOML, headed by a comment that says what it was and what was fitted. The
/// original's own comments do not survive.
fn fitted_text(path: &Path, sets: &[Override], table: &toml::Table) -> String {
    let sets: Vec<String> = sets.iter().map(ToString::to_string).collect();
    format!("# {} with the values `climbsim fit` found: {}\n{}", path.display(), sets.join(" "), toml::to_string(table).unwrap_or_default())
}

/// The firmware profile at `path` with the fitted `profile.…` keys set.
fn fitted_profile(path: &Path, sets: &[Override]) -> Result<String, CompareError> {
    Ok(fitted_text(path, sets, &fitted_table(crate::device::profile::WHAT, path, PROFILE_PREFIX, sets)?))
}

/// The robot description with the fitted `robot.…` keys set. Its profile is `fitted_profile`
/// (a file beside it) when profile keys were fitted, else the original's made absolute (the
/// description is written elsewhere).
fn fitted_robot(robot: &Path, sets: &[Override], fitted_profile: Option<&str>) -> Result<String, CompareError> {
    let mut table = fitted_table(crate::robot::WHAT, robot, ROBOT_PREFIX, sets)?;
    if let Some(profile) = table.get_mut("bus").and_then(|bus| bus.get_mut("profile"))
        && let Some(relative) = profile.as_str()
    {
        let resolved = fitted_profile.map_or_else(|| named_from_anywhere(robot, relative), PathBuf::from);
        *profile = toml::Value::String(resolved.display().to_string());
    }
    // A servo's own profile is named relative to the original too. (Fitted profile keys are
    // written into the bus's profile only; a robot with per-servo profiles is not fitted yet.)
    if let Some(servos) = table.get_mut("servo").and_then(|servos| servos.as_array_mut()) {
        for profile in servos.iter_mut().filter_map(|servo| servo.get_mut("profile")) {
            if let Some(relative) = profile.as_str() {
                *profile = toml::Value::String(named_from_anywhere(robot, relative).display().to_string());
            }
        }
    }
    Ok(fitted_text(robot, sets, &table))
}

/// A file `robot` names relative to itself, as a path that works from any folder: a file
/// climbsim has built in, or the absolute path.
fn named_from_anywhere(robot: &Path, relative: &str) -> PathBuf {
    let absolute = robot.parent().unwrap_or(Path::new(".")).join(relative);
    match crate::embedded::find(&absolute) {
        Some(built_in) => built_in.embedded_path(),
        None => std::fs::canonicalize(&absolute).unwrap_or(absolute),
    }
}
