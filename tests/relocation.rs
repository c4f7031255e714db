//! Relocation between welds: the built-in controller's legs, a path that keeps off obstacles it
//! learnt of from its LIDAR, and the weld list an external controller gets.

use std::process::Command;

mod support;

#[test]
fn the_robot_welds_relocates_around_what_its_lidar_finds_and_welds_again() {
    let dir = support::scratch_dir("relocation");
    let out = dir.join("out");
    let scenario = support::repo().join("scenarios/three-welds.toml");
    let args = ["run", &scenario.display().to_string(), "--set", "expect={}", "--set", "capture.mcap=false", "--out", &out.display().to_string()];
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim")).args(args).current_dir(support::repo()).output().expect("climbsim");
    assert!(output.status.success(), "{}", support::output_text(&output));
    let csv = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv");
    let column = |name: &str| csv.column(name).unwrap_or_else(|| panic!("no column {name}"));
    let (leg, x, z) = (column("relocation_leg"), column("x_m"), column("z_m"));

    // The legs in order: weld 0, to weld 1, weld 1, to weld 2, weld 2, finished.
    let mut legs: Vec<f64> = Vec::new();
    for &l in &leg {
        if legs.last() != Some(&l) {
            legs.push(l);
        }
    }
    assert_eq!(legs, [0.0, 0.5, 1.0, 1.5, 2.0, -1.0]);

    // The centre never comes within the robot's half-width (0.15 m) of the stiffener (x −0.2 to
    // 0.8, z 0.425 to 0.575) or the post (radius 0.1 at (0.2, 1.5)).
    for (&px, &pz) in x.iter().zip(&z) {
        let (dx, dz) = ((-0.2 - px).max(px - 0.8).max(0.0), (0.425 - pz).max(pz - 0.575).max(0.0));
        assert!(dx.hypot(dz) > 0.15, "at ({px:.3}, {pz:.3}) the robot is in the stiffener");
        assert!((px - 0.2).hypot(pz - 1.5) > 0.1 + 0.15, "at ({px:.3}, {pz:.3}) the robot is in the post");
    }
    // It ends at the last weld's end, on it.
    let end = x.len() - 1;
    assert!((x[end] - 0.6).abs() < 0.01 && (z[end] - 2.0).abs() < 0.005, "ends at ({}, {})", x[end], z[end]);

    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json")).expect("json");
    assert_eq!(summary["relocation.completed"], 2, "{summary}");
    assert_eq!(summary["welds.reached"], 3, "{summary}");
    // The given map has no obstacles: the first path ran through the stiffener until the LIDAR
    // saw it.
    assert!(summary["relocation.replans"].as_u64().is_some_and(|n| n >= 1), "{summary}");
}

#[test]
fn an_external_controller_gets_the_weld_list_and_the_pose() {
    let serve = support::Options::default().sensors().start(&[&support::repo().join("scenarios/three-welds.toml").display().to_string()]);
    std::thread::sleep(std::time::Duration::from_millis(500));
    let welds = support::get_json(serve.sensors(), "/welds");
    let state = support::get_json(serve.sensors(), "/state");
    serve.finish();
    let list = welds["welds"].as_array().expect("a list");
    assert_eq!(list.len(), 3, "{welds}");
    let points: Vec<Vec<f64>> = serde_json::from_value(list[2]["points"].clone()).expect("points");
    assert_eq!(points.len(), 2, "{welds}");
    assert!(points.iter().zip([[0.0, 2.0], [0.6, 2.0]]).all(|(p, q)| (p[0] - q[0]).abs() < 1e-6 && (p[1] - q[1]).abs() < 1e-6), "{welds}");
    assert!(list.iter().all(|w| (w["length_m"].as_f64().unwrap_or(0.0) - 0.6).abs() < 1e-3), "{welds}");
    // Standing at the start of weld 0, heading along it.
    assert_eq!(state["weld"], 0, "{state}");
    assert!(state["heading_rad"].as_f64().is_some_and(|h| h.abs() < 0.01), "{state}");
}

#[test]
fn welds_without_a_first_line_and_bad_relocation_settings_are_refused_by_name() {
    let dir = support::scratch_dir("relocation-bad");
    let without_line = |text: &str| text.replace("[line]\npoints = [[0.0, 0.0], [0.6, 0.0]]\n", "").replace("[start]\nx_m = 0.05\n", "");
    support::assert_changed_scenario_refused("scenarios/three-welds.toml", &dir, without_line, &["welds", "[line]"]);
    let scenario = support::repo().join("scenarios/three-welds.toml");
    support::assert_each_set_refused(&scenario, &dir.join("out"), &["relocation.cell_m=0", "relocation.clearance_m=5", "relocation.speed_mm_min=-1", "welds[1].width_m=0"]);
}
