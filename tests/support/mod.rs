//! Test support, not part of the library: [`Emulator`], a guard around one `climbsim serve`
//! process, shared by the integration tests (`mod support;`) and the benches
//! (`#[path = "../tests/support/mod.rs"] mod support;`).
//!
//! It is `tests/support/mod.rs` rather than `tests/support.rs` so that cargo does not build it as
//! a test target of its own.

// Every test and bench target compiles this module, and each uses only part of it.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// How long `climbsim serve` has to print `port: <path>` (and `tcp: <addr>`).
const ANNOUNCE_WITHIN: Duration = Duration::from_secs(20);
/// How long it has to exit after SIGTERM in [`Emulator::stop`] / [`Emulator::finish`].
const STOP_WITHIN: Duration = Duration::from_secs(10);
/// The same when the guard is dropped without being stopped (a failing test or bench).
const STOP_ON_DROP_WITHIN: Duration = Duration::from_secs(5);

/// How to start an [`Emulator`]. The default is plain `climbsim serve <args>` with stderr
/// inherited.
#[derive(Clone, Copy, Debug, Default)]
pub struct Options {
    temp_link: bool,
    stderr_log: bool,
    sensors: bool,
    binary: Option<&'static Path>,
}

impl Options {
    /// Run this climbsim binary instead of the one just built (a bench's A/B against a baseline).
    pub fn binary(mut self, binary: &'static Path) -> Self {
        self.binary = Some(binary);
        self
    }

    /// Pass `--link <dir>/ttyDXL`, `<dir>` a fresh temporary directory removed on drop.
    pub fn temp_link(mut self) -> Self {
        self.temp_link = true;
        self
    }

    /// Also wait for the sensor server's `sensors: <url>` (serve with a scenario);
    /// [`Emulator::sensors`] gives it.
    pub fn sensors(mut self) -> Self {
        self.sensors = true;
        self
    }

    /// Write stderr to `stderr.log` in a fresh temporary directory (removed on drop) instead of
    /// inheriting it; [`Emulator::stderr`] reads it back and failure messages quote it.
    pub fn stderr_log(mut self) -> Self {
        self.stderr_log = true;
        self
    }

    /// `climbsim serve [--link <dir>/ttyDXL] <args...>`; returns once it has announced its port,
    /// and its TCP address too if `args` has `--tcp`. With a link (from [`Options::temp_link`] or a
    /// `--link` in `args`), the announced port must be the link and resolve to a device.
    pub fn start(self, args: &[&str]) -> Emulator {
        let dir = (self.temp_link || self.stderr_log).then(temp_dir);
        let given_link = arg_value(args, "--link").map(PathBuf::from);
        let link = match (&dir, self.temp_link) {
            (Some(dir), true) => {
                assert!(given_link.is_none(), "Options::temp_link and a --link in the arguments");
                Some(dir.join("ttyDXL"))
            }
            _ => given_link,
        };
        let stderr = match (&dir, self.stderr_log) {
            (Some(dir), true) => Stdio::from(std::fs::File::create(dir.join("stderr.log")).expect("create stderr log")),
            _ => Stdio::inherit(),
        };

        let mut command = Command::new(self.binary.unwrap_or(Path::new(env!("CARGO_BIN_EXE_climbsim"))));
        command.arg("serve");
        if self.temp_link {
            command.arg("--link").arg(link.as_ref().expect("temp link"));
        }
        let mut child = command.args(args).stdin(Stdio::null()).stdout(Stdio::piped()).stderr(stderr).spawn().expect("spawn climbsim");

        // Keep reading stdout for the whole run, so the emulator never blocks on a full pipe.
        let stdout = child.stdout.take().expect("piped stdout");
        let (tx, rx) = mpsc::channel::<String>();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let mut emulator = Emulator { child: Some(child), dir, stderr_log: self.stderr_log, port: PathBuf::new(), link, tcp: None, sensors: None };

        let want_tcp = arg_value(args, "--tcp").is_some();
        let deadline = Instant::now() + ANNOUNCE_WITHIN;
        let first = emulator.announced(&rx, deadline, want_tcp);
        let port = first.strip_prefix("port: ").unwrap_or_else(|| panic!("climbsim's first stdout line is not `port: <path>`: {first:?}"));
        emulator.port = PathBuf::from(port.trim());
        while want_tcp && emulator.tcp.is_none() {
            let line = emulator.announced(&rx, deadline, want_tcp);
            if let Some(addr) = line.strip_prefix("tcp: ") {
                emulator.tcp = Some(addr.trim().parse().unwrap_or_else(|e| panic!("bad tcp line {line:?}: {e}")));
            }
        }
        while self.sensors && emulator.sensors.is_none() {
            let line = emulator.announced(&rx, deadline, want_tcp);
            emulator.sensors = line.strip_prefix("sensors: ").map(|url| url.trim().to_owned());
        }
        if let Some(link) = &emulator.link {
            assert_eq!(&emulator.port, link, "with --link, `port:` must print the link path");
            assert!(std::fs::metadata(link).is_ok(), "link {} does not resolve to a device", link.display());
        }
        emulator
    }
}

