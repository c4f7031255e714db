//! What the virtual-time tests share (`tests/virtual_time*.rs`): a bare scenario around an
//! external controller, runs on virtual time, their outputs, controllers compiled for a test.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use super::{climbsim_with_sdk_python, output_text, repo, scratch_dir};

/// A flat world `duration_s` long driven by `command` (paths relative to the repository, or
/// absolute), with `extra` TOML after it.
pub fn scenario(dir: &Path, name: &str, duration_s: f64, command: &[&str], ends_by_itself: bool) -> PathBuf {
    scenario_with(dir, name, duration_s, command, ends_by_itself, "")
}

/// [`scenario`] on a 1 Mbps bus.
pub fn scenario_1mbps(dir: &Path, name: &str, duration_s: f64, command: &[&str]) -> PathBuf {
    scenario_with(dir, name, duration_s, command, true, "\n[bus]\nbaud_bps = 1000000\n")
}

pub fn scenario_with(dir: &Path, name: &str, duration_s: f64, command: &[&str], ends_by_itself: bool, extra: &str) -> PathBuf {
    // The program relative to the repository (or absolute); its arguments as they are.
    let command: Vec<String> = command.iter().enumerate().map(|(i, part)| if i == 0 { format!("\"{}\"", repo().join(part).display()) } else { format!("\"{part}\"") }).collect();
    let text = format!(
        "[world]\nseed = 1\nduration_s = {duration_s}\n\n[terrain]\nkind = \"flat\"\nsize_m = 4.0\n\n[line]\npoints = [[-0.5, 0.0], [1.5, 0.0]]\n\n[start]\nx_m = 0.5\n\n\
         [controller]\nkind = \"external\"\ncommand = [{}]\nends_by_itself = {ends_by_itself}\n{extra}",
        command.join(", ")
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).expect("write scenario");
    path
}

/// `climbsim run SCENARIO --clock virtual --out OUT`: its output and wall time.
pub fn run_virtual(scenario: &Path, out: &Path) -> (std::process::Output, Duration) {
    run_virtual_with(scenario, out, &[])
}

/// [`run_virtual`] with more arguments.
pub fn run_virtual_with(scenario: &Path, out: &Path, more: &[&str]) -> (std::process::Output, Duration) {
    let started = Instant::now();
    let (scenario, out) = (scenario.display().to_string(), out.display().to_string());
    let mut args = vec!["run", &scenario, "--clock", "virtual", "--out", &out];
    args.extend_from_slice(more);
    let output = climbsim_with_sdk_python(&args);
    (output, started.elapsed())
}

pub fn summary(out: &Path) -> serde_json::Map<String, serde_json::Value> {
    let text = std::fs::read_to_string(out.join("summary.json")).unwrap_or_else(|e| panic!("{}: {e}", out.display()));
    serde_json::from_str(&text).expect("summary.json")
}

/// The summary without what measures the host (wall time): what must repeat exactly.
pub fn repeatable(out: &Path) -> serde_json::Map<String, serde_json::Value> {
    let mut summary = summary(out);
    summary.remove("realtime_factor");
    summary
}

/// A controller `command` (relative to the repository, or absolute) that ends by itself, run
/// twice for `duration_s` in a scratch folder `vt-NAME` with identical outputs; its log.
pub fn command_log_repeated(name: &str, duration_s: f64, command: &[&str]) -> String {
    log_repeated_in(&scratch_dir(&format!("vt-{name}")), name, duration_s, command)
}

/// `command` run twice from the scratch folder `dir` as a controller that ends by itself, in a
/// world `duration_s` long, with identical outputs; its log.
pub fn log_repeated_in(dir: &Path, name: &str, duration_s: f64, command: &[&str]) -> String {
    let path = scenario(dir, name, duration_s, command, true);
    controller_log_repeated(&path, dir)
}

/// Run `path` on virtual time twice: both succeed, and the controller prints the same and the
/// world's series are the same; what it printed.
pub fn controller_log_repeated(path: &Path, dir: &Path) -> String {
    let mut logs = Vec::new();
    let mut series = Vec::new();
    let mut summaries = Vec::new();
    for run in ["a", "b"] {
        let (output, _) = run_virtual(path, &dir.join(run));
        assert_eq!(output.status.code(), Some(0), "{}", output_text(&output));
        logs.push(std::fs::read_to_string(dir.join(run).join("controller.log")).expect("controller.log"));
        series.push(std::fs::read(dir.join(run).join("timeseries.csv")).expect("timeseries.csv"));
        summaries.push(repeatable(&dir.join(run)));
        assert!(dir.join(run).join("scheduler.json").is_file(), "the scheduler's counts beside the summary");
    }
    assert_eq!(logs[0], logs[1], "the controller's own timings differ between runs");
    // The world too: a run that ends at another instant (a thread's end seen late) differs here.
    assert!(series[0] == series[1], "timeseries.csv differs between runs (in {})", dir.display());
    // And the summary, but for the wall-clock ratio (the scheduler's counts are scheduler.json's).
    assert_eq!(summaries[0], summaries[1], "summary.json differs between runs (in {})", dir.display());
    logs.swap_remove(0)
}

