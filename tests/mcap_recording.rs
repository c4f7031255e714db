//! `run.mcap`, read back with the `mcap` crate (not the writer's SDK): schemas, topics, message
//! counts and timestamps match the run's `timeseries.csv`, the transforms decode and put the
//! robot where the series says it was, the scene holds the terrain, the line, the robot and its
//! magnets' pulls, the servos' registers are there by name, faults are logged, and the camera
//! frames are PNG images.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use foxglove::Decode;
use foxglove::messages::{FrameTransforms, SceneUpdate};
use rapier3d::prelude::{Pose, Rotation, Vector};

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
    assert_eq!(schema("/servos"), ("climbsim.Servos".into(), "jsonschema".into(), "json".into()));
    for topic in ["/scene/terrain", "/scene/robot", "/scene/magnets"] {
        assert_eq!(schema(topic), ("foxglove.SceneUpdate".into(), "protobuf".into(), "protobuf".into()), "{topic}");
    }
    // Only what the scenario has is advertised and drawn: flat-line has no LIDAR and no obstacles.
    assert!(summary.channels.values().all(|channel| channel.topic != "/lidar"), "a /lidar channel without a [lidar]");
    let terrain = SceneUpdate::decode(&by_topic["/scene/terrain"][0].data[..]).expect("SceneUpdate");
    assert!(terrain.entities.iter().all(|e| e.id != "obstacles"), "an empty obstacles entity");
    // Every field of a JSON message is in its channel's schema (a field the schema lacks is
    // hidden from schema-driven tools).
    for topic in ["/signals", "/servos"] {
        let schema: serde_json::Value = serde_json::from_slice(&by_topic[topic][0].channel.schema.as_ref().expect("schema").data).expect("JSON schema");
        let message: serde_json::Value = serde_json::from_slice(&by_topic[topic].last().expect("a message").data).expect("JSON message");
        for (key, value) in message.as_object().expect("an object") {
            let described = &schema["properties"][key];
            assert!(described.is_object(), "{topic}: {key} is not in the schema");
            for field in value.as_object().into_iter().flat_map(|fields| fields.keys()) {
                assert!(described["properties"][field].is_object(), "{topic}: {key}.{field} is not in the schema");
            }
        }
    }

    let csv = climbsim::report::read_timeseries_csv(&out.join("timeseries.csv")).expect("timeseries.csv");
    let (t, x, y, z) = (csv.column("t_s").expect("t"), csv.column("x_m").expect("x"), csv.column("y_m").expect("y"), csv.column("z_m").expect("z"));
    // One signals message and one set of transforms per captured row, at the row's time (the
    // view's 50 Hz is the capture's default rate).
    for topic in ["/signals", "/tf", "/servos"] {
        let times: Vec<u64> = by_topic[topic].iter().map(|m| m.log_time).collect();
        assert_eq!(times.len(), t.len(), "{topic}: one message per row");
        for (time, t_s) in times.iter().zip(&t) {
            assert!((*time as f64 / 1e9 - t_s).abs() < 1e-6, "{topic}: {time} ns against row t = {t_s}");
        }
    }
    // The signals carry the row's values.
    let last: serde_json::Value = serde_json::from_slice(&by_topic["/signals"].last().expect("rows").data).expect("JSON");
    assert!((last["x_m"].as_f64().expect("x_m") - x[x.len() - 1]).abs() < 1e-9, "{last}");
    // d and speed in the scenarios' units too, for plots.
    let value = |key: &str| last[key].as_f64().unwrap_or_else(|| panic!("no {key} in {last}"));
    assert!((value("d_true_mm") - 1000.0 * value("d_true_m")).abs() < 1e-9 && (value("speed_mm_min") - 60_000.0 * value("speed_m_s")).abs() < 1e-6, "{last}");

    // The robot's frame tree, at the view's 50 Hz: the middle section where the series puts
    // the robot, the wheels a track apart, each magnet pulling straight down on the flat floor.
    let parents = ["map", "world", "middle", "front", "wheel_front_left", "front", "wheel_front_right", "middle", "wheel_rear_left", "middle", "wheel_rear_right", "middle"];
    let children = [
        "world",
        "middle",
        "front",
        "wheel_front_left",
        "magnet_front_left",
        "wheel_front_right",
        "magnet_front_right",
        "wheel_rear_left",
        "magnet_rear_left",
        "wheel_rear_right",
        "magnet_rear_right",
        "camera",
    ];
    for (index, message) in by_topic["/tf"].iter().enumerate().step_by(25) {
        let transforms = FrameTransforms::decode(&message.data[..]).expect("FrameTransforms");
        let pairs: Vec<(&str, &str)> = transforms.transforms.iter().map(|f| (f.parent_frame_id.as_str(), f.child_frame_id.as_str())).collect();
        assert_eq!(pairs, parents.iter().copied().zip(children).collect::<Vec<_>>());
        let middle = transforms.transforms[1].translation.as_ref().expect("translation");
        assert!((middle.x - x[index]).abs() < 1e-5 && (middle.y - y[index]).abs() < 1e-5 && (middle.z - z[index]).abs() < 1e-5, "row {index}: {middle:?}");
        let in_world = |name: &str| world_pose(&transforms, name);
        let (left, right) = (in_world("wheel_front_left").translation, in_world("wheel_front_right").translation);
        assert!(((left - right).length() - 0.26).abs() < 0.005, "front wheels {left:?} and {right:?} are a 260 mm track apart");
        for magnet in ["magnet_front_left", "magnet_rear_right"] {
            let pull = in_world(magnet).rotation * -Vector::Y;
            assert!(pull.y < -0.99, "{magnet} pulls along {pull:?}, not down");
        }
        // The camera's optical frame looks down, its image columns to the robot's right and its
        // rows backward (row 0 is the forward edge).
        let (camera, body) = (in_world("camera").rotation, in_world("middle").rotation);
        assert!((camera * Vector::Z).y < -0.99, "the camera looks along {:?}", camera * Vector::Z);
        assert!((camera * Vector::X).dot(body * Vector::Z) > 0.99 && (camera * Vector::Y).dot(body * -Vector::X) > 0.99);
    }
    // Each image comes with its calibration, in the camera's frame: Foxglove can place it in 3D.
    let calibrations = &by_topic["/camera/calibration"];
    assert_eq!(calibrations.len(), by_topic["/camera/image"].len());
    let calibration = foxglove::messages::CameraCalibration::decode(&calibrations[0].data[..]).expect("CameraCalibration");
    assert!(calibration.frame_id == "camera" && calibration.k[0] > 0.0 && calibration.width > 0, "{calibration:?}");

    // The scene: the terrain as an indexed mesh, the line's stripe just above it, the robot's
    // boxes and wheels, and one arrow per magnet as long as its pull.
    let terrain = SceneUpdate::decode(&by_topic["/scene/terrain"][0].data[..]).expect("SceneUpdate");
    let ground = terrain.entities.iter().find(|e| e.id == "terrain").expect("terrain entity");
    let mesh = &ground.triangles[0];
    assert!(mesh.points.len() >= 4 && !mesh.indices.is_empty() && mesh.indices.len() % 3 == 0, "{} points, {} indices", mesh.points.len(), mesh.indices.len());
    assert!(mesh.indices.iter().all(|&i| (i as usize) < mesh.points.len()));
    assert_eq!(mesh.colors.len(), mesh.points.len());
    let stripe = &terrain.entities.iter().find(|e| e.id == "weld_line").expect("weld line entity").triangles[0];
    assert!(!stripe.points.is_empty() && stripe.points.iter().all(|p| (0.0005..0.002).contains(&p.y)), "the stripe lies 1 mm over the flat floor");
    let robot = SceneUpdate::decode(&by_topic["/scene/robot"][0].data[..]).expect("SceneUpdate");
    let count = |kind: fn(&foxglove::messages::SceneEntity) -> usize| robot.entities.iter().map(kind).sum::<usize>();
    assert_eq!((count(|e| e.cubes.len()), count(|e| e.cylinders.len())), (3, 4), "three section boxes and four wheels");
    assert!(robot.entities.iter().all(|e| e.frame_locked));
    let magnets = &by_topic["/scene/magnets"];
    assert_eq!(magnets.len(), by_topic["/tf"].len());
    let pull_fl = csv.column("adhesion_fl_n").expect("adhesion");
    let last_arrows = SceneUpdate::decode(&magnets.last().expect("arrows").data[..]).expect("SceneUpdate");
    let arrow = &last_arrows.entities.iter().find(|e| e.frame_id == "magnet_front_left").expect("front-left arrow").arrows[0];
    let length = arrow.shaft_length + arrow.head_length;
    assert!((length - pull_fl[pull_fl.len() - 1] * 0.0005).abs() < 0.002, "arrow {length} m for {} N", pull_fl[pull_fl.len() - 1]);

    // The servos' registers by name: the wheels were told to turn and do.
    let servos: serde_json::Value = serde_json::from_slice(&by_topic["/servos"].last().expect("servos").data).expect("JSON");
    for name in ["wheel_front_left", "wheel_rear_right"] {
        let servo = &servos[name];
        assert_eq!(servo["torque_enable"], 1, "{servos}");
        assert!(servo["goal_velocity"].as_i64().is_some_and(|v| v != 0) && servo["present_velocity"].as_i64().is_some_and(|v| v != 0), "{name}: {servo}");
        assert!(servo["present_temperature"].as_i64().is_some() && servo["hardware_error_status"] == 0, "{name}: {servo}");
    }
    assert_eq!(servos["magnet_front_left"]["id"], 5);
    support::layout::names_only_what_the_recording_has(&support::repo().join("hil/foxglove/climbsim-layout.json"), &bytes);
    assert!(!by_topic.contains_key("/bus/packets"), "bus packets only when asked");

    // The camera's frames at its 30 Hz, each a PNG.
    let images = &by_topic["/camera/image"];
    assert!((85..=95).contains(&images.len()), "{} frames in 3 s at 30 Hz", images.len());
    let image = foxglove::messages::CompressedImage::decode(&images[0].data[..]).expect("CompressedImage");
    assert_eq!(image.format, "png");
    assert!(image.data.starts_with(b"\x89PNG\r\n\x1a\n"), "a PNG");
}

