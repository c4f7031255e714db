//! `climbsim run`, `check` and `sweep` as a user runs them: the binary, real files, exit codes;
//! and the reference external controller on the official SDK over a real pty.

use std::path::Path;
use std::process::Command;

mod support;

use support::{climbsim, output_text as text, repo};

fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let body = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = body.lines();
    let header = lines.next().expect("header").split(',').map(str::to_owned).collect();
    let rows = lines.map(|l| l.split(',').map(|v| v.parse().unwrap_or(f64::NAN)).collect()).collect();
    (header, rows)
}

fn column(csv: &(Vec<String>, Vec<Vec<f64>>), name: &str) -> Vec<f64> {
    let index = csv.0.iter().position(|c| c == name).unwrap_or_else(|| panic!("no column {name}"));
    csv.1.iter().map(|r| r[index]).collect()
}

#[test]
fn run_writes_every_output_file() {
    let out = support::scratch_dir("run-outputs");
    let out_arg = out.display().to_string();
    let output = climbsim(&["run", "scenarios/flat-line.toml", "--out", &out_arg, "--set", "world.duration_s=4", "--set", "expect={}"]);
    assert!(output.status.success(), "{}", text(&output));
    for file in ["timeseries.csv", "summary.json", "settings.json", "report.xlsx", "distance.png", "distance.svg", "speed.png", "speed.svg"] {
        let size = std::fs::metadata(out.join(file)).unwrap_or_else(|e| panic!("{file}: {e}")).len();
        assert!(size > 0, "{file} is empty");
    }
    let summary: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("summary.json")).expect("summary")).expect("json");
    assert!(summary["realtime_factor"].as_f64().is_some_and(|f| f > 1.0), "{summary}");
    let csv = read_csv(&out.join("timeseries.csv"));
    assert!(csv.0.len() >= 20 && csv.1.len() >= 150, "{} columns, {} rows", csv.0.len(), csv.1.len());
    // Nothing half-written is left behind.
    assert!(std::fs::read_dir(&out).expect("out").all(|e| !e.expect("entry").file_name().to_string_lossy().ends_with(".tmp")));
}

/// `run --help` names the clock an external controller runs on (it said "in real time" after
/// `--clock virtual` was built; the default for `run` is the wall clock).
#[test]
fn run_help_says_which_clock_an_external_controller_runs_on() {
    let output = climbsim(&["run", "--help"]);
    assert!(output.status.success(), "{}", text(&output));
    let help = String::from_utf8_lossy(&output.stdout);
    assert!(!help.contains("runs in real time"), "{help}");
    assert!(help.contains("runs on `--clock`: the wall clock unless `--clock virtual`"), "{help}");
}

