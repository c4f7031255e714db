//! `report.xlsx`: the seed's workbook (section 4.2) with three sheets — the raw time series, the
//! simulation settings, and the step-response characteristics.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use rust_xlsxwriter::{Format, Workbook, Worksheet, XlsxError};
use serde_json::Value;

use super::atomic::write_atomically_at;
use super::timeseries::CsvRows;
use super::{ReportError, Summary, io_error};

/// File name of the workbook in the output directory.
pub const REPORT_XLSX: &str = "report.xlsx";
/// Sheet of the time series: a header row of column names, then one row per sample.
pub const SHEET_RAW_DATA: &str = "Raw data";
/// Sheet of the settings, one `setting | value` row per leaf of the settings JSON.
pub const SHEET_SETTINGS: &str = "Settings";
/// Sheet of the metrics, one `metric | value` row per entry of the summary.
pub const SHEET_STEP_CHARACTERISTICS: &str = "Step characteristics";

/// Data rows a sheet holds (Excel's 1 048 576 rows, less the header).
pub const MAX_SHEET_ROWS: u64 = 1_048_575;

/// Writes `out_dir/report.xlsx` atomically and returns its path, with the Raw data sheet copied
/// row by row from the CSV file `series` (a `timeseries.csv`). Nested settings are flattened to
/// dotted keys (`controller.kd`, `line.points[2]`); `null` values leave the value cell empty.
/// Excel cannot hold NaN or infinities: such samples appear as the text `NAN`, `INF`, `-INF`.
///
/// The Raw data sheet is a constant-memory worksheet: each row goes to a temporary file in
/// `out_dir` as it is written, so a series of any length costs the same memory. A sheet holds at
/// most [`MAX_SHEET_ROWS`] samples; a longer series is thinned to every n-th row, which the
/// Settings sheet records (`raw_data.every_nth_row`, `raw_data.note`); the CSV keeps them all.
pub fn write_workbook(out_dir: &Path, series: &Path, settings: &Value, summary: &Summary) -> Result<PathBuf, ReportError> {
    write_workbook_with_limit(out_dir, series, settings, summary, MAX_SHEET_ROWS)
}

/// [`write_workbook`] with at most `max_rows` samples in the Raw data sheet.
fn write_workbook_with_limit(out_dir: &Path, series: &Path, settings: &Value, summary: &Summary, max_rows: u64) -> Result<PathBuf, ReportError> {
    let path = out_dir.join(REPORT_XLSX);
    let rows = count_rows(series)?;
    write_atomically_at(&path, |temporary| {
        let workbook_error = |source| ReportError::Workbook { path: path.clone(), source };
        without_panicking(&path, || {
            let mut workbook = build_workbook(out_dir, series, (rows, max_rows), settings, summary).map_err(|error| match error {
                Built::Xlsx(source) => workbook_error(source),
                Built::Report(error) => error,
            })?;
            workbook.save(temporary).map_err(workbook_error)
        })
    })?;
    Ok(path)
}

thread_local! {
    /// Set while this thread runs the xlsx writer under [`without_panicking`].
    static GUARDED: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Run `write` and turn a panic in it into an error. rust_xlsxwriter panics when it cannot
/// write its constant-memory sheet's temporary file (a full disk: "Couldn't write to xml
/// file"); that is an I/O error of the run's outputs, not a crash. The panic is not printed: a
/// hook installed once passes every other panic on to the one before it.
fn without_panicking(path: &Path, write: impl FnOnce() -> Result<(), ReportError>) -> Result<(), ReportError> {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !GUARDED.with(std::cell::Cell::get) {
                previous(info);
            }
        }));
    });
    GUARDED.with(|guarded| guarded.set(true));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(write));
    GUARDED.with(|guarded| guarded.set(false));
    result.unwrap_or_else(|payload| {
        let message = payload.downcast_ref::<String>().cloned().or_else(|| payload.downcast_ref::<&str>().map(|s| (*s).to_owned())).unwrap_or_else(|| "the xlsx writer failed".to_owned());
        Err(ReportError::Io { path: path.to_owned(), source: std::io::Error::other(message) })
    })
}

