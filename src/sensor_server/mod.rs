//! The sensor server for external controllers: a small HTTP/1.1 server on localhost
//! that serves what the robot's camera and line detector see.
//!
//! - `GET /camera.png`: the latest camera frame (8-bit grayscale PNG);
//! - `GET /camera.mjpg`: every new frame as a `multipart/x-mixed-replace` JPEG stream, which
//!   OpenCV's `VideoCapture("http://…/camera.mjpg")` and browsers open;
//! - `GET /line`: the line detector's latest output, JSON `{"t": s, "d": m, "psi": rad, "valid": bool}`,
//!   in the run's one convention (as `timeseries.csv`'s `d_m`, `psi_rad` and the ground truth):
//!   the robot relative to the line, `d` > 0 when the robot is left of it, `psi` > 0 when it
//!   points left of it;
//! - `GET /state`: the ground-truth pose, for debugging only (a real robot has no such thing);
//! - `GET /lidar`: the front LIDAR's latest scan, when the scenario has a `[lidar]`: JSON with its
//!   time, the sensor's pose in the world, the beams' angles and one range per beam (`null`: no
//!   return);
//! - `GET /welds`: the job: every weld of the scenario (`[line]`, then `[[welds]]`) in order,
//!   each with its points as written and as smoothed, and its length, JSON
//!   `{"welds": [{"index": 0, "points": [[x, z], …], "smoothed": …, "length_m": m}, …]}`.
//!
//! The simulation publishes into a [`SensorFeed`]; the server only reads it, so a slow or stuck
//! HTTP client never holds up the physics. Frames are published raw and encoded (PNG, JPEG) only
//! when a client asks, on the server's thread: at `--speed 10` the camera's 30 Hz is 300 frames a
//! wall second, and encoding each one cost the world thread a tenth of its time whether anyone
//! looked or not. Its URL reaches the controller in `CLIMBSIM_SENSORS`.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex, PoisonError};

use thiserror::Error;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tracing::{debug, warn};

/// Longest request head accepted (a GET line and a few headers).
const MAX_REQUEST_BYTES: usize = 8192;
const MJPEG_BOUNDARY: &str = "climbsimframe";
/// JPEG quality of the MJPEG stream (the PNG is lossless).
const JPEG_QUALITY: u8 = 90;

#[derive(Debug, Error)]
pub enum SensorServerError {
    #[error("sensor server: cannot listen on {addr}: {source}")]
    Bind { addr: SocketAddr, source: std::io::Error },
    #[error("sensor server: {0}")]
    Io(#[from] std::io::Error),
    #[error("camera frame {width}×{height} cannot be encoded: {reason}")]
    Encode { width: u32, height: u32, reason: String },
}

/// One grayscale frame and its encodings, each made at the first request for it.
#[derive(Debug)]
struct Frame {
    width: u32,
    height: u32,
    gray: Vec<u8>,
    png: std::sync::OnceLock<Result<Vec<u8>, String>>,
    jpeg: std::sync::OnceLock<Result<Vec<u8>, String>>,
}

impl Frame {
    fn png(&self) -> Result<&[u8], SensorServerError> {
        let encoded = self.png.get_or_init(|| {
            let mut bytes = Vec::new();
            let mut encoder = png::Encoder::new(&mut bytes, self.width, self.height);
            encoder.set_color(png::ColorType::Grayscale);
            encoder.set_depth(png::BitDepth::Eight);
            let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
            writer.write_image_data(&self.gray).map_err(|e| e.to_string())?;
            drop(writer);
            Ok(bytes)
        });
        encoded.as_deref().map_err(|reason| self.encode_error(reason))
    }