/// `tests/vt/NAME.c` compiled into `dir` with the system's C compiler (Rust links with it, so
/// it is there wherever these tests build).
pub fn compiled_c(dir: &Path, name: &str) -> PathBuf {
    compiled_c_source(dir, &format!("tests/vt/{name}.c"))
}

/// The C file at `source` (relative to the repository) compiled into `dir`, named as the file.
pub fn compiled_c_source(dir: &Path, source: &str) -> PathBuf {
    let name = Path::new(source).file_stem().expect("a file name").to_str().expect("utf-8 name");
    compiled_c_as(dir, source, name, &[])
}

/// The C file at `source` (relative to the repository) compiled into `dir` as `name`, with
/// `flags` (`-static`) besides.
pub fn compiled_c_as(dir: &Path, source: &str, name: &str, flags: &[&str]) -> PathBuf {
    let program = dir.join(name);
    let compiled = Command::new("cc").args(flags).arg(repo().join(source)).arg("-o").arg(&program).output().expect("run cc");
    assert!(compiled.status.success(), "{}", output_text(&compiled));
    program
}

/// `tests/vt/NAME.cpp` compiled into `dir` with the system's C++ compiler (threads and C++17).
pub fn compiled_cpp(dir: &Path, name: &str) -> PathBuf {
    let program = dir.join(name);
    let source = repo().join(format!("tests/vt/{name}.cpp"));
    let compiled = Command::new("c++").args(["-O1", "-std=c++17", "-pthread"]).arg(&source).arg("-o").arg(&program).output().expect("run c++");
    assert!(compiled.status.success(), "{}", output_text(&compiled));
    program
}

/// A program of tests/vt/go (`package`: "." for the controller, or a folder in it) built into
/// `dir` with Debian's Go (scripts/test.sh installs golang-go): with cgo (dynamically linked)
/// or without (static). Go's build cache lives in the target directory, so that a second build
/// is quick and no home directory is needed.
pub fn compiled_go(dir: &Path, package: &str, cgo: bool) -> PathBuf {
    let go = on_path("go", "the Go controller's tests (apt-get install golang-go; scripts/test.sh does)");
    let name = if package == "." { "controller" } else { package.trim_start_matches("./") };
    let program = dir.join(format!("go-{name}{}", if cgo { "" } else { "-static" }));
    let cache = repo().join("target/go-cache");
    let compiled = Command::new(go)
        .args(["build", "-o"])
        .arg(&program)
        .arg(package)
        .current_dir(repo().join("tests/vt/go"))
        .env("CGO_ENABLED", if cgo { "1" } else { "0" })
        .env("GOCACHE", cache.join("build"))
        .env("GOPATH", cache.join("path"))
        .env("GOTOOLCHAIN", "local")
        .output()
        .expect("run go build");
    assert!(compiled.status.success(), "{}", output_text(&compiled));
    program
}

/// `program`'s path on PATH (the machine's own runtimes), or a failure saying which test needs it.
pub fn on_path(program: &str, needed_by: &str) -> String {
    let found = Command::new("sh").args(["-c", &format!("command -v {program}")]).output().expect("sh");
    let path = String::from_utf8_lossy(&found.stdout).trim().to_owned();
    assert!(!path.is_empty(), "{program} is not on PATH: {needed_by} needs it");
    path
}

/// Every one of `expected` is in the controller's `log`.
pub fn assert_log_has(log: &str, expected: &[&str]) {
    for line in expected {
        assert!(log.contains(line), "missing {line:?} in:\n{log}");
    }
}

/// A test program `cargo test` built (examples are built with the tests).
pub fn example(name: &str) -> PathBuf {
    let deps = std::env::current_exe().expect("the test's path");
    let path = deps.parent().and_then(Path::parent).expect("target/<profile>").join("examples").join(name);
    assert!(path.is_file(), "{} is missing: `cargo test` builds the examples", path.display());
    path
}
