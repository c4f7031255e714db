//! The user's own controller as a child process: finding the program (one clear line when it
//! cannot start), its environment (port, baud, sensors, parameters), its clocks scaled with
//! libfaketime for `--speed N`, watching it for an early exit, and stopping it with everything it
//! started. Its output goes to a capped log ([`super::capped_log`]).

use std::collections::BTreeMap;
use std::io::{Read as _, Seek as _};
use std::os::unix::process::CommandExt as _;
use std::path::{Path, PathBuf};
use std::process::{Child, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use super::capped_log::CappedLog;
use super::{During as _, Result, RunnerError};
use crate::proc_stat::{PGRP, STATE, cpu_ticks, stat_field};
use tracing::warn;

/// How long a controller that has said it ends may stay idle before it is no longer waited for
/// (see [`Controller::wait_for_ending`]).
const ENDING_IDLE: Duration = Duration::from_secs(1);
/// How long a controller that has said it ends is waited for at most, busy or not.
const ENDING_AT_MOST: Duration = Duration::from_secs(30);
/// How long a controller gets to stop after SIGTERM before it is killed.
const STOP_GRACE: Duration = Duration::from_secs(3);
/// How long after SIGTERM stopping looks each millisecond whether the controller has gone.
const STOP_LOOKS_CLOSELY: Duration = Duration::from_millis(100);
/// The controller's niceness (see [`Controller::start`]).
const CONTROLLER_NICE: libc::c_int = 10;
/// How long stopping waits for the controller's log to be complete.
const LOG_FINISH: Duration = Duration::from_secs(2);
/// How many scripts deep an interpreter chain is followed (the kernel's BINPRM_MAX_RECURSION).
const MAX_INTERPRETER_DEPTH: usize = 4;
/// Lines of the controller's log quoted in a failure message.
const LOG_TAIL_LINES: usize = 15;

/// Where Debian and most distributions put libfaketime; `CLIMBSIM_LIBFAKETIME` overrides.
const LIBFAKETIME_GLOBS: &[&str] =
    &["/usr/lib/*/faketime/libfaketimeMT.so.1", "/usr/lib/faketime/libfaketimeMT.so.1", "/usr/local/lib/faketime/libfaketimeMT.so.1", "/usr/lib64/faketime/libfaketimeMT.so.1"];

/// What the controller process is told.
pub struct Launch<'a> {
    /// Program and arguments, placeholders already substituted.
    pub command: &'a [String],
    pub env: Vec<(String, String)>,
    /// Simulated seconds per wall-clock second: above 1 the program runs under libfaketime.
    pub speed: f64,
    /// The program runs on virtual time (the shim's preload is in `env`).
    pub virtual_time: bool,
    pub log_path: &'a Path,
    /// Told the inode of the pipe the program's output will come through, before it starts.
    pub output_pipe: &'a dyn Fn(u64),
}

/// What a controller must be able to preload, for the refusal's words.
struct Preload {
    name: &'static str,
    remedy: &'static str,
}

const FAKETIME: Preload = Preload { name: "libfaketime", remedy: "run it at --speed 1" };
const SHIM: Preload = Preload { name: "climbsim's virtual-time shim", remedy: "run it with --clock wall" };

/// The variable every process a controller starts inherits, with a value of its run's own: how
/// climbsim finds them at the end, even those that left its process group (`setsid`).
const RUN_MARKER: &str = "CLIMBSIM_CONTROLLER_RUN";
/// Controllers started by this climbsim so far (a sweep starts many), for [`RUN_MARKER`]'s values.
static STARTED: AtomicU64 = AtomicU64::new(0);

/// A running controller: its process, leader of a process group of its own.
pub struct Controller {
    child: Child,
    pub description: String,
    log_path: PathBuf,
    /// The copy of its output into the log (stdout and stderr; capped), until it is stopped.
    log: Option<CappedLog>,
    /// `RUN_MARKER=value` as it stands in /proc/PID/environ.
    marker: Vec<u8>,
    /// Its process group and every marked process have been ended.
    ended: bool,
    /// When SIGTERM was sent (see [`Controller::ask_to_stop`]).
    asked_to_stop: Option<Instant>,
}

