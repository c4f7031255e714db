//! `climbsim sweep`: a scenario over a grid of parameters, in parallel (or one shard of it),
//! every point's row in `sweep.csv`/`sweep.json` whatever became of it, overlay and metric
//! plots; and `--merge` of shards' tables.

use std::collections::BTreeMap;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use serde_json::Value;

use crate::report::{self, PlotLabels, PlotSeries, TimeSeries, units};
use crate::robot::{RobotDescription, RobotOverrides};
use crate::runner::observe::capture::MetricTrack;
use crate::scenario::Scenario;
use crate::scenario::sweep::{Axis, GridPoint, Shard, grid, table_columns};

use super::clock::Pace;
use super::outputs::failures;
use super::{Console, During as _, Result, RunnerError, describe, each_in_parallel, run_scenario};

/// One finished sweep run, as `sweep.json` stores it.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct SweepRow {
    index: usize,
    label: String,
    /// Swept key → value as TOML text.
    parameters: BTreeMap<String, String>,
    summary: BTreeMap<String, Value>,
    /// `completed`, `failed` (the run's own verdict or an error: see `error`), `interrupted`
    /// (stopped part way, its outputs cover what ran) or `not_run` (an interrupted sweep never
    /// started it). Older tables have no status: their rows were completed.
    #[serde(default = "completed")]
    status: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    error: Option<String>,
    /// The run's metric track, for the overlay plots (a merged table's rows have none: their
    /// runs' time series are read instead).
    #[serde(skip)]
    track: Option<MetricTrack>,
}

fn completed() -> String {
    "completed".to_owned()
}

#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct SweepFile {
    scenario: String,
    axes: Vec<String>,
    /// The whole grid (every shard's points), so that a merge can tell which are missing.
    /// Tables written before it was recorded have none: their merge trusts the rows.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    grid: Vec<Axis>,
    rows: Vec<SweepRow>,
}

/// `climbsim sweep --list --json`: the grid points of this shard as one JSON document (index,
/// label, overrides, shard), without running them.
pub fn grid_listing(axes: &[Axis], shard: Shard) -> Value {
    let points: Vec<Value> = shard
        .select(grid(axes))
        .iter()
        .map(|p| serde_json::json!({"index": p.index, "label": p.label(), "overrides": p.overrides.iter().map(|o| (o.key.clone(), Value::String(o.value.to_string()))).collect::<serde_json::Map<_, _>>()}))
        .collect();
    serde_json::json!({"grid_size": grid(axes).len(), "shard": {"index": shard.index, "count": shard.count}, "points": points})
}

/// Which part of a sweep's grid to run, and how.
pub struct SweepPlan<'a> {
    pub axes: &'a [Axis],
    pub jobs: usize,
    pub shard: Shard,
    /// For an external controller: each point at this pace.
    pub pace: Pace,
    /// Record `run.mcap` for every point (`--mcap`).
    pub record_mcap: bool,
}