/// Rows of the CSV file at `path` (lines after the header that are not empty).
fn count_rows(path: &Path) -> Result<u64, ReportError> {
    let mut rows = 0;
    for row in CsvLines::open(path)? {
        row?;
        rows += 1;
    }
    Ok(rows)
}

/// Non-empty lines after the header, unparsed: counting them must not cost a parse.
struct CsvLines {
    path: PathBuf,
    reader: BufReader<File>,
    buffer: Vec<u8>,
}

impl CsvLines {
    fn open(path: &Path) -> Result<Self, ReportError> {
        let mut reader = BufReader::new(File::open(path).map_err(io_error(path))?);
        let mut buffer = Vec::new();
        reader.read_until(b'\n', &mut buffer).map_err(io_error(path))?;
        Ok(Self { path: path.to_owned(), reader, buffer })
    }
}

impl Iterator for CsvLines {
    type Item = Result<(), ReportError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            self.buffer.clear();
            match self.reader.read_until(b'\n', &mut self.buffer) {
                Ok(0) => return None,
                Ok(_) if self.buffer.iter().all(|b| b.is_ascii_whitespace()) => continue,
                Ok(_) => return Some(Ok(())),
                Err(source) => return Some(Err(ReportError::Io { path: self.path.clone(), source })),
            }
        }
    }
}

enum Built {
    Xlsx(XlsxError),
    Report(ReportError),
}

impl From<XlsxError> for Built {
    fn from(error: XlsxError) -> Self {
        Self::Xlsx(error)
    }
}

impl From<ReportError> for Built {
    fn from(error: ReportError) -> Self {
        Self::Report(error)
    }
}

fn build_workbook(out_dir: &Path, series: &Path, (rows, max_rows): (u64, u64), settings: &Value, summary: &Summary) -> Result<Workbook, Built> {
    let mut workbook = Workbook::new();
    // The raw sheet's rows spill to a temporary file beside the outputs, not in /tmp (often a
    // RAM-backed tmpfs, which would bring the memory back).
    workbook.set_tempdir(out_dir)?;
    let header = Format::new().set_bold();

    let every = rows.div_ceil(max_rows.max(1)).max(1);
    let csv = CsvRows::open(series)?;
    let raw = workbook.add_worksheet_with_constant_memory().set_name(SHEET_RAW_DATA)?;
    for (column, name) in (0..).zip(csv.columns()) {
        raw.write_string_with_format(0, column, name, &header)?;
    }
    raw.set_freeze_panes(1, 0)?;
    for (row, values) in (1..).zip(csv.step_by(every as usize)) {
        for (column, value) in (0..).zip(values?) {
            raw.write_number(row, column, value)?;
        }
    }

    let mut flat_settings = flatten_json(settings);
    flat_settings.push(("raw_data.rows".to_owned(), Value::from(rows)));
    if every > 1 {
        flat_settings.push(("raw_data.every_nth_row".to_owned(), Value::from(every)));
        flat_settings.push((
            "raw_data.note".to_owned(),
            Value::from(format!("the series has {rows} rows, more than the {max_rows} a sheet holds: Raw data shows every {every}th; timeseries.csv has them all")),
        ));
    }
    let sheet = workbook.add_worksheet().set_name(SHEET_SETTINGS)?;
    write_key_values(sheet, ["setting", "value"], flat_settings.iter().map(|(key, value)| (key.as_str(), value)), &header)?;

    let sheet = workbook.add_worksheet().set_name(SHEET_STEP_CHARACTERISTICS)?;
    write_key_values(sheet, ["metric", "value"], summary.iter().map(|(key, value)| (key.as_str(), value)), &header)?;

    Ok(workbook)
}

/// The most characters an Excel cell holds.
const CELL_CHARS: usize = 32_767;

/// `text` as a cell can hold it: cut to Excel's limit, saying so (a failure that names 4000
/// threads is longer; the whole text stays in summary.json). Writing it whole fails the workbook.
fn cell_text(text: &str) -> std::borrow::Cow<'_, str> {
    const CUT: &str = " … (cut to Excel's cell limit: the whole text is in summary.json)";
    if text.chars().count() <= CELL_CHARS {
        return text.into();
    }
    let kept: String = text.chars().take(CELL_CHARS - CUT.chars().count()).collect();
    (kept + CUT).into()
}