/// Resolve `./` and `../` arguments against the scenario's folder, so a scenario can name a
/// controller beside it whatever the working directory.
pub fn resolve_command(command: &[String], scenario: &Path) -> Vec<String> {
    let base = scenario.parent().unwrap_or(Path::new("."));
    command.iter().map(|arg| if arg.starts_with("./") || arg.starts_with("../") { base.join(arg).display().to_string() } else { arg.clone() }).collect()
}

/// The environment variables that carry a scenario's `[controller] params` to the program:
/// `CLIMBSIM_PARAM_<NAME>` (upper case).
pub fn param_env(params: &BTreeMap<String, String>) -> Vec<(String, String)> {
    params.iter().map(|(name, value)| (format!("CLIMBSIM_PARAM_{}", name.to_ascii_uppercase()), value.clone())).collect()
}

impl Controller {
    /// Start the program. A program that cannot be found or run, or cannot be sped up, is one
    /// clear error naming the command.
    pub fn start(launch: &Launch<'_>) -> Result<Self> {
        let description = launch.command.join(" ");
        let (program, args) = launch.command.split_first().ok_or_else(|| RunnerError::Invalid("the external controller's command is empty".to_owned()))?;
        let resolved = find_program(program).during(|| format!("cannot start the controller `{description}`"))?;
        let (log, writer) = CappedLog::start(launch.log_path).during(|| format!("cannot create {}", launch.log_path.display()))?;
        let output_pipe = nix::sys::stat::fstat(&writer).map_or(0, |stat| stat.st_ino);
        (launch.output_pipe)(output_pipe);
        let mut command = std::process::Command::new(&resolved);
        let marker = format!("{}-{}", std::process::id(), STARTED.fetch_add(1, Ordering::Relaxed));
        // Its own process group, so that stopping it stops what it started (background jobs,
        // a shell's children) and a terminal's Ctrl-C reaches climbsim alone, which then stops it.
        command.process_group(0).env(RUN_MARKER, &marker);
        command
            .args(args)
            .envs(launch.env.iter().map(|(k, v)| (k, v)))
            .stdin(Stdio::null())
            .stdout(writer.try_clone().during(|| format!("cannot share {}", launch.log_path.display()))?)
            .stderr(writer);
        if launch.virtual_time {
            refuse_unpreloadable(&resolved, &SHIM).during(|| format!("--clock virtual cannot follow `{description}`"))?;
        }
        if launch.speed != 1.0 {
            refuse_unpreloadable(&resolved, &FAKETIME).during(|| format!("--speed {} cannot scale the clocks of `{description}`", launch.speed))?;
            command.envs(faketime_env(launch.speed).during(|| format!("--speed {} for `{description}`", launch.speed))?);
        }
        // The emulated servos are the hardware: on a machine with few cores a busy controller
        // (the SDK polls the port in a tight loop) must not delay their replies or the world's
        // ticks by a scheduler time slice. A lower priority lets climbsim's threads preempt it
        // when they wake; the controller still gets every cycle they leave.
        // Under virtual time nothing is late, and the controller and climbsim take turns: a
        // lower priority would only let the machine's other load starve the run.
        if !launch.virtual_time {
            // SAFETY: setpriority is async-signal-safe and touches only the child being started.
            unsafe {
                command.pre_exec(|| {
                    libc::setpriority(libc::PRIO_PROCESS, 0, CONTROLLER_NICE);
                    Ok(())
                });
            }
        }
        let child = command.spawn().during(|| format!("cannot start the controller `{description}`"))?;
        Ok(Self { child, description, log_path: launch.log_path.to_owned(), log: Some(log), marker: format!("{RUN_MARKER}={marker}").into_bytes(), ended: false, asked_to_stop: None })
    }

    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// The exit status if the program has ended.
    pub fn try_wait(&mut self) -> Result<Option<ExitStatus>> {
        self.child.try_wait().during(|| format!("cannot watch the controller `{}`", self.description))
    }