/// `climbsim sweep SCENARIO --set KEY=V1,V2 ...`. Every grid point gets a row in `sweep.csv` and
/// `sweep.json`, whether it completed, failed, was interrupted or never ran. `progress` is told
/// the number of runs, then called as each finishes.
pub fn sweep(scenario_path: &Path, plan: &SweepPlan<'_>, robot: &RobotDescription, out_dir: &Path, stop: &AtomicBool, console: &dyn Console, progress: &dyn Progress) -> Result<()> {
    let SweepPlan { axes, jobs, shard, pace, record_mcap } = *plan;
    // Every point runs in the climbing robot's world: a bench robot is refused before any runs.
    robot.climber()?;
    let points = shard.select(grid(axes));
    if points.is_empty() {
        return Err(RunnerError::Invalid(format!("shard {}/{} of this grid is empty", shard.index, shard.count)));
    }
    // Check every grid point loads before spending minutes on the first ones. A point that sets
    // `robot.…` or `profile.…` keys has a robot description of its own.
    let scenarios: Vec<(GridPoint, Scenario, Option<RobotDescription>)> = points
        .into_iter()
        .map(|point| {
            let (overrides, robot_sets) = RobotOverrides::split(&point.overrides);
            let mut scenario = Scenario::load_with(scenario_path, &overrides)?;
            scenario.capture.mcap = record_mcap;
            let own_robot = if robot_sets.is_empty() { None } else { Some(RobotDescription::load_with(&robot.path, &robot_sets)?) };
            Ok((point.clone(), scenario, own_robot))
        })
        .collect::<Result<_>>()?;
    progress.start(scenarios.len());
    let started = Instant::now();
    let mut rows = each_in_parallel(&scenarios, jobs, |(point, scenario, own_robot)| {
        let parameters = point.overrides.iter().map(|o| (o.key.clone(), o.value.to_string())).collect();
        let mut row = SweepRow { index: point.index, label: point.label(), parameters, summary: BTreeMap::new(), status: "not_run".to_owned(), error: None, track: None };
        // Interrupted: the runs under way stop and write; no new ones start.
        if !stop.load(Ordering::Relaxed) {
            let run_dir = out_dir.join("runs").join(point.label());
            match run_scenario(scenario, own_robot.as_ref().unwrap_or(robot), &run_dir, pace, stop, console) {
                Ok(outcome) => {
                    let failures = failures(&outcome.summary);
                    row.status = if failures.is_empty() { "completed" } else { "failed" }.to_owned();
                    row.error = (!failures.is_empty()).then(|| failures.join("; "));
                    row.summary = outcome.summary;
                    row.track = Some(outcome.track);
                }
                Err(error) => {
                    row.status = if error.is_interrupted() { "interrupted" } else { "failed" }.to_owned();
                    row.error = Some(describe(&error));
                    // An interrupted run wrote its outputs: keep what its summary says.
                    if let Ok(text) = std::fs::read_to_string(run_dir.join("summary.json")) {
                        row.summary = serde_json::from_str(&text).unwrap_or_default();
                    }
                }
            }
            progress.done_one();
        }
        Some(row)
    });
    progress.finish();
    let wall_s = started.elapsed().as_secs_f64();
    rows.sort_by_key(|r| r.index);
    let file = SweepFile { scenario: scenario_path.display().to_string(), axes: axes.iter().map(|a| a.key.clone()).collect(), grid: axes.to_vec(), rows };
    write_sweep(&file, out_dir)?;
    let count = |status: &str| file.rows.iter().filter(|r| r.status == status).count();
    console.say(&format!("{} of {} runs completed in {wall_s:.1} s with {} jobs; table: {}", count("completed"), file.rows.len(), jobs.max(1), out_dir.join("sweep.csv").display()));
    if stop.load(Ordering::Relaxed) {
        return Err(RunnerError::Interrupted(format!("interrupted: {} runs interrupted, {} not run; sweep.csv marks them", count("interrupted"), count("not_run"))));
    }
    let failed: Vec<String> = file.rows.iter().filter(|r| r.status == "failed").map(|r| format!("{}: {}", r.label, r.error.as_deref().unwrap_or("failed"))).collect();
    if !failed.is_empty() {
        return Err(RunnerError::Failed(format!("{} runs failed:\n  {}", failed.len(), failed.join("\n  "))));
    }
    Ok(())
}