/// Where frame `name` is in `world`, from the tree of transforms.
fn world_pose(transforms: &FrameTransforms, name: &str) -> Pose {
    let transform = transforms.transforms.iter().find(|t| t.child_frame_id == name).unwrap_or_else(|| panic!("no frame {name}"));
    let (t, r) = (transform.translation.expect("translation"), transform.rotation.expect("rotation"));
    let local = Pose::from_parts(Vector::new(t.x as f32, t.y as f32, t.z as f32), Rotation::from_xyzw(r.x as f32, r.y as f32, r.z as f32, r.w as f32));
    if transform.parent_frame_id == "world" { local } else { world_pose(transforms, &transform.parent_frame_id) * local }
}

#[test]
fn faults_are_logged_as_they_start_and_end() {
    let out = support::scratch_dir("mcap-log").join("run");
    run(&out, &["--fault", "voltage_sag:volts=11,at=1,until=2"]);
    let bytes = std::fs::read(out.join("run.mcap")).expect("run.mcap");
    let logs: Vec<(f64, String)> = mcap::MessageStream::new(&bytes)
        .expect("stream")
        .map(|m| m.expect("message"))
        .filter(|m| m.channel.topic == "/log")
        .map(|m| (m.log_time as f64 / 1e9, foxglove::messages::Log::decode(&m.data[..]).expect("Log").message))
        .collect();
    assert_eq!(logs.len(), 3, "{logs:?}");
    assert!(logs[0].1.ends_with("flat-line.toml: the run starts") && logs[0].0 == 0.0, "{logs:?}");
    assert!(logs[1].1.starts_with("fault starts") && logs[1].1.contains("voltage_sag") && (1.0..1.05).contains(&logs[1].0), "{logs:?}");
    assert!(logs[2].1.starts_with("fault ends") && (2.0..2.05).contains(&logs[2].0), "{logs:?}");
}

