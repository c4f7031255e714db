//! `climbsim diff A B`: compare two runs' `timeseries.csv` (column by column, aligned on `t_s`)
//! and `summary.json` (metric by metric) against tolerances.
//!
//! A difference passes if it is within the key's absolute tolerance *or* within the relative
//! tolerance times the key's scale (the larger |value| of the two metrics; the largest |value|
//! in either column). Default absolute tolerances go by the key's unit suffix
//! ([`DEFAULT_TOLERANCES`]); the default relative tolerance is 0. Series are compared over the
//! time both cover; `t_s` itself checks that they cover the same span (start and end within
//! 1.5 capture periods of A). A value that is NaN on one side only (the camera saw the line in
//! one run, not the other) is an infinite difference. Keys in one run only are listed, not
//! failed; wall-clock figures (`realtime_factor`, `physics_overruns`) and non-numeric metrics are
//! not compared.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::Value;

use super::{ReportError, SUMMARY_JSON, Summary, TIMESERIES_CSV, TimeSeries, read_timeseries_csv};

/// Absolute tolerance by key suffix; the first match wins (so `_rad_s` before `_rad`). Chosen to
/// be well under what matters for the task (0.1 mm of line distance, 0.06° of heading, 6 mm/min
/// of speed) while far above floating-point noise.
pub const DEFAULT_TOLERANCES: &[(&str, f64)] = &[("line_valid", 0.0), ("_rad_s", 1e-2), ("_m_s", 1e-4), ("_rad", 1e-3), ("_m", 1e-4), ("_n", 0.5), ("_pct", 0.5), ("_fraction", 5e-3), ("_s", 0.02)];
/// Any other key (counts, unitless numbers).
pub const DEFAULT_OTHER_TOLERANCE: f64 = 1e-9;
/// Summary keys that depend on the wall clock, not the trajectory.
pub const NOT_COMPARED: &[&str] = &["realtime_factor", "physics_overruns"];

/// One run's outputs: a folder's `summary.json` and `timeseries.csv`, or one of the files.
#[derive(Debug, Clone)]
pub struct RunData {
    pub source: PathBuf,
    pub summary: Option<Summary>,
    pub series: Option<TimeSeries>,
}

/// Read a run folder (its `summary.json` and `timeseries.csv`, whichever exist) or one file.
pub fn load_run(path: &Path) -> Result<RunData, ReportError> {
    let invalid = |message: String| ReportError::Io { path: path.to_owned(), source: std::io::Error::new(std::io::ErrorKind::InvalidData, message) };
    let (summary_path, series_path) = if path.is_dir() {
        let (s, t) = (path.join(SUMMARY_JSON), path.join(TIMESERIES_CSV));
        if !s.exists() && !t.exists() {
            return Err(invalid(format!("neither {SUMMARY_JSON} nor {TIMESERIES_CSV} in this folder")));
        }
        (s.exists().then_some(s), t.exists().then_some(t))
    } else if path.extension().is_some_and(|e| e == "json") {
        (Some(path.to_owned()), None)
    } else if path.extension().is_some_and(|e| e == "csv") {
        (None, Some(path.to_owned()))
    } else {
        return Err(invalid("not a run folder, a summary .json or a time-series .csv".to_owned()));
    };
    let summary = match summary_path {
        Some(p) => {
            let text = std::fs::read_to_string(&p).map_err(super::io_error(&p))?;
            Some(serde_json::from_str::<Summary>(&text).map_err(|source| ReportError::Json { path: p.clone(), source })?)
        }
        None => None,
    };
    let series = series_path.map(|p| read_timeseries_csv(&p)).transpose()?;
    Ok(RunData { source: path.to_owned(), summary, series })
}

/// Tolerances given on the command line.
#[derive(Debug, Clone, Default)]
pub struct Tolerances {
    /// Key → absolute tolerance (overrides the default).
    pub abs: BTreeMap<String, f64>,
    /// Relative tolerance for every key (0 when absent).
    pub rel: Option<f64>,
}

impl Tolerances {
    /// `KEY=ABS` (ABS may be `inf` to ignore the key).
    pub fn parse_abs(text: &str) -> Result<(String, f64), String> {
        let (key, value) = text.split_once('=').ok_or_else(|| format!("`{text}` is not KEY=ABS"))?;
        let value: f64 = value.trim().parse().map_err(|_| format!("`{text}`: `{value}` is not a number"))?;
        if value.is_nan() || value < 0.0 {
            return Err(format!("`{text}`: a tolerance is a non-negative number"));
        }
        Ok((key.trim().to_owned(), value))
    }

    /// The absolute tolerance of `key`.
    pub fn abs_for(&self, key: &str) -> f64 {
        if let Some(&given) = self.abs.get(key) {
            return given;
        }
        DEFAULT_TOLERANCES.iter().find(|(suffix, _)| key.ends_with(suffix)).map_or(DEFAULT_OTHER_TOLERANCE, |&(_, tolerance)| tolerance)
    }