    /// The exit of a controller known to be ending (its last handlers have run): waits for the
    /// kernel to finish it while it gets on with that (a thread runnable or in the disk, or its
    /// CPU time growing: a JVM's teardown took more than a second at the controller's
    /// niceness beside two busy loops, and the exit was then seen at a later simulated instant
    /// than in other runs), [`ENDING_AT_MOST`] at most; `None` if it is still there, idle, for
    /// [`ENDING_IDLE`] (something keeps it: a thread that does not end).
    pub fn wait_for_ending(&mut self) -> Result<Option<ExitStatus>> {
        let pid = self.child.id();
        wait_while_busy(pid, || self.try_wait())
    }

    /// Stop the controller and everything it started: SIGTERM to its process group and to every
    /// process that carries its run's marker (children that left the group with `setsid`), a
    /// grace period, then SIGKILL for whatever is left. The controller's exit status (if it had
    /// already ended by itself, that one: what it left running is ended all the same).
    pub fn stop(&mut self) -> Result<ExitStatus> {
        let pgid = self.process_group()?;
        let mut status = self.try_wait()?;
        if !self.ended {
            let asked = self.ask_to_stop()?;
            let deadline = asked + STOP_GRACE;
            while Instant::now() < deadline {
                status = status.or(self.try_wait()?);
                if status.is_some() && !self.any_left(pgid) {
                    break;
                }
                // Most controllers are gone within a few milliseconds, and every run waits for
                // this: looked at each millisecond at first, then less often (a look may scan
                // /proc).
                let pause = if asked.elapsed() < STOP_LOOKS_CLOSELY { Duration::from_millis(1) } else { Duration::from_millis(20) };
                std::thread::sleep(pause);
            }
            if status.is_none() || self.any_left(pgid) {
                warn!("the controller or what it started ignored SIGTERM for {STOP_GRACE:?}; killing them");
                self.signal_all(pgid, nix::sys::signal::Signal::SIGKILL);
            }
            self.ended = true;
        }
        let status = match status {
            Some(status) => status,
            None => self.child.wait().during(|| format!("cannot reap the controller `{}`", self.description))?,
        };
        // Everything that held its output is gone: the log is complete once the copy ends.
        if let Some(log) = self.log.take()
            && !log.finish(LOG_FINISH)
        {
            warn!(log = %self.log_path.display(), "the controller's output was still being written after {LOG_FINISH:?}");
        }
        Ok(status)
    }

    /// SIGTERM to the controller and everything it started, once (what [`Controller::stop`]
    /// begins with); when it was sent. Under virtual time it is sent while every controller
    /// thread is still parked at the run's last instant, so that what the controller does on
    /// it does not depend on how far it ran on the wall clock after the run.
    pub fn ask_to_stop(&mut self) -> Result<Instant> {
        if let Some(asked) = self.asked_to_stop {
            return Ok(asked);
        }
        if !self.ended {
            self.signal_all(self.process_group()?, nix::sys::signal::Signal::SIGTERM);
        }
        Ok(*self.asked_to_stop.insert(Instant::now()))
    }

    /// The controller's process group (it leads its own).
    fn process_group(&self) -> Result<nix::unistd::Pid> {
        Ok(nix::unistd::Pid::from_raw(i32::try_from(self.child.id()).map_err(|_| RunnerError::Invalid("pid out of range".to_owned()))?))
    }

    /// Send `signal` to the controller's process group and to every process marked as its run's
    /// that left the group (`setsid`): once each. A second SIGTERM to a process the group's
    /// already reached could run its handler twice, as the host's timing had it.
    fn signal_all(&self, pgid: nix::unistd::Pid, signal: nix::sys::signal::Signal) {
        let _ = nix::sys::signal::killpg(pgid, signal);
        for pid in marked_processes(&self.marker) {
            if nix::unistd::getpgid(Some(pid)) != Ok(pgid) {
                let _ = nix::sys::signal::kill(pid, signal);
            }
        }
    }

