//! The benches' history: every full bench run appends its headline figures to
//! `docs/bench-history.csv` with the date and commit, and prints each beside the figure's last
//! recorded value, so a change in a figure shows the day it lands. The file is committed with the
//! change that moved the figures (docs/performance.md explains how to read it).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::process::Command;

const HEADER: &str = "date_utc,commit,bench,figure,value,unit";

/// One headline figure of a bench run.
pub struct Figure {
    pub name: String,
    pub value: f64,
    pub unit: &'static str,
}

pub fn figure(name: impl Into<String>, value: impl Into<f64>, unit: &'static str) -> Figure {
    Figure { name: name.into(), value: value.into(), unit }
}

/// Append `figures` of `bench` to the history (`CLIMBSIM_BENCH_HISTORY`, default
/// `docs/bench-history.csv`) and print each with the change from its last recorded value.
pub fn record(bench: &str, figures: &[Figure]) {
    let repo = super::repo();
    let path = std::env::var_os("CLIMBSIM_BENCH_HISTORY").map_or_else(|| repo.join("docs/bench-history.csv"), Into::into);
    let existing = std::fs::read_to_string(&path).unwrap_or_default();
    let date = command_text(&repo, "date", &["-u", "+%Y-%m-%dT%H:%MZ"]).unwrap_or_else(|| "unknown".into());
    let mut commit = command_text(&repo, "git", &["rev-parse", "--short=7", "HEAD"]).unwrap_or_else(|| "unknown".into());
    // Figures of uncommitted code are marked: they belong to no commit yet.
    if command_text(&repo, "git", &["status", "--porcelain", "--untracked-files=no", "--", "src", "benches", "tests", "Cargo.toml", "Cargo.lock"]).is_some_and(|s| !s.is_empty()) {
        commit.push_str("+dirty");
    }
    let mut lines = String::new();
    println!("history ({}):", path.display());
    for figure in figures {
        let previous = last_value(&existing, bench, &figure.name);
        let change = previous.filter(|p| *p != 0.0).map(|p| format!(" ({:+.1} % from {p})", 100.0 * (figure.value - p) / p.abs())).unwrap_or_default();
        println!("  {bench} {}: {:.4} {}{change}", figure.name, figure.value, figure.unit);
        let _ = writeln!(lines, "{date},{commit},{bench},{},{:.6},{}", figure.name, figure.value, figure.unit);
    }
    let mut file = std::fs::OpenOptions::new().create(true).append(true).open(&path).unwrap_or_else(|e| panic!("open {}: {e}", path.display()));
    if existing.is_empty() {
        writeln!(file, "{HEADER}").expect("write the history header");
    }
    file.write_all(lines.as_bytes()).unwrap_or_else(|e| panic!("append to {}: {e}", path.display()));
}

/// The last value recorded for `bench`'s `figure` in the CSV text.
fn last_value(csv: &str, bench: &str, figure: &str) -> Option<f64> {
    csv.lines().rev().find_map(|line| {
        let fields: Vec<&str> = line.split(',').collect();
        (fields.len() >= 6 && fields[2] == bench && fields[3] == figure).then(|| fields[4].parse().ok()).flatten()
    })
}

fn command_text(dir: &Path, program: &str, args: &[&str]) -> Option<String> {
    let output = Command::new(program).args(args).current_dir(dir).output().ok()?;
    output.status.success().then(|| String::from_utf8_lossy(&output.stdout).trim().to_owned())
}
