//! External controllers under `run`, `check` and `sweep`: a controller that dies fails the run,
//! one that cannot start is one clear line, `--speed N` scales its clocks through libfaketime,
//! a run the machine cannot pace fails, and sweep values reach the program.

use std::path::{Path, PathBuf};

mod support;

use support::{climbsim, output_text as text};

/// The world of these tests: flat, a straight line under the robot, a loose threshold.
const WORLD: &str = "[world]\nseed = 1\nduration_s = {duration_s}\n\n[terrain]\nkind = \"flat\"\nsize_m = 4.0\n\n[line]\npoints = [[-0.5, 0.0], [1.5, 0.0]]\n\n[start]\nx_m = 0.5\n\n[expect]\nmax_abs_distance_m = { max = 1.0 }\n";

fn world(duration_s: f64) -> String {
    WORLD.replace("{duration_s}", &duration_s.to_string())
}

/// The flat world, `duration_s` long, driven by `controller` (a script written beside it,
/// started through /bin/sh).
fn scenario(dir: &Path, name: &str, duration_s: f64, controller: &str, extra: &str) -> PathBuf {
    support::executable_script(dir, &format!("{name}.sh"), &format!("#!/bin/sh\n{controller}\n"));
    let path = dir.join(format!("{name}.toml"));
    let text = format!("{}\n[controller]\nkind = \"external\"\ncommand = [\"./{name}.sh\"]\n{extra}\n", world(duration_s));
    std::fs::write(&path, text).expect("write scenario");
    path
}

fn summary(out: &Path) -> serde_json::Value {
    let bytes = std::fs::read(out.join("summary.json")).unwrap_or_else(|e| panic!("{}: {e}", out.join("summary.json").display()));
    serde_json::from_slice(&bytes).expect("summary.json")
}

#[test]
fn a_controller_that_crashes_fails_check_with_its_output_in_junit() {
    let dir = support::scratch_dir("ext-crash");
    let path = scenario(&dir, "crash", 5.0, "echo \"starting on $DXL_PORT at $DXL_BAUD\"\nsleep 0.5\necho 'segfault in control loop' >&2\nexit 3", "");
    let junit = dir.join("junit.xml");
    let output = climbsim(&["check", &path.display().to_string(), "--junit", &junit.display().to_string(), "--out", &dir.join("runs").display().to_string()]);
    assert_eq!(output.status.code(), Some(1), "a crashed controller fails the check: {}", text(&output));
    let all = text(&output);
    assert!(all.contains("FAIL") && all.contains("exit status: 3"), "{all}");
    let xml = std::fs::read_to_string(&junit).expect("junit");
    assert!(xml.contains("<failure") && xml.contains("segfault in control loop"), "the log's last lines are in the failure:\n{xml}");
    assert!(xml.contains("<system-out>") && xml.contains("starting on /dev/pts/"), "the controller's output is in system-out:\n{xml}");
    let s = summary(&dir.join("runs").join("crash"));
    assert_eq!(s["controller_exit_code"], 3, "{s}");
    let at = s["controller_exited_at_s"].as_f64().expect("exit time");
    assert!((0.3..2.0).contains(&at), "it died at ~0.5 s of simulated time, not {at}");
}

