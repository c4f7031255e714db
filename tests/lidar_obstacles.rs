//! Obstacles stand on the terrain as real colliders: the LIDAR sees them at the distance the
//! geometry says, the robot cannot drive through them, and both show in the recording and on
//! the sensor server.

use std::path::{Path, PathBuf};
use std::process::Command;

use foxglove::Decode;
use foxglove::messages::{LaserScan, SceneUpdate};

mod support;

/// A plate of steel across the robot's path: its near face 0.95 m ahead of the robot's centre.
const PLATE: &str = "
[[obstacles]]
kind = \"box\"
at_m = [1.0, -0.05]
size_m = [0.1, 0.3, 0.6]

[lidar]
beams = 91
fov_deg = 180.0
range_m = 3.0
rate_hz = 10.0
noise_std_m = 0.002
";

/// `flat-line.toml` with the plate and a LIDAR.
fn scenario(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(support::repo().join("scenarios/flat-line.toml")).expect("flat-line.toml") + PLATE;
    let path = dir.join("plate.toml");
    std::fs::write(&path, text).expect("write");
    path
}

fn run(dir: &Path, extra: &[&str]) -> PathBuf {
    let out = dir.join("out");
    let scenario = scenario(dir);
    let mut args = vec!["run".to_owned(), scenario.display().to_string(), "--set".to_owned(), "expect={}".to_owned(), "--out".to_owned(), out.display().to_string()];
    args.extend(extra.iter().map(|a| (*a).to_owned()));
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim")).args(&args).current_dir(support::repo()).output().expect("climbsim");
    assert!(output.status.success(), "{}", support::output_text(&output));
    out
}