/// One `climbsim serve` process. Stop it with [`Emulator::stop`], [`Emulator::finish`] or
/// [`Emulator::terminate`]; dropping it without (a failing test or bench) still ends the process:
/// SIGTERM, then SIGKILL if it does not exit.
pub struct Emulator {
    child: Option<Child>,
    dir: Option<PathBuf>,
    stderr_log: bool,
    port: PathBuf,
    link: Option<PathBuf>,
    tcp: Option<SocketAddr>,
    sensors: Option<String>,
}

impl Emulator {
    /// `climbsim serve <args...>` with stderr inherited: [`Options::start`] with the defaults.
    pub fn start(args: &[&str]) -> Self {
        Options::default().start(args)
    }

    /// The pty path it announced (`port: <path>`).
    pub fn port(&self) -> &Path {
        &self.port
    }

    /// Its `--link` path.
    pub fn link(&self) -> &Path {
        self.link.as_deref().expect("emulator started without --link")
    }

    /// The sensor server's URL it announced, with [`Options::sensors`].
    pub fn sensors(&self) -> &str {
        self.sensors.as_deref().expect("emulator started without Options::sensors")
    }

    /// The TCP address it announced (`tcp: <addr>`).
    pub fn tcp(&self) -> SocketAddr {
        self.tcp.expect("emulator started without --tcp")
    }

    /// What it wrote to stderr so far, with [`Options::stderr_log`].
    pub fn stderr(&self) -> String {
        match &self.dir {
            Some(dir) if self.stderr_log => std::fs::read_to_string(dir.join("stderr.log")).unwrap_or_default(),
            _ => "(not captured)".into(),
        }
    }

    /// True unless it had a link that is still there.
    pub fn link_removed(&self) -> bool {
        self.link.as_ref().is_none_or(|link| std::fs::symlink_metadata(link).is_err())
    }

    /// SIGTERM, then wait up to 10 s for it to exit; its exit status, or `None` if it did not exit
    /// in time (it is then killed) or had already been stopped.
    pub fn terminate(&mut self) -> Option<ExitStatus> {
        self.terminate_within(STOP_WITHIN)
    }

    /// SIGTERM; true if it exited 0 and removed its link.
    pub fn stop(&mut self) -> bool {
        self.terminate().is_some_and(|status| status.success()) && self.link_removed()
    }

    /// SIGTERM; asserts that it exits 0 and removes its link, quoting its stderr if not.
    pub fn finish(mut self) {
        assert!(self.child.is_some(), "climbsim was already stopped");
        let Some(status) = self.terminate() else {
            panic!("climbsim did not exit within 10 s of SIGTERM\nstderr:\n{}", self.stderr());
        };
        assert!(status.success(), "climbsim exited with {status} after SIGTERM\nstderr:\n{}", self.stderr());
        assert!(self.link_removed(), "climbsim left its link {} behind", self.link().display());
    }

