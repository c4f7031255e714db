//! A child's output (stdout and stderr, through one pipe) into a log file of bounded size: the
//! first [`HEAD_BYTES`] as they come, the last [`TAIL_BYTES`] when the output ends, and one line
//! saying how much was cut between them. A controller stuck printing in a loop then costs a few
//! megabytes, not the disk (a 2-point sweep once left 202 MB), and the log still shows how it
//! started and how it ended.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{PipeReader, PipeWriter, Read, Write};
use std::path::Path;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tracing::warn;

/// How much of the start of the output is kept (written as it comes).
pub const HEAD_BYTES: usize = 4 << 20;
/// How much of the end of the output is kept (written when it ends).
pub const TAIL_BYTES: usize = 4 << 20;

/// The thread copying a child's output into its log.
pub struct CappedLog {
    thread: JoinHandle<()>,
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
        let shown = path.display().to_string();
        let thread = std::thread::Builder::new().name("controller-log".into()).spawn(move || {
            if let Err(error) = copy_capped(reader, file, head, tail) {
                warn!(log = shown, %error, "the controller's output could not be written");
            }
        })?;
        Ok((Self { thread }, writer))
    }

    /// Wait up to `limit` for the output to end (every process holding the pipe has exited) and
    /// the log to be complete; false if it did not in time (the copy goes on by itself).
    pub fn finish(self, limit: Duration) -> bool {
        let deadline = Instant::now() + limit;
        while !self.thread.is_finished() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        self.thread.is_finished() && self.thread.join().is_ok()
    }
}

/// Copy `reader` into `file` until it ends: the first `head` bytes at once, the last `tail`
/// bytes at the end, a line saying how many were cut between them if any were.
fn copy_capped(mut reader: PipeReader, mut file: File, head: usize, tail: usize) -> std::io::Result<()> {
    let mut buffer = vec![0u8; 64 * 1024];
    let mut head_left = head;
    let mut last: VecDeque<u8> = VecDeque::new();
    let mut cut = 0u64;
    loop {
        let n = match reader.read(&mut buffer) {
            Ok(0) => break,
            Ok(n) => n,
            Err(error) if error.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(error) => return Err(error),
        };
        let (to_head, rest) = buffer[..n].split_at(head_left.min(n));
        file.write_all(to_head)?;
        head_left -= to_head.len();
        last.extend(rest);
        if last.len() > tail {
            let excess = last.len() - tail;
            last.drain(..excess);
            cut += excess as u64;
        }
    }
    if cut > 0 {
        writeln!(file, "\n[climbsim: {cut} bytes of the controller's output were cut here; the log keeps its first {head} and its last {tail} bytes]")?;
    }
    let (a, b) = last.as_slices();
    file.write_all(a)?;
    file.write_all(b)?;
    file.flush()
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
