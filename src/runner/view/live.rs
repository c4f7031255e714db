//! The live view: Foxglove's WebSocket server on the view's channels. Foxglove's protocol keeps
//! no message for late subscribers, so a viewer that connects after the start is sent the latest
//! terrain and robot scene when it subscribes to them.

use std::str::FromStr;
use std::sync::{Arc, Mutex, PoisonError};

use foxglove::websocket::{Capability, ChannelView, Client, ServerListener};
use foxglove::{Context, WebSocketServer, WebSocketServerHandle};

use super::{Channels, LatestScene, ViewError};

/// Where the live view listens: `127.0.0.1:8765` unless told otherwise. Only this machine can
/// connect unless a host is given.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LiveAddress {
    pub host: String,
    pub port: u16,
}

impl LiveAddress {
    pub const DEFAULT_HOST: &'static str = "127.0.0.1";
    /// Foxglove's own default for its WebSocket connections.
    pub const DEFAULT_PORT: u16 = 8765;
}

impl Default for LiveAddress {
    fn default() -> Self {
        Self { host: Self::DEFAULT_HOST.to_owned(), port: Self::DEFAULT_PORT }
    }
}

impl std::fmt::Display for LiveAddress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.host.contains(':') { write!(f, "[{}]:{}", self.host, self.port) } else { write!(f, "{}:{}", self.host, self.port) }
    }
}

impl FromStr for LiveAddress {
    type Err = String;

    /// `PORT`, `HOST`, `HOST:PORT` or `[IPv6]:PORT`.
    fn from_str(text: &str) -> Result<Self, String> {
        let text = text.trim();
        let port = |p: &str| p.parse::<u16>().map_err(|_| format!("`{text}`: the port must be a number from 0 to 65535, got `{p}`"));
        if text.is_empty() {
            return Err("an empty address: give PORT, HOST or HOST:PORT".to_owned());
        }
        if let Some(rest) = text.strip_prefix('[') {
            let (host, after) = rest.split_once(']').ok_or_else(|| format!("`{text}`: an IPv6 address needs its closing `]`"))?;
            let port = match after.strip_prefix(':') {
                Some(p) => port(p)?,
                None if after.is_empty() => Self::DEFAULT_PORT,
                None => return Err(format!("`{text}`: expected `:PORT` after `]`")),
            };
            return Ok(Self { host: host.to_owned(), port });
        }
        if text.bytes().all(|b| b.is_ascii_digit()) {
            return Ok(Self { host: Self::DEFAULT_HOST.to_owned(), port: port(text)? });
        }
        match text.split_once(':') {
            Some((host, p)) if !p.contains(':') => Ok(Self { host: host.to_owned(), port: port(p)? }),
            // A bare IPv6 address.
            Some(_) => Ok(Self { host: text.to_owned(), port: Self::DEFAULT_PORT }),
            None => Ok(Self { host: text.to_owned(), port: Self::DEFAULT_PORT }),
        }
    }
}

/// Sends the latest scene to each new subscriber of its topics.
struct SceneForLateViewers {
    channels: Arc<Channels>,
    latest: Arc<Mutex<LatestScene>>,
}

impl ServerListener for SceneForLateViewers {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        let latest = self.latest.lock().unwrap_or_else(PoisonError::into_inner);
        let (message, to) = match channel.topic() {
            "/scene/terrain" => (latest.terrain.as_ref(), &self.channels.terrain),
            "/scene/robot" => (latest.robot.as_ref(), &self.channels.robot),
            _ => return,
        };
        if let Some(message) = message {
            to.log_to_sink(message, client.sink_id());
        }
    }
}

pub(super) struct LiveServer {
    handle: WebSocketServerHandle,
    host: String,
}

impl LiveServer {
    pub(super) fn start(context: &Arc<Context>, address: &LiveAddress, channels: Arc<Channels>, latest: Arc<Mutex<LatestScene>>) -> Result<Self, ViewError> {
        let listener = Arc::new(SceneForLateViewers { channels, latest });
        let handle = WebSocketServer::new()
            .name("climbsim")
            .context(context)
            .bind(address.host.clone(), address.port)
            // Time: the viewer's clock follows the simulated one, whatever the run's pace.
            .capabilities([Capability::Time])
            .listener(listener)
            .start_blocking()
            .map_err(|e| ViewError::Listen { address: address.to_string(), message: e.to_string() })?;
        Ok(Self { handle, host: address.host.clone() })
    }

    pub(super) fn url(&self) -> String {
        let address = LiveAddress { host: self.host.clone(), port: self.handle.port() };
        format!("ws://{address}")
    }

    pub(super) fn broadcast_time(&self, nanos: u64) {
        self.handle.broadcast_time(nanos);
    }

    pub(super) fn stop(self) {
        // Connected viewers get their close frames in the background.
        self.handle.stop().detach_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parsed(text: &str) -> Result<(String, u16), String> {
        text.parse::<LiveAddress>().map(|a| (a.host, a.port))
    }

    #[test]
    fn addresses_take_a_port_a_host_or_both() {
        assert_eq!(parsed("9000"), Ok(("127.0.0.1".to_owned(), 9000)));
        assert_eq!(parsed("0.0.0.0"), Ok(("0.0.0.0".to_owned(), 8765)));
        assert_eq!(parsed("0.0.0.0:0"), Ok(("0.0.0.0".to_owned(), 0)));
        assert_eq!(parsed("localhost:8766"), Ok(("localhost".to_owned(), 8766)));
        assert_eq!(parsed("[::1]:9000"), Ok(("::1".to_owned(), 9000)));
        assert_eq!(parsed("::1"), Ok(("::1".to_owned(), 8765)));
        assert_eq!(LiveAddress { host: "::1".to_owned(), port: 9000 }.to_string(), "[::1]:9000");
    }

    #[test]
    fn bad_ports_are_named() {
        for bad in ["70000", "host:x", "", "[::1", "[::1]x"] {
            let error = parsed(bad).expect_err(bad);
            assert!(!error.is_empty(), "{bad}");
        }
        assert!(parsed("host:x").unwrap_err().contains("`x`"));
    }
}