    /// Whether anything of the controller's is still running (zombies waiting for their parent
    /// to reap them are not running).
    fn any_left(&self, pgid: nix::unistd::Pid) -> bool {
        group_alive(pgid) || !marked_processes(&self.marker).is_empty()
    }

    /// The last lines of the controller's output.
    pub fn log_tail(&self) -> String {
        log_tail(&self.log_path, LOG_TAIL_LINES)
    }
}

impl Drop for Controller {
    /// A run that ends by an error between start and stop still leaves nothing running.
    fn drop(&mut self) {
        if !self.ended
            && let Ok(pid) = i32::try_from(self.child.id())
        {
            self.signal_all(nix::unistd::Pid::from_raw(pid), nix::sys::signal::Signal::SIGKILL);
            let _ = self.child.wait();
        }
    }
}

/// Whether a process group has a member that is not a zombie.
fn group_alive(pgid: nix::unistd::Pid) -> bool {
    let pgid = pgid.as_raw().to_string();
    processes().any(|(_, stat)| stat_field(&stat, PGRP) == Some(pgid.as_str()) && stat_field(&stat, STATE) != Some("Z"))
}

/// Every live (not zombie) process whose environment holds `marker` (`NAME=value`).
fn marked_processes(marker: &[u8]) -> Vec<nix::unistd::Pid> {
    processes()
        .filter(|(_, stat)| stat_field(stat, STATE) != Some("Z"))
        .filter(|(pid, _)| std::fs::read(format!("/proc/{pid}/environ")).is_ok_and(|environ| environ.split(|&b| b == 0).any(|entry| entry == marker)))
        .map(|(pid, _)| nix::unistd::Pid::from_raw(pid))
        .collect()
}

/// Every process as (pid, its /proc/PID/stat line), this one's threads' process excluded.
fn processes() -> impl Iterator<Item = (i32, String)> {
    let own = std::process::id() as i32;
    std::fs::read_dir("/proc")
        .into_iter()
        .flatten()
        .filter_map(|entry| entry.ok()?.file_name().to_str()?.parse::<i32>().ok())
        .filter(move |&pid| pid != own)
        .filter_map(|pid| Some((pid, std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?)))
}

/// The environment that runs a dynamically linked program's clocks (time, gettimeofday,
/// clock_gettime including the monotonic ones) and its sleeps, selects and polls `speed` times
/// as fast, starting at the real time: an unchanged program sees the same time course as at 1x.
pub fn faketime_env(speed: f64) -> Result<Vec<(String, String)>> {
    let library = libfaketime()?;
    let preload = match std::env::var("LD_PRELOAD") {
        Ok(existing) if !existing.is_empty() => format!("{}:{existing}", library.display()),
        _ => library.display().to_string(),
    };
    Ok(vec![
        ("LD_PRELOAD".to_owned(), preload),
        ("FAKETIME".to_owned(), format!("+0 x{speed}")),
        ("FAKETIME_DONT_FAKE_MONOTONIC".to_owned(), "0".to_owned()),
        // Children the controller starts share its clock instead of starting their own.
        ("FAKETIME_DONT_RESET".to_owned(), "1".to_owned()),
    ])
}

/// The last `lines` lines of a log file (at most its last 16 KiB).
pub fn log_tail(path: &Path, lines: usize) -> String {
    let text = read_tail(path, 16 * 1024).unwrap_or_default();
    let all: Vec<&str> = text.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}

/// The last `limit` bytes of a text file, if it has any (read from the end: a log may be long).
pub fn read_tail(path: &Path, limit: u64) -> Option<String> {
    let mut file = std::fs::File::open(path).ok()?;
    let length = file.metadata().ok()?.len();
    file.seek(std::io::SeekFrom::Start(length.saturating_sub(limit))).ok()?;
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes).ok()?;
    (!bytes.is_empty()).then(|| String::from_utf8_lossy(&bytes).into_owned())
}