    fn terminate_within(&mut self, limit: Duration) -> Option<ExitStatus> {
        let mut child = self.child.take()?;
        // SAFETY: kill(2) with a pid we spawned and have not reaped yet.
        unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
        let deadline = Instant::now() + limit;
        loop {
            if let Ok(Some(status)) = child.try_wait() {
                return Some(status);
            }
            if Instant::now() >= deadline {
                let _ = child.kill();
                let _ = child.wait();
                return None;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// The next stdout line before `deadline`.
    fn announced(&mut self, lines: &mpsc::Receiver<String>, deadline: Instant, want_tcp: bool) -> String {
        let left = deadline.saturating_duration_since(Instant::now());
        lines.recv_timeout(left.max(Duration::from_millis(1))).unwrap_or_else(|_| {
            panic!(
                "climbsim did not announce its port{} within {} s (exit: {:?})\nstderr:\n{}",
                if want_tcp { " and tcp address" } else { "" },
                ANNOUNCE_WITHIN.as_secs(),
                self.child.as_mut().and_then(|c| c.try_wait().ok().flatten()),
                self.stderr()
            )
        })
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.terminate_within(STOP_ON_DROP_WITHIN);
        if let Some(dir) = &self.dir {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// A fresh, empty `climbsim-emu-<pid>-<n>` in the system's temporary directory.
fn temp_dir() -> PathBuf {
    static COUNTER: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!("climbsim-emu-{}-{}", std::process::id(), COUNTER.fetch_add(1, Ordering::Relaxed)));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create temp dir");
    dir
}

/// The value of `--name <value>` or `--name=<value>` in `args`.
fn arg_value<'a>(args: &[&'a str], name: &str) -> Option<&'a str> {
    args.iter().enumerate().find_map(|(i, arg)| match arg.strip_prefix(name)? {
        "" => args.get(i + 1).copied(),
        rest => rest.strip_prefix('='),
    })
}

/// Where benches write their JSON results (`target/bench-results`, or under `CARGO_TARGET_DIR`).
pub fn results_dir() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let target = match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) if !dir.is_empty() => manifest.join(dir),
        _ => manifest.join("target"),
    };
    let dir = target.join("bench-results");
    std::fs::create_dir_all(&dir).expect("create bench-results dir");
    dir
}

/// The Python with the official `dynamixel-sdk`: `$CLIMBSIM_PYTHON`, else `<repo>/.venv/bin/python`
/// (made by `./scripts/test.sh`, which installs `tests/sdk/requirements.txt`).
pub fn sdk_python() -> PathBuf {
    match std::env::var_os("CLIMBSIM_PYTHON") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv").join("bin").join("python"),
    }
}

/// Run pytest on `selection` with `python` from the repository, against this build's climbsim
/// (`CLIMBSIM_BIN`): first `imports` must load (else a failure with `hint`, never a skip); pytest's
/// output is printed and its failure fails the test.
pub fn pytest_with(python: &Path, imports: &str, hint: &str, selection: &[String]) {
    let probe = Command::new(python).args(["-c", &format!("import {imports}")]).output();
    match probe {
        Err(e) => panic!("cannot run {}: {e}; {hint}", python.display()),
        Ok(out) if !out.status.success() => panic!("{} cannot import {imports}: {}; {hint}", python.display(), String::from_utf8_lossy(&out.stderr).trim()),
        Ok(_) => {}
    }
    let out = Command::new(python)
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
        .args(selection)
        .current_dir(repo())
        .env("CLIMBSIM_BIN", env!("CARGO_BIN_EXE_climbsim"))
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .unwrap_or_else(|e| panic!("cannot run pytest with {}: {e}", python.display()));
    print!("{}", String::from_utf8_lossy(&out.stdout));
    eprint!("{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "pytest on {} failed ({}); its output is above", selection.join(" "), out.status);
}

/// An executable script `name` in `dir` holding `text` (with its `#!` line); its path.
pub fn executable_script(dir: &Path, name: &str, text: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let script = dir.join(name);
    std::fs::write(&script, text).expect("write script");
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).expect("chmod");
    script
}

/// A fresh, empty folder under the target directory for one test's outputs.
pub fn scratch_dir(name: &str) -> PathBuf {
    let dir = results_dir().join("scratch").join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create scratch dir");
    dir
}

/// The median of `values` (sorted in place).
pub fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

/// Open a serial port (an emulator's pty) as a controller would, raw at `baud`.
pub fn open_raw_port(path: &Path, baud: nix::sys::termios::BaudRate) -> std::fs::File {
    use std::os::unix::fs::OpenOptionsExt;
    let port = std::fs::OpenOptions::new().read(true).write(true).custom_flags(libc::O_NOCTTY).open(path).unwrap_or_else(|e| panic!("open {}: {e}", path.display()));
    configure_raw(&port, baud);
    port
}