    fn jpeg(&self) -> Result<&[u8], SensorServerError> {
        let encoded = self.jpeg.get_or_init(|| {
            let mut bytes = Vec::new();
            let (w, h) = (u16::try_from(self.width).map_err(|e| e.to_string())?, u16::try_from(self.height).map_err(|e| e.to_string())?);
            jpeg_encoder::Encoder::new(&mut bytes, JPEG_QUALITY).encode(&self.gray, w, h, jpeg_encoder::ColorType::Luma).map_err(|e| e.to_string())?;
            Ok(bytes)
        });
        encoded.as_deref().map_err(|reason| self.encode_error(reason))
    }

    fn encode_error(&self, reason: &str) -> SensorServerError {
        SensorServerError::Encode { width: self.width, height: self.height, reason: reason.to_owned() }
    }
}

#[derive(Debug, Default, Clone)]
struct Snapshot {
    frame: Option<Arc<Frame>>,
    line: Option<serde_json::Value>,
    state: Option<serde_json::Value>,
    lidar: Option<serde_json::Value>,
    welds: Option<serde_json::Value>,
}

/// Told of every read the server answers: (path, HTTP status code, content type, body). For
/// `--record`, which keeps what the controller was shown.
pub type ReadHook = Box<dyn Fn(&str, u16, &str, &[u8]) + Send + Sync>;

/// What the simulation publishes and the server serves.
pub struct SensorFeed {
    snapshot: Mutex<Snapshot>,
    /// Bumped on every new frame; MJPEG streams wait on it.
    frames: watch::Sender<u64>,
    on_read: std::sync::OnceLock<ReadHook>,
}

impl std::fmt::Debug for SensorFeed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SensorFeed").field("recording_reads", &self.on_read.get().is_some()).finish_non_exhaustive()
    }
}

impl Default for SensorFeed {
    fn default() -> Self {
        Self { snapshot: Mutex::default(), frames: watch::channel(0).0, on_read: std::sync::OnceLock::new() }
    }
}

impl SensorFeed {
    /// Call `hook` on every read answered from now on (set once; later calls are ignored).
    pub fn on_read(&self, hook: ReadHook) {
        if self.on_read.set(hook).is_err() {
            warn!("sensor read hook already set; the new one is ignored");
        }
    }

    fn snapshot(&self) -> Snapshot {
        self.snapshot.lock().unwrap_or_else(PoisonError::into_inner).clone()
    }

    fn update(&self, change: impl FnOnce(&mut Snapshot)) {
        change(&mut self.snapshot.lock().unwrap_or_else(PoisonError::into_inner));
    }

    /// A new grayscale frame (`width × height` bytes, row 0 at the top). It is encoded only
    /// when a client asks for it.
    pub fn publish_frame(&self, width: u32, height: u32, gray: &[u8]) -> Result<(), SensorServerError> {
        if u64::from(width) * u64::from(height) != gray.len() as u64 {
            return Err(SensorServerError::Encode { width, height, reason: format!("{} bytes of pixels", gray.len()) });
        }
        let frame = Arc::new(Frame { width, height, gray: gray.to_vec(), png: std::sync::OnceLock::new(), jpeg: std::sync::OnceLock::new() });
        self.update(|s| s.frame = Some(frame));
        self.frames.send_modify(|n| *n += 1);
        Ok(())
    }

    /// The detector's latest output, the robot relative to the line (see the module documentation).
    pub fn publish_line(&self, t_s: f64, d_m: f64, psi_rad: f64, valid: bool) {
        let value = serde_json::json!({ "t": t_s, "d": d_m, "psi": psi_rad, "valid": valid });
        self.update(|s| s.line = Some(value));
    }

    /// The LIDAR's latest scan.
    pub fn publish_lidar(&self, scan: serde_json::Value) {
        self.update(|s| s.lidar = Some(scan));
    }

    /// The scenario's welds (published once).
    pub fn publish_welds(&self, welds: serde_json::Value) {
        self.update(|s| s.welds = Some(welds));
    }

    /// Ground truth for debugging.
    pub fn publish_state(&self, state: serde_json::Value) {
        self.update(|s| s.state = Some(state));
    }
}

