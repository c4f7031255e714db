//! A child's output (stdout and stderr, through one pipe) into a log file of bounded size: the
//! first [`HEAD_BYTES`] as they come, the last [`TAIL_BYTES`] when the output ends, and one line
//! saying how much was cut between them. A controller stuck printing in a loop then costs a few
//! megabytes, not the disk (a 2-point sweep once left 202 MB), and the log still shows how it
//! started and how it ended.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{PipeReader, PipeWriter, Read, Write};
use std::path::Path;
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tracing::warn;

/// How much of the start of the output is kept (written as it comes).
pub const HEAD_BYTES: usize = 4 << 20;
/// How much of the end of the output is kept (written when it ends).
pub const TAIL_BYTES: usize = 4 << 20;

/// The thread copying a child's output into its log, and what it holds back for the end.
pub struct CappedLog {
    thread: JoinHandle<()>,
    state: Arc<Mutex<LogState>>,
}

/// The log file and the output's last bytes, shared by the copying thread and
/// [`CappedLog::finish`] (which writes the tail itself when the output does not end in time).
struct LogState {
    file: File,
    /// Room left for the head.
    head_left: usize,
    tail: VecDeque<u8>,
    tail_limit: usize,
    head_limit: usize,
    /// Bytes dropped between head and tail.
    cut: u64,
    /// The tail has been written: later output is read and dropped.
    closed: bool,
    /// A write failed: output is read and dropped (the child must not get SIGPIPE for it).
    failed: bool,
}

impl LogState {
    fn take(&mut self, bytes: &[u8]) {
        if self.closed || self.failed {
            return;
        }
        let (to_head, rest) = bytes.split_at(self.head_left.min(bytes.len()));
        if let Err(error) = self.file.write_all(to_head) {
            warn!(%error, "the controller's output could not be written; the rest is dropped");
            self.failed = true;
            return;
        }
        self.head_left -= to_head.len();
        self.tail.extend(rest);
        if self.tail.len() > self.tail_limit {
            let excess = self.tail.len() - self.tail_limit;
            self.tail.drain(..excess);
            self.cut += excess as u64;
        }
    }

    /// The line saying how much was cut (if anything was), then the tail.
    fn close(&mut self) -> std::io::Result<()> {
        if self.closed || self.failed {
            return Ok(());
        }
        self.closed = true;
        if self.cut > 0 {
            writeln!(self.file, "\n[climbsim: {} bytes of the controller's output were cut here; the log keeps its first {} and its last {} bytes]", self.cut, self.head_limit, self.tail_limit)?;
        }
        let (a, b) = self.tail.as_slices();
        self.file.write_all(a)?;
        self.file.write_all(b)?;
        self.file.flush()
    }
}

impl CappedLog {
    /// Create (truncate) the log at `path`; the pipe's write end for the child's stdout and
    /// stderr.
    pub fn start(path: &Path) -> std::io::Result<(Self, PipeWriter)> {
        Self::start_with(path, HEAD_BYTES, TAIL_BYTES)
    }

    fn start_with(path: &Path, head: usize, tail: usize) -> std::io::Result<(Self, PipeWriter)> {
        let file = File::create(path)?;
        let (reader, writer) = std::io::pipe()?;
        let state = Arc::new(Mutex::new(LogState { file, head_left: head, tail: VecDeque::new(), tail_limit: tail, head_limit: head, cut: 0, closed: false, failed: false }));
        let copying = Arc::clone(&state);
        let shown = path.display().to_string();
        let thread = std::thread::Builder::new().name("controller-log".into()).spawn(move || {
            if let Err(error) = copy_capped(reader, &copying) {
                warn!(log = shown, %error, "the controller's output could not be written");
            }
        })?;
        Ok((Self { thread, state }, writer))
    }

    /// Wait up to `limit` for the output to end (every process holding the pipe has exited) and
    /// the log to be complete; false if it did not end in time. The log is complete either way:
    /// its tail is written now, and what comes later is dropped.
    pub fn finish(self, limit: Duration) -> bool {
        let deadline = Instant::now() + limit;
        while !self.thread.is_finished() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        if self.thread.is_finished() {
            return self.thread.join().is_ok();
        }
        let mut state = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        if let Err(error) = state.close() {
            warn!(%error, "the controller's log could not be completed");
        }
        false
    }
}

/// Copy `reader` into the log until it ends (see [`LogState::take`]), then close it.
fn copy_capped(mut reader: PipeReader, state: &Mutex<LogState>) -> std::io::Result<()> {
    let mut buffer = vec![0u8; 64 * 1024];
    loop {
        let n = match reader.read(&mut buffer) {
            Ok(0) => break,
            Ok(n) => n,
            Err(error) if error.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(error) => return Err(error),
        };
        state.lock().unwrap_or_else(PoisonError::into_inner).take(&buffer[..n]);
    }
    state.lock().unwrap_or_else(PoisonError::into_inner).close()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn capped(output: &[u8], head: usize, tail: usize) -> Vec<u8> {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("controller.log");
        let (log, mut writer) = CappedLog::start_with(&path, head, tail).expect("start");
        // Written in pieces, as a program prints.
        for piece in output.chunks(7) {
            writer.write_all(piece).expect("write");
        }
        drop(writer);
        assert!(log.finish(Duration::from_secs(5)), "the copy ends when the pipe does");
        std::fs::read(&path).expect("log")
    }

    #[test]
    fn a_log_whose_output_does_not_end_is_completed_at_the_limit() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("controller.log");
        let (log, mut writer) = CappedLog::start_with(&path, 8, 8).expect("start");
        writer.write_all(b"0123456789abcdefghij-the-end").expect("write");
        // The pipe stays open (an escaped child holds it): the tail is written all the same.
        std::thread::sleep(Duration::from_millis(100));
        assert!(!log.finish(Duration::from_millis(50)));
        let text = String::from_utf8(std::fs::read(&path).expect("log")).expect("UTF-8");
        assert!(text.starts_with("01234567") && text.ends_with("-the-end") && text.contains("cut here"), "{text}");
        drop(writer);
    }

    #[test]
    fn output_within_the_cap_is_kept_whole() {
        let output = b"line 1\nline 2\nline 3\n";
        assert_eq!(capped(output, 16, 16), output);
        assert_eq!(capped(output, 100, 100), output);
    }

    #[test]
    fn a_long_output_keeps_its_head_and_its_tail() {
        let output: Vec<u8> = (0..1000).flat_map(|i| format!("line {i}\n").into_bytes()).collect();
        let log = capped(&output, 20, 30);
        let text = String::from_utf8(log).expect("UTF-8");
        let cut = output.len() - 50;
        assert!(text.starts_with("line 0\nline 1\nline 2\n"), "{text}");
        assert!(text.contains(&format!("[climbsim: {cut} bytes of the controller's output were cut here")), "{text}");
        assert!(text.ends_with("line 997\nline 998\nline 999\n"), "{text}");
        assert!(text.len() < 50 + 200, "{} bytes", text.len());
    }
}
