//! `run --foxglove`: a WebSocket client speaking Foxglove's protocol (tungstenite, not the
//! server's SDK) connects after the run has started, subscribes, and receives the robot's
//! transforms, a camera image, the terrain (sent to a late subscriber) and the server's clock.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use foxglove::Decode;
use foxglove::messages::{CompressedImage, FrameTransforms, SceneUpdate};
use serde_json::json;

mod support;

/// Kills the run if the test fails half-way.
struct Running(std::process::Child);

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn a_late_viewer_gets_the_scene_transforms_images_and_time() {
    let out = support::scratch_dir("foxglove-live").join("run");
    let mut child = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["run", "scenarios/flat-line.toml", "--foxglove=127.0.0.1:0", "--set", "world.duration_s=20", "--set", "expect={}", "--set", "capture.mcap=false", "--out", &out.display().to_string()])
        .current_dir(support::repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("climbsim");
    let stdout = child.stdout.take().expect("stdout");
    let _running = Running(child);
    let mut lines = BufReader::new(stdout).lines();
    let url = lines.by_ref().map_while(Result::ok).find_map(|line| line.strip_prefix("foxglove: ").map(str::to_owned)).expect("a `foxglove: URL` line");
    assert!(url.starts_with("ws://127.0.0.1:"), "{url}");
    // Join late: the terrain was sent long before.
    std::thread::sleep(Duration::from_millis(500));

    let wanted = ["/tf", "/camera/image", "/scene/terrain", "/scene/robot"];
    let seen = support::foxglove::watch(&url, &wanted, Duration::from_secs(15), |seen| {
        wanted.iter().all(|t| seen.count(t) >= 3 || (t.starts_with("/scene") && seen.count(t) > 0)) && seen.server_time.is_some()
    });
    let (received, server_time) = (&seen.received, seen.server_time);
    let info = seen.server_info.as_ref().expect("serverInfo");
    assert_eq!(info["name"], "climbsim");
    assert!(info["capabilities"].as_array().expect("capabilities").contains(&json!("time")), "{info}");
    for topic in ["/tf", "/scene/terrain", "/scene/robot", "/scene/magnets", "/signals", "/servos", "/log", "/camera/image"] {
        assert!(seen.advertised(topic), "{topic} advertised: {:?}", seen.channels);
    }

    let transforms = &received["/tf"];
    assert!(transforms.len() >= 3, "{} transforms", transforms.len());
    let last = FrameTransforms::decode(&transforms[transforms.len() - 1].1[..]).expect("FrameTransforms");
    assert!(last.transforms.iter().any(|t| t.child_frame_id == "magnet_rear_right"));
    // Time moves on at about real time: the run keeps to 1x for its watcher.
    let (first_t, last_t) = (transforms[0].0, transforms[transforms.len() - 1].0);
    assert!(last_t > first_t && first_t > 300_000_000, "joined after 0.5 s; frames from {first_t} to {last_t} ns");
    assert!(server_time.is_some_and(|t| t >= first_t), "server time {server_time:?}");

    let image = CompressedImage::decode(&received["/camera/image"][0].1[..]).expect("CompressedImage");
    assert_eq!(image.format, "png");
    assert!(image.data.starts_with(b"\x89PNG\r\n\x1a\n"));
    let terrain = SceneUpdate::decode(&received["/scene/terrain"][0].1[..]).expect("SceneUpdate");
    assert!(terrain.entities.iter().any(|e| e.id == "terrain") && terrain.entities.iter().any(|e| e.id == "weld_line"));
    let robot = SceneUpdate::decode(&received["/scene/robot"][0].1[..]).expect("SceneUpdate");
    assert_eq!(robot.entities.iter().map(|e| e.cylinders.len()).sum::<usize>(), 4);
}

/// A Foxglove port that is taken is one clear error before the run, and leaves no half-written
/// recording behind.
#[test]
fn a_taken_port_is_refused_and_leaves_no_litter() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = taken.local_addr().expect("addr").port();
    let out = support::scratch_dir("foxglove-taken").join("run");
    let output = support::climbsim(&["run", "scenarios/flat-line.toml", &format!("--foxglove=127.0.0.1:{port}"), "--out", &out.display().to_string()]);
    assert_eq!(output.status.code(), Some(2), "{}", support::output_text(&output));
    let left: Vec<_> = std::fs::read_dir(&out).map(|dir| dir.filter_map(|e| e.ok()).map(|e| e.file_name()).filter(|n| n.to_string_lossy().ends_with(".tmp")).collect()).unwrap_or_default();
    assert!(left.is_empty(), "{left:?}");
}