/// Raw mode at `baud`, blocking reads that return as soon as one byte is there.
pub fn configure_raw(port: &std::fs::File, baud: nix::sys::termios::BaudRate) {
    use nix::sys::termios::{SetArg, SpecialCharacterIndices, cfmakeraw, cfsetspeed, tcgetattr, tcsetattr};
    let mut t = tcgetattr(port).expect("tcgetattr");
    cfmakeraw(&mut t);
    cfsetspeed(&mut t, baud).expect("cfsetspeed");
    t.control_chars[SpecialCharacterIndices::VMIN as usize] = 1;
    t.control_chars[SpecialCharacterIndices::VTIME as usize] = 0;
    tcsetattr(port, SetArg::TCSANOW, &t).expect("tcsetattr");
}

/// Write `request`, read until `expect` bytes have arrived in `buf`; the elapsed nanoseconds.
pub fn round_trip(mut port: &std::fs::File, request: &[u8], expect: usize, buf: &mut [u8]) -> u64 {
    use std::io::{Read, Write};
    let t0 = Instant::now();
    port.write_all(request).expect("write request");
    let mut got = 0;
    while got < expect {
        match port.read(&mut buf[got..expect]) {
            Ok(0) => panic!("port closed after {got} of {expect} bytes"),
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => panic!("read: {e}"),
        }
    }
    t0.elapsed().as_nanos() as u64
}

/// The repository root (where `climbsim` runs in these tests: scenarios' relative paths work).
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `climbsim ARGS` in the repository root, run to completion.
pub fn climbsim(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_climbsim")).args(args).current_dir(repo()).output().expect("run climbsim")
}

/// A finished command's stdout and stderr, for failure messages.
pub fn output_text(output: &std::process::Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr))
}

/// `climbsim run SCENARIO --set SET` for each of `sets`: every one is refused before the run
/// (exit 2) with its key named.
pub fn assert_each_set_refused(scenario: &Path, out: &Path, sets: &[&str]) {
    for set in sets {
        let output = climbsim(&["run", &scenario.display().to_string(), "--set", set, "--out", &out.display().to_string()]);
        assert_eq!(output.status.code(), Some(2), "{set}: {}", output_text(&output));
        let key = set.split('=').next().unwrap_or_default();
        assert!(output_text(&output).contains(key), "{set}: {}", output_text(&output));
    }
}

/// `climbsim run` on a copy of the shipped `scenario` (a path in the repository) changed by
/// `change` must refuse it (exit 2) and name each of `names`.
pub fn assert_changed_scenario_refused(scenario: &str, dir: &Path, change: impl FnOnce(&str) -> String, names: &[&str]) {
    let text = std::fs::read_to_string(repo().join(scenario)).expect("scenario");
    let changed = change(&text);
    assert_ne!(changed, text, "the change to {scenario} changed nothing");
    let path = dir.join("changed.toml");
    std::fs::write(&path, changed).expect("write the changed scenario");
    let output = climbsim(&["run", &path.display().to_string(), "--out", &dir.join("out").display().to_string()]);
    assert_eq!(output.status.code(), Some(2), "{}", output_text(&output));
    for name in names {
        assert!(output_text(&output).contains(name), "{name}: {}", output_text(&output));
    }
}

pub mod history;
/// The robot of `hil/robot.toml` in a rapier world, driven through the bus in lockstep, and the
/// measurements the physics tests and the solver-fidelity bench share.
pub mod physics;

pub mod vt;

/// A viewer on Foxglove's WebSocket protocol.
pub mod foxglove;
/// A Foxglove layout checked against a recording.
pub mod layout;
/// Two ptys joined like a null-modem cable (`climbsim tap` between a controller and `serve --device`).
pub mod null_modem;
/// A `climbsim tap` process.
pub mod tap;

/// `climbsim ARGS` with the official SDK's Python first on PATH, so that a scenario's external
/// controller (`command = ["python", ...]`) runs in the venv.
pub fn climbsim_with_sdk_python(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_climbsim")).args(args).env("PATH", path_with_sdk_python()).current_dir(repo()).output().expect("run climbsim")
}

/// `PATH` with the SDK's Python first: what a scenario's `#!/usr/bin/env python3` controller
/// runs on.
pub fn path_with_sdk_python() -> std::ffi::OsString {
    let python = sdk_python();
    let bin = python.parent().expect("python's folder").to_owned();
    std::env::join_paths(std::iter::once(bin).chain(std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default()))).expect("PATH")
}

/// GET `path` from the sensor server at `url` (`http://HOST:PORT`), the body as JSON.
pub fn get_json(url: &str, path: &str) -> serde_json::Value {
    let body = get_body(url, path);
    serde_json::from_str(&body).unwrap_or_else(|e| panic!("{e}: {body}"))
}