#[test]
fn bus_packets_are_recorded_when_asked() {
    let out = support::scratch_dir("mcap-packets").join("run");
    run(&out, &["--set", "capture.bus_packets=true", "--set", "world.duration_s=1"]);
    let bytes = std::fs::read(out.join("run.mcap")).expect("run.mcap");
    let packets: Vec<(u64, serde_json::Value)> = mcap::MessageStream::new(&bytes)
        .expect("stream")
        .map(|m| m.expect("message"))
        .filter(|m| m.channel.topic == "/bus/packets")
        .map(|m| (m.log_time, serde_json::from_slice(&m.data).expect("JSON")))
        .collect();
    let requests: Vec<&serde_json::Value> = packets.iter().map(|(_, p)| p).filter(|p| p["dir"] == "controller->servos").collect();
    let replies = packets.len() - requests.len();
    // The built-in controller reads and writes the servos every 20 ms period.
    assert!(requests.len() >= 50 * 2 && replies >= 50 * 8, "{} requests, {replies} replies in 1 s", requests.len());
    assert!(requests.iter().all(|p| p["hex"].as_str().is_some_and(|h| h.starts_with("FF FF FD 00")) && p["decoded"]["instruction"].is_string()), "{:?}", requests[0]);
    assert!(packets.windows(2).all(|w| w[0].0 <= w[1].0 + 1_000_000), "packets in time order, within a reply's wire time");
}

