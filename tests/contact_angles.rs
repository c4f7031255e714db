//! The wheels' contact angles in the time series, against the geometry of a pipe: on top of a
//! 0.5 m pipe the wheel centres sit 0.13 m either side of its top line, 0.55 m from its axis,
//! so each wheel touches the pipe asin(0.13 / 0.55) = 13.7° off its tread's middle, toward the
//! pipe's top line, and straight below in its own plane.

use std::process::Command;

mod support;

#[test]
fn on_a_pipe_the_wheels_touch_off_their_treads_middle_toward_the_top_line() {
    let out = support::scratch_dir("contact-angles").join("run");
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["run", "scenarios/pipe-line.toml", "--set", "world.duration_s=2", "--set", "expect={}", "--set", "capture.mcap=false", "--out", &out.display().to_string()])
        .current_dir(support::repo())
        .output()
        .expect("climbsim");
    assert!(output.status.success(), "{}", support::output_text(&output));
    let csv = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv");
    let last = |name: &str| csv.column(name).and_then(|c| c.last().copied()).expect(name).to_degrees();
    let expected = (0.13_f64 / 0.55).asin().to_degrees();
    // z points to the robot's right: the left wheels touch toward +z, the right ones toward -z.
    for (wheel, sign) in [("fl", 1.0), ("rl", 1.0), ("fr", -1.0), ("rr", -1.0)] {
        let lateral = last(&format!("contact_lateral_{wheel}_rad"));
        assert!((lateral * sign - expected).abs() < 2.5, "{wheel}: {lateral:.2}° off the tread's middle, geometry says {:.2}°", sign * expected);
        let in_plane = last(&format!("contact_in_plane_{wheel}_rad"));
        assert!(in_plane.abs() < 1.0, "{wheel}: {in_plane:.2}° in the wheel's plane");
    }
}