/// GET `path` from the sensor server at `url`, the body whatever the status.
pub fn get_body(url: &str, path: &str) -> String {
    use std::io::{Read, Write};
    let address = url.strip_prefix("http://").expect("http URL");
    let mut stream = std::net::TcpStream::connect(address).expect("connect");
    write!(stream, "GET {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n\r\n").expect("request");
    let mut response = String::new();
    stream.read_to_string(&mut response).expect("response");
    let (_, body) = response.split_once("\r\n\r\n").expect("headers and body");
    body.to_owned()
}

/// `CLIMBSIM_BASELINE`: another climbsim binary a bench times beside this build (an A/B).
pub fn baseline_binary() -> Option<&'static Path> {
    // Leaked once per bench run: the emulator options keep a `'static` path.
    std::env::var_os("CLIMBSIM_BASELINE").map(|path| &*Box::leak(PathBuf::from(path).into_boxed_path()))
}

/// `climbsim serve ARGS` of the `CLIMBSIM_BASELINE` build, if one is given.
pub fn start_baseline(args: &[&str]) -> Option<Emulator> {
    baseline_binary().map(|binary| Options::default().binary(binary).start(args))
}

/// A raw pseudo-terminal echo, the floor any pty-based emulator sits on: a thread does a blocking
/// read on the master and writes the same bytes back; the client end is the slave, raw.
pub struct PtyEcho {
    client: std::fs::File,
    thread: std::thread::JoinHandle<()>,
}

/// How long before its due time a timed echo stops sleeping and spins: climbsim's final spin
/// under the wire model (`FINAL_SPIN` in src/transport/mod.rs).
const TIMED_ECHO_SPIN: Duration = Duration::from_micros(200);

impl PtyEcho {
    pub fn start(baud: nix::sys::termios::BaudRate) -> Self {
        Self::delayed(baud, Duration::ZERO)
    }

    /// An echo that writes the bytes back `delay` after it read them, sleeping until
    /// [`TIMED_ECHO_SPIN`] before then and spinning the rest, as climbsim waits for a reply's due
    /// time under the wire model: the floor of a timed reply on this host, with the same long
    /// sleeps on both sides of the pty (a zero delay is the plain echo).
    pub fn delayed(baud: nix::sys::termios::BaudRate, delay: Duration) -> Self {
        use std::os::fd::AsRawFd;
        let pty = nix::pty::openpty(None, None).expect("openpty");
        // openpty(3) descriptors are inheritable; keep them out of emulator processes.
        for fd in [&pty.master, &pty.slave] {
            // SAFETY: fcntl on a descriptor we own.
            let rc = unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_SETFD, libc::FD_CLOEXEC) };
            assert_eq!(rc, 0, "fcntl(FD_CLOEXEC)");
        }
        let client = std::fs::File::from(pty.slave);
        configure_raw(&client, baud);
        let master = pty.master;
        let thread = std::thread::Builder::new().name("echo".into()).spawn(move || echo_loop(master, delay)).expect("spawn echo thread");
        Self { client, thread }
    }

    pub fn client(&self) -> &std::fs::File {
        &self.client
    }

    /// Close the client end: the echo thread reads EIO and ends.
    pub fn stop(self) {
        drop(self.client);
        self.thread.join().expect("echo thread");
    }
}

fn echo_loop(master: std::os::fd::OwnedFd, delay: Duration) {
    use std::os::fd::AsFd;
    let mut buf = [0u8; 256];
    loop {
        match nix::unistd::read(master.as_fd(), &mut buf) {
            Ok(0) | Err(nix::errno::Errno::EIO) => return,
            Ok(n) => {
                if !delay.is_zero() {
                    let due = Instant::now() + delay;
                    if let Some(sleep) = delay.checked_sub(TIMED_ECHO_SPIN) {
                        std::thread::sleep(sleep);
                    }
                    while Instant::now() < due {
                        std::hint::spin_loop();
                    }
                }
                let mut data = &buf[..n];
                while !data.is_empty() {
                    match nix::unistd::write(master.as_fd(), data) {
                        Ok(w) => data = &data[w..],
                        Err(nix::errno::Errno::EINTR) => {}
                        Err(_) => return,
                    }
                }
            }
            Err(nix::errno::Errno::EINTR) => {}
            Err(_) => return,
        }
    }
}
