//! `--record FILE`: the transcript of a session, for `climbsim replay` and `climbsim diff`.
//!
//! JSON lines. The first is a [`Header`] (format and version, climbsim's version, the scenario's
//! path, `--set` overrides and full text, the robot description's path and text, the firmware
//! profile's CRC-64, seed, baud, timing). Then, in the order they happened under the bus lock:
//!
//! - `{"k":"tick","t":NS}`: the pacer advanced the world to `t` and observed it (camera,
//!   events, capture). Recorded because in a wall-clock run the ticks fall where the scheduler
//!   put them (late ticks, deadlines reset after an overrun); replaying them as recorded, rather
//!   than on an ideal 1 kHz grid, is what makes the replay an exact re-enactment.
//! - `{"k":"rx","t":NS,"baud":B,"hex":"FFFFFD00…","end":NS,"replies":["FFFFFD00…"]}`: an
//!   instruction packet as the bus received it (`t` when its bytes had arrived, `baud` the line's
//!   baud where the transport has one), when its last byte was on the modelled wire (`end`, where
//!   the plant was advanced to) and what the servos answered.
//! - `{"k":"sensor","t":NS,"path":"/line","status":200,"body":{…}}`: a read of the sensor
//!   server; JSON bodies are kept whole, others (the camera PNG) as `bytes` and `crc64`.
//! - `{"k":"end","t":NS,"ticks":N,"overruns":M}`: the session ended cleanly.
//!
//! Times are integer nanoseconds since the bus was made, so they round-trip exactly. Lines are
//! written whole and flushed at least every [`FLUSH_EVERY`], so a killed run leaves a readable
//! prefix: the reader accepts a torn last line (no newline) and a missing `end`.

use std::fs::File;
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use thiserror::Error;
use tracing::warn;

use crate::bus::Transaction;
use crate::protocol::{Decoder, RawPacket};

/// The `format` of a transcript's header.
pub const FORMAT: &str = "climbsim-transcript";
/// The version this climbsim writes and reads.
pub const VERSION: u32 = 1;
/// The `format` of a real bus's transcript (`climbsim tap`, [`crate::real_bus::transcript`]):
/// named here, so that each kind's reader can say what the other one is.
pub const REAL_FORMAT: &str = "climbsim-real-transcript";
/// Longest time a written line may sit in memory before it reaches the file.
pub const FLUSH_EVERY: Duration = Duration::from_millis(20);

#[derive(Debug, Error)]
pub enum TranscriptError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: io::Error },
    #[error("{}:{line}: {message}", path.display())]
    Line { path: PathBuf, line: usize, message: String },
    #[error("{}: empty: no header line", path.display())]
    Empty { path: PathBuf },
    #[error("{}:1: not a {expected} file (format {found:?}, version {version}; this climbsim reads {expected:?} version {expected_version}){}", path.display(), format_hint(found, expected))]
    Format { path: PathBuf, found: String, version: u32, expected: String, expected_version: u32 },
}

/// What to do with a file of the other kind of transcript.
fn format_hint(found: &str, expected: &str) -> &'static str {
    match (found, expected) {
        (REAL_FORMAT, FORMAT) => ": it is a real bus's session, recorded by `climbsim tap`",
        (FORMAT, REAL_FORMAT) => ": it is a simulated session, recorded by `--record`; `climbsim replay` re-enacts it",
        _ => "",
    }
}

/// What a transcript needs to rebuild the session's world and bus.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub format: String,
    pub version: u32,
    /// The climbsim that recorded it (`CARGO_PKG_VERSION`).
    pub climbsim: String,
    /// `run` or `serve`.
    pub mode: String,
    pub scenario: ScenarioCopy,
    pub robot: RobotCopy,
    /// The scenario's `world.seed` (after overrides).
    pub seed: u64,
    pub bus: BusSettings,
}

