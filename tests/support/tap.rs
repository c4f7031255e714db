//! One `climbsim tap` process for the tests and the benches: started on a device, its port
//! announced, ended with SIGINT as a person's Ctrl-C would.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

pub struct TapProcess {
    child: Child,
    /// The port the controller opens (`--link`).
    pub port: PathBuf,
    stderr: PathBuf,
    /// What it printed after its port, read as it comes.
    stdout: std::sync::Arc<std::sync::Mutex<String>>,
}

impl TapProcess {
    /// `climbsim tap --device DEVICE --link DIR/ttyDXL --record DIR/real.jsonl EXTRA...`, once
    /// it has announced its port; its stderr goes to DIR/tap.stderr.
    pub fn start(device: &Path, dir: &Path, extra: &[&str]) -> Self {
        let stderr = dir.join("tap.stderr");
        let mut child = Command::new(env!("CARGO_BIN_EXE_climbsim"))
            .args(["tap", "--device"])
            .arg(device)
            .arg("--link")
            .arg(dir.join("ttyDXL"))
            .arg("--record")
            .arg(dir.join("real.jsonl"))
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&stderr).expect("stderr file"))
            .spawn()
            .expect("start climbsim tap");
        let mut stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let mut line = String::new();
        stdout.read_line(&mut line).expect("tap's first line");
        let port = line.trim().strip_prefix("port: ").unwrap_or_else(|| panic!("tap announced {line:?}; stderr: {}", std::fs::read_to_string(&stderr).unwrap_or_default())).into();
        let rest = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
        let sink = std::sync::Arc::clone(&rest);
        std::thread::spawn(move || {
            for line in stdout.lines().map_while(Result::ok) {
                let mut text = sink.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                text.push_str(&line);
                text.push('\n');
            }
        });
        Self { child, port, stderr, stdout: rest }
    }

    /// What it printed after its port line, so far.
    pub fn stdout(&self) -> String {
        self.stdout.lock().unwrap_or_else(std::sync::PoisonError::into_inner).clone()
    }

    /// The URL of its Foxglove server (`foxglove: ws://…`), once it has printed it (panics
    /// after `within`).
    pub fn foxglove_url(&self, within: Duration) -> String {
        let deadline = Instant::now() + within;
        loop {
            if let Some(url) = self.stdout().lines().find_map(|line| line.strip_prefix("foxglove: ")).and_then(|rest| rest.split_whitespace().next()) {
                return url.to_owned();
            }
            assert!(Instant::now() < deadline, "no `foxglove:` line within {within:?}: {}", self.stdout());
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    pub fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }

    /// SIGINT, as Ctrl-C.
    pub fn interrupt(&self) {
        nix::sys::signal::kill(nix::unistd::Pid::from_raw(self.child.id() as i32), nix::sys::signal::Signal::SIGINT).expect("SIGINT");
    }

    /// Its exit status once it has exited (panics after `within`).
    pub fn wait(&mut self, within: Duration) -> ExitStatus {
        let deadline = Instant::now() + within;
        loop {
            if let Some(status) = self.child.try_wait().expect("try_wait") {
                return status;
            }
            assert!(Instant::now() < deadline, "tap did not exit within {within:?}: {}", self.stderr());
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for TapProcess {
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
