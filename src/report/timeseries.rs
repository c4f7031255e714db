//! The run's time series and its CSV file.

use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use super::atomic::{commit, temporary_path, write_atomically};
use super::{ReportError, io_error};

/// File name of the time series in the output directory.
pub const TIMESERIES_CSV: &str = "timeseries.csv";

/// Named columns of numbers, one row per sample (climbsim uses columns such as `t_s`, `d_m`,
/// `speed_m_s`, `wheel_rate_fl_rad_s`). Every row has one value per column.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TimeSeries {
    columns: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl TimeSeries {
    /// An empty series with these column names.
    pub fn new<S: Into<String>>(columns: impl IntoIterator<Item = S>) -> Self {
        Self { columns: columns.into_iter().map(Into::into).collect(), rows: Vec::new() }
    }

    /// Appends a sample; it must have one value per column.
    pub fn push_row(&mut self, row: &[f64]) -> Result<(), ReportError> {
        if row.len() != self.columns.len() {
            return Err(ReportError::RowWidth { expected: self.columns.len(), got: row.len() });
        }
        self.rows.push(row.to_vec());
        Ok(())
    }

    pub fn columns(&self) -> &[String] {
        &self.columns
    }

    pub fn rows(&self) -> &[Vec<f64>] {
        &self.rows
    }

    /// The values of the column called `name`, or `None` if there is no such column.
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let index = self.columns.iter().position(|column| column == name)?;
        Some(self.rows.iter().map(|row| row[index]).collect())
    }

    /// Number of rows (samples).
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Writes the series as CSV: a header line of column names, then one line per row. Numbers
    /// use Rust's shortest representation that parses back to the same `f64`; non-finite values
    /// are written `NaN`, `inf` and `-inf`, which pandas and numpy read.
    pub fn write_csv(&self, out: &mut impl Write) -> io::Result<()> {
        write_csv_header(out, &self.columns)?;
        for row in &self.rows {
            write_csv_row(out, row)?;
        }
        Ok(())
    }
}

fn write_csv_header(out: &mut impl Write, columns: &[String]) -> io::Result<()> {
    let header: Vec<String> = columns.iter().map(|name| csv_field(name)).collect();
    writeln!(out, "{}", header.join(","))
}

fn write_csv_row(out: &mut impl Write, row: &[f64]) -> io::Result<()> {
    for (index, value) in row.iter().enumerate() {
        if index > 0 {
            out.write_all(b",")?;
        }
        write!(out, "{value}")?;
    }
    out.write_all(b"\n")
}

/// `timeseries.csv` written row by row while a run goes on, so that a long run does not hold
/// its series in memory: the rows go into `timeseries.csv.tmp` in the output folder, which
/// [`TimeSeriesWriter::finish`] flushes, fsyncs and renames over `timeseries.csv` (atomically,
/// as every output). Dropped unfinished (a run that failed), it removes the temporary file.
pub struct TimeSeriesWriter {
    path: PathBuf,
    temporary: PathBuf,
    writer: Option<BufWriter<File>>,
    columns: usize,
    rows: u64,
}

impl TimeSeriesWriter {
    /// Start `out_dir/timeseries.csv.tmp` with its header line.
    pub fn create<S: Into<String>>(out_dir: &Path, columns: impl IntoIterator<Item = S>) -> Result<Self, ReportError> {
        let path = out_dir.join(TIMESERIES_CSV);
        let temporary = temporary_path(&path);
        let columns: Vec<String> = columns.into_iter().map(Into::into).collect();
        let mut writer = BufWriter::new(File::create(&temporary).map_err(io_error(&temporary))?);
        let mut stream = Self { path, temporary, writer: None, columns: columns.len(), rows: 0 };
        let header = write_csv_header(&mut writer, &columns);
        stream.writer = Some(writer);
        header.map_err(io_error(&stream.temporary))?;
        Ok(stream)
    }

    /// Append a sample; it must have one value per column.
    pub fn push_row(&mut self, row: &[f64]) -> Result<(), ReportError> {
        if row.len() != self.columns {
            return Err(ReportError::RowWidth { expected: self.columns, got: row.len() });
        }
        let Some(writer) = self.writer.as_mut() else { return Err(io_error(&self.temporary)(io::Error::other("the time series was already finished"))) };
        write_csv_row(writer, row).map_err(io_error(&self.temporary))?;
        self.rows += 1;
        Ok(())
    }

    /// Rows written so far.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// Flush and fsync the rows, rename the file to `timeseries.csv`; its path.
    pub fn finish(mut self) -> Result<PathBuf, ReportError> {
        let Some(writer) = self.writer.take() else { return Err(io_error(&self.temporary)(io::Error::other("the time series was already finished"))) };
        let synced = writer.into_inner().map_err(io::IntoInnerError::into_error).and_then(|file| file.sync_all());
        if let Err(source) = synced {
            let _ = std::fs::remove_file(&self.temporary);
            return Err(ReportError::Io { path: self.temporary.clone(), source });
        }
        commit(&self.temporary, &self.path)?;
        Ok(self.path.clone())
    }
}

impl Drop for TimeSeriesWriter {
    fn drop(&mut self) {
        // Unfinished: the run failed before its outputs were written, and leaves no half file.
        if self.writer.take().is_some() {
            let _ = std::fs::remove_file(&self.temporary);
        }
    }
}

