//! `climbsim fit TRANSCRIPT --scenario S --param KEY=LO..HI …`: the values that make the world
//! answer a real session as the robot did.

use std::path::PathBuf;

use anyhow::{Result, bail};

use climbsim::real_bus::fit::{FitParam, Stop};
use climbsim::real_bus::transcript::read;
use climbsim::runner::Console as _;
use climbsim::runner::fit::{FitOptions, Session, fit, session_out};

use climbsim::runner::compare::CompareOptions;

use super::compare::{AgainstArgs, refuse_unknown_tolerances, say_report, verdict};
use super::console::{Bar, Terminal};

/// Fit robot-description, firmware-profile or scenario keys to a real session: the values in
/// the given ranges that make `compare`'s error smallest (a coarse grid, then Nelder–Mead;
/// deterministic), how well
/// the session determines each (a parameter it does not excite is reported as not
/// identifiable), and compare reports before and after. Writes fit.json, fitted.sets (one
/// KEY=VALUE per line, for --set), fitted-robot.toml (for --robot, when robot or profile keys
/// were fitted; with fitted-profile.toml beside it when profile keys were)
/// and before/ and after/compare.json. Exits 1 when the fitted world still differs past
/// tolerance.
#[derive(Debug, clap::Args)]
pub struct FitArgs {
    #[command(flatten)]
    pub against: AgainstArgs,
    /// A key to fit and its range (repeatable): `robot.wheel.friction=0.2..0.9`. A range in
    /// whole numbers fits an integer (`robot.magnet.encoder_at_down_pulses=2000..2100`): give a
    /// continuous one a decimal point (`robot.magnet.pull_at_contact_n=30.0..120.0`).
    #[arg(long = "param", value_name = "KEY=LO..HI", required = true)]
    pub param: Vec<String>,
    /// Another real session to fit at the same time (repeatable): its transcript, and after `=`
    /// the scenario it was recorded in when that is not --scenario. The error is the mean over
    /// the sessions; parameters one session cannot tell apart (the tread's friction and the
    /// magnets' pull, on a floor) two may (a floor and a wall). Its reports go into
    /// OUT/session-2/ and on.
    #[arg(long = "session", value_name = "TRANSCRIPT[=SCENARIO]")]
    pub sessions: Vec<String>,
    /// Evaluations at once (default: the machine's cores).
    #[arg(long, value_name = "N")]
    pub jobs: Option<usize>,
    /// The most evaluations the search may spend.
    #[arg(long, value_name = "N", default_value = "150")]
    pub max_evaluations: usize,
    /// Output folder (default: results/fit/<transcript name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn exec(args: FitArgs) -> Result<()> {
    let params = args.param.iter().map(|text| FitParam::parse(text).map_err(|e| anyhow::anyhow!("--param {e}"))).collect::<Result<Vec<_>>>()?;
    if let Some(twice) = params.iter().enumerate().find_map(|(i, p)| params[..i].iter().any(|q| q.key == p.key).then_some(&p.key)) {
        bail!("--param {twice} is given twice");
    }
    if args.max_evaluations < params.len() + 2 {
        bail!("--max-evaluations {} is too few for {} parameters (at least {})", args.max_evaluations, params.len(), params.len() + 2);
    }
    let compare = args.against.options("fit", args.out)?;
    let jobs = args.jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from)).max(1);
    let transcript = &args.against.transcript;
    let mut sessions = vec![Session { transcript: read(transcript)?, path: transcript.clone(), compare: compare.clone() }];
    for (index, text) in args.sessions.iter().enumerate() {
        let (path, scenario) = match text.split_once('=') {
            Some((path, scenario)) if !scenario.is_empty() => (PathBuf::from(path), PathBuf::from(scenario)),
            Some(_) => bail!("--session {text}: a scenario after `=`, or no `=`"),
            None => (PathBuf::from(text), compare.scenario.clone()),
        };
        let out = session_out(&compare.out, index + 1);
        sessions.push(Session { transcript: read(&path)?, path, compare: CompareOptions { scenario, out, ..compare.clone() } });
    }
    let options = FitOptions { sessions, params, jobs, stop: Stop { max_evaluations: args.max_evaluations, ..Stop::default() } };
    let outcome = fit(&options, &Bar::new())?;
    for (session, reports) in options.sessions.iter().zip(&outcome.sessions) {
        refuse_unknown_tolerances(&session.compare, &reports.after)?;
    }
    Terminal.say(&format!(
        "{} evaluations; error (mean of (RMS / tolerance)² over registers{}) {:.4} before, {:.4} after",
        outcome.evaluations,
        if options.sessions.len() > 1 { ", then over sessions" } else { "" },
        outcome.error_before,
        outcome.error_after
    ));
    for fitted in &outcome.fitted {
        let how = match (fitted.determination.identifiable, fitted.determination.resolution) {
            (true, Some(resolution)) => format!("determined within ± {resolution:.4} (the error rises by 10 % there, the other parameters free)"),
            (true, None) => "identifiable".to_owned(),
            (false, Some(resolution)) => format!("NOT identifiable from {}: only within ± {resolution:.4}, over a quarter of its range", these(options.sessions.len())),
            (false, None) => format!("NOT identifiable from {}: the error hardly changes along it, or only together with another parameter", these(options.sessions.len())),
        };
        Terminal.say(&format!("  {} = {} (range {}..{}): {how}", fitted.param.key, fitted.value, fitted.param.lo, fitted.param.hi));
    }
    for (session, reports) in options.sessions.iter().zip(&outcome.sessions) {
        say_report(&session.path, &session.compare.scenario, &reports.after);
    }
    Terminal.say(&format!("wrote {}", compare.out.display()));
    // Every session must match: the first one that does not is the verdict.
    let judged = outcome.sessions.iter().find(|reports| !reports.after.failures().is_empty()).or(outcome.sessions.first());
    judged.map_or(Ok(()), |reports| verdict(&reports.after))
}

fn these(sessions: usize) -> &'static str {
    if sessions > 1 { "these sessions" } else { "this session" }
}