/// `climbsim sweep --merge DIR...`: join shards' tables and plots. Grid points no shard ran,
/// or that did not finish, fail the merge (after writing the table, with them marked) unless
/// `allow_incomplete`.
pub fn merge(dirs: &[PathBuf], out_dir: &Path, allow_incomplete: bool, console: &dyn Console) -> Result<()> {
    let mut merged: Option<SweepFile> = None;
    for dir in dirs {
        let path = dir.join("sweep.json");
        let text = std::fs::read_to_string(&path).during(|| format!("cannot read {}", path.display()))?;
        let mut file: SweepFile = serde_json::from_str(&text).during(|| format!("{} is not a sweep table", path.display()))?;
        if let Some(all) = &merged {
            if !same_scenario(&all.scenario, &file.scenario) {
                return Err(RunnerError::Invalid(format!("{} is a sweep of {}, the others of {}: shards of different scenarios do not merge", path.display(), file.scenario, all.scenario)));
            }
            if all.axes != file.axes {
                return Err(RunnerError::Invalid(format!("{} sweeps {:?}, the others {:?}", path.display(), file.axes, all.axes)));
            }
            if !all.grid.is_empty() && !file.grid.is_empty() && all.grid != file.grid {
                return Err(RunnerError::Invalid(format!("{} is a shard of another grid than the others (same keys, other values)", path.display())));
            }
        }
        // Runs' folders are referenced by the overlay plots: copy their time series over. A
        // completed run's must be there: a shard copied without its runs/ would merge into a
        // table whose plots silently lack it.
        for row in &file.rows {
            let from = dir.join("runs").join(&row.label);
            if row.status == "completed" && !from.join(report::TIMESERIES_CSV).is_file() {
                return Err(RunnerError::Invalid(format!(
                    "{}: run {} completed, but {} is missing (copy the shard's runs/ folder with its sweep.json)",
                    path.display(),
                    row.label,
                    from.join(report::TIMESERIES_CSV).display()
                )));
            }
            let to = out_dir.join("runs").join(&row.label);
            if from != to && from.is_dir() {
                copy_dir(&from, &to)?;
            }
        }
        match &mut merged {
            None => merged = Some(file),
            Some(all) => all.rows.append(&mut file.rows),
        }
    }
    let mut merged = merged.ok_or_else(|| RunnerError::Invalid("nothing to merge".to_owned()))?;
    merged.rows.sort_by_key(|r| r.index);
    merged.rows.dedup_by_key(|r| r.index);
    // The points of the whole grid that no shard brought: rows marked `not_run`.
    let missing: Vec<GridPoint> = grid(&merged.grid).into_iter().filter(|p| merged.rows.binary_search_by_key(&p.index, |r| r.index).is_err()).collect();
    for point in &missing {
        let parameters = point.overrides.iter().map(|o| (o.key.clone(), o.value.to_string())).collect();
        merged.rows.push(SweepRow {
            index: point.index,
            label: point.label(),
            parameters,
            summary: BTreeMap::new(),
            status: "not_run".to_owned(),
            error: Some("no merged shard has this point".to_owned()),
            track: None,
        });
    }
    merged.rows.sort_by_key(|r| r.index);
    write_sweep(&merged, out_dir)?;
    console.say(&format!("merged {} runs into {}", merged.rows.len() - missing.len(), out_dir.join("sweep.csv").display()));
    let unfinished: Vec<&str> = merged.rows.iter().filter(|r| r.status == "not_run" || r.status == "interrupted").map(|r| r.label.as_str()).collect();
    if !unfinished.is_empty() && !allow_incomplete {
        let shown: Vec<&str> = unfinished.iter().take(20).copied().collect();
        let more = if unfinished.len() > shown.len() { format!("\n  ... and {} more", unfinished.len() - shown.len()) } else { String::new() };
        return Err(RunnerError::Failed(format!(
            "the merged sweep is incomplete: {} of {} grid points missing or unfinished (sweep.csv marks them; --allow-incomplete accepts this):\n  {}{more}",
            unfinished.len(),
            merged.rows.len(),
            shown.join("\n  ")
        )));
    }
    Ok(())
}

/// Whether two shards' scenario paths name the same file (the same text, or the same file once
/// resolved: shards may run from different folders).
fn same_scenario(a: &str, b: &str) -> bool {
    a == b || matches!((std::fs::canonicalize(a), std::fs::canonicalize(b)), (Ok(x), Ok(y)) if x == y)
}

fn copy_dir(from: &Path, to: &Path) -> Result<()> {
    std::fs::create_dir_all(to).during(|| format!("cannot create {}", to.display()))?;
    for entry in std::fs::read_dir(from).during(|| format!("cannot list {}", from.display()))? {
        let entry = entry.during(|| format!("cannot list {}", from.display()))?;
        if entry.file_type().during(|| format!("cannot list {}", from.display()))?.is_file() {
            std::fs::copy(entry.path(), to.join(entry.file_name())).during(|| format!("cannot copy {}", entry.path().display()))?;
        }
    }
    Ok(())
}