/// `program` as the OS would run it: a path (checked to exist and be executable) or a name on
/// PATH.
fn find_program(program: &str) -> Result<PathBuf> {
    use std::os::unix::fs::PermissionsExt as _;
    let executable = |path: &Path| std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0);
    if program.contains('/') {
        let path = PathBuf::from(program);
        let metadata = std::fs::metadata(&path).during(|| format!("{program}: not found"))?;
        if !metadata.is_file() {
            return Err(RunnerError::Invalid(format!("{program}: not a file")));
        }
        if !executable(&path) {
            return Err(RunnerError::Invalid(format!("{program}: not executable (chmod +x, or name its interpreter first, e.g. [\"python3\", \"{program}\"])")));
        }
        return Ok(path);
    }
    let path_var = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path_var).map(|dir| dir.join(program)).find(|candidate| executable(candidate)).ok_or_else(|| RunnerError::Invalid(format!("{program}: not found on PATH")))
}

/// The libfaketime library: `CLIMBSIM_LIBFAKETIME`, or the multi-threaded build where the
/// distribution installs it (controllers often have threads: ROS executors, SDK readers).
fn libfaketime() -> Result<PathBuf> {
    if let Some(path) = std::env::var_os("CLIMBSIM_LIBFAKETIME") {
        let path = PathBuf::from(path);
        if !path.is_file() {
            return Err(RunnerError::Invalid(format!("CLIMBSIM_LIBFAKETIME={} is not a file", path.display())));
        }
        return Ok(path);
    }
    for pattern in LIBFAKETIME_GLOBS {
        if let Some(found) = glob_one(pattern) {
            return Ok(found);
        }
    }
    Err(RunnerError::Invalid(
        "it needs libfaketime to scale the controller's clocks and none was found (Debian/Ubuntu: apt-get install libfaketime; or set CLIMBSIM_LIBFAKETIME to libfaketimeMT.so.1)".to_owned(),
    ))
}

/// The first file matching `pattern`, whose only wildcard is one `*` path component.
fn glob_one(pattern: &str) -> Option<PathBuf> {
    let Some((head, tail)) = pattern.split_once("/*/") else {
        return Path::new(pattern).is_file().then(|| PathBuf::from(pattern));
    };
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(head).ok()?.filter_map(|e| e.ok().map(|e| e.path())).collect();
    dirs.sort();
    dirs.into_iter().map(|dir| dir.join(tail)).find(|p| p.is_file())
}

/// LD_PRELOAD only reaches dynamically linked programs: refuse a static one (Go, musl, static
/// Rust) and a set-uid one, following a `#!` script to its interpreter.
fn refuse_unpreloadable(program: &Path, preload: &Preload) -> Result<()> {
    // A script's interpreter may be a script itself (a pyenv shim is a bash script standing for
    // python3); the kernel follows such a chain up to 4 deep (BINPRM_MAX_RECURSION), so do we.
    let mut binary = program.to_owned();
    for _ in 0..=MAX_INTERPRETER_DEPTH {
        match script_interpreter(&binary)? {
            Some(interpreter) => binary = interpreter,
            None => break,
        }
    }
    let binary = binary.as_path();
    use std::os::unix::fs::PermissionsExt as _;
    if std::fs::metadata(binary).is_ok_and(|m| m.permissions().mode() & 0o4000 != 0) {
        return Err(RunnerError::Invalid(format!("{} is set-uid, and the loader ignores LD_PRELOAD for it", binary.display())));
    }
    match elf_is_dynamic(binary)? {
        Some(true) => Ok(()),
        Some(false) => Err(RunnerError::Invalid(format!("{} is statically linked, so {} cannot be preloaded into it; {}, or link it dynamically", binary.display(), preload.name, preload.remedy))),
        None => Err(RunnerError::Invalid(format!("{} is neither an ELF program nor a #! script, so whether {} reaches it cannot be told", binary.display(), preload.name))),
    }
}

