//! `climbsim diff A B`: two runs compared column by column and metric by metric.

use std::path::{Path, PathBuf};

use anyhow::Result;

use climbsim::report::diff::{self, Tolerances};
use climbsim::runner::{Console as _, RunnerError};

use super::console::Terminal;

/// Compare two runs (output folders, or their timeseries.csv / summary.json): max |A-B| per
/// time-series column (aligned on t_s) and per summary metric; exit non-zero if any exceeds
/// its tolerance. Defaults by unit: _m 1e-4, _rad 1e-3, _m_s 1e-4, _rad_s 1e-2, _n 0.5,
/// _s 0.02, _pct 0.5, _fraction 5e-3, line_valid 0, others 1e-9; t_s (the span) 1.5 capture
/// periods; realtime_factor and physics_overruns are not compared.
#[derive(Debug, clap::Args)]
pub struct DiffArgs {
    pub a: PathBuf,
    pub b: PathBuf,
    /// Absolute tolerance of a column or metric (repeatable); `inf` ignores it.
    #[arg(long = "tolerance", value_name = "KEY=ABS")]
    pub tolerance: Vec<String>,
    /// Relative tolerance for every key: |A-B| <= R * max |value| also passes.
    #[arg(long, value_name = "R")]
    pub rel: Option<f64>,
}

pub fn exec(args: DiffArgs) -> Result<()> {
    let DiffArgs { a, b, tolerance, rel } = args;
    diff_command(&a, &b, &tolerance, rel)
}

/// `climbsim diff A B`: print the table; fail if any key exceeds its tolerance.
fn diff_command(a: &Path, b: &Path, tolerances: &[String], rel: Option<f64>) -> Result<()> {
    let mut given = Tolerances { rel, ..Tolerances::default() };
    for text in tolerances {
        let (key, value) = Tolerances::parse_abs(text).map_err(|e| anyhow::anyhow!("--tolerance {e}"))?;
        given.abs.insert(key, value);
    }
    if rel.is_some_and(|r| r.is_nan() || r < 0.0) {
        anyhow::bail!("--rel must be a non-negative number");
    }
    let (run_a, run_b) = (diff::load_run(a)?, diff::load_run(b)?);
    let report = diff::compare(&run_a, &run_b, &given);
    // A tolerance for a key neither run has is a typo that would otherwise loosen nothing.
    if let Some(unknown) = given.abs.keys().find(|key| !report.rows.iter().any(|row| &row.key == *key)) {
        let known: Vec<&str> = report.rows.iter().map(|row| row.key.as_str()).collect();
        anyhow::bail!("--tolerance {unknown}=...: neither {} nor {} has a column or metric `{unknown}` (they have: {})", a.display(), b.display(), known.join(", "));
    }
    if report.rows.is_empty() {
        anyhow::bail!("{} and {} have nothing in common to compare (a time series or a summary each)", a.display(), b.display());
    }
    Terminal.say(&format!("A: {}\nB: {}", a.display(), b.display()));
    Terminal.say(report.table().trim_end_matches('\n'));
    let failures = report.failures();
    if failures > 0 {
        // A difference is the comparison's verdict (exit 1), not bad input (exit 2).
        return Err(RunnerError::Failed(format!("{failures} of {} keys differ by more than their tolerance", report.rows.len())).into());
    }
    Terminal.say("no differences beyond tolerance");
    Ok(())
}
