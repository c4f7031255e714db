//! The timing report of a served session (`--report FILE`): the JSON from the line statistics
//! and a plot of the request→reply latency and loop-period distributions beside it.

use std::path::{Path, PathBuf};

use crate::transport::TimingReport;

use super::ReportError;
use super::plot::{PlotLabels, PlotSeries, plot_series_log_x};
use super::summary::write_json;

/// Writes `report` to `path` (JSON, atomically) and its distributions to `STEM-latency.png`
/// and `.svg` in the same folder; returns every file written.
pub fn write_timing_report(path: &Path, report: &TimingReport) -> Result<Vec<PathBuf>, ReportError> {
    let mut files = vec![write_json(path, report)?];
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let stem = path.file_stem().map_or_else(|| "timing".to_owned(), |s| s.to_string_lossy().into_owned());
    // Cumulative distributions share one axis in milliseconds: latencies per instruction and
    // the controller's loop period. A logarithmic axis: sub-millisecond replies and a loop
    // period of seconds (a controller that paused) both stay readable.
    let mut curves: Vec<(String, Vec<f64>, Vec<f64>)> = report
        .latency_us
        .iter()
        .map(|(name, latency)| {
            let (x, y) = latency.cdf_us.iter().map(|&(us, f)| (us / 1000.0, f)).unzip();
            (format!("{name} request→reply"), x, y)
        })
        .collect();
    if let Some(controller_loop) = &report.controller_loop {
        let (x, y) = controller_loop.cdf_ms.iter().copied().unzip();
        curves.push(("loop period".to_owned(), x, y));
    }
    if curves.is_empty() {
        return Ok(files);
    }
    let series: Vec<PlotSeries<'_>> = curves.iter().map(|(label, x, y)| PlotSeries { label, x, y }).collect();
    let labels = PlotLabels { title: "Bus timing: cumulative distributions", x: "time (ms, log scale)", y: "fraction ≤ time" };
    let plot = plot_series_log_x(dir, &format!("{stem}-latency"), &labels, &series)?;
    files.extend([plot.png, plot.svg]);
    Ok(files)
}