#[test]
fn the_lidar_measures_the_plate_ahead_as_the_robot_closes_in() {
    let dir = support::scratch_dir("lidar-plate");
    let out = run(&dir, &["--set", "world.duration_s=10"]);
    let csv = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv");
    let (x, ahead, nearest) = (csv.column("x_m").expect("x"), csv.column("lidar_ahead_m").expect("ahead"), csv.column("lidar_nearest_m").expect("nearest"));
    // The line runs along x, so the heading error is the robot's yaw.
    let yaw = csv.column("psi_true_rad").expect("psi");
    // The LIDAR sits 80 mm ahead of the middle section's centre (hil/robot.toml).
    let rows: Vec<usize> = (0..x.len()).filter(|&i| ahead[i].is_finite()).collect();
    assert!(rows.len() > x.len() * 9 / 10, "a scan from the first tenth of a second on");
    let moved = x[rows[rows.len() - 1]] - x[rows[0]];
    assert!(moved > 0.1, "the robot drove {moved} m toward the plate");
    for &i in &rows {
        // The beam straight ahead meets the plate's face obliquely when the robot turns toward
        // the line. The scan is at most 100 ms old: the robot moves < 2 mm in that time.
        let expected = (0.95 - x[i]) / yaw[i].cos() - 0.08;
        assert!((ahead[i] - expected).abs() < 0.02, "t row {i}: ahead {} m, geometry says {expected} m", ahead[i]);
        assert!(nearest[i] <= ahead[i] + 1e-9);
    }

    let bytes = std::fs::read(out.join("run.mcap")).expect("run.mcap");
    let messages: Vec<mcap::Message> = mcap::MessageStream::new(&bytes).expect("stream").map(|m| m.expect("message")).collect();
    let scans: Vec<&mcap::Message> = messages.iter().filter(|m| m.channel.topic == "/lidar").collect();
    assert!((99..=101).contains(&scans.len()), "{} scans in 10 s at 10 Hz", scans.len());
    let scan = LaserScan::decode(&scans[0].data[..]).expect("LaserScan");
    assert_eq!(scan.ranges.len(), 91);
    assert!((scan.start_angle + std::f64::consts::FRAC_PI_2).abs() < 1e-6 && (scan.end_angle - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
    assert_eq!(scan.frame_id, "middle");
    let terrain = messages.iter().find(|m| m.channel.topic == "/scene/terrain").expect("terrain scene");
    let terrain = SceneUpdate::decode(&terrain.data[..]).expect("SceneUpdate");
    let plate = terrain.entities.iter().find(|e| e.id == "obstacles").expect("obstacles entity");
    assert_eq!(plate.cubes.len(), 1);
    let size = plate.cubes[0].size.expect("size");
    assert!((size.x - 0.1).abs() < 1e-6 && (size.y - 0.3).abs() < 1e-6 && (size.z - 0.6).abs() < 1e-6, "{size:?}");
}

#[test]
fn the_robot_cannot_drive_through_the_plate() {
    let dir = support::scratch_dir("plate-stop");
    // At 100 mm/s the robot would be 1.4 m on after 14 s; the plate's face is 0.95 m ahead.
    let out = run(&dir, &["--set", "world.duration_s=14", "--set", "speed.target_mm_min=6000", "--set", "capture.mcap=false"]);
    let csv = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv");
    let x = csv.column("x_m").expect("x");
    let furthest = x.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    // The front section reaches 0.18 m ahead of the centre, its wheels 0.2 m.
    assert!(furthest > 0.6 && furthest < 0.95 - 0.17, "the robot's centre got to {furthest} m");
    // Pressed against the plate by its front wheels, the LIDAR 80 mm ahead of the centre reads
    // the rest of the way.
    let (ahead, last) = (csv.column("lidar_ahead_m").expect("ahead"), x.len() - 1);
    assert!((ahead[last] - (0.95 - 0.08 - x[last])).abs() < 0.02, "LIDAR {} m with the centre at {} m", ahead[last], x[last]);
}

#[test]
fn an_obstacle_off_the_terrain_and_bad_lidar_settings_are_refused_by_name() {
    let dir = support::scratch_dir("bad-obstacle");
    let path = scenario(&dir);
    for (set, needle) in [("obstacles[0].size_m[1]=-1", "obstacles[0].size_m[1]"), ("lidar.beams=0", "lidar.beams"), ("lidar.min_range_m=10", "lidar.min_range_m")] {
        let output = support::climbsim(&["run", &path.display().to_string(), "--set", set, "--out", &dir.join("out").display().to_string()]);
        assert_eq!(output.status.code(), Some(2), "{set}: {}", support::output_text(&output));
        assert!(support::output_text(&output).contains(needle), "{set}: {}", support::output_text(&output));
    }
    let text = std::fs::read_to_string(&path).expect("read").replace("at_m = [1.0, -0.05]", "at_m = [40.0, 0.0]");
    std::fs::write(&path, text).expect("write");
    let output = support::climbsim(&["run", &path.display().to_string(), "--out", &dir.join("out").display().to_string()]);
    assert_eq!(output.status.code(), Some(2), "{}", support::output_text(&output));
    assert!(support::output_text(&output).contains("obstacles[0]: no terrain below"), "{}", support::output_text(&output));
    // A tall box where the robot starts: the robot would stand on it, 100 m up.
    let text = std::fs::read_to_string(&path).expect("read").replace("at_m = [40.0, 0.0]", "at_m = [0.0, 0.0]").replace("size_m = [0.1, 0.3, 0.6]", "size_m = [1.0, 100.0, 1.0]");
    std::fs::write(&path, text).expect("write");
    let output = support::climbsim(&["run", &path.display().to_string(), "--out", &dir.join("out").display().to_string()]);
    assert_eq!(output.status.code(), Some(2), "{}", support::output_text(&output));
    assert!(support::output_text(&output).contains("obstacles[0] stands where the robot starts"), "{}", support::output_text(&output));
}

#[test]
fn serve_gives_the_scans_to_an_external_controller() {
    let dir = support::scratch_dir("lidar-serve");
    let serve = support::Options::default().sensors().start(&[&scenario(&dir).display().to_string()]);
    std::thread::sleep(std::time::Duration::from_millis(500));
    let scan = support::get_json(serve.sensors(), "/lidar");
    serve.finish();
    let ranges = scan["ranges_m"].as_array().expect("ranges");
    assert_eq!(ranges.len(), 91, "{scan}");
    // The robot stands still (torque off): the plate is 0.87 m ahead of the LIDAR.
    assert!((ranges[45].as_f64().expect("a return ahead") - 0.87).abs() < 0.02, "{scan}");
    assert!(ranges[0].is_null() || ranges[0].as_f64().is_some_and(|r| r > 0.5), "{scan}");
    assert!(scan["t"].as_f64().is_some_and(|t| t > 0.0) && scan["pose"]["position"].as_array().is_some_and(|p| p.len() == 3), "{scan}");
}