/// The metrics plotted against the first swept parameter.
/// Metrics plotted against the first swept parameter, and their labels; each is shown in the
/// unit its key's suffix names for plots (`report::units::shown_unit`: m/s as mm/min, m as mm).
const SWEEP_METRICS: &[(&str, &str)] = &[
    ("distance.overshoot_pct", "overshoot (%)"),
    ("distance.rise_time_s", "distance rise time (s)"),
    ("distance.settling_time_s", "distance settling time (s)"),
    ("speed.steady_state_error_m_s", "speed steady-state error (mm/min)"),
    ("speed.mean_abs_error_m_s", "mean |speed error| over the last 80 % (mm/min)"),
    ("speed.rise_time_s", "speed rise time (s)"),
    ("rms_distance_m", "RMS distance error (mm)"),
];

fn write_sweep(file: &SweepFile, out_dir: &Path) -> Result<()> {
    std::fs::create_dir_all(out_dir).during(|| format!("cannot create {}", out_dir.display()))?;
    let json_bytes = serde_json::to_vec_pretty(file).during(|| "cannot encode sweep.json".to_owned())?;
    report::write_atomically(&out_dir.join("sweep.json"), |w| w.write_all(&json_bytes))?;
    let axes: Vec<Axis> = file.axes.iter().map(|key| Axis { key: key.clone(), values: Vec::new() }).collect();
    let summaries: Vec<BTreeMap<String, Value>> = file.rows.iter().map(|r| r.summary.clone()).collect();
    let columns = table_columns(&axes, &summaries);
    let (keys, metrics) = columns.split_at(1 + file.axes.len());
    // One header cell per row cell: the run and its keys, its status and error, the metrics.
    let mut header: Vec<&str> = keys.iter().map(String::as_str).collect();
    header.extend(["status", "error"]);
    header.extend(metrics.iter().map(String::as_str));
    let mut csv = header.join(",");
    csv.push('\n');
    for row in &file.rows {
        let mut cells = vec![row.index.to_string()];
        cells.extend(file.axes.iter().map(|k| csv_cell(row.parameters.get(k).map_or("", String::as_str))));
        cells.push(row.status.clone());
        cells.push(csv_cell(row.error.as_deref().unwrap_or("")));
        cells.extend(metrics.iter().map(|k| row.summary.get(k).map_or(String::new(), |v| csv_cell(&v.to_string()))));
        csv.push_str(&cells.join(","));
        csv.push('\n');
    }
    report::write_atomically(&out_dir.join("sweep.csv"), |w| w.write_all(csv.as_bytes()))?;
    plot_sweep(file, out_dir)
}

/// A value as one unquoted CSV cell: its commas become semicolons, its line breaks spaces.
fn csv_cell(text: &str) -> String {
    text.replace(',', ";").replace(['\n', '\r'], " ")
}

/// A run's signals for the overlay plots.
enum Overlay<'a> {
    Track(&'a MetricTrack),
    Series(TimeSeries),
}

impl Overlay<'_> {
    fn column(&self, name: &str) -> Option<Vec<f64>> {
        match self {
            Self::Track(track) => track.column(name),
            Self::Series(series) => series.column(name),
        }
    }
}

