//! A viewer speaking Foxglove's WebSocket protocol (tungstenite, not the server's SDK): it
//! connects, subscribes to the topics it wants as they are advertised, and keeps what comes.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, http::HeaderValue};

/// What a viewer saw.
#[derive(Default)]
pub struct Seen {
    /// The server's `serverInfo`.
    pub server_info: Option<Value>,
    /// Every channel advertised: its id and topic.
    pub channels: HashMap<u64, String>,
    /// The wanted topics' messages: log time (ns) and payload.
    pub received: HashMap<String, Vec<(u64, Vec<u8>)>>,
    /// The server's last time message (ns).
    pub server_time: Option<u64>,
}

impl Seen {
    /// Whether `topic` was advertised.
    pub fn advertised(&self, topic: &str) -> bool {
        self.channels.values().any(|t| t == topic)
    }

    /// How many messages of `topic` came.
    pub fn count(&self, topic: &str) -> usize {
        self.received.get(topic).map_or(0, Vec::len)
    }
}

/// Connect to `url`, subscribe to `wanted` and read until `done` says so or `within` has
/// passed (a quiet server ends the read after 5 s).
pub fn watch(url: &str, wanted: &[&str], within: Duration, mut done: impl FnMut(&Seen) -> bool) -> Seen {
    let mut request = url.into_client_request().expect("request");
    request.headers_mut().insert("Sec-WebSocket-Protocol", HeaderValue::from_static("foxglove.sdk.v1"));
    let (mut socket, _) = tungstenite::connect(request).expect("connect");
    if let tungstenite::stream::MaybeTlsStream::Plain(stream) = socket.get_ref() {
        stream.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    }
    let mut seen = Seen::default();
    let mut subscriptions: HashMap<u32, String> = HashMap::new();
    let deadline = Instant::now() + within;
    while Instant::now() < deadline && !done(&seen) {
        match socket.read().expect("read") {
            Message::Text(text) => {
                let message: Value = serde_json::from_str(&text).expect("JSON");
                match message["op"].as_str() {
                    Some("serverInfo") => seen.server_info = Some(message),
                    Some("advertise") => {
                        let mut subscribe = Vec::new();
                        for channel in message["channels"].as_array().expect("channels") {
                            let (id, topic) = (channel["id"].as_u64().expect("id"), channel["topic"].as_str().expect("topic").to_owned());
                            if wanted.contains(&topic.as_str()) {
                                let subscription = u32::try_from(subscriptions.len() + 1).expect("few");
                                subscribe.push(json!({ "id": subscription, "channelId": id }));
                                subscriptions.insert(subscription, topic.clone());
                            }
                            seen.channels.insert(id, topic);
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
                    seen.received.entry(subscriptions[&subscription].clone()).or_default().push((log_time, bytes[13..].to_vec()));
                }
                // Time: the server's clock.
                Some(2) => seen.server_time = Some(u64::from_le_bytes(bytes[1..9].try_into().expect("time"))),
                _ => {}
            },
            _ => {}
        }
    }
    seen
}
