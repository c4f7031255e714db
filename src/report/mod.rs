//! A run's outputs, written into an output directory: `timeseries.csv`, `summary.json`,
//! `settings.json`, the seed's three-sheet `report.xlsx`, PNG/SVG plots, and JUnit XML for
//! `climbsim check`.
//!
//! Every file is written atomically ([`write_atomically`]): a run killed mid-write leaves either
//! the previous file or none, never half of one. The functions do not create the output
//! directory; the caller does, once.

mod atomic;
pub mod diff;
pub mod junit;
mod path;
mod plot;
mod summary;
mod timeseries;
mod timing;
pub mod units;
mod workbook;

use std::io;
use std::path::{Path, PathBuf};

use thiserror::Error;

pub use atomic::write_atomically;
pub use path::{HeightGrid, PathView, plot_path};
pub use plot::{PLOT_SIZE_PX, PlotFiles, PlotLabels, PlotSeries, plot_metric_vs_parameter, plot_series};
pub use summary::{SCHEDULER_JSON, SETTINGS_JSON, SUMMARY_JSON, Summary, summarise, write_scheduler_json, write_settings_json, write_summary_json};
pub use timeseries::{CsvRows, TIMESERIES_CSV, TimeSeries, TimeSeriesWriter, read_timeseries_csv, write_timeseries_csv};
pub use timing::write_timing_report;
pub use workbook::{REPORT_XLSX, SHEET_RAW_DATA, SHEET_SETTINGS, SHEET_STEP_CHARACTERISTICS, write_workbook};

/// Why an output could not be written. Variants about a file name it.
#[derive(Debug, Error)]
pub enum ReportError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: io::Error },
    #[error("{}: JSON: {source}", path.display())]
    Json { path: PathBuf, source: serde_json::Error },
    #[error("{}: workbook: {source}", path.display())]
    Workbook { path: PathBuf, source: rust_xlsxwriter::XlsxError },
    #[error("{}: plot: {message}", path.display())]
    Plot { path: PathBuf, message: String },
    #[error("{}: PNG encoding: {source}", path.display())]
    PngEncoding { path: PathBuf, source: png::EncodingError },
    #[error("a time-series row has {got} values but the series has {expected} columns")]
    RowWidth { expected: usize, got: usize },
    #[error("plot series {label:?} has {x_len} x values and {y_len} y values")]
    SeriesLengthMismatch { label: String, x_len: usize, y_len: usize },
    #[error("plot file stem {stem:?} is not a plain file name")]
    InvalidFileStem { stem: String },
    #[error("the embedded plot font could not be loaded")]
    Font,
}

/// Wraps an I/O error with the file it concerns: `.map_err(io_error(path))`.
pub(crate) fn io_error(path: &Path) -> impl FnOnce(io::Error) -> ReportError + use<> {
    let path = path.to_path_buf();
    move |source| ReportError::Io { path, source }
}
