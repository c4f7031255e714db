//! The seed's wall transition on a line painted across floor, fillet and wall: the built-in
//! controller's phases, what it does with the front magnet servos, and where the robot ends up.
//! (`climbsim check scenarios/` checks the scenario's thresholds; this checks how it got there.)

use std::process::Command;

mod support;

#[test]
fn the_seeds_scheme_squares_up_turns_the_front_magnets_lets_them_go_and_follows_the_line_up_the_wall() {
    let dir = support::scratch_dir("wall-transition");
    let out = dir.join("out");
    let scenario = support::repo().join("scenarios/floor-to-wall-line.toml");
    // 70 s: the transition completes at about 57 s.
    let args = ["run", &scenario.display().to_string(), "--set", "world.duration_s=70", "--set", "expect={}", "--set", "capture.mcap=false", "--out", &out.display().to_string()];
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim")).args(args).current_dir(support::repo()).output().expect("climbsim");
    assert!(output.status.success(), "{}", support::output_text(&output));
    let csv = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv");
    let column = |name: &str| csv.column(name).unwrap_or_else(|| panic!("no column {name}"));
    let (t, phase, ahead) = (column("t_s"), column("transition_phase"), column("lidar_ahead_m"));
    let (magnet_fl, magnet_fr, x, y) = (column("magnet_angle_fl_rad"), column("magnet_angle_fr_rad"), column("x_m"), column("y_m"));
    let (valid, d_true) = (column("line_valid"), column("d_true_m"));

    // The phases come in order, each at its LIDAR range (one control period's travel late at most).
    let first = |p: f64| phase.iter().position(|&v| v == p).unwrap_or_else(|| panic!("phase {p} never came: {phase:?}"));
    let (squaring, climbing, done) = (first(1.0), first(2.0), first(3.0));
    assert!(phase.windows(2).all(|w| w[1] >= w[0]), "the phases never go back");
    assert!(squaring < climbing && climbing < done);
    assert!(ahead[squaring - 1] > 0.45 && ahead[squaring] <= 0.45 + 0.01, "squaring at {} m", ahead[squaring]);
    assert!(ahead[climbing] <= 0.21 + 0.01, "climbing at {} m", ahead[climbing]);

    // While held, the front magnets stand at 30° forward of straight down (the servo's position
    // loop, after its first second); both sides alike.
    let settled = t.iter().position(|&ti| ti > t[climbing] + 1.0).expect("a second after the turn");
    for k in settled..done {
        for (side, angle) in [("left", magnet_fl[k]), ("right", magnet_fr[k])] {
            assert!((angle.to_degrees() - 30.0).abs() < 3.0, "front {side} magnet at {:.1}° at t = {:.2} s", angle.to_degrees(), t[k]);
        }
    }
    // Let go, they turn with the fillet until the front section stands on the wall: back to
    // straight down in their section (the wall's normal), within 3°.
    let end = t.len() - 1;
    assert!(magnet_fl[end].abs().to_degrees() < 3.0 && magnet_fr[end].abs().to_degrees() < 3.0, "{} {}", magnet_fl[end], magnet_fr[end]);

    // The robot ends up the wall (its face at x = 0.5 m): 50 mm of wheel plus 10 mm of axle drop
    // in front of it, above the fillet's 150 mm, still on the line the camera sees there.
    assert!((x[end] - 0.44).abs() < 0.005 && y[end] > 0.3, "end at x = {}, y = {}", x[end], y[end]);
    assert!(valid[end] == 1.0 && d_true[end].abs() < 0.005, "line seen {}, d = {} m", valid[end], d_true[end]);

    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json")).expect("json");
    assert_eq!(summary["transition.completed"], 1, "{summary}");
    assert!(summary["transition.started_at_s"].as_f64().is_some_and(|s| s > t[climbing] - 1.0), "{summary}");
}

#[test]
fn a_wall_transition_without_a_lidar_and_out_of_range_settings_are_refused_by_name() {
    let dir = support::scratch_dir("wall-transition-bad");
    let without_lidar = |text: &str| text.replace("[lidar]\n", "");
    support::assert_changed_scenario_refused("scenarios/floor-to-wall-line.toml", &dir, without_lidar, &["controller.wall_transition", "[lidar]"]);
    let scenario = support::repo().join("scenarios/floor-to-wall-line.toml");
    support::assert_each_set_refused(&scenario, &dir.join("out"), &["controller.wall_transition.front_magnet_deg=200", "controller.wall_transition.detect_m=-1", "capture.adhesion_floor_n=-5"]);
}

/// The documented range of `front_magnet_deg` ends at 180°, the same shaft angle as -180°: the
/// magnets turn there and the run goes on (a Goal Position one past the servo's limit once ended
/// it at 16 s with exit 2 and no outputs).
#[test]
fn the_front_magnets_turn_to_the_end_of_their_documented_range() {
    let dir = support::scratch_dir("wall-transition-180");
    let out = dir.join("out");
    let scenario = support::repo().join("scenarios/floor-to-wall-line.toml");
    let args = [
        "run",
        &scenario.display().to_string(),
        "--set",
        "world.duration_s=25",
        "--set",
        "controller.wall_transition.front_magnet_deg=180",
        "--set",
        "expect={}",
        "--set",
        "capture.mcap=false",
        "--out",
        &out.display().to_string(),
    ];
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim")).args(args).current_dir(support::repo()).output().expect("climbsim");
    assert!(output.status.success(), "{}", support::output_text(&output));
    let csv = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv");
    let t = csv.column("t_s").expect("t_s");
    assert!(t.last().is_some_and(|&end| end > 24.0), "the run went to its end: {:?}", t.last());
    let magnet = csv.column("magnet_angle_fl_rad").expect("magnet angle");
    assert!(magnet.iter().any(|a| a.abs() > 3.0), "the front magnets turned to ±180°");
}
