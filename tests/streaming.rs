//! A run's outputs as a long run needs them: memory that does not grow with simulated time,
//! summary metrics that do not depend on `[capture] rate_hz`, settings that record everything
//! that shaped the run, and one sign for the distance error `d` everywhere.

use std::path::Path;
use std::process::Command;

mod support;

use serde_json::Value;
use support::{climbsim, output_text as text, repo, scratch_dir};

fn read_json(path: &Path) -> Value {
    let body = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&body).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `climbsim run scenarios/flat-line.toml --set ...` into a fresh folder; the folder.
fn run_flat_line(name: &str, sets: &[&str]) -> std::path::PathBuf {
    let out = scratch_dir(name);
    let out_arg = out.display().to_string();
    let mut args = vec!["run", "scenarios/flat-line.toml", "--out", &out_arg, "--set", "expect={}"];
    for set in sets {
        args.extend(["--set", set]);
    }
    let output = climbsim(&args);
    assert!(output.status.success(), "{}", text(&output));
    out
}

/// The metric keys of a summary (what the run measured, not how fast the machine was).
fn metrics(summary: &Value) -> serde_json::Map<String, Value> {
    let mut map = summary.as_object().expect("a JSON object").clone();
    map.remove("realtime_factor");
    map
}

#[test]
fn summary_metrics_do_not_depend_on_the_capture_rate() {
    let reference = metrics(&read_json(&run_flat_line("rate-50", &["world.duration_s=8"]).join("summary.json")));
    assert!(reference.contains_key("distance.rise_time_s") && reference.contains_key("speed.rise_time_s"), "{reference:?}");
    for rate in ["1", "0.1"] {
        let out = run_flat_line(&format!("rate-{rate}"), &["world.duration_s=8", &format!("capture.rate_hz={rate}")]);
        assert_eq!(metrics(&read_json(&out.join("summary.json"))), reference, "summary at {rate} Hz differs from 50 Hz");
        // The CSV keeps the rate asked for.
        let rows = std::fs::read_to_string(out.join("timeseries.csv")).expect("timeseries.csv").lines().count() - 1;
        let expected = (8.0 * rate.parse::<f64>().expect("rate")).ceil() as usize;
        assert!(rows.abs_diff(expected) <= 1, "{rows} rows at {rate} Hz for 8 s");
    }
}