/// The interpreter of a `#!` script (through `/usr/bin/env NAME`), None for a binary.
fn script_interpreter(program: &Path) -> Result<Option<PathBuf>> {
    let mut head = [0u8; 256];
    let mut file = std::fs::File::open(program).during(|| format!("cannot read {}", program.display()))?;
    let n = file.read(&mut head).during(|| format!("cannot read {}", program.display()))?;
    let Some(line) = head[..n].strip_prefix(b"#!") else { return Ok(None) };
    let line = String::from_utf8_lossy(line);
    let line = line.lines().next().unwrap_or_default();
    let mut words = line.split_whitespace();
    let first = words.next().ok_or_else(|| RunnerError::Invalid(format!("{}: empty #! line", program.display())))?;
    if Path::new(first).file_name().is_some_and(|name| name == "env") {
        let name = words.find(|w| !w.starts_with('-')).ok_or_else(|| RunnerError::Invalid(format!("{}: #!{line} names no program", program.display())))?;
        return find_program(name).map(Some);
    }
    Ok(Some(PathBuf::from(first)))
}

/// Some(true) for a dynamically linked ELF file (it has a PT_INTERP program header, the loader
/// that honours LD_PRELOAD), Some(false) for a static one, None for a file that is not ELF.
pub fn elf_is_dynamic(path: &Path) -> Result<Option<bool>> {
    let bytes = std::fs::read(path).during(|| format!("cannot read {}", path.display()))?;
    Ok(elf_has_interpreter(&bytes))
}

/// The ELF header's program-header table, searched for PT_INTERP (type 3).
fn elf_has_interpreter(bytes: &[u8]) -> Option<bool> {
    const PT_INTERP: u32 = 3;
    if bytes.get(..4)? != b"\x7fELF" {
        return None;
    }
    let wide = match bytes.get(4)? {
        1 => false,
        2 => true,
        _ => return None,
    };
    let little = *bytes.get(5)? == 1;
    let read = |at: usize, len: usize| -> Option<u64> {
        let field = bytes.get(at..at + len)?;
        let mut value = 0u64;
        for (i, &b) in field.iter().enumerate() {
            let shift = if little { 8 * i } else { 8 * (len - 1 - i) };
            value |= u64::from(b) << shift;
        }
        Some(value)
    };
    let (phoff, phentsize, phnum) = if wide { (read(0x20, 8)?, read(0x36, 2)?, read(0x38, 2)?) } else { (read(0x1C, 4)?, read(0x2A, 2)?, read(0x2C, 2)?) };
    let (phoff, phentsize) = (usize::try_from(phoff).ok()?, usize::try_from(phentsize).ok()?);
    for index in 0..usize::try_from(phnum).ok()? {
        let entry = phoff.checked_add(index.checked_mul(phentsize)?)?;
        if read(entry, 4)? == u64::from(PT_INTERP) {
            return Some(true);
        }
    }
    Some(false)
}

