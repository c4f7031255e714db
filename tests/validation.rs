//! Bad scenario values are load errors that name the file, line, key and unit (exit 2), never a
//! panic or a hang; a world the run cannot happen in fails the run (exit 1) with the reason.

use std::path::{Path, PathBuf};

mod support;

use support::{climbsim, output_text as text, repo};

/// `flat-line.toml` with `replace` applied to its text, written into `dir`.
fn variant(dir: &Path, name: &str, replace: &[(&str, &str)]) -> PathBuf {
    let mut scenario = std::fs::read_to_string(repo().join("scenarios/flat-line.toml")).expect("flat-line.toml");
    for (from, to) in replace {
        assert!(scenario.contains(from), "flat-line.toml has no `{from}`");
        scenario = scenario.replacen(from, to, 1);
    }
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, scenario).expect("write");
    path
}

fn assert_refused(output: &std::process::Output, what: &str, must_contain: &[&str]) {
    let all = text(output);
    assert_eq!(output.status.code(), Some(2), "{what}: {all}");
    assert!(!all.contains("panicked"), "{what}: {all}");
    for needle in must_contain {
        assert!(all.contains(needle), "{what}: no `{needle}` in: {all}");
    }
}

#[test]
fn every_bad_number_is_refused_naming_key_and_unit() {
    let dir = support::scratch_dir("bad-numbers");
    let out = dir.join("out").display().to_string();
    for (set, key, unit) in [
        ("world.duration_s=-1", "world.duration_s", " s "),
        ("world.duration_s=nan", "world.duration_s", " s "),
        ("world.duration_s=inf", "world.duration_s", " s "),
        ("world.duration_s=1e30", "world.duration_s", " s "),
        ("controller.period_s=0", "controller.period_s", " s "),
        ("controller.period_s=-0.02", "controller.period_s", " s "),
        ("controller.zeta=nan", "controller.zeta", "outside"),
        ("world.payload_kg=-1", "world.payload_kg", "kg"),
        ("world.gravity_m_s2=[0, nan, 0]", "world.gravity_m_s2[1]", "m/s²"),
        ("world.solver.iterations=100000", "world.solver.iterations", "solver iterations"),
        ("speed.target_mm_min=1e9", "speed.target_mm_min", "mm/min"),
        ("camera.frame_rate_hz=0", "camera.frame_rate_hz", "Hz"),
    ] {
        let output = climbsim(&["run", "scenarios/flat-line.toml", "--set", set, "--out", &out]);
        assert_refused(&output, set, &[key, unit, "--set"]);
    }
}

#[test]
fn a_bad_number_in_the_file_names_its_line() {
    let dir = support::scratch_dir("bad-number-line");
    let path = variant(&dir, "negative", &[("duration_s = 120.0", "duration_s = -1")]);
    let line = std::fs::read_to_string(&path).expect("read").lines().position(|l| l.starts_with("duration_s")).expect("line") + 1;
    let output = climbsim(&["run", &path.display().to_string(), "--out", &dir.join("out").display().to_string()]);
    assert_refused(&output, "duration_s = -1", &[&format!("negative.toml:{line}:"), "world.duration_s", "-1 s"]);
}