/// How the bus was set up.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BusSettings {
    /// The servos' power-on baud, and the `--baud` override if one was given.
    pub baud: u32,
    pub baud_override: Option<u32>,
    /// `wire` or `off`.
    pub timing: String,
    /// The firmware tick (ns) the pacer ran at.
    pub tick_ns: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScenarioCopy {
    /// As given on the command line.
    pub path: PathBuf,
    /// `--set KEY=VALUE` overrides, as given.
    #[serde(default)]
    pub overrides: Vec<String>,
    /// The file's text when the session started.
    pub text: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobotCopy {
    pub path: PathBuf,
    pub text: String,
    pub profile_path: PathBuf,
    /// CRC-64/XZ of the firmware profile's text, in hex (the profile is large and rarely edited).
    pub profile_crc64: String,
}

impl Header {
    /// A header for this climbsim, with `format`, `version` and `climbsim` filled in.
    pub fn new(mode: &str, scenario: ScenarioCopy, robot: RobotCopy, seed: u64, bus: BusSettings) -> Self {
        Self { format: FORMAT.to_owned(), version: VERSION, climbsim: env!("CARGO_PKG_VERSION").to_owned(), mode: mode.to_owned(), scenario, robot, seed, bus }
    }
}

/// One line after the header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "k", rename_all = "snake_case")]
pub enum Record {
    Tick {
        t: u64,
    },
    Rx {
        t: u64,
        #[serde(default)]
        baud: Option<u32>,
        hex: String,
        /// When the instruction's last byte was on the wire (the plant was advanced to it).
        #[serde(default)]
        end: Option<u64>,
        /// The replies' bytes in hex (optional: a replay compares them when present).
        #[serde(default)]
        replies: Option<Vec<String>>,
    },
    Sensor {
        t: u64,
        path: String,
        status: u16,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        body: Option<Value>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        bytes: Option<usize>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        crc64: Option<String>,
    },
    End {
        t: u64,
        ticks: u64,
        overruns: u64,
    },
}

/// A duration in whole nanoseconds (saturating at ~584 years).
pub fn nanos(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

/// CRC-64/XZ of `bytes`, 16 hex digits: a change detector, not a security measure.
pub fn crc64_hex(bytes: &[u8]) -> String {
    const CRC64: crc::Crc<u64> = crc::Crc::<u64>::new(&crc::CRC_64_XZ);
    format!("{:016x}", CRC64.checksum(bytes))
}

/// Bytes as contiguous upper-case hex.
pub fn to_hex(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(bytes.len() * 2);
    for b in bytes {
        out.push_str(&format!("{b:02X}"));
    }
    out
}

/// Contiguous hex (either case, spaces allowed) back to bytes.
pub fn from_hex(text: &str) -> Result<Vec<u8>, String> {
    let digits: Vec<u8> = text.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
    if !digits.len().is_multiple_of(2) {
        return Err(format!("odd number of hex digits ({})", digits.len()));
    }
    digits
        .chunks(2)
        .map(|pair| {
            let text = std::str::from_utf8(pair).map_err(|e| e.to_string())?;
            u8::from_str_radix(text, 16).map_err(|_| format!("`{text}` is not a hex byte"))
        })
        .collect()
}

/// The one whole packet `hex` holds (a recorded instruction or reply).
pub fn packet_from_hex(hex: &str) -> Result<RawPacket, String> {
    packet_from_bytes(&from_hex(hex)?)
}

/// The one whole packet `bytes` are.
pub fn packet_from_bytes(bytes: &[u8]) -> Result<RawPacket, String> {
    let mut framed = Decoder::default().push(Duration::ZERO, bytes).into_iter();
    match (framed.next(), framed.next()) {
        (Some(Ok(packet)), None) if packet.bytes.len() == bytes.len() => Ok(packet),
        (Some(Err(error)), _) => Err(format!("the recorded packet does not frame: {error}")),
        _ => Err(format!("the recorded bytes are not exactly one packet ({} bytes)", bytes.len())),
    }
}

/// Writes a transcript as the session goes. Shared by the transports (packets), the pacer
/// (ticks) and the sensor server (reads); each line is appended whole, in the order the calls
/// were made.
pub struct Recorder {
    path: PathBuf,
    inner: Mutex<Inner>,
}

struct Inner {
    file: File,
    pending: Vec<u8>,
    last_flush: Instant,
    /// The first write error; recording stops there and [`Recorder::finish`] reports it.
    failed: Option<io::Error>,
    /// The `end` line is written: the session is over for the transcript, even if a transport
    /// still handles the last bytes the controller sent (after the world stopped).
    finished: bool,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder").field("path", &self.path).finish_non_exhaustive()
    }
}

impl Recorder {
    /// Create `path` and write the header (flushed at once: a transcript is never headless).
    pub fn create(path: &Path, header: &impl Serialize) -> Result<Self, TranscriptError> {
        let io_error = |source| TranscriptError::Io { path: path.to_owned(), source };
        let mut file = File::create(path).map_err(io_error)?;
        let mut line = serde_json::to_vec(header).map_err(|e| io_error(e.into()))?;
        line.push(b'\n');
        file.write_all(&line).map_err(io_error)?;
        Ok(Self { path: path.to_owned(), inner: Mutex::new(Inner { file, pending: Vec::with_capacity(64 * 1024), last_flush: Instant::now(), failed: None, finished: false }) })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The pacer advanced the world to `t` and observed it.
    pub fn tick(&self, t: Duration) {
        self.append(&Record::Tick { t: nanos(t) });
    }

    /// An instruction the bus handled, with the line's baud (if the transport has one).
    pub fn packet(&self, transaction: &Transaction, line_baud: Option<u32>) {
        self.append(&Record::Rx {
            t: nanos(transaction.received_at),
            baud: line_baud,
            hex: to_hex(&transaction.packet.bytes),
            end: Some(nanos(transaction.instruction_end)),
            replies: Some(transaction.replies.iter().map(|r| to_hex(&r.bytes)).collect()),
        });
    }

    /// A sensor-server read: JSON bodies whole, anything else as its length and CRC-64.
    pub fn sensor_read(&self, t: Duration, path: &str, status: u16, content_type: &str, body: &[u8]) {
        let json = (content_type == "application/json").then(|| serde_json::from_slice::<Value>(body).ok()).flatten();
        let record = match json {
            Some(body) => Record::Sensor { t: nanos(t), path: path.to_owned(), status, body: Some(body), bytes: None, crc64: None },
            None => Record::Sensor { t: nanos(t), path: path.to_owned(), status, body: None, bytes: Some(body.len()), crc64: Some(crc64_hex(body)) },
        };
        self.append(&record);
    }

    /// Write the `end` line and flush; the first write error of the session, if any.
    pub fn finish(&self, t: Duration, ticks: u64, overruns: u64) -> Result<(), TranscriptError> {
        self.finish_with(&Record::End { t: nanos(t), ticks, overruns })
    }

    /// Write `end` (the last line, whatever its kind) and flush; the first write error of the
    /// session, if any.
    pub fn finish_with(&self, end: &impl Serialize) -> Result<(), TranscriptError> {
        self.append(end);
        let mut inner = self.lock();
        inner.finished = true;
        inner.flush();
        match inner.failed.take() {
            Some(source) => Err(TranscriptError::Io { path: self.path.clone(), source }),
            None => Ok(()),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Append one line (any record kind that serialises to a JSON object).
    pub fn append(&self, record: &impl Serialize) {
        let mut inner = self.lock();
        if inner.failed.is_some() || inner.finished {
            return;
        }
        // ok: records always serialise (no maps with non-string keys, no foreign types).
        if serde_json::to_writer(&mut inner.pending, record).is_ok() {
            inner.pending.push(b'\n');
        }
        if inner.last_flush.elapsed() >= FLUSH_EVERY {
            inner.flush();
        }
    }
}

impl Inner {
    /// Hand the pending whole lines to the file in one write.
    fn flush(&mut self) {
        self.last_flush = Instant::now();
        if self.pending.is_empty() || self.failed.is_some() {
            return;
        }
        if let Err(error) = self.file.write_all(&self.pending) {
            warn!(%error, "transcript write failed; recording stopped");
            self.failed = Some(error);
        }
        self.pending.clear();
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.lock().flush();
    }
}

/// A transcript read back.
#[derive(Debug, Clone)]
pub struct Transcript {
    pub path: PathBuf,
    pub header: Header,
    /// Each record with its line number in the file (the header is line 1).
    pub records: Vec<(usize, Record)>,
    /// The last line was cut short (a killed run) and was left out.
    pub torn_tail: bool,
    /// The session ended cleanly (an `end` line).
    pub complete: bool,
}

impl Transcript {
    /// Read `path`. A bad line is an error naming its number, except a last line without its
    /// newline, which a killed run leaves behind: it is dropped and `torn_tail` set.
    pub fn read(path: &Path) -> Result<Self, TranscriptError> {
        let lines = read_json_lines(path, FORMAT, VERSION, |record: &Record| matches!(record, Record::End { .. }))?;
        Ok(Self { path: path.to_owned(), header: lines.header, records: lines.records, torn_tail: lines.torn_tail, complete: lines.complete })
    }
}

/// A file of JSON lines read back: a header, then records up to an end record.
#[derive(Debug, Clone)]
pub struct JsonLines<H, R> {
    pub header: H,
    /// Each record with its line number in the file (the header is line 1).
    pub records: Vec<(usize, R)>,
    /// The last line was cut short (a killed session) and was left out.
    pub torn_tail: bool,
    /// The last record is an end record (`is_end`).
    pub complete: bool,
}

/// Read a header of `format` and `version`, then records up to one that `is_end`. A bad line is
/// an error naming its number, except a last line without its newline, which a killed session
/// leaves behind: it is dropped and `torn_tail` set.
pub fn read_json_lines<H: DeserializeOwned, R: DeserializeOwned>(path: &Path, format: &str, version: u32, is_end: impl Fn(&R) -> bool) -> Result<JsonLines<H, R>, TranscriptError> {
    let io_error = |source| TranscriptError::Io { path: path.to_owned(), source };
    let file = File::open(path).map_err(io_error)?;
    let mut reader = BufReader::new(file);
    let line_error = |line: usize, message: String| TranscriptError::Line { path: path.to_owned(), line, message };
    let mut text = String::new();
    if reader.read_line(&mut text).map_err(io_error)? == 0 {
        return Err(TranscriptError::Empty { path: path.to_owned() });
    }
    let header_value: Value = serde_json::from_str(text.trim_end()).map_err(|e| line_error(1, format!("header is not JSON: {e}")))?;
    let found = header_value.get("format").and_then(Value::as_str).unwrap_or_default().to_owned();
    let found_version = header_value.get("version").and_then(Value::as_u64).and_then(|v| u32::try_from(v).ok()).unwrap_or(0);
    if found != format || found_version != version {
        return Err(TranscriptError::Format { path: path.to_owned(), found, version: found_version, expected: format.to_owned(), expected_version: version });
    }
    let header: H = serde_json::from_value(header_value).map_err(|e| line_error(1, format!("header: {e}")))?;
    let mut records = Vec::new();
    let (mut torn_tail, mut complete) = (false, false);
    let mut number = 1;
    loop {
        text.clear();
        if reader.read_line(&mut text).map_err(io_error)? == 0 {
            break;
        }
        number += 1;
        let whole = text.ends_with('\n');
        let line = text.trim_end();
        if line.is_empty() {
            continue;
        }
        if complete {
            return Err(line_error(number, "a record after the `end` line".to_owned()));
        }
        match serde_json::from_str::<R>(line) {
            Ok(record) => {
                complete = is_end(&record);
                records.push((number, record));
            }
            Err(_) if !whole => {
                warn!(path = %path.display(), line = number, "the last line is cut short (a killed session?); using what precedes it");
                torn_tail = true;
            }
            Err(error) => return Err(line_error(number, format!("not a {format} record: {error}"))),
        }
    }
    Ok(JsonLines { header, records, torn_tail, complete })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> Header {
        Header::new(
            "run",
            ScenarioCopy { path: "s.toml".into(), overrides: vec!["world.duration_s=2".into()], text: "[world]\nseed = 1\n".into() },
            RobotCopy { path: "r.toml".into(), text: "x = 1\n".into(), profile_path: "p.toml".into(), profile_crc64: crc64_hex(b"p") },
            1,
            BusSettings { baud: 57600, baud_override: None, timing: "wire".into(), tick_ns: 1_000_000 },
        )
    }

    #[test]
    fn records_round_trip_and_a_torn_tail_is_dropped() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("t.jsonl");
        let recorder = Recorder::create(&path, &header()).expect("created");
        recorder.tick(Duration::from_nanos(1_000_123));
        recorder.sensor_read(Duration::from_millis(2), "/line", 200, "application/json", br#"{"d":0.01}"#);
        recorder.sensor_read(Duration::from_millis(3), "/camera.png", 200, "image/png", b"\x89PNG");
        recorder.finish(Duration::from_millis(4), 1, 0).expect("finished");
        recorder.tick(Duration::from_millis(5)); // after the end: not recorded
        drop(recorder);
        let read = Transcript::read(&path).expect("reads");
        assert_eq!(read.header, header());
        assert!(read.complete && !read.torn_tail);
        assert_eq!(read.records[0], (2, Record::Tick { t: 1_000_123 }));
        assert!(matches!(&read.records[1].1, Record::Sensor { body: Some(body), .. } if body["d"] == 0.01));
        assert!(matches!(&read.records[2].1, Record::Sensor { bytes: Some(4), crc64: Some(_), body: None, .. }));

        // Cut inside the `end` line: the prefix reads, the tail is reported torn.
        let text = std::fs::read_to_string(&path).expect("readable");
        let cut = text.trim_end().len() - 5;
        std::fs::write(&path, &text[..cut]).expect("written");
        let read = Transcript::read(&path).expect("the prefix reads");
        assert!(read.torn_tail && !read.complete);
        assert_eq!(read.records.len(), 3);
    }

    #[test]
    fn a_corrupted_line_is_named() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("t.jsonl");
        let mut text = serde_json::to_string(&header()).expect("json");
        text.push_str("\n{\"k\":\"tick\",\"t\":5}\n{\"k\":\"tick\",\"t\":oops}\n{\"k\":\"tick\",\"t\":7}\n");
        std::fs::write(&path, text).expect("written");
        let error = Transcript::read(&path).expect_err("line 3 is bad").to_string();
        assert!(error.contains("t.jsonl:3:"), "{error}");
    }

    #[test]
    fn another_format_or_version_is_refused() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("t.jsonl");
        let mut value = serde_json::to_value(header()).expect("json");
        value["version"] = 99.into();
        std::fs::write(&path, format!("{value}\n")).expect("written");
        let error = Transcript::read(&path).expect_err("version 99").to_string();
        assert!(error.contains("version 99"), "{error}");
    }

    #[test]
    fn hex_round_trips() {
        assert_eq!(to_hex(&[0xFF, 0x0A]), "FF0A");
        assert_eq!(from_hex("ff 0a"), Ok(vec![0xFF, 0x0A]));
        assert!(from_hex("F").is_err() && from_hex("ZZ").is_err());
    }

    #[test]
    fn a_recorded_packet_must_be_one_whole_packet() {
        let ping = "FFFFFD0001030001194E";
        assert_eq!(packet_from_hex(ping).map(|p| p.id), Ok(1));
        assert!(packet_from_hex(&ping[..12]).is_err(), "a partial packet");
        assert!(packet_from_hex(&format!("{ping}{ping}")).is_err(), "two packets");
        assert!(packet_from_hex("FFFFFD0001030001194F").is_err(), "a bad CRC");
    }
}
