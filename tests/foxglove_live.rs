//! `run --foxglove`: a WebSocket client speaking Foxglove's protocol (tungstenite, not the
//! server's SDK) connects after the run has started, subscribes, and receives the robot's
//! transforms, a camera image, the terrain (sent to a late subscriber) and the server's clock.

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use foxglove::Decode;
use foxglove::messages::{CompressedImage, FrameTransforms, SceneUpdate};
use serde_json::{Value, json};
use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, http::HeaderValue};

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

    let mut request = url.as_str().into_client_request().expect("request");
    request.headers_mut().insert("Sec-WebSocket-Protocol", HeaderValue::from_static("foxglove.sdk.v1"));
    let (mut socket, _) = tungstenite::connect(request).expect("connect");
    if let tungstenite::stream::MaybeTlsStream::Plain(stream) = socket.get_ref() {
        stream.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    }

    let mut channels: HashMap<u64, String> = HashMap::new();
    let mut subscriptions: HashMap<u32, String> = HashMap::new();
    let mut received: HashMap<String, Vec<(u64, Vec<u8>)>> = HashMap::new();
    let mut server_time = None;
    let mut server_info = None;
    let wanted = ["/tf", "/camera/image", "/scene/terrain", "/scene/robot"];
    let deadline = Instant::now() + Duration::from_secs(15);
    while Instant::now() < deadline && !(wanted.iter().all(|t| received.get(*t).is_some_and(|m| m.len() >= 3 || (t.starts_with("/scene") && !m.is_empty()))) && server_time.is_some()) {
        match socket.read().expect("read") {
            Message::Text(text) => {
                let message: Value = serde_json::from_str(&text).expect("JSON");
                match message["op"].as_str() {
                    Some("serverInfo") => server_info = Some(message),
                    Some("advertise") => {
                        let mut subscribe = Vec::new();
                        for channel in message["channels"].as_array().expect("channels") {
                            let (id, topic) = (channel["id"].as_u64().expect("id"), channel["topic"].as_str().expect("topic").to_owned());
                            if wanted.contains(&topic.as_str()) {
                                let subscription = u32::try_from(subscriptions.len() + 1).expect("few");
                                subscribe.push(json!({ "id": subscription, "channelId": id }));
                                subscriptions.insert(subscription, topic.clone());
                            }
                            channels.insert(id, topic);
                        }
                        socket.send(Message::text(json!({ "op": "subscribe", "subscriptions": subscribe }).to_string())).expect("subscribe");
                    }
                    _ => {}
                }
            }
            Message::Binary(bytes) => match bytes.first() {
                // Message data: opcode, subscription id (u32 LE), log time (u64 LE), payload.
                Some(1) => {
                    let subscription = u32::from_le_bytes(bytes[1..5].try_into().expect("id"));
                    let log_time = u64::from_le_bytes(bytes[5..13].try_into().expect("time"));
                    received.entry(subscriptions[&subscription].clone()).or_default().push((log_time, bytes[13..].to_vec()));
                }
                // Time: the simulated clock.
                Some(2) => server_time = Some(u64::from_le_bytes(bytes[1..9].try_into().expect("time"))),
                _ => {}
            },
            _ => {}
        }
    }
    let info = server_info.expect("serverInfo");
    assert_eq!(info["name"], "climbsim");
    assert!(info["capabilities"].as_array().expect("capabilities").contains(&json!("time")), "{info}");
    for topic in ["/tf", "/scene/terrain", "/scene/robot", "/scene/magnets", "/signals", "/servos", "/log", "/camera/image"] {
        assert!(channels.values().any(|t| t == topic), "{topic} advertised: {channels:?}");
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