/// A bound sensor server.
pub struct SensorServer {
    listener: TcpListener,
}

impl SensorServer {
    pub async fn bind(addr: SocketAddr) -> Result<Self, SensorServerError> {
        let listener = TcpListener::bind(addr).await.map_err(|source| SensorServerError::Bind { addr, source })?;
        Ok(Self { listener })
    }

    pub fn local_addr(&self) -> Result<SocketAddr, SensorServerError> {
        Ok(self.listener.local_addr()?)
    }

    /// The base URL controllers get in `CLIMBSIM_SENSORS`.
    pub fn url(&self) -> Result<String, SensorServerError> {
        Ok(format!("http://{}", self.local_addr()?))
    }

    /// Serve clients until the task is dropped; each client on its own task.
    pub async fn run(self, feed: Arc<SensorFeed>) -> Result<(), SensorServerError> {
        loop {
            let (stream, peer) = self.listener.accept().await?;
            let feed = Arc::clone(&feed);
            tokio::spawn(async move {
                if let Err(error) = serve_client(stream, &feed).await {
                    debug!(%peer, %error, "sensor client gone");
                }
            });
        }
    }
}

async fn serve_client(mut stream: TcpStream, feed: &SensorFeed) -> std::io::Result<()> {
    let mut buffer = Vec::with_capacity(512);
    let mut chunk = [0u8; 1024];
    loop {
        let head = loop {
            if let Some(head) = take_request(&mut buffer) {
                break head;
            }
            let n = stream.read(&mut chunk).await?;
            if n == 0 {
                return Ok(());
            }
            buffer.extend_from_slice(&chunk[..n]);
        };
        match answer(&head, feed, true) {
            Answer::Mjpeg => return stream_mjpeg(stream, feed).await,
            Answer::Reply { status, content_type, body, keep_alive } => {
                stream.write_all(&response(status, content_type, &body, keep_alive)).await?;
                if !keep_alive {
                    return stream.shutdown().await;
                }
            }
        }
    }
}

/// The first whole request head in `buffer`, taken out of it (what follows it stays, for the
/// next request on a kept connection); or all of it, when it is too long to be one.
fn take_request(buffer: &mut Vec<u8>) -> Option<Vec<u8>> {
    if let Some(end) = buffer.windows(4).position(|w| w == b"\r\n\r\n") {
        let rest = buffer.split_off(end + 4);
        return Some(std::mem::replace(buffer, rest));
    }
    (buffer.len() > MAX_REQUEST_BYTES).then(|| std::mem::take(buffer))
}

/// Whether the client asked to keep the connection (`Connection: keep-alive`). Only then is it
/// kept: a server may close after any answer, and a client written to read an answer to the
/// end of the stream, as many hand-written ones are, then still gets its end.
fn asks_keep_alive(head: &[u8]) -> bool {
    String::from_utf8_lossy(head)
        .split("\r\n")
        .skip(1)
        .filter_map(|line| line.split_once(':'))
        .any(|(name, value)| name.trim().eq_ignore_ascii_case("connection") && value.split(',').any(|option| option.trim().eq_ignore_ascii_case("keep-alive")))
}

/// What the server sends back for a request head.
enum Answer {
    /// The camera's MJPEG stream, frame after frame.
    Mjpeg,
    /// `keep_alive`: the connection stays open for the client's next request.
    Reply { status: &'static str, content_type: &'static str, body: Vec<u8>, keep_alive: bool },
}