#[test]
fn check_fails_on_a_broken_threshold_and_writes_junit() {
    let dir = support::scratch_dir("check");
    let scenario = std::fs::read_to_string(repo().join("scenarios/flat-line.toml")).expect("scenario");
    let base = scenario.split("[expect]").next().expect("before expect").replace("duration_s = 120.0", "duration_s = 3.0").to_owned();
    let pass = dir.join("pass.toml");
    let fail = dir.join("fail.toml");
    // Relative paths inside do not matter here: flat terrain, no heightmap.
    std::fs::write(&pass, format!("{base}[expect]\n\"max_abs_distance_m\" = {{ max = 0.1 }}\n")).expect("write");
    std::fs::write(&fail, format!("{base}[expect]\n\"max_abs_distance_m\" = {{ max = 0.001 }}\n")).expect("write");
    let junit = dir.join("junit.xml");
    let (junit_arg, out_arg) = (junit.display().to_string(), dir.join("runs").display().to_string());
    let output = climbsim(&["check", &pass.display().to_string(), "--junit", &junit_arg, "--out", &out_arg]);
    assert!(output.status.success(), "{}", text(&output));
    let output = climbsim(&["check", &pass.display().to_string(), &fail.display().to_string(), "--junit", &junit_arg, "--out", &out_arg]);
    assert!(!output.status.success(), "a failed threshold fails the check");
    let all = text(&output);
    assert!(all.contains("PASS") && all.contains("FAIL") && all.contains("max_abs_distance_m"), "{all}");
    let xml = std::fs::read_to_string(&junit).expect("junit");
    assert!(xml.contains("tests=\"2\"") && xml.contains("failures=\"1\""), "{xml}");
    // The failed run's summary.json says why, as the exit code and the printed lines do.
    let summary: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("runs/fail/summary.json")).expect("summary")).expect("json");
    let listed = summary["failures"].as_array().unwrap_or_else(|| panic!("no failures in {summary}"));
    assert!(listed.iter().any(|f| f.as_str().is_some_and(|f| f.contains("max_abs_distance_m"))), "{summary}");
    let passed: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("runs/pass/summary.json")).expect("summary")).expect("json");
    assert!(passed.get("failures").is_none(), "{passed}");
    // Side by side (--jobs 2): the same verdicts and the same runs (lockstep repeats whatever
    // else runs), each verdict said once, the JUnit cases in the files' order.
    std::fs::write(dir.join("pass2.toml"), format!("{base}[expect]\n\"max_abs_distance_m\" = {{ max = 0.1 }}\n")).expect("write");
    let jobs_out = dir.join("runs-jobs").display().to_string();
    let output = climbsim(&["check", &dir.display().to_string(), "--jobs", "2", "--junit", &junit_arg, "--out", &jobs_out]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    let all = text(&output);
    assert_eq!(all.matches("PASS ").count(), 2, "{all}");
    assert_eq!(all.matches("FAIL ").count(), 1, "{all}");
    let xml = std::fs::read_to_string(&junit).expect("junit");
    let order: Vec<usize> = ["fail.toml", "pass.toml", "pass2.toml"].iter().map(|name| xml.find(name).unwrap_or_else(|| panic!("{name} missing in {xml}"))).collect();
    assert!(order.windows(2).all(|w| w[0] < w[1]), "{xml}");
    let series = |root: &str| std::fs::read(Path::new(root).join("pass/timeseries.csv")).expect("timeseries.csv");
    assert!(series(&out_arg) == series(&jobs_out), "a run checked beside another differs");
    // `--set` applies to every scenario checked: the failing threshold loosened passes both,
    // a key of the robot's reaches the robot, and a wrong key is bad input naming it.
    let set_out = dir.join("runs-set").display().to_string();
    let loosened = r#"expect={ "max_abs_distance_m" = { max = 0.1 } }"#;
    let output = climbsim(&["check", &pass.display().to_string(), &fail.display().to_string(), "--set", loosened, "--set", "robot.wheel.friction=0.5", "--out", &set_out]);
    assert!(output.status.success(), "{}", text(&output));
    let settings: serde_json::Value = serde_json::from_slice(&std::fs::read(Path::new(&set_out).join("fail/settings.json")).expect("settings.json")).expect("json");
    assert_eq!(settings["friction"], 0.5, "{settings}");
    let output = climbsim(&["check", &pass.display().to_string(), "--set", "world.durashon_s=2", "--out", &set_out]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    assert!(text(&output).contains("durashon_s"), "{}", text(&output));
    // And `run` alike.
    let run_out = dir.join("run-fail");
    let output = climbsim(&["run", &fail.display().to_string(), "--out", &run_out.display().to_string()]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    let summary: serde_json::Value = serde_json::from_slice(&std::fs::read(run_out.join("summary.json")).expect("summary")).expect("json");
    assert!(summary["failures"].to_string().contains("max_abs_distance_m"), "{summary}");
}

/// `climbsim run … | head -1`, `sweep --list | head`, `diff … | head`: a reader that goes away
/// early is no panic; the command ends with its own verdict.
#[test]
fn a_closed_stdout_is_no_panic() {
    let dir = support::scratch_dir("closed-stdout");
    let out = dir.join("run").display().to_string();
    let commands: [&[&str]; 3] = [
        &["run", "scenarios/flat-line.toml", "--out", &out, "--set", "world.duration_s=1", "--set", "expect={}"],
        &["sweep", "scenarios/flat-line.toml", "--list", "--set", "controller.zeta=0.3,0.5,0.7,0.9"],
        &["diff", &out, &out],
    ];
    for args in commands {
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_climbsim"))
            .args(args)
            .current_dir(repo())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("start climbsim");
        // The reader closes its end before climbsim says anything.
        drop(child.stdout.take());
        let output = child.wait_with_output().expect("wait");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        assert_eq!(output.status.code(), Some(0), "{args:?}: {stderr}");
    }
}

#[test]
fn sweep_shards_merge_into_one_table() {
    let dir = support::scratch_dir("sweep");
    let (one, two, merged) = (dir.join("one"), dir.join("two"), dir.join("merged"));
    for (shard, out) in [("1/2", &one), ("2/2", &two)] {
        let output =
            climbsim(&["sweep", "scenarios/flat-line.toml", "--set", "controller.zeta=0.5,1.0", "--set", "world.duration_s=3", "--shard", shard, "--jobs", "1", "--out", &out.display().to_string()]);
        assert!(output.status.success(), "{}", text(&output));
    }
    let output = climbsim(&["sweep", "--merge", &one.display().to_string(), &two.display().to_string(), "--out", &merged.display().to_string()]);
    assert!(output.status.success(), "{}", text(&output));
    let table = std::fs::read_to_string(merged.join("sweep.csv")).expect("sweep.csv");
    let lines: Vec<&str> = table.lines().collect();
    assert_eq!(lines.len(), 3, "{table}");
    assert!(lines[0].starts_with("run,controller.zeta,world.duration_s,"), "{}", lines[0]);
    assert!(lines[1].starts_with("0,0.5,") && lines[2].starts_with("1,1.0,"), "{table}");
    for plot in ["overlay_distance.png", "distance_overshoot_pct_vs_zeta.svg"] {
        assert!(merged.join(plot).is_file(), "{plot} missing");
    }

    // One shard alone is an incomplete grid: the merge names the missing point and fails,
    // unless told to accept it; the table marks the point either way.
    let partial = dir.join("partial");
    let output = climbsim(&["sweep", "--merge", &one.display().to_string(), "--out", &partial.display().to_string()]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    assert!(text(&output).contains("001-controller.zeta=1.0,world.duration_s=3"), "{}", text(&output));
    let table = std::fs::read_to_string(partial.join("sweep.csv")).expect("sweep.csv");
    assert!(table.lines().nth(2).is_some_and(|row| row.starts_with("1,1.0,") && row.contains("not_run")), "{table}");
    // Every row has a cell under every header, and the missing point says why in `error`.
    let header: Vec<&str> = table.lines().next().expect("header").split(',').collect();
    assert!(header.iter().all(|cell| !cell.is_empty()) && header.contains(&"error"), "{table}");
    let error = header.iter().position(|cell| *cell == "error").expect("error column");
    for row in table.lines() {
        assert_eq!(row.split(',').count(), header.len(), "ragged row {row:?} in\n{table}");
    }
    assert!(table.lines().nth(2).is_some_and(|row| row.split(',').nth(error).is_some_and(|e| e.contains("no merged shard"))), "{table}");
    let output = climbsim(&["sweep", "--merge", &one.display().to_string(), "--allow-incomplete", "--out", &partial.display().to_string()]);
    assert!(output.status.success(), "{}", text(&output));

    // A shard of another scenario, and a shard whose runs/ folder was not copied, are refused.
    let table = std::fs::read_to_string(two.join("sweep.json")).expect("sweep.json");
    let (other, bare) = (dir.join("other"), dir.join("bare"));
    for (shard, json) in [(&other, table.replace("scenarios/flat-line.toml", "scenarios/flat-corners-smooth.toml")), (&bare, table.clone())] {
        std::fs::create_dir_all(shard).expect("shard dir");
        std::fs::write(shard.join("sweep.json"), json).expect("sweep.json");
    }
    let output = climbsim(&["sweep", "--merge", &one.display().to_string(), &other.display().to_string(), "--out", &dir.join("merged-other").display().to_string()]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    assert!(text(&output).contains("flat-corners-smooth.toml") && text(&output).contains("different scenarios"), "{}", text(&output));
    let output = climbsim(&["sweep", "--merge", &one.display().to_string(), &bare.display().to_string(), "--out", &dir.join("merged-bare").display().to_string()]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    assert!(text(&output).contains("runs/") && text(&output).contains("is missing"), "{}", text(&output));
}

/// A job array's task index picks the shard (`--shard auto/N`), and `--list --json` shows the
/// points a task would run, without running them.
#[test]
fn job_array_shards_list_their_points() {
    let list = |env: (&str, &str)| {
        let output = Command::new(env!("CARGO_BIN_EXE_climbsim"))
            .args(["sweep", "scenarios/flat-line.toml", "--set", "controller.zeta=0.3,0.5,0.7", "--set", "controller.kp=1,2", "--shard", "auto/4", "--list", "--json"])
            .env(env.0, env.1)
            .current_dir(repo())
            .output()
            .expect("climbsim");
        assert!(output.status.success(), "{}", text(&output));
        serde_json::from_slice::<serde_json::Value>(&output.stdout).expect("JSON")
    };
    let slurm = list(("SLURM_ARRAY_TASK_ID", "1"));
    assert_eq!(slurm["grid_size"], 6);
    assert_eq!(slurm["shard"]["index"], 2, "task 1 (0-based) is shard 2");
    let indices: Vec<u64> = slurm["points"].as_array().expect("points").iter().map(|p| p["index"].as_u64().expect("index")).collect();
    assert_eq!(indices, [1, 5]);
    assert_eq!(slurm["points"][0]["overrides"]["controller.zeta"], "0.3");
    let kubernetes = list(("JOB_COMPLETION_INDEX", "1"));
    assert_eq!(kubernetes["points"], slurm["points"]);
    let output = climbsim(&["sweep", "scenarios/flat-line.toml", "--set", "controller.zeta=0.3", "--shard", "auto/4", "--list"]);
    assert_eq!(output.status.code(), Some(2), "no task index in the environment: {}", text(&output));
    assert!(text(&output).contains("SLURM_ARRAY_TASK_ID"), "{}", text(&output));
}

#[test]
fn a_malformed_scenario_names_file_line_and_key() {
    let dir = support::scratch_dir("malformed");
    let path = dir.join("typo.toml");
    let scenario = std::fs::read_to_string(repo().join("scenarios/flat-line.toml")).expect("scenario");
    std::fs::write(&path, scenario.replace("frame_rate_hz = 30.0", "frame_rate_hz = 30.0\nframerate = 60")).expect("write");
    let output = climbsim(&["run", &path.display().to_string(), "--out", &dir.join("out").display().to_string()]);
    assert!(!output.status.success());
    let message = text(&output);
    let line = scenario.lines().position(|l| l.starts_with("frame_rate_hz")).expect("line") + 2;
    assert!(message.contains(&format!("typo.toml:{line}:")) && message.contains("framerate"), "{message}");
}

/// The reference external controller (Python, official dynamixel-sdk) follows the line over a
/// real pty and the sensor server, started, timed and stopped by `climbsim run`.
#[test]
fn the_python_reference_controller_follows_the_line_over_a_pty() {
    let out = support::scratch_dir("external");
    // The test runner loads both cores, so the pace is not judged here (tests/external.rs is), and
    // 8 s is too short for the scenario's settling thresholds (`climbsim check` applies them).
    let output = support::climbsim_with_sdk_python(&[
        "run",
        "scenarios/external-line-follower.toml",
        "--set",
        "world.duration_s=8",
        "--set",
        "expect={}",
        "--timing",
        "off",
        "--pace-tolerance-ms",
        "1000",
        "--out",
        &out.display().to_string(),
    ]);
    let log = std::fs::read_to_string(out.join("controller.log")).unwrap_or_default();
    assert!(output.status.success(), "{}\ncontroller.log:\n{log}", text(&output));
    assert!(log.contains("control periods"), "the controller ran and stopped cleanly:\n{log}");
    let csv = read_csv(&out.join("timeseries.csv"));
    let (x, psi, seen) = (column(&csv, "x_m"), column(&csv, "psi_true_rad"), column(&csv, "line_valid"));
    let travelled = x.last().expect("rows") - x[0];
    // 1000 mm/min for 8 s is 133 mm, less the start-up.
    assert!(travelled > 0.06, "the robot moved {travelled} m");
    // Starting 10 mm left of the line, it turned right (negative heading) toward it.
    let most_right = psi.iter().copied().fold(0.0, f64::min);
    assert!(most_right < -0.02, "heading never turned toward the line (min {most_right} rad)");
    assert!(seen.iter().filter(|&&v| v == 1.0).count() * 10 > seen.len() * 9, "the camera saw the line");
}

/// `climbsim serve` with a scenario that has a weld line also serves the camera and the line
/// detector over HTTP, for controllers written against the real robot's sensors.
#[test]
fn serve_with_a_line_starts_the_sensor_server() {
    use std::io::{BufRead, BufReader, Read, Write};
    use std::time::{Duration, Instant};
    let mut child = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["serve", "scenarios/flat-line.toml", "--timing", "off"])
        .current_dir(repo())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("spawn climbsim serve");
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let deadline = Instant::now() + Duration::from_secs(20);
    let url = loop {
        let line = rx.recv_timeout(deadline.saturating_duration_since(Instant::now())).expect("`sensors: URL` on stdout");
        if let Some(url) = line.strip_prefix("sensors: ") {
            break url.trim().to_owned();
        }
    };
    let addr = url.trim_start_matches("http://").to_owned();
    let get = |path: &str| {
        let mut stream = std::net::TcpStream::connect(&addr).expect("connect");
        write!(stream, "GET {path} HTTP/1.1\r\n\r\n").expect("request");
        let mut response = Vec::new();
        stream.read_to_end(&mut response).expect("response");
        response
    };
    // The world runs on the wall clock; the camera delivers its first frame within 1/30 s.
    let mut line = serde_json::Value::Null;
    while Instant::now() < deadline {
        let response = get("/line");
        if let Some(body) = response.windows(4).position(|w| w == b"\r\n\r\n").map(|i| &response[i + 4..])
            && let Ok(value) = serde_json::from_slice::<serde_json::Value>(body)
        {
            line = value;
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let png = get("/camera.png");
    let _ = child.kill();
    let _ = child.wait();
    assert_eq!(line["valid"], true, "{line}");
    // The robot starts 50 mm left of the line: d > 0 (the robot relative to the line, as
    // timeseries.csv's d_m).
    assert!(line["d"].as_f64().is_some_and(|d| (d - 0.05).abs() < 0.003), "{line}");
    assert!(png.starts_with(b"HTTP/1.1 200") && png.windows(4).any(|w| w == b"\x89PNG"), "camera.png");
}

#[test]
fn a_run_stopped_by_sigterm_writes_complete_outputs_of_the_part_it_ran() {
    let out = support::scratch_dir("run-interrupted");
    let out_arg = out.display().to_string();
    // As a user stops it: `timeout` sends SIGTERM to climbsim and then to its process group, two
    // signals a moment apart, which must not cut the writing of the outputs short.
    let output = Command::new("timeout")
        .args(["3", env!("CARGO_BIN_EXE_climbsim"), "run", "scenarios/flat-line.toml", "--out", &out_arg, "--set", "world.duration_s=80000", "--set", "expect={}"])
        .current_dir(repo())
        .output()
        .expect("timeout(1) from coreutils runs climbsim");
    assert_eq!(output.status.code(), Some(124), "timeout stopped it: {}", text(&output));
    assert!(text(&output).contains("interrupted at t ="), "{}", text(&output));
    assert_complete_interrupted_outputs(&out);

    // Two SIGTERMs in quick succession, straight to the process: still complete outputs.
    let out = support::scratch_dir("run-interrupted-twice");
    let child = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["run", "scenarios/flat-line.toml", "--out", &out.display().to_string(), "--set", "world.duration_s=80000", "--set", "expect={}"])
        .current_dir(repo())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start climbsim run");
    std::thread::sleep(std::time::Duration::from_secs(2));
    let pid = nix::unistd::Pid::from_raw(child.id() as i32);
    for _ in 0..2 {
        nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).expect("SIGTERM");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let output = child.wait_with_output().expect("wait");
    assert_eq!(output.status.code(), Some(130), "an interrupted run exits 130: {}", text(&output));
    assert_complete_interrupted_outputs(&out);
}

/// Every output of a run interrupted part-way is there, whole, and says where it stopped.
fn assert_complete_interrupted_outputs(out: &Path) {
    let summary: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("summary.json")).expect("summary.json")).expect("summary is JSON");
    let stopped_at = summary["interrupted_at_s"].as_f64().unwrap_or_else(|| panic!("no interrupted_at_s: {summary}"));
    assert!(stopped_at > 0.0 && stopped_at < 80000.0, "{stopped_at}");
    let series = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv reads back");
    let t = series.column("t_s").expect("t_s");
    assert!(!t.is_empty() && t.last().is_some_and(|&last| last <= stopped_at + 1e-9), "{} rows up to {:?}", t.len(), t.last());
    for file in ["settings.json", "report.xlsx", "distance.png", "speed.png"] {
        assert!(std::fs::metadata(out.join(file)).is_ok_and(|m| m.len() > 0), "{file}");
    }
    assert!(std::fs::read_dir(out).expect("out").all(|e| !e.expect("entry").file_name().to_string_lossy().ends_with(".tmp")));
}

/// Start `climbsim ARGS`, send SIGINT after `after`, and return its output.
fn interrupted(args: &[&str], after: std::time::Duration) -> std::process::Output {
    let child = Command::new(env!("CARGO_BIN_EXE_climbsim")).args(args).current_dir(repo()).stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::piped()).spawn().expect("start climbsim");
    std::thread::sleep(after);
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(child.id() as i32), nix::sys::signal::Signal::SIGINT).expect("SIGINT");
    child.wait_with_output().expect("wait")
}

/// An interrupted `check` still writes its JUnit file, with the interrupted scenario in it; an
/// interrupted `sweep` still writes its table, marking the points it did not finish.
#[test]
fn interrupted_check_and_sweep_write_what_they_have() {
    let dir = support::scratch_dir("interrupted-batch");
    let junit = dir.join("junit.xml");
    let long = dir.join("long-flat-line.toml");
    let scenario = std::fs::read_to_string(repo().join("scenarios/flat-line.toml")).expect("scenario");
    std::fs::write(&long, scenario.replace("duration_s = 120.0", "duration_s = 80000.0")).expect("write");
    let output = interrupted(&["check", &long.display().to_string(), "--junit", &junit.display().to_string(), "--out", &dir.join("check").display().to_string()], std::time::Duration::from_secs(2));
    assert_eq!(output.status.code(), Some(130), "{}", text(&output));
    let xml = std::fs::read_to_string(&junit).expect("junit.xml written on interrupt");
    assert!(xml.contains("flat-line") && xml.contains("interrupted"), "{xml}");

    let sweep = dir.join("sweep");
    let output = interrupted(
        &["sweep", "scenarios/flat-line.toml", "--set", "world.duration_s=80000", "--set", "controller.zeta=0.5,1.0,1.5", "--jobs", "1", "--out", &sweep.display().to_string()],
        std::time::Duration::from_secs(2),
    );
    assert_eq!(output.status.code(), Some(130), "{}", text(&output));
    let table = std::fs::read_to_string(sweep.join("sweep.csv")).expect("sweep.csv written on interrupt");
    assert_eq!(table.lines().count(), 4, "every point has a row: {table}");
    assert!(table.lines().nth(1).is_some_and(|row| row.contains("interrupted")), "{table}");
    assert!(table.lines().skip(2).all(|row| row.contains("not_run")), "{table}");
}

/// A 1 MB tmpfs, unmounted when dropped.
struct TinyDisk(std::path::PathBuf);

impl Drop for TinyDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// A disk that fills up while the outputs are written (the time series fits, the workbook does
/// not) is a clear error, exit 2, with what was written kept: no panic in the xlsx writer.
/// Needs root to mount a tmpfs: `scripts/test.sh` runs it where it is root.
#[test]
#[ignore = "needs root to mount a tmpfs; scripts/test.sh runs it as root"]
fn a_full_disk_is_a_clear_error_keeping_what_was_written() {
    let mount = support::scratch_dir("full-disk");
    let mounted = Command::new("mount").args(["-t", "tmpfs", "-o", "size=1000k", "tmpfs"]).arg(&mount).status().expect("mount");
    assert!(mounted.success(), "cannot mount a tmpfs at {}", mount.display());
    let _disk = TinyDisk(mount.clone());
    let out = mount.join("run");
    let output = climbsim(&["run", "scenarios/flat-line.toml", "--set", "world.duration_s=20", "--set", "capture.mcap=false", "--set", "expect={}", "--out", &out.display().to_string()]);
    let all = text(&output);
    assert_eq!(output.status.code(), Some(2), "{all}");
    assert!(!all.contains("panicked") && all.contains("No space left on device") && all.contains("report.xlsx"), "{all}");
    for kept in ["timeseries.csv", "summary.json", "settings.json"] {
        assert!(out.join(kept).is_file(), "{kept} was not kept: {all}");
    }
}

/// climbsim outside its checkout: from an empty folder, a shipped scenario copied there runs on
/// the robot description built into climbsim (settings.json says so), `export controller`
/// writes the reference controller beside a scenario that names it, and `check` runs that
/// external controller under virtual time from there; `export robot` gives a description that
/// `--robot` takes.
#[test]
fn from_an_empty_folder_climbsim_runs_on_the_files_it_has_built_in() {
    let dir = std::env::temp_dir().join(format!("climbsim-outside-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("an empty folder");
    let in_dir =
        |args: &[&str]| Command::new(env!("CARGO_BIN_EXE_climbsim")).args(args).current_dir(&dir).env("PATH", support::path_with_sdk_python()).env_remove("CLIMBSIM_ROBOT").output().expect("climbsim");
    let shipped = std::fs::read_to_string(repo().join("scenarios/flat-line.toml")).expect("a shipped scenario");
    std::fs::write(dir.join("flat.toml"), shipped.replace("duration_s = 120.0", "duration_s = 5.0")).expect("copied");
    let run = in_dir(&["run", "flat.toml", "--set", "expect={}", "--out", "out"]);
    assert!(run.status.success(), "{}", text(&run));
    let settings = std::fs::read_to_string(dir.join("out/settings.json")).expect("settings.json");
    assert!(settings.contains("\"embedded:hil/robot.toml\""), "the built-in robot, named as such: {settings}");

    let default = in_dir(&["run", "--set", "world.duration_s=2", "--set", "expect={}", "--out", "default"]);
    assert!(default.status.success(), "{}", text(&default));
    assert!(std::fs::read_to_string(dir.join("default/settings.json")).expect("settings.json").contains("embedded:scenarios/flat-line.toml"), "run's default scenario, built in");

    let exported = in_dir(&["export", "controller", "."]);
    assert!(exported.status.success() && String::from_utf8_lossy(&exported.stdout).contains("line_follower.py"), "{}", text(&exported));
    let again = in_dir(&["export", "controller", "."]);
    assert_eq!(again.status.code(), Some(2), "not overwritten (bad input): {}", text(&again));
    assert!(text(&again).contains("--force"), "{}", text(&again));
    let external = std::fs::read_to_string(repo().join("scenarios/external-line-follower.toml")).expect("the external scenario");
    let (external, _expect) = external.split_once("[expect]").expect("it has expectations");
    let external = external.replace("\"../hil/controllers/line_follower.py\"", "\"./line_follower.py\"").replace("duration_s = 40.0", "duration_s = 4.0");
    std::fs::write(dir.join("external.toml"), format!("{external}[expect]\n\"controller.period_p50_ms\" = {{ max = 22.0 }}\n")).expect("written");
    let check = in_dir(&["check", "external.toml", "--out", "checked"]);
    assert!(check.status.success(), "{}\n{}", text(&check), std::fs::read_to_string(dir.join("checked/external/controller.log")).unwrap_or_default());

    let robot = in_dir(&["export", "robot", "my-robot"]);
    assert!(robot.status.success(), "{}", text(&robot));
    let with_file = in_dir(&["run", "flat.toml", "--robot", "my-robot/robot.toml", "--set", "expect={}", "--set", "robot.wheel.friction=0.5", "--out", "out2"]);
    assert!(with_file.status.success(), "{}", text(&with_file));
    assert!(std::fs::read_to_string(dir.join("out2/settings.json")).expect("settings.json").contains("my-robot/robot.toml"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A built-in robot by name, from a folder with no checkout: `serve --robot koch-follower`
/// serves LeRobot's Koch follower bus from the files climbsim has built in (each servo its own
/// model, at 1 Mbps); a name no robot has is refused with the names there are.
#[test]
fn a_built_in_robot_is_served_by_name_from_any_folder() {
    use std::io::{BufRead, BufReader};
    let dir = std::env::temp_dir().join(format!("climbsim-named-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("an empty folder");
    /// Ends climbsim whatever the test does (a failed assert would leave it serving).
    struct Served(std::process::Child);
    impl Drop for Served {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let mut serve = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["serve", "--robot", "koch-follower", "--link", "ttyKoch"])
        .current_dir(&dir)
        .env_remove("CLIMBSIM_ROBOT")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .map(Served)
        .expect("climbsim serve");
    let mut lines = BufReader::new(serve.0.stdout.take().expect("stdout"));
    let mut first = String::new();
    lines.read_line(&mut first).expect("a line");
    let port = first.strip_prefix("port: ").map(str::trim).unwrap_or_else(|| panic!("not a port line: {first:?}"));
    let port = support::open_raw_port(&dir.join(port), nix::sys::termios::BaudRate::B1000000);
    let mut reply = [0u8; 14];
    for (id, model) in [(1u8, 1060u16), (6, 1200)] {
        let mut ping = vec![0xFF, 0xFF, 0xFD, 0x00, id, 0x03, 0x00, 0x01];
        let crc = climbsim::protocol::crc16(&ping);
        ping.extend_from_slice(&crc.to_le_bytes());
        support::round_trip(&port, &ping, reply.len(), &mut reply);
        assert_eq!((reply[4], u16::from_le_bytes([reply[9], reply[10]])), (id, model), "ping of {id}: {reply:02X?}");
    }
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(serve.0.id() as i32), nix::sys::signal::Signal::SIGTERM).expect("SIGTERM");
    assert!(serve.0.wait().expect("ends").success());

    let unknown = Command::new(env!("CARGO_BIN_EXE_climbsim")).args(["serve", "--robot", "koch-lead", "--link", "ttyX"]).current_dir(&dir).env_remove("CLIMBSIM_ROBOT").output().expect("climbsim");
    assert_eq!(unknown.status.code(), Some(2), "{}", text(&unknown));
    assert!(text(&unknown).contains("koch-lead:") && text(&unknown).contains("koch-follower, koch-leader"), "names the robots there are: {}", text(&unknown));
    let _ = std::fs::remove_dir_all(&dir);
}