#[test]
fn a_capture_rate_above_the_control_rate_is_refused_by_name() {
    let out = scratch_dir("rate-100");
    let output = climbsim(&["run", "scenarios/flat-line.toml", "--out", &out.display().to_string(), "--set", "world.duration_s=1", "--set", "capture.rate_hz=100"]);
    assert!(!output.status.success(), "a 100 Hz capture in lockstep was silently capped: {}", text(&output));
    let stderr = String::from_utf8_lossy(&output.stderr);
    for needle in ["flat-line.toml", "[capture] rate_hz", "100 Hz", "50 Hz"] {
        assert!(stderr.contains(needle), "`{needle}` not in: {stderr}");
    }
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn settings_record_everything_that_shaped_the_run() {
    let sets = ["world.duration_s=1", "world.payload_kg=1.5", "world.friction=0.6", "capture.rate_hz=25"];
    let out = run_flat_line("settings", &sets);
    let settings = read_json(&out.join("settings.json"));
    let overrides: Vec<&str> = settings["overrides"].as_array().expect("overrides").iter().map(|v| v.as_str().expect("text")).collect();
    assert_eq!(overrides, ["expect={}", sets[0], sets[1], sets[2], sets[3]]);
    assert_eq!(settings["camera"]["image_px"], 128);
    assert_eq!(settings["camera"]["frame_rate_hz"], 30.0);
    assert_eq!(settings["start"]["line_offset_m"].as_f64().map(|v| (v - 0.05).abs() < 1e-6), Some(true), "{settings}");
    assert!(settings["start"]["pose"]["yaw_deg"].is_number(), "{settings}");
    assert_eq!(settings["payload_kg"], 1.5);
    assert_eq!(settings["friction"].as_f64().map(|v| (v - 0.6).abs() < 1e-6), Some(true), "{settings}");
    assert_eq!(settings["magnets"], true);
    assert_eq!(settings["solver"]["iterations"], climbsim::sim::SolverSettings::default().iterations.get());
    assert_eq!(settings["capture"]["rate_hz"], 25.0);
    assert_eq!(settings["capture"]["on_line_tolerance_m"], 0.002);

    // The workbook's Settings sheet has the same leaves.
    use calamine::{Reader, Xlsx, open_workbook};
    let mut workbook: Xlsx<_> = open_workbook(out.join("report.xlsx")).expect("report.xlsx");
    let sheet = workbook.worksheet_range("Settings").expect("Settings sheet");
    let rows: Vec<(String, String)> = sheet.rows().map(|r| (r[0].to_string(), r.get(1).map(ToString::to_string).unwrap_or_default())).collect();
    for (key, value) in [("overrides[2]", "world.payload_kg=1.5"), ("camera.image_px", "128"), ("capture.rate_hz", "25"), ("payload_kg", "1.5"), ("magnets", "true")] {
        assert!(rows.iter().any(|(k, v)| k == key && v.eq_ignore_ascii_case(value)), "no `{key} | {value}` in the Settings sheet: {rows:?}");
    }
}

/// An "external controller" that only reads the sensor server: it prints every `/line` answer,
/// so the test can set them beside the CSV of the same run.
// `r##`: the probe holds `"#` (an f-string starting with `#`), which would end an `r#` string.
const LINE_PROBE: &str = r##"
import json, os, sys, time, urllib.request
url = os.environ["CLIMBSIM_SENSORS"] + "/line"
while True:
    try:
        with urllib.request.urlopen(url, timeout=0.5) as response:
            print(json.dumps(json.load(response)), flush=True)
    except Exception as error:
        print(f"# {error}", file=sys.stderr, flush=True)
    time.sleep(0.1)
"##;

#[test]
fn the_line_endpoint_and_the_csv_agree_on_the_sign_of_d() {
    let dir = scratch_dir("line-sign");
    let probe = dir.join("probe.py");
    std::fs::write(&probe, LINE_PROBE).expect("probe");
    // The robot stands 30 mm left of the line (d = +0.03) with its torque off: it does not move.
    let scenario = std::fs::read_to_string(repo().join("scenarios/external-line-follower.toml")).expect("scenario");
    let scenario = scenario
        .replace("line_offset_m = 0.01", "line_offset_m = 0.03")
        .lines()
        .map(|line| if line.starts_with("command") { format!("command = [\"python3\", {:?}]", probe.display().to_string()) } else { line.to_owned() })
        .collect::<Vec<_>>()
        .join("\n");
    let scenario_path = dir.join("probe.toml");
    std::fs::write(&scenario_path, scenario).expect("scenario");
    let out = dir.join("out");
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["run", &scenario_path.display().to_string(), "--set", "world.duration_s=8", "--set", "expect={}", "--timing", "off", "--pace-tolerance-ms", "1000", "--out", &out.display().to_string()])
        .current_dir(repo())
        .output()
        .expect("run climbsim");
    assert!(output.status.success(), "{}", text(&output));
    let log = std::fs::read_to_string(out.join("controller.log")).expect("controller.log");
    let answers: Vec<Value> = log.lines().filter_map(|l| serde_json::from_str(l).ok()).filter(|v: &Value| v["valid"] == true).collect();
    // 8 s: a loaded machine once took the 3 s this run used to last just to start Python.
    assert!(answers.len() >= 5, "too few valid /line answers: {log}");
    let csv = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv");
    let (t, d) = (csv.column("t_s").expect("t_s"), csv.column("d_m").expect("d_m"));
    for answer in &answers {
        let (at, line_d) = (answer["t"].as_f64().expect("t"), answer["d"].as_f64().expect("d"));
        let nearest = (0..t.len()).min_by(|&a, &b| (t[a] - at).abs().total_cmp(&(t[b] - at).abs())).expect("rows");
        assert!((line_d - d[nearest]).abs() < 0.005, "/line d = {line_d} at {at} s but timeseries.csv d_m = {} at {} s", d[nearest], t[nearest]);
        assert!(line_d > 0.02, "the robot is left of the line: d must be positive, /line says {line_d}");
    }
}

/// Peak resident set size (kB) of `climbsim ARGS`, by `/usr/bin/time`.
fn peak_rss_kb(args: &[&str]) -> u64 {
    let output = Command::new("/usr/bin/time").args(["-f", "peak_rss_kb=%M", env!("CARGO_BIN_EXE_climbsim")]).args(args).current_dir(repo()).output().expect("/usr/bin/time (GNU time) runs climbsim");
    assert!(output.status.success(), "{}", text(&output));
    let stderr = String::from_utf8_lossy(&output.stderr);
    stderr.lines().rev().find_map(|l| l.strip_prefix("peak_rss_kb=")).and_then(|v| v.trim().parse().ok()).unwrap_or_else(|| panic!("no peak RSS in: {stderr}"))
}

#[test]
fn memory_does_not_grow_with_simulated_time() {
    let peak = |seconds: u32| {
        let out = scratch_dir(&format!("memory-{seconds}"));
        peak_rss_kb(&["run", "scenarios/flat-line.toml", "--out", &out.display().to_string(), "--set", "expect={}", "--set", &format!("world.duration_s={seconds}")])
    };
    let (short, long) = (peak(10), peak(130));
    // Before streaming the series grew ~0.46 MB per simulated second (~55 MB over these 120 s).
    assert!(long < short + 12_000, "peak RSS {short} kB at 10 s but {long} kB at 130 s");
}