/// `try_wait` process `pid` until it has ended, while it works (see
/// [`Controller::wait_for_ending`]); `None` if it is still there after [`ENDING_IDLE`] without
/// working, or after [`ENDING_AT_MOST`].
fn wait_while_busy<E>(pid: u32, mut try_wait: impl FnMut() -> std::result::Result<Option<ExitStatus>, E>) -> std::result::Result<Option<ExitStatus>, E> {
    let started = Instant::now();
    let mut progress = (process_cpu_ticks(pid), Instant::now());
    loop {
        let status = try_wait()?;
        if status.is_some() || started.elapsed() > ENDING_AT_MOST {
            return Ok(status);
        }
        let cpu = process_cpu_ticks(pid);
        if cpu != progress.0 || any_thread_busy(pid) {
            progress = (cpu, Instant::now());
        } else if progress.1.elapsed() > ENDING_IDLE {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}

/// The CPU time (utime + stime, in clock ticks) of process `pid` and its threads, if it can be
/// read.
fn process_cpu_ticks(pid: u32) -> Option<u64> {
    cpu_ticks(&std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?)
}

/// Whether a thread of process `pid` is runnable or waiting for the disk (R, D).
fn any_thread_busy(pid: u32) -> bool {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return false };
    tasks.filter_map(|task| std::fs::read_to_string(task.ok()?.path().join("stat")).ok()).any(|stat| stat_field(&stat, STATE).is_some_and(|state| matches!(state, "R" | "D")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dynamic_and_static_programs_are_told_apart() {
        assert_eq!(elf_is_dynamic(Path::new("/bin/sh")).expect("read /bin/sh"), Some(true));
        // Debian's ldconfig is a static-pie program: libfaketime cannot reach it.
        if Path::new("/sbin/ldconfig").is_file() {
            assert_eq!(elf_is_dynamic(Path::new("/sbin/ldconfig")).expect("read ldconfig"), Some(false));
        }
        assert_eq!(elf_has_interpreter(b"#!/bin/sh\n"), None);
        assert_eq!(elf_has_interpreter(b"\x7fELF\x02"), None, "a truncated header is not ELF");
    }

    #[test]
    fn scripts_are_followed_to_their_interpreter() {
        let dir = tempfile::tempdir().expect("temp dir");
        let script = dir.path().join("controller");
        std::fs::write(&script, "#!/usr/bin/env sh\necho hi\n").expect("write");
        let interpreter = script_interpreter(&script).expect("read").expect("a script");
        assert!(interpreter.ends_with("sh"), "{}", interpreter.display());
        assert!(refuse_unpreloadable(&script, &FAKETIME).is_ok());
        // A script whose interpreter is a script (a pyenv shim standing for python3) is followed
        // on to the program at the end of the chain.
        let shim = dir.path().join("python3");
        std::fs::write(&shim, "#!/usr/bin/env sh\nexec true \"$@\"\n").expect("write");
        std::fs::set_permissions(&shim, std::os::unix::fs::PermissionsExt::from_mode(0o755)).expect("chmod");
        let controller = dir.path().join("controller.py");
        std::fs::write(&controller, format!("#!{}\nprint(1)\n", shim.display())).expect("write");
        if let Err(error) = refuse_unpreloadable(&controller, &FAKETIME) {
            panic!("a nested #! is followed: {error}");
        }
    }

    #[test]
    fn an_ending_process_is_waited_for_while_it_works_and_not_while_it_idles() {
        // Computes for 2 to 3 s before it exits (after a second, the wait used to give up).
        let mut busy = std::process::Command::new("bash").args(["-c", "while (( SECONDS < 3 )); do :; done"]).spawn().expect("bash");
        let pid = busy.id();
        let status = wait_while_busy(pid, || busy.try_wait()).expect("try_wait");
        assert!(status.is_some_and(|s| s.success()), "{status:?}");
        let mut idle = std::process::Command::new("sleep").arg("10").spawn().expect("sleep");
        let started = Instant::now();
        let pid = idle.id();
        let status = wait_while_busy(pid, || idle.try_wait()).expect("try_wait");
        assert!(status.is_none(), "{status:?}");
        assert!(started.elapsed() < Duration::from_secs(5), "given up after {:?} idle", started.elapsed());
        let _ = idle.kill();
        let _ = idle.wait();
    }

    #[test]
    fn missing_and_unexecutable_programs_are_named() {
        let error = find_program("./no-such-controller").expect_err("missing");
        assert!(error.to_string().contains("./no-such-controller: not found"), "{error}");
        let error = find_program("no-such-controller-on-path").expect_err("missing");
        assert!(error.to_string().contains("not found on PATH"), "{error}");
        let dir = tempfile::tempdir().expect("temp dir");
        let script = dir.path().join("plain.py");
        std::fs::write(&script, "print(1)\n").expect("write");
        let error = find_program(&script.display().to_string()).expect_err("not executable");
        assert!(error.to_string().contains("not executable"), "{error}");
    }

    #[test]
    fn log_tails_keep_the_last_lines() {
        let dir = tempfile::tempdir().expect("temp dir");
        let log = dir.path().join("controller.log");
        std::fs::write(&log, (1..=40).map(|i| format!("line {i}\n")).collect::<String>()).expect("write");
        let tail = log_tail(&log, 3);
        assert_eq!(tail, "line 38\nline 39\nline 40");
    }
}