/// Writes `series` to `out_dir/timeseries.csv` atomically and returns the file's path.
pub fn write_timeseries_csv(out_dir: &Path, series: &TimeSeries) -> Result<PathBuf, ReportError> {
    let path = out_dir.join(TIMESERIES_CSV);
    write_atomically(&path, |writer| series.write_csv(writer))?;
    Ok(path)
}

/// Reads a `timeseries.csv` back (as [`TimeSeries::write_csv`] writes it: unquoted numeric
/// cells), e.g. to overlay the runs of a sweep. Column names must not hold commas.
pub fn read_timeseries_csv(path: &Path) -> Result<TimeSeries, ReportError> {
    let rows = CsvRows::open(path)?;
    let mut series = TimeSeries::new(rows.columns().iter().cloned());
    for row in rows {
        series.push_row(&row?)?;
    }
    Ok(series)
}

/// The rows of a `timeseries.csv`, read one line at a time (the workbook copies a series of
/// any length this way). Column names must not hold commas.
pub struct CsvRows {
    path: PathBuf,
    lines: io::Lines<BufReader<File>>,
    columns: Vec<String>,
    /// Line number of the next line (the header is line 1).
    line: usize,
}

impl CsvRows {
    pub fn open(path: &Path) -> Result<Self, ReportError> {
        let file = File::open(path).map_err(io_error(path))?;
        let mut lines = BufReader::new(file).lines();
        let header = lines.next().transpose().map_err(io_error(path))?.unwrap_or_default();
        let columns = header.split(',').map(|c| c.trim_matches('"').to_owned()).collect();
        Ok(Self { path: path.to_owned(), lines, columns, line: 2 })
    }

    pub fn columns(&self) -> &[String] {
        &self.columns
    }
}

impl Iterator for CsvRows {
    type Item = Result<Vec<f64>, ReportError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let line = match self.lines.next()? {
                Ok(line) => line,
                Err(source) => return Some(Err(ReportError::Io { path: self.path.clone(), source })),
            };
            let number = self.line;
            self.line += 1;
            if line.is_empty() {
                continue;
            }
            let row: Result<Vec<f64>, _> = line.split(',').map(str::parse::<f64>).collect();
            return Some(row.map_err(|e| ReportError::Io { path: self.path.clone(), source: io::Error::new(io::ErrorKind::InvalidData, format!("line {number}: {e}")) }));
        }
    }
}

/// A CSV field, quoted (RFC 4180) only when it holds a separator, quote or line break.
fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) { format!("\"{}\"", text.replace('"', "\"\"")) } else { text.to_owned() }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn csv_of(series: &TimeSeries) -> String {
        let mut out = Vec::new();
        series.write_csv(&mut out).expect("writes to memory");
        String::from_utf8(out).expect("UTF-8")
    }

    #[test]
    fn writes_a_header_and_rows_that_round_trip() {
        let mut series = TimeSeries::new(["t_s", "d_m"]);
        let awkward = [0.1 + 0.2, 1e-300, -123456.789e10, 5.0];
        series.push_row(&[0.0, awkward[0]]).expect("width 2");
        series.push_row(&[awkward[1], awkward[2]]).expect("width 2");
        series.push_row(&[awkward[3], f64::NAN]).expect("width 2");
        let csv = csv_of(&series);
        let mut lines = csv.lines();
        assert_eq!(lines.next(), Some("t_s,d_m"));
        let parsed: Vec<f64> = lines.flat_map(|line| line.split(',').map(|field| field.parse::<f64>().expect("a number")).collect::<Vec<_>>()).collect();
        assert_eq!(&parsed[..5], &[0.0, awkward[0], awkward[1], awkward[2], awkward[3]]);
        assert!(parsed[5].is_nan());
        assert!(csv.ends_with('\n'));
    }

    #[test]
    fn a_row_of_the_wrong_width_is_refused() {
        let mut series = TimeSeries::new(["t_s", "d_m"]);
        assert!(matches!(series.push_row(&[1.0]), Err(ReportError::RowWidth { expected: 2, got: 1 })));
        assert!(series.is_empty());
    }

    #[test]
    fn column_names_with_separators_are_quoted() {
        let series = TimeSeries::new(["t_s", "a,b", "say \"hi\""]);
        assert_eq!(csv_of(&series), "t_s,\"a,b\",\"say \"\"hi\"\"\"\n");
    }

    #[test]
    fn a_column_can_be_taken_out_by_name() {
        let mut series = TimeSeries::new(["t_s", "d_m"]);
        series.push_row(&[0.0, 0.5]).expect("width 2");
        series.push_row(&[0.001, 0.25]).expect("width 2");
        assert_eq!(series.column("d_m"), Some(vec![0.5, 0.25]));
        assert_eq!(series.column("psi_rad"), None);
        assert_eq!(series.len(), 2);
    }

    #[test]
    fn the_file_is_written_into_the_output_directory() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let mut series = TimeSeries::new(["t_s"]);
        series.push_row(&[0.5]).expect("width 1");
        let path = write_timeseries_csv(dir.path(), &series).expect("written");
        assert_eq!(path, dir.path().join("timeseries.csv"));
        assert_eq!(std::fs::read_to_string(&path).expect("readable"), "t_s\n0.5\n");
    }
}