/// Answer a whole request head from the feed's latest snapshot (`streams`: the MJPEG stream
/// can be served).
fn answer(head: &[u8], feed: &SensorFeed, streams: bool) -> Answer {
    // A refused request is the connection's last: what follows it cannot be trusted to start a
    // request (a body, the rest of an over-long head).
    let text = |status, body: &[u8]| Answer::Reply { status, content_type: "text/plain", body: body.to_vec(), keep_alive: false };
    if head.len() > MAX_REQUEST_BYTES {
        return text("431 Request Header Fields Too Large", b"request too large\n");
    }
    let request_line = String::from_utf8_lossy(head.split(|&b| b == b'\r').next().unwrap_or_default()).into_owned();
    let mut parts = request_line.split_whitespace();
    let (method, target) = (parts.next().unwrap_or_default(), parts.next().unwrap_or_default());
    if method != "GET" {
        return text("405 Method Not Allowed", b"only GET\n");
    }
    // Query strings (e.g. cache busters) are ignored.
    let path = target.split('?').next().unwrap_or_default();
    if path == "/camera.mjpg" {
        if streams {
            return Answer::Mjpeg;
        }
        return text("501 Not Implemented", b"/camera.mjpg is not served under --clock virtual: poll /camera.png\n");
    }
    let snapshot = feed.snapshot();
    let not_yet = |what: &str| format!("no {what} yet\n").into_bytes();
    let json = |value: Option<serde_json::Value>, what: &str| match value {
        Some(value) => (200, "application/json", value.to_string().into_bytes()),
        None => (503, "text/plain", not_yet(what)),
    };
    let (status, content_type, body): (u16, &'static str, Vec<u8>) = match path {
        "/camera.png" => match snapshot.frame.as_deref().map(Frame::png) {
            Some(Ok(png)) => (200, "image/png", png.to_vec()),
            Some(Err(error)) => (500, "text/plain", format!("{error}\n").into_bytes()),
            None => (503, "text/plain", not_yet("camera frame")),
        },
        "/line" => json(snapshot.line, "line measurement"),
        "/state" => json(snapshot.state, "state"),
        "/lidar" => json(snapshot.lidar, "LIDAR scan (the scenario needs a [lidar])"),
        "/welds" => json(snapshot.welds, "weld list"),
        "/" => (200, "text/plain", b"climbsim sensors: /camera.png /camera.mjpg /line /state /lidar /welds\n".to_vec()),
        _ => (404, "text/plain", b"not found\n".to_vec()),
    };
    if let Some(hook) = feed.on_read.get() {
        hook(path, status, content_type, &body);
    }
    let status = match status {
        200 => "200 OK",
        500 => "500 Internal Server Error",
        503 => "503 Service Unavailable",
        _ => "404 Not Found",
    };
    Answer::Reply { status, content_type, body, keep_alive: asks_keep_alive(head) }
}

/// A whole response, head and body, to be written at once.
fn response(status: &str, content_type: &str, body: &[u8], keep_alive: bool) -> Vec<u8> {
    let connection = if keep_alive { "keep-alive" } else { "close" };
    let mut bytes = format!("HTTP/1.1 {status}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: {connection}\r\n\r\n", body.len()).into_bytes();
    bytes.extend_from_slice(body);
    bytes
}

mod virtual_time;
pub use virtual_time::VirtualSensorServer;

/// Send the current frame, then each new one, until the client goes away.
async fn stream_mjpeg(mut stream: TcpStream, feed: &SensorFeed) -> std::io::Result<()> {
    let head = format!("HTTP/1.1 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary={MJPEG_BOUNDARY}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n");
    stream.write_all(head.as_bytes()).await?;
    let mut frames = feed.frames.subscribe();
    loop {
        if let Some(frame) = feed.snapshot().frame {
            match frame.jpeg() {
                Ok(jpeg) => {
                    let part = format!("--{MJPEG_BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {}\r\n\r\n", jpeg.len());
                    stream.write_all(part.as_bytes()).await?;
                    stream.write_all(jpeg).await?;
                    stream.write_all(b"\r\n").await?;
                }
                Err(error) => warn!(%error, "camera frame not streamed"),
            }
        }
        if frames.changed().await.is_err() {
            warn!("sensor feed closed; ending MJPEG stream");
            return Ok(());
        }
    }
}
