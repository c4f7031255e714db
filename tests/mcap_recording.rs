//! `run.mcap`, read back with the `mcap` crate (not the writer's SDK): schemas, topics, message
//! counts and timestamps match the run's `timeseries.csv`, the transforms decode and put the
//! robot where the series says it was, the camera frames are PNG images.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use foxglove::Decode;
use foxglove::messages::FrameTransforms;

mod support;

fn run(out: &Path, extra: &[&str]) {
    let mut args = vec!["run", "scenarios/flat-line.toml", "--set", "world.duration_s=3", "--set", "expect={}", "--out"];
    let out_text = out.display().to_string();
    args.push(&out_text);
    args.extend(extra);
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim")).args(&args).current_dir(support::repo()).output().expect("climbsim");
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
}

#[test]
fn a_run_records_transforms_camera_and_signals_that_match_its_time_series() {
    let out = support::scratch_dir("mcap").join("run");
    run(&out, &[]);
    assert!(!out.join("run.mcap.tmp").exists(), "the temporary file was renamed");
    let bytes = std::fs::read(out.join("run.mcap")).expect("run.mcap");
    let summary = mcap::Summary::read(&bytes).expect("readable").expect("a complete file has a summary");
    assert!(summary.stats.is_some_and(|s| s.message_count > 0));

    let mut by_topic: BTreeMap<String, Vec<mcap::Message>> = BTreeMap::new();
    for message in mcap::MessageStream::new(&bytes).expect("stream") {
        let message = message.expect("message");
        by_topic.entry(message.channel.topic.clone()).or_default().push(message);
    }
    let schema = |topic: &str| {
        let channel = &by_topic[topic][0].channel;
        let schema = channel.schema.as_ref().expect("schema");
        (schema.name.clone(), schema.encoding.clone(), channel.message_encoding.clone())
    };
    assert_eq!(schema("/tf"), ("foxglove.FrameTransforms".into(), "protobuf".into(), "protobuf".into()));
    assert_eq!(schema("/camera/image"), ("foxglove.CompressedImage".into(), "protobuf".into(), "protobuf".into()));
    assert_eq!(schema("/signals"), ("climbsim.Signals".into(), "jsonschema".into(), "json".into()));

    let csv = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv");
    let (t, x, y, z) = (csv.column("t_s").expect("t"), csv.column("x_m").expect("x"), csv.column("y_m").expect("y"), csv.column("z_m").expect("z"));
    // One signals message and one set of transforms per captured row, at the row's time.
    for topic in ["/signals", "/tf"] {
        let times: Vec<u64> = by_topic[topic].iter().map(|m| m.log_time).collect();
        assert_eq!(times.len(), t.len(), "{topic}: one message per row");
        for (time, t_s) in times.iter().zip(&t) {
            assert!((*time as f64 / 1e9 - t_s).abs() < 1e-6, "{topic}: {time} ns against row t = {t_s}");
        }
    }
    // The signals carry the row's values.
    let last: serde_json::Value = serde_json::from_slice(&by_topic["/signals"].last().expect("rows").data).expect("JSON");
    assert!((last["x_m"].as_f64().expect("x_m") - x[x.len() - 1]).abs() < 1e-9, "{last}");

    // The middle section's transform is where the series puts the robot.
    for (index, message) in by_topic["/tf"].iter().enumerate().step_by(25) {
        let transforms = FrameTransforms::decode(&message.data[..]).expect("FrameTransforms");
        let frames: Vec<&str> = transforms.transforms.iter().map(|f| f.child_frame_id.as_str()).collect();
        assert_eq!(frames, ["world", "middle", "front", "wheel_front_left", "wheel_front_right", "wheel_rear_left", "wheel_rear_right"]);
        let middle = transforms.transforms[1].translation.as_ref().expect("translation");
        assert!((middle.x - x[index]).abs() < 1e-5 && (middle.y - y[index]).abs() < 1e-5 && (middle.z - z[index]).abs() < 1e-5, "row {index}: {middle:?}");
    }

    // The camera's frames at its 30 Hz, each a PNG.
    let images = &by_topic["/camera/image"];
    assert!((85..=95).contains(&images.len()), "{} frames in 3 s at 30 Hz", images.len());
    let image = foxglove::messages::CompressedImage::decode(&images[0].data[..]).expect("CompressedImage");
    assert_eq!(image.format, "png");
    assert!(image.data.starts_with(b"\x89PNG\r\n\x1a\n"), "a PNG");
}

#[test]
fn capture_mcap_false_records_nothing() {
    let out = support::scratch_dir("mcap-off").join("run");
    run(&out, &["--set", "capture.mcap=false"]);
    assert!(out.join("timeseries.csv").exists());
    assert!(!out.join("run.mcap").exists() && !out.join("run.mcap.tmp").exists());
}