#[test]
fn a_controller_killed_by_a_signal_fails_the_run() {
    let dir = support::scratch_dir("ext-signal");
    let path = scenario(&dir, "killed", 5.0, "sleep 0.3\nkill -SEGV $$", "");
    let out = dir.join("out");
    let output = climbsim(&["run", &path.display().to_string(), "--out", &out.display().to_string()]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    let s = summary(&out);
    assert!(s["controller_exit"].as_str().is_some_and(|e| e.contains("signal")), "{s}");
    assert!(s["failures"].as_array().is_some_and(|f| !f.is_empty()), "{s}");
}

#[test]
fn a_controller_that_ends_by_itself_passes_only_with_a_zero_exit() {
    let dir = support::scratch_dir("ext-ends");
    let ok = scenario(&dir, "ok", 5.0, "sleep 0.3\nexit 0", "ends_by_itself = true");
    let bad = scenario(&dir, "bad", 5.0, "sleep 0.3\nexit 1", "ends_by_itself = true");
    let early = scenario(&dir, "early", 5.0, "sleep 0.3\nexit 0", "");
    let runs = dir.join("runs").display().to_string();
    let output = climbsim(&["check", &ok.display().to_string(), "--out", &runs]);
    assert!(output.status.success(), "{}", text(&output));
    let output = climbsim(&["check", &bad.display().to_string(), "--out", &runs]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    let output = climbsim(&["check", &early.display().to_string(), "--out", &runs]);
    assert_eq!(output.status.code(), Some(1), "exit 0 before the end fails unless ends_by_itself: {}", text(&output));
    // One that had not finished by the scenario's end (blocked for good, or too slow) fails
    // too, saying so: stopped, it would otherwise have passed.
    let unfinished = scenario(&dir, "unfinished", 1.0, "sleep 30\nexit 0", "ends_by_itself = true");
    let output = climbsim(&["check", &unfinished.display().to_string(), "--out", &runs]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    assert!(text(&output).contains("controller still running at the scenario's end (t = 1 s, simulated), though it ends by itself"), "{}", text(&output));
}

/// A controller that runs until stopped may end as it likes when asked (SIGTERM), but one that
/// crashes in its own ending (libuv's assertion, a segfault in a SIGTERM handler) fails the run:
/// what it does there (a final report, the torque off) is lost. Both clocks.
#[test]
fn a_controller_that_crashes_as_it_stops_fails_the_run() {
    let dir = support::scratch_dir("ext-crash-on-stop");
    let crashes = scenario(&dir, "crashes", 1.0, "trap 'echo stopping; kill -ABRT $$' TERM\nwhile :; do sleep 0.05; done", "");
    let stops = scenario(&dir, "stops", 1.0, "trap 'echo stopping; exit 0' TERM\nwhile :; do sleep 0.05; done", "");
    for clock in ["virtual", "wall"] {
        let out = dir.join(format!("crashes-{clock}")).display().to_string();
        let output = climbsim(&["run", &crashes.display().to_string(), "--clock", clock, "--set", "expect={}", "--pace-tolerance-ms", "1000", "--out", &out]);
        assert_eq!(output.status.code(), Some(1), "{clock}: {}", text(&output));
        assert!(text(&output).contains("controller crashed as it stopped at the scenario's end (asked with SIGTERM): signal: 6 (SIGABRT)"), "{clock}: {}", text(&output));
        let out = dir.join(format!("stops-{clock}")).display().to_string();
        let output = climbsim(&["run", &stops.display().to_string(), "--clock", clock, "--set", "expect={}", "--pace-tolerance-ms", "1000", "--out", &out]);
        assert!(output.status.success(), "{clock}: {}", text(&output));
    }
}

/// Whether `pid` is still running (a zombie waiting to be reaped is not).
fn running(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|stat| stat.rsplit(')').next().is_some_and(|rest| !rest.trim_start().starts_with('Z')))
}

/// What a controller starts ends with its run: a background job, a child that left the process
/// group (`setsid`), and one that ignores SIGTERM; also when the controller itself ended first.
#[test]
fn a_controllers_children_do_not_outlive_the_run() {
    let dir = support::scratch_dir("ext-orphans");
    let pids = dir.join("pids");
    for (name, extra, tail) in [("lingers", "", "sleep 30"), ("leaves-first", "ends_by_itself = true", "exit 0")] {
        let path = scenario(
            &dir,
            name,
            1.0,
            &format!(
                "sleep 300 &\necho $! > {pids}.{name}\nsetsid sleep 301 &\necho $! >> {pids}.{name}\nsh -c 'trap \"\" TERM; sleep 302' &\necho $! >> {pids}.{name}\n{tail}",
                pids = pids.display()
            ),
            extra,
        );
        // Not a test of pace: on a loaded CI machine a wall-clock run can fall behind its ticks.
        let output = climbsim(&["run", &path.display().to_string(), "--set", "expect={}", "--pace-tolerance-ms", "1000", "--out", &dir.join(name).display().to_string()]);
        assert!(output.status.success(), "{name}: {}", text(&output));
        let started: Vec<u32> = std::fs::read_to_string(format!("{}.{name}", pids.display())).expect("pids").lines().map(|l| l.trim().parse().expect("a pid")).collect();
        assert_eq!(started.len(), 3, "{name}: {started:?}");
        let left: Vec<u32> = started.into_iter().filter(|&pid| running(pid)).collect();
        assert!(left.is_empty(), "{name}: still running after the run: {left:?}");
    }
}

/// A controller that prints 100 MB leaves a log of a few megabytes: its first and last lines,
/// and how much was cut between them. It ends by itself once it has printed them all: on a
/// loaded machine the printing outlasted a 1 s run, which then ended before the last line.
#[test]
fn a_controllers_log_is_capped_keeping_head_and_tail() {
    let dir = support::scratch_dir("ext-loud");
    let path = scenario(&dir, "loud", 120.0, "echo first-line\nhead -c 100000000 /dev/zero | tr '\\0' x\necho\necho last-line", "ends_by_itself = true");
    let out = dir.join("out");
    let output = climbsim(&["run", &path.display().to_string(), "--set", "expect={}", "--pace-tolerance-ms", "1000", "--out", &out.display().to_string()]);
    assert!(output.status.success(), "{}", text(&output));
    let log = std::fs::read(out.join("controller.log")).expect("controller.log");
    assert!(log.len() < 9 << 20, "controller.log is {} bytes", log.len());
    let (start, end) = (String::from_utf8_lossy(&log[..20]), String::from_utf8_lossy(&log[log.len() - 20..]));
    assert!(start.starts_with("first-line\n"), "{start:?}");
    assert!(end.ends_with("\nlast-line\n"), "{end:?}");
    assert!(String::from_utf8_lossy(&log).contains("bytes of the controller's output were cut here"));
}

#[test]
fn a_controller_that_cannot_start_is_one_clear_line() {
    let dir = support::scratch_dir("ext-missing");
    let path = dir.join("missing.toml");
    std::fs::write(&path, format!("{}[controller]\nkind = \"external\"\ncommand = [\"./no-such-controller\"]\n", world(1.0))).expect("write");
    let output = climbsim(&["run", &path.display().to_string(), "--out", &dir.join("out").display().to_string()]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("no-such-controller") && !stderr.contains("panicked"), "{stderr}");
    assert!(stderr.lines().filter(|l| !l.trim().is_empty()).count() <= 2, "one clear line:\n{stderr}");
    // Nothing half-written is left behind (the recording had been started).
    let left: Vec<_> = std::fs::read_dir(dir.join("out")).expect("out").filter_map(|e| e.ok()).map(|e| e.file_name()).filter(|n| n.to_string_lossy().ends_with(".tmp")).collect();
    assert!(left.is_empty(), "{left:?}");
    // Under `check` it is a case that could not run: ERROR, and a JUnit <error>, not a
    // <failure> of the controller under test.
    let junit = dir.join("junit.xml");
    let output = climbsim(&["check", &path.display().to_string(), "--junit", &junit.display().to_string(), "--out", &dir.join("check").display().to_string()]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    assert!(text(&output).contains("ERROR") && text(&output).contains("no-such-controller"), "{}", text(&output));
    let xml = std::fs::read_to_string(&junit).expect("junit");
    assert!(xml.contains("errors=\"1\"") && xml.contains("failures=\"0\"") && xml.contains("<error ") && !xml.contains("<failure"), "{xml}");
}

/// At `--speed 5` the controller's own clocks (time(), sleep, monotonic) run 5× fast: a shell
/// `sleep 2` inside a 3 s scenario ends after 2 simulated seconds, 0.4 wall seconds.
#[test]
fn speed_runs_the_controller_clock_n_times_faster() {
    let dir = support::scratch_dir("ext-speed");
    let path = scenario(&dir, "clock", 5.0, "echo \"speed $CLIMBSIM_SPEED\"\nsleep 2\necho slept\nexit 0", "ends_by_itself = true");
    let out = dir.join("out");
    let started = std::time::Instant::now();
    let output = climbsim(&["run", &path.display().to_string(), "--speed", "5", "--pace-tolerance-ms", "1000", "--out", &out.display().to_string()]);
    let wall = started.elapsed().as_secs_f64();
    assert!(output.status.success(), "{}", text(&output));
    let s = summary(&out);
    let at = s["controller_exited_at_s"].as_f64().expect("exit time");
    // At 5x the 2 s sleep takes 0.4 s of wall time; the shell's start and the host's delays
    // come on top, 5x in simulated time (beside two busy loops, the other tests and a build:
    // 0.2 s of wall time, 3.02 s; a 3 s run once ended before the sleep did). Unscaled, the
    // sleep alone would take 10 simulated seconds, past the run's 5.
    assert!((1.8..4.5).contains(&at), "the controller's 2 s sleep took {at} simulated seconds");
    assert!(wall < 3.0, "5 simulated seconds at 5x took {wall:.2} s of wall time");
    assert_eq!(s["pace.speed"], 5.0, "{s}");
    let log = std::fs::read_to_string(out.join("controller.log")).expect("log");
    assert!(log.contains("speed 5") && log.contains("slept"), "{log}");
}

#[test]
fn speed_refuses_a_statically_linked_controller() {
    let Some(static_program) = ["/bin/busybox", "/usr/bin/busybox", "/sbin/ldconfig"].into_iter().map(Path::new).find(|p| is_static_elf(p)) else {
        panic!("no statically linked program on this machine to test with (looked for busybox, ldconfig)");
    };
    let dir = support::scratch_dir("ext-static");
    let path = dir.join("static.toml");
    std::fs::write(&path, format!("{}[controller]\nkind = \"external\"\ncommand = [\"{}\"]\n", world(1.0), static_program.display())).expect("write");
    let output = climbsim(&["run", &path.display().to_string(), "--speed", "4", "--out", &dir.join("out").display().to_string()]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    assert!(text(&output).contains("statically linked"), "{}", text(&output));
}

/// An ELF file without a PT_INTERP program header (the dynamic loader's path).
fn is_static_elf(path: &Path) -> bool {
    let Ok(bytes) = std::fs::read(path) else {
        return false;
    };
    if bytes.len() < 64 || &bytes[..4] != b"\x7fELF" || bytes[4] != 2 {
        return false;
    }
    let u64_at = |o: usize| u64::from_le_bytes(bytes[o..o + 8].try_into().expect("8 bytes")) as usize;
    let u16_at = |o: usize| u16::from_le_bytes(bytes[o..o + 2].try_into().expect("2 bytes")) as usize;
    let (phoff, phentsize, phnum) = (u64_at(0x20), u16_at(0x36), u16_at(0x38));
    (0..phnum).all(|i| bytes.get(phoff + i * phentsize..phoff + i * phentsize + 4).is_some_and(|h| u32::from_le_bytes(h.try_into().expect("4")) != 3))
}

#[test]
fn a_run_the_machine_cannot_pace_fails() {
    let dir = support::scratch_dir("ext-pace");
    let path = scenario(&dir, "idle", 1.0, "sleep 5", "");
    let out = dir.join("out");
    // No machine hands every tick over within a nanosecond of its deadline.
    let output = climbsim(&["run", &path.display().to_string(), "--pace-tolerance-ms", "0.000001", "--out", &out.display().to_string()]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    let s = summary(&out);
    assert_eq!(s["pace.kept"], false, "{s}");
    assert!(s["failures"].as_array().is_some_and(|f| f.iter().any(|l| l.as_str().is_some_and(|l| l.contains("could not keep up")))), "{s}");
}

#[test]
fn sweep_values_reach_an_external_controller() {
    let dir = support::scratch_dir("ext-sweep");
    let path = scenario(&dir, "params", 1.0, "echo \"gain=$CLIMBSIM_PARAM_GAIN arg=$1\"\nsleep 5", "params = { gain = 1.0 }");
    // The command takes the value as an argument too.
    let text_now = std::fs::read_to_string(&path).expect("read");
    std::fs::write(&path, text_now.replace("command = [\"./params.sh\"]", "command = [\"./params.sh\", \"{gain}\"]")).expect("write");
    let out = dir.join("sweep");
    let output = climbsim(&["sweep", &path.display().to_string(), "--set", "controller.params.gain=0.5,2.5", "--jobs", "2", "--out", &out.display().to_string()]);
    assert!(output.status.success(), "{}", text(&output));
    let mut seen = Vec::new();
    for entry in walk(&out) {
        if entry.file_name().is_some_and(|n| n == "controller.log") {
            seen.push(std::fs::read_to_string(&entry).expect("log"));
        }
    }
    seen.sort();
    assert_eq!(seen.len(), 2, "{seen:?}");
    assert!(seen[0].contains("gain=0.5 arg=0.5") && seen[1].contains("gain=2.5 arg=2.5"), "{seen:?}");
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let path = entry.path();
        if path.is_dir() {
            files.extend(walk(&path));
        } else {
            files.push(path);
        }
    }
    files
}