    fn allowed(&self, key: &str, scale: f64) -> f64 {
        self.abs_for(key).max(self.rel.unwrap_or(0.0) * scale)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// The series' time span.
    Span,
    Column,
    Metric,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    Pass,
    Fail,
    OnlyIn(&'static str),
}

/// One compared key.
#[derive(Debug, Clone)]
pub struct DiffRow {
    pub key: String,
    pub kind: Kind,
    /// Largest |A − B| (infinite where one side is NaN or null and the other is not).
    pub max_abs: f64,
    /// Where the largest difference is (columns).
    pub at_t: Option<f64>,
    pub allowed: f64,
    pub verdict: Verdict,
}

#[derive(Debug, Clone)]
pub struct DiffReport {
    pub rows: Vec<DiffRow>,
    /// The time span compared, and the number of rows of A in it.
    pub overlap: Option<(f64, f64, usize)>,
}

impl DiffReport {
    pub fn failures(&self) -> usize {
        self.rows.iter().filter(|r| r.verdict == Verdict::Fail).count()
    }

    /// A fixed-width table, one key a line.
    pub fn table(&self) -> String {
        let width = self.rows.iter().map(|r| r.key.len()).max().unwrap_or(3).max(3);
        let mut out = format!("{:<width$}  {:>12}  {:>10}  {:>12}  result\n", "key", "max |A-B|", "at t (s)", "tolerance");
        for row in &self.rows {
            let at = row.at_t.map_or_else(|| "-".to_owned(), |t| format!("{t:.3}"));
            let verdict = match &row.verdict {
                Verdict::Pass => "ok".to_owned(),
                Verdict::Fail => "FAIL".to_owned(),
                Verdict::OnlyIn(side) => format!("only in {side}"),
            };
            let number = |v: f64| if v.is_nan() { "-".to_owned() } else { format!("{v:.3e}") };
            let _ = writeln!(out, "{:<width$}  {:>12}  {:>10}  {:>12}  {verdict}", row.key, number(row.max_abs), at, number(row.allowed));
        }
        if let Some((from, to, rows)) = self.overlap {
            let _ = writeln!(out, "series compared over t = {from:.3} .. {to:.3} s ({rows} rows)");
        }
        out
    }
}

/// Compare `a` with `b`.
pub fn compare(a: &RunData, b: &RunData, tolerances: &Tolerances) -> DiffReport {
    let mut rows = Vec::new();
    let mut overlap = None;
    if let (Some(sa), Some(sb)) = (&a.series, &b.series) {
        overlap = compare_series(sa, sb, tolerances, &mut rows);
    }
    if let (Some(ma), Some(mb)) = (&a.summary, &b.summary) {
        compare_summaries(ma, mb, tolerances, &mut rows);
    }
    DiffReport { rows, overlap }
}

fn verdict(max_abs: f64, allowed: f64) -> Verdict {
    if max_abs <= allowed { Verdict::Pass } else { Verdict::Fail }
}

fn compare_series(a: &TimeSeries, b: &TimeSeries, tolerances: &Tolerances, rows: &mut Vec<DiffRow>) -> Option<(f64, f64, usize)> {
    let (ta, tb) = (a.column("t_s")?, b.column("t_s")?);
    // A time series with no rows against one with rows (a header-only file): nothing in common,
    // which is the largest difference there is, not "no differences".
    if ta.is_empty() != tb.is_empty() {
        let allowed = tolerances.abs.get("t_s").copied().unwrap_or(0.0);
        rows.push(DiffRow { key: "t_s".to_owned(), kind: Kind::Span, max_abs: f64::INFINITY, at_t: None, allowed, verdict: Verdict::Fail });
        return None;
    }
    let (&a0, &an, &b0, &bn) = (ta.first()?, ta.last()?, tb.first()?, tb.last()?);
    let mut steps: Vec<f64> = ta.windows(2).map(|w| w[1] - w[0]).collect();
    steps.sort_by(f64::total_cmp);
    let period = steps.get(steps.len() / 2).copied().unwrap_or(0.0);
    let span = (a0 - b0).abs().max((an - bn).abs());
    let allowed = tolerances.abs.get("t_s").copied().unwrap_or(1.5 * period);
    rows.push(DiffRow { key: "t_s".to_owned(), kind: Kind::Span, max_abs: span, at_t: None, allowed, verdict: verdict(span, allowed) });

    let same_times = ta == tb;
    let (from, to) = (a0.max(b0), an.min(bn));
    let compared: Vec<usize> = (0..ta.len()).filter(|&i| same_times || (ta[i] >= from && ta[i] <= to)).collect();
    for name in a.columns().iter().filter(|c| c.as_str() != "t_s") {
        let Some(ya) = a.column(name) else { continue };
        let Some(yb) = b.column(name) else {
            rows.push(DiffRow { key: name.clone(), kind: Kind::Column, max_abs: f64::NAN, at_t: None, allowed: f64::NAN, verdict: Verdict::OnlyIn("A") });
            continue;
        };
        let (mut max_abs, mut at_t, mut scale) = (0.0_f64, None, 0.0_f64);
        for &i in &compared {
            let other = if same_times { yb[i] } else { interpolate(&tb, &yb, ta[i]) };
            let difference = match (ya[i].is_nan(), other.is_nan()) {
                (true, true) => 0.0,
                (false, false) => (ya[i] - other).abs(),
                _ => f64::INFINITY,
            };
            scale = scale.max(if ya[i].is_nan() { 0.0 } else { ya[i].abs() }).max(if other.is_nan() { 0.0 } else { other.abs() });
            if at_t.is_none() || difference > max_abs {
                (max_abs, at_t) = (difference, Some(ta[i]));
            }
        }
        let allowed = tolerances.allowed(name, scale);
        rows.push(DiffRow { key: name.clone(), kind: Kind::Column, max_abs, at_t, allowed, verdict: verdict(max_abs, allowed) });
    }
    for name in b.columns().iter().filter(|c| a.column(c).is_none()) {
        rows.push(DiffRow { key: name.clone(), kind: Kind::Column, max_abs: f64::NAN, at_t: None, allowed: f64::NAN, verdict: Verdict::OnlyIn("B") });
    }
    Some((from, to, compared.len()))
}

/// `y(t)` by linear interpolation between the samples around `t` (NaN if either is NaN).
fn interpolate(t: &[f64], y: &[f64], at: f64) -> f64 {
    let i = t.partition_point(|&x| x < at);
    if i < t.len() && t[i] == at {
        return y[i];
    }
    if i == 0 || i >= t.len() {
        return f64::NAN;
    }
    let (t0, t1, y0, y1) = (t[i - 1], t[i], y[i - 1], y[i]);
    if t1 <= t0 { y1 } else { y0 + (y1 - y0) * (at - t0) / (t1 - t0) }
}

fn metric_value(value: &Value) -> Option<Option<f64>> {
    match value {
        Value::Number(n) => Some(n.as_f64()),
        Value::Bool(b) => Some(Some(f64::from(u8::from(*b)))),
        Value::Null => Some(None),
        _ => None, // text (e.g. the controller's exit status) is not compared
    }
}

fn compare_summaries(a: &Summary, b: &Summary, tolerances: &Tolerances, rows: &mut Vec<DiffRow>) {
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    for key in keys.into_iter().filter(|k| !NOT_COMPARED.contains(&k.as_str())) {
        let row = |max_abs, allowed, verdict| DiffRow { key: key.clone(), kind: Kind::Metric, max_abs, at_t: None, allowed, verdict };
        match (a.get(key).and_then(metric_value), b.get(key).and_then(metric_value)) {
            (Some(va), Some(vb)) => {
                let (difference, scale) = match (va, vb) {
                    (Some(x), Some(y)) => ((x - y).abs(), x.abs().max(y.abs())),
                    (None, None) => (0.0, 0.0),
                    _ => (f64::INFINITY, 0.0),
                };
                let allowed = tolerances.allowed(key, scale);
                rows.push(row(difference, allowed, verdict(difference, allowed)));
            }
            (Some(_), None) if !b.contains_key(key) => rows.push(row(f64::NAN, f64::NAN, Verdict::OnlyIn("A"))),
            (None, Some(_)) if !a.contains_key(key) => rows.push(row(f64::NAN, f64::NAN, Verdict::OnlyIn("B"))),
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(rows: &[[f64; 3]]) -> TimeSeries {
        let mut s = TimeSeries::new(["t_s", "x_m", "psi_true_rad"]);
        for row in rows {
            s.push_row(row).expect("width 3");
        }
        s
    }

    fn run(rows: &[[f64; 3]], summary: &[(&str, Value)]) -> RunData {
        RunData { source: PathBuf::from("x"), series: Some(series(rows)), summary: Some(summary.iter().map(|(k, v)| ((*k).to_owned(), v.clone())).collect()) }
    }

    #[test]
    fn a_series_without_rows_differs_from_one_with_rows() {
        let rows = [[0.0, 0.0, 0.0], [0.02, 0.001, 0.01]];
        let summary = [("rms_distance_m", 0.01.into())];
        let report = compare(&run(&rows, &summary), &run(&[], &summary), &Tolerances::default());
        assert_eq!(report.failures(), 1, "{}", report.table());
        assert!(report.rows.iter().any(|r| r.key == "t_s" && r.verdict == Verdict::Fail && r.max_abs.is_infinite()), "{}", report.table());
        let empty = compare(&run(&[], &summary), &run(&[], &summary), &Tolerances::default());
        assert_eq!(empty.failures(), 0, "{}", empty.table());
    }

    #[test]
    fn identical_runs_pass_and_a_real_difference_fails() {
        let rows = [[0.0, 0.0, 0.0], [0.02, 0.001, 0.01], [0.04, 0.002, 0.02]];
        let a = run(&rows, &[("rms_distance_m", 0.01.into()), ("realtime_factor", 3.0.into())]);
        let same = compare(&a, &a.clone(), &Tolerances::default());
        assert_eq!(same.failures(), 0, "{}", same.table());
        let mut moved = rows;
        moved[2][1] += 0.001; // 1 mm at t = 0.04
        let b = run(&moved, &[("rms_distance_m", 0.01.into()), ("realtime_factor", 1.0.into())]);
        let report = compare(&a, &b, &Tolerances::default());
        assert_eq!(report.failures(), 1, "{}", report.table());
        let x = report.rows.iter().find(|r| r.key == "x_m").expect("x_m compared");
        assert!((x.max_abs - 0.001).abs() < 1e-12 && x.at_t == Some(0.04) && x.verdict == Verdict::Fail);
        assert!(!report.rows.iter().any(|r| r.key == "realtime_factor"), "wall-clock keys are not compared");
        // A looser tolerance, absolute or relative, lets it pass.
        let loose = Tolerances { abs: [("x_m".to_owned(), 0.002)].into(), rel: None };
        assert_eq!(compare(&a, &b, &loose).failures(), 0);
        let relative = Tolerances { abs: BTreeMap::new(), rel: Some(0.5) };
        assert_eq!(compare(&a, &b, &relative).failures(), 0);
    }

    #[test]
    fn series_are_aligned_on_time_and_must_span_the_same_time() {
        let a = run(&[[0.0, 0.0, 0.0], [0.02, 0.002, 0.0], [0.04, 0.004, 0.0]], &[]);
        // B sampled half-way between: interpolation of a straight line is exact.
        let b = run(&[[0.01, 0.001, 0.0], [0.03, 0.003, 0.0], [0.05, 0.005, 0.0]], &[]);
        let report = compare(&a, &b, &Tolerances::default());
        assert_eq!(report.failures(), 0, "{}", report.table());
        // One capture period short is within the span tolerance (1.5 periods); two are not.
        let a = run(&[[0.0, 0.0, 0.0], [0.02, 0.002, 0.0], [0.04, 0.004, 0.0], [0.06, 0.006, 0.0]], &[]);
        let one_short = run(&[[0.0, 0.0, 0.0], [0.02, 0.002, 0.0], [0.04, 0.004, 0.0]], &[]);
        assert_eq!(compare(&a, &one_short, &Tolerances::default()).failures(), 0);
        let short = run(&[[0.0, 0.0, 0.0], [0.02, 0.002, 0.0]], &[]);
        let report = compare(&a, &short, &Tolerances::default());
        assert!(report.rows.iter().any(|r| r.key == "t_s" && r.verdict == Verdict::Fail), "{}", report.table());
    }

    #[test]
    fn nan_on_one_side_only_and_null_metrics_are_differences() {
        let a = run(&[[0.0, f64::NAN, 0.0], [0.02, 0.0, 0.0]], &[("distance.settling_time_s", Value::Null)]);
        let b = run(&[[0.0, f64::NAN, 0.0], [0.02, f64::NAN, 0.0]], &[("distance.settling_time_s", 1.5.into())]);
        let report = compare(&a, &b, &Tolerances::default());
        assert_eq!(report.failures(), 2, "{}", report.table());
        assert_eq!(compare(&a, &a.clone(), &Tolerances::default()).failures(), 0, "NaN on both sides is equal");
    }

    #[test]
    fn tolerances_parse_and_default_by_unit() {
        assert_eq!(Tolerances::parse_abs("x_m=0.001"), Ok(("x_m".to_owned(), 0.001)));
        assert_eq!(Tolerances::parse_abs("realtime_factor=inf").map(|(_, v)| v.is_infinite()), Ok(true));
        assert!(Tolerances::parse_abs("x_m").is_err() && Tolerances::parse_abs("x_m=-1").is_err() && Tolerances::parse_abs("x_m=abc").is_err());
        let t = Tolerances::default();
        assert_eq!(t.abs_for("wheel_rate_fl_rad_s"), 1e-2);
        assert_eq!(t.abs_for("psi_true_rad"), 1e-3);
        assert_eq!(t.abs_for("speed_m_s"), 1e-4);
        assert_eq!(t.abs_for("physics_ticks"), DEFAULT_OTHER_TOLERANCE);
    }
}