/// A mistake in the second of several `[[obstacles]]` or `[[welds]]` is named by its own key and
/// line, not blamed on the first one's header (obstacles) or on `[line]` with no line (welds).
#[test]
fn a_bad_entry_in_an_array_of_tables_names_its_own_line_and_key() {
    let dir = support::scratch_dir("validation-arrays");
    let base = std::fs::read_to_string(repo().join("scenarios/flat-line.toml")).expect("flat-line.toml");
    let obstacles = "\n[[obstacles]]\nkind = \"box\"\nat_m = [1.0, -0.05]\nsize_m = [0.1, 0.3, 0.6]\n\n[[obstacles]]\nkind = \"box\"\nat_m = [2.0, -0.05]\nsize_m = [0.1, 0.3, 0.6]\ncolour = 3\n";
    let path = dir.join("obstacles.toml");
    let written = format!("{base}{obstacles}");
    std::fs::write(&path, &written).expect("write");
    let line = written.lines().position(|l| l.starts_with("colour")).expect("colour") + 1;
    let output = climbsim(&["run", &path.display().to_string(), "--out", &dir.join("out").display().to_string()]);
    assert_refused(&output, "unknown key in the second obstacle", &[&format!("obstacles.toml:{line}:"), "colour"]);

    let welds = "\n[[welds]]\npoints = [[0.0, 1.0], [3.0, 1.0]]\n\n[[welds]]\npoints = [[0.0, 2.0], [0.0, 2.0]]\n";
    let path = dir.join("welds.toml");
    let written = format!("{base}{welds}");
    std::fs::write(&path, &written).expect("write");
    let line = written.lines().position(|l| l.starts_with("points = [[0.0, 2.0]")).expect("second weld") + 1;
    let output = climbsim(&["run", &path.display().to_string(), "--out", &dir.join("out").display().to_string()]);
    assert_refused(&output, "a second weld of one point", &["welds[1]", "welds.toml:"]);
    let all = text(&output);
    let reported: usize = all.split("welds.toml:").nth(1).and_then(|rest| rest.split(':').next()).and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("no line in {all}"));
    assert!((line - 1..=line).contains(&reported), "the second weld is at line {line} (its header just above), reported {reported}: {all}");
}

#[test]
fn a_fault_beyond_any_run_or_on_a_missing_servo_is_refused() {
    let out = support::scratch_dir("bad-fault").join("out").display().to_string();
    let output = climbsim(&["run", "scenarios/flat-line.toml", "--fault", "overload:id=2,at=1e30", "--out", &out]);
    assert_refused(&output, "at=1e30", &["overload", "at"]);
    let output = climbsim(&["run", "scenarios/flat-line.toml", "--fault", "overload:id=12,at=1", "--out", &out]);
    assert_refused(&output, "id=12", &["servo ID 12 is not on the robot's bus"]);
}

#[test]
fn moving_a_line_that_is_not_there_is_refused() {
    let dir = support::scratch_dir("no-line-to-move");
    let mut scenario = std::fs::read_to_string(repo().join("scenarios/floor-to-wall.toml")).expect("floor-to-wall.toml");
    scenario.push_str("\n[[events]]\nat_s = 1.0\nline_offset_m = 0.01\n");
    let path = dir.join("moves.toml");
    std::fs::write(&path, scenario).expect("write");
    let output = climbsim(&["serve", &path.display().to_string()]);
    assert_refused(&output, "a line offset without a line", &["events[0].line_offset_m", "no [line]"]);
}

#[test]
fn sweep_refuses_a_bad_grid_point_before_any_run() {
    let dir = support::scratch_dir("bad-grid");
    let out = dir.join("sweep");
    let output = climbsim(&["sweep", "scenarios/flat-line.toml", "--set", "world.duration_s=1,-1", "--out", &out.display().to_string()]);
    assert_refused(&output, "duration_s=-1 in a grid", &["world.duration_s", "-1"]);
    let runs = std::fs::read_dir(&out).map(|entries| entries.count()).unwrap_or(0);
    assert_eq!(runs, 0, "no point ran before the bad one was found");
}