#[test]
fn capture_mcap_false_records_nothing() {
    let out = support::scratch_dir("mcap-off").join("run");
    run(&out, &["--set", "capture.mcap=false"]);
    assert!(out.join("timeseries.csv").exists());
    assert!(!out.join("run.mcap").exists() && !out.join("run.mcap.tmp").exists());
}

#[test]
fn serve_shows_a_world_without_a_line_and_records_it_until_stopped() {
    let file = support::scratch_dir("mcap-serve").join("session.mcap");
    let serve = support::Options::default().sensors().start(&["scenarios/floor-to-wall.toml", "--mcap", &file.display().to_string()]);
    std::thread::sleep(std::time::Duration::from_millis(1500));
    // The robot's state is served without a line too; d and psi have no meaning there.
    let state = support::get_json(serve.sensors(), "/state");
    serve.finish();
    assert!(state["t"].as_f64().is_some_and(|t| t > 1.0) && state["x"].is_number() && state["d_err_m"].is_null(), "{state}");

    let bytes = std::fs::read(&file).expect("the recording has its final name");
    let messages: Vec<mcap::Message> = mcap::MessageStream::new(&bytes).expect("stream").map(|m| m.expect("message")).collect();
    let times: Vec<u64> = messages.iter().filter(|m| m.channel.topic == "/tf").map(|m| m.log_time).collect();
    // The world ran on the wall clock for about 1.5 s, its frames at 50 Hz.
    assert!(times.len() >= 50 && times.windows(2).all(|w| w[0] < w[1]), "{} frames", times.len());
    let terrain = messages.iter().find(|m| m.channel.topic == "/scene/terrain").expect("the terrain");
    let terrain = SceneUpdate::decode(&terrain.data[..]).expect("SceneUpdate");
    let mesh = &terrain.entities.iter().find(|e| e.id == "terrain").expect("terrain entity").triangles[0];
    // The wall stands: its mesh reaches well above the floor.
    let top = mesh.points.iter().map(|p| p.y).fold(f64::NEG_INFINITY, f64::max);
    assert!(top > 0.5, "the wall's top at {top} m");
    assert!(!messages.iter().any(|m| m.channel.topic == "/camera/image"), "no line, no camera frames");
    // serve keeps no time series, but its view still gets the signals at the capture rate.
    let signals = messages.iter().filter(|m| m.channel.topic == "/signals").count();
    assert!(signals >= 30, "{signals} /signals messages in 1.5 s");
}