fn plot_sweep(file: &SweepFile, out_dir: &Path) -> Result<()> {
    // Overlay: every run's distance error and speed over time, from its metric track (the
    // rows of a merged table have none: their time series, copied beside them, are read).
    let mut loaded: Vec<(String, Overlay)> = Vec::new();
    for row in &file.rows {
        let overlay = match &row.track {
            Some(track) => Some(Overlay::Track(track)),
            None => report::read_timeseries_csv(&out_dir.join("runs").join(&row.label).join(report::TIMESERIES_CSV)).ok().map(Overlay::Series),
        };
        if let Some(overlay) = overlay {
            let label = row.parameters.iter().map(|(k, v)| units::parameter_label(k, v)).collect::<Vec<_>>().join(", ");
            loaded.push((label, overlay));
        }
    }
    for (column, stem, title, y) in [("d_true_m", "overlay_distance", "Distance error", "d (mm)"), ("speed_m_s", "overlay_speed", "Speed", "speed (mm/min)")] {
        let (factor, _) = units::shown_unit(column);
        let data: Vec<(String, Vec<f64>, Vec<f64>)> =
            loaded.iter().map(|(label, s)| (label.clone(), s.column("t_s").unwrap_or_default(), s.column(column).unwrap_or_default().into_iter().map(|v| v * factor).collect())).collect();
        let series: Vec<PlotSeries<'_>> = data.iter().map(|(label, x, y)| PlotSeries { label, x, y }).collect();
        if !series.is_empty() {
            report::plot_series(out_dir, stem, &PlotLabels { title, x: "t (s)", y }, &series)?;
        }
    }
    // Metric against the first axis, one line per combination of the other axes.
    let Some(first) = file.axes.first() else { return Ok(()) };
    for (metric, y_label) in SWEEP_METRICS {
        let ((factor, _), (x_factor, _)) = (units::shown_unit(metric), units::shown_unit(first));
        let mut groups: BTreeMap<String, (Vec<f64>, Vec<f64>)> = BTreeMap::new();
        for row in &file.rows {
            let (Some(x), Some(y)) = (row.parameters.get(first).and_then(|v| v.parse::<f64>().ok()), row.summary.get(*metric).and_then(Value::as_f64)) else {
                continue;
            };
            let group = file.axes[1..].iter().map(|k| units::parameter_label(k, row.parameters.get(k).map_or("", String::as_str))).collect::<Vec<_>>().join(", ");
            let entry = groups.entry(if group.is_empty() { y_label.to_string() } else { group }).or_default();
            entry.0.push(x * x_factor);
            entry.1.push(y * factor);
        }
        if groups.is_empty() {
            continue;
        }
        let series: Vec<PlotSeries<'_>> = groups.iter().map(|(label, (x, y))| PlotSeries { label, x, y }).collect();
        let stem = format!("{}_vs_{}", metric.replace('.', "_"), first.rsplit('.').next().unwrap_or(first));
        let x_label = units::parameter_axis(first);
        report::plot_metric_vs_parameter(out_dir, &stem, &PlotLabels { title: y_label, x: &x_label, y: y_label }, &series)?;
    }
    Ok(())
}

/// Where a sweep reports how far it is (the command line draws a bar).
pub trait Progress: Sync {
    /// The sweep will run `runs` points.
    fn start(&self, runs: usize);
    /// One more point finished.
    fn done_one(&self);
    /// Every point has finished or been given up.
    fn finish(&self);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A merge reads the tables the shards wrote: every metric comes back bit for bit, so that a
    /// merged table equals an unsharded run's. (serde_json parses floats exactly only with its
    /// `float_roundtrip` feature; without it, metrics came back 1 ulp off: 28 of 390 in a real
    /// sweep's merge.)
    #[test]
    fn a_table_read_back_has_every_metric_bit_for_bit() {
        // Metrics as runs make them: any mantissa, magnitudes from 1e-9 to 1e6 and both signs.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let summary: BTreeMap<String, Value> = (0..5000)
            .map(|i| {
                let random = next();
                let exponent = 1023 - 30 + (random % 50);
                let value = f64::from_bits((random >> 63) << 63 | exponent << 52 | (next() >> 12));
                (format!("metric_{i:04}"), Value::from(value))
            })
            .collect();
        let row = SweepRow { index: 0, label: "run".to_owned(), parameters: BTreeMap::new(), summary, status: completed(), error: None, track: None };
        let table = SweepFile { scenario: "s.toml".to_owned(), axes: Vec::new(), grid: Vec::new(), rows: vec![row] };
        let written = serde_json::to_vec_pretty(&table).expect("encodes");
        let read: SweepFile = serde_json::from_slice(&written).expect("decodes");
        let (before, after) = (&table.rows[0].summary, &read.rows[0].summary);
        let differing: Vec<&String> = before.keys().filter(|key| before[*key].as_f64().map(f64::to_bits) != after[*key].as_f64().map(f64::to_bits)).collect();
        assert!(differing.is_empty(), "{} of {} metrics came back changed, first {}: {} became {}", differing.len(), before.len(), differing[0], before[differing[0]], after[differing[0]]);
    }
}