#[test]
fn sweep_refuses_a_bad_robot_key_in_its_grid_before_any_run_naming_it() {
    let dir = support::scratch_dir("bad-robot-grid");
    let out = dir.join("sweep");
    let output = climbsim(&["sweep", "scenarios/flat-line.toml", "--set", "robot.wheel.friction=0.5,\"x\"", "--out", &out.display().to_string()]);
    assert_refused(&output, "a friction that is not a number", &["--set robot.wheel.friction=\"x\"", "robot description"]);
    let output = climbsim(&["run", "scenarios/flat-line.toml", "--set", "profile.motor.no_such_key=1", "--out", &dir.join("run").display().to_string()]);
    assert_refused(&output, "a profile key the profile lacks", &["--set profile.motor.no_such_key=1", "unknown field `no_such_key`"]);
    let runs = std::fs::read_dir(&out).map(|entries| entries.count()).unwrap_or(0);
    assert_eq!(runs, 0, "no point ran before the bad one was found");
    // serve: a robot key it lacks, and a scenario key on the bench, before anything is served.
    let output = climbsim(&["serve", "--set", "robot.wheel.frction=0.3"]);
    assert_refused(&output, "a misspelt robot key on serve", &["--set robot.wheel.frction=0.3", "unknown field `frction`"]);
    let output = climbsim(&["serve", "--set", "world.seed=2"]);
    assert_refused(&output, "a scenario key on the bench", &["--set world.seed=2", "serve has no scenario"]);
}

#[test]
fn a_start_off_the_terrain_is_refused() {
    let dir = support::scratch_dir("start-off");
    let path =
        variant(&dir, "off", &[("size_m = 10.0", "size_m = 1.0"), ("points = [[-0.5, 0.0], [3.0, 0.0]]", "points = [[-0.45, 0.0], [0.45, 0.0]]"), ("line_offset_m = 0.05", "line_offset_m = 0.45")]);
    let output = climbsim(&["run", &path.display().to_string(), "--out", &dir.join("out").display().to_string()]);
    assert_refused(&output, "start off the terrain", &["starts off the terrain"]);
}

/// Driving off the edge of a 1 m plate: the run stops about a second after the last wheel
/// left it, fails, and still writes every output.
#[test]
fn a_robot_that_falls_off_the_terrain_fails_the_run() {
    let dir = support::scratch_dir("falls-off");
    let path = variant(
        &dir,
        "edge",
        &[
            ("size_m = 10.0", "size_m = 1.0"),
            ("points = [[-0.5, 0.0], [3.0, 0.0]]", "points = [[-0.4, 0.0], [0.45, 0.0]]"),
            ("x_m = 0.5", "x_m = 0.6"),
            ("target_mm_min = 1000.0", "target_mm_min = 3000.0"),
            ("duration_s = 120.0", "duration_s = 30.0"),
        ],
    );
    let out = dir.join("out");
    let output = climbsim(&["run", &path.display().to_string(), "--out", &out.display().to_string()]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    let summary: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("summary.json")).expect("summary")).expect("json");
    let failures = summary["failures"].as_array().expect("failures");
    assert!(failures.iter().any(|f| f.as_str().is_some_and(|f| f.starts_with("world:"))), "{summary}");
    let at = summary["failure_at_s"].as_f64().expect("failure_at_s");
    assert!(at < 20.0, "the run stopped at the fall, t = {at} s, not at its end");
    assert!(out.join("timeseries.csv").exists() && out.join("report.xlsx").exists());
}

/// The heaviest solver the scenario allows still stops soon after Ctrl-C: the run checks for a
/// stop request between physics steps, and the iteration counts are bounded so a step stays short.
#[test]
fn the_heaviest_solver_still_stops_on_sigint() {
    let dir = support::scratch_dir("heavy-solver");
    let out = dir.join("out");
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["run", "scenarios/flat-line.toml", "--set", "world.solver.iterations=100", "--set", "world.solver.internal_iterations=100", "--set", "expect={}", "--out", &out.display().to_string()])
        .current_dir(repo())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start climbsim run");
    std::thread::sleep(std::time::Duration::from_millis(1500));
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(child.id() as i32), nix::sys::signal::Signal::SIGINT).expect("SIGINT");
    let asked = std::time::Instant::now();
    let output = child.wait_with_output().expect("wait");
    let took = asked.elapsed();
    assert_eq!(output.status.code(), Some(130), "{}", String::from_utf8_lossy(&output.stderr));
    // Generous for a debug build on a loaded machine; before the bound a single step could take
    // minutes (1000 × 1000 iterations).
    assert!(took < std::time::Duration::from_secs(10), "stopped {took:?} after SIGINT");
    assert!(out.join("summary.json").exists());
}