fn write_key_values<'a>(sheet: &mut Worksheet, headings: [&str; 2], entries: impl Iterator<Item = (&'a str, &'a Value)>, header: &Format) -> Result<(), XlsxError> {
    sheet.write_string_with_format(0, 0, headings[0], header)?;
    sheet.write_string_with_format(0, 1, headings[1], header)?;
    for (row, (key, value)) in (1..).zip(entries) {
        sheet.write_string(row, 0, key)?;
        match value {
            Value::Null => {}
            Value::Bool(flag) => {
                sheet.write_boolean(row, 1, *flag)?;
            }
            Value::Number(number) => match number.as_f64() {
                Some(number) => {
                    sheet.write_number(row, 1, number)?;
                }
                None => {
                    sheet.write_string(row, 1, number.to_string())?;
                }
            },
            Value::String(text) => {
                sheet.write_string(row, 1, cell_text(text))?;
            }
            // flatten_json leaves no containers; a summary could hold one, so show it as JSON.
            Value::Array(_) | Value::Object(_) => {
                sheet.write_string(row, 1, cell_text(&value.to_string()))?;
            }
        }
    }
    sheet.set_column_width(0, 36)?;
    sheet.set_column_width(1, 18)?;
    Ok(())
}

/// The leaves of a JSON value with their dotted paths, in document order (serde_json keeps object
/// keys sorted). A scalar at the top has the path `value`; empty arrays and objects are leaves.
fn flatten_json(value: &Value) -> Vec<(String, Value)> {
    fn walk(path: String, value: &Value, leaves: &mut Vec<(String, Value)>) {
        match value {
            Value::Object(map) if !map.is_empty() => {
                for (key, child) in map {
                    let child_path = if path.is_empty() { key.clone() } else { format!("{path}.{key}") };
                    walk(child_path, child, leaves);
                }
            }
            Value::Array(items) if !items.is_empty() => {
                for (index, child) in items.iter().enumerate() {
                    walk(format!("{path}[{index}]"), child, leaves);
                }
            }
            leaf => {
                let path = if path.is_empty() { "value".to_owned() } else { path };
                leaves.push((path, leaf.clone()));
            }
        }
    }
    let mut leaves = Vec::new();
    walk(String::new(), value, &mut leaves);
    leaves
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::TimeSeries;
    use calamine::{Data, Reader, Xlsx, open_workbook};
    use serde_json::json;

    #[test]
    fn settings_flatten_to_dotted_paths() {
        let settings = json!({
            "controller": {"kd": 2.0, "gains": [1, 2]},
            "name": "flat",
            "empty": {},
            "none": null
        });
        let flat = flatten_json(&settings);
        let keys: Vec<&str> = flat.iter().map(|(key, _)| key.as_str()).collect();
        assert_eq!(keys, ["controller.gains[0]", "controller.gains[1]", "controller.kd", "empty", "name", "none"]);
        assert_eq!(flat[2].1, json!(2.0));
        assert_eq!(flatten_json(&json!(3)), vec![("value".to_owned(), json!(3))]);
    }

    #[test]
    fn a_text_past_excels_cell_limit_is_cut_and_says_so() {
        let long = "é".repeat(CELL_CHARS + 10);
        let cut = cell_text(&long);
        assert_eq!(cut.chars().count(), CELL_CHARS);
        assert!(cut.ends_with("the whole text is in summary.json)"), "{}", &cut[cut.len() - 80..]);
        assert_eq!(cell_text("short"), "short");
        // And the workbook takes it (rust_xlsxwriter refuses a longer string).
        let mut workbook = Workbook::new();
        let sheet = workbook.add_worksheet();
        assert!(sheet.write_string(0, 0, cut).is_ok());
        assert!(sheet.write_string(1, 0, long.as_str()).is_err());
    }

    #[test]
    fn the_workbook_has_the_seeds_three_sheets() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let mut series = TimeSeries::new(["t_s", "d_m", "speed_m_s"]);
        series.push_row(&[0.0, 0.3, 0.0]).expect("width 3");
        series.push_row(&[0.001, 0.299, 0.0001]).expect("width 3");
        let settings = json!({"controller": {"kd": 2.0}, "magnets": true, "terrain": "flat"});
        let mut summary = Summary::new();
        summary.insert("distance.rise_time_s".to_owned(), json!(1.25));
        summary.insert("distance.settled".to_owned(), json!(true));
        summary.insert("speed.settling_time_s".to_owned(), Value::Null);

        let csv = crate::report::write_timeseries_csv(dir.path(), &series).expect("csv");
        let path = write_workbook(dir.path(), &csv, &settings, &summary).expect("written");
        assert_eq!(path, dir.path().join("report.xlsx"));

        let mut workbook: Xlsx<_> = open_workbook(&path).expect("a valid xlsx");
        assert_eq!(workbook.sheet_names(), ["Raw data", "Settings", "Step characteristics"]);

        let raw = workbook.worksheet_range("Raw data").expect("sheet");
        assert_eq!(raw.get_value((0, 1)), Some(&Data::String("d_m".to_owned())));
        assert_eq!(raw.get_value((2, 1)), Some(&Data::Float(0.299)));
        assert_eq!(raw.get_value((2, 2)), Some(&Data::Float(0.0001)));
        assert_eq!(raw.height(), 3);

        let settings_sheet = workbook.worksheet_range("Settings").expect("sheet");
        assert_eq!(settings_sheet.get_value((1, 0)), Some(&Data::String("controller.kd".to_owned())));
        assert_eq!(settings_sheet.get_value((1, 1)), Some(&Data::Float(2.0)));
        assert_eq!(settings_sheet.get_value((2, 1)), Some(&Data::Bool(true)));
        assert_eq!(settings_sheet.get_value((3, 1)), Some(&Data::String("flat".to_owned())));

        let steps = workbook.worksheet_range("Step characteristics").expect("sheet");
        assert_eq!(steps.get_value((0, 0)), Some(&Data::String("metric".to_owned())));
        assert_eq!(steps.get_value((1, 0)), Some(&Data::String("distance.rise_time_s".to_owned())));
        assert_eq!(steps.get_value((1, 1)), Some(&Data::Float(1.25)));
        assert_eq!(steps.get_value((3, 0)), Some(&Data::String("speed.settling_time_s".to_owned())));
        assert!(matches!(steps.get_value((3, 1)), None | Some(Data::Empty)));
    }

    #[test]
    fn a_series_longer_than_a_sheet_is_thinned_and_the_settings_say_so() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let mut series = TimeSeries::new(["t_s", "d_m"]);
        for i in 0..10 {
            series.push_row(&[f64::from(i), f64::from(i) / 10.0]).expect("width 2");
        }
        let csv = crate::report::write_timeseries_csv(dir.path(), &series).expect("csv");
        let path = write_workbook_with_limit(dir.path(), &csv, &json!({}), &Summary::new(), 4).expect("written");
        let mut workbook: Xlsx<_> = open_workbook(&path).expect("a valid xlsx");
        let raw = workbook.worksheet_range("Raw data").expect("sheet");
        // 10 rows, 4 per sheet: every 3rd (0, 3, 6, 9), after the header.
        assert_eq!(raw.height(), 5);
        assert_eq!(raw.get_value((2, 0)), Some(&Data::Float(3.0)));
        let settings = workbook.worksheet_range("Settings").expect("sheet");
        let rows: Vec<String> = settings.rows().map(|r| format!("{}={}", r[0], r.get(1).map(ToString::to_string).unwrap_or_default())).collect();
        assert!(rows.contains(&"raw_data.rows=10".to_owned()) && rows.contains(&"raw_data.every_nth_row=3".to_owned()), "{rows:?}");
        assert!(rows.iter().any(|r| r.starts_with("raw_data.note=")), "{rows:?}");
        assert!(std::fs::read_dir(dir.path()).expect("dir").all(|e| !e.expect("entry").file_name().to_string_lossy().contains("tmp")), "no temporary file left");
    }
}
