//! The sensor server over real TCP sockets: what an external controller's HTTP client sees.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::Arc;
use std::time::Duration;

use climbsim::sensor_server::{SensorFeed, SensorServer};

/// Start a server on an ephemeral port on its own runtime thread.
fn start() -> (SocketAddr, Arc<SensorFeed>) {
    let feed = Arc::new(SensorFeed::default());
    let (tx, rx) = std::sync::mpsc::channel();
    let served = Arc::clone(&feed);
    std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
        runtime.block_on(async move {
            let server = SensorServer::bind("127.0.0.1:0".parse().expect("addr")).await.expect("bind");
            tx.send(server.local_addr().expect("addr")).expect("send addr");
            server.run(served).await.expect("serve");
        });
    });
    (rx.recv_timeout(Duration::from_secs(5)).expect("server started"), feed)
}

/// GET `path` as a client that reads to the end of the stream (it does not ask to keep the
/// connection); (status line, headers, body).
fn get(addr: SocketAddr, path: &str) -> (String, String, Vec<u8>) {
    let mut stream = TcpStream::connect(addr).expect("connect");
    stream.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    write!(stream, "GET {path} HTTP/1.1\r\nHost: localhost\r\n\r\n").expect("request");
    let mut response = Vec::new();
    stream.read_to_end(&mut response).expect("response");
    let split = response.windows(4).position(|w| w == b"\r\n\r\n").expect("head end");
    let head = String::from_utf8(response[..split].to_vec()).expect("utf8 head");
    let (status, headers) = head.split_once("\r\n").unwrap_or((&head, ""));
    (status.to_owned(), headers.to_owned(), response[split + 4..].to_vec())
}

fn gradient(width: u32, height: u32) -> Vec<u8> {
    (0..width * height).map(|i| (i % 251) as u8).collect()
}

#[test]
fn camera_png_is_the_published_frame() {
    let (addr, feed) = start();
    assert!(get(addr, "/camera.png").0.contains("503"), "no frame before the first publish");
    let pixels = gradient(64, 32);
    feed.publish_frame(64, 32, &pixels).expect("publish");
    let (status, headers, body) = get(addr, "/camera.png");
    assert!(status.contains("200"), "{status}");
    assert!(headers.contains("image/png"), "{headers}");
    let decoder = png::Decoder::new(std::io::Cursor::new(body));
    let mut reader = decoder.read_info().expect("png header");
    let mut decoded = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut decoded).expect("png frame");
    assert_eq!((info.width, info.height, info.color_type), (64, 32, png::ColorType::Grayscale));
    assert_eq!(&decoded[..info.buffer_size()], &pixels[..]);
}

#[test]
fn line_and_state_are_json() {
    let (addr, feed) = start();
    assert!(get(addr, "/line").0.contains("503"));
    feed.publish_line(1.5, -0.012, 0.05, true);
    feed.publish_state(serde_json::json!({ "x": 1.0 }));
    let (status, _, body) = get(addr, "/line");
    assert!(status.contains("200"));
    let line: serde_json::Value = serde_json::from_slice(&body).expect("json");
    assert_eq!(line["t"], 1.5);
    assert_eq!(line["d"], -0.012);
    assert_eq!(line["psi"], 0.05);
    assert_eq!(line["valid"], true);
    let state: serde_json::Value = serde_json::from_slice(&get(addr, "/state").2).expect("json");
    assert_eq!(state["x"], 1.0);
}

#[test]
fn unknown_paths_and_methods_are_refused() {
    let (addr, _feed) = start();
    assert!(get(addr, "/nothing").0.contains("404"));
    let mut stream = TcpStream::connect(addr).expect("connect");
    stream.write_all(b"POST /line HTTP/1.1\r\n\r\n").expect("request");
    let mut response = String::new();
    stream.read_to_string(&mut response).expect("response");
    assert!(response.starts_with("HTTP/1.1 405"), "{response}");
}

/// The MJPEG stream sends the current frame, then each new one, as JPEG parts.
#[test]
fn mjpeg_stream_sends_a_jpeg_part_per_frame() {
    let (addr, feed) = start();
    feed.publish_frame(32, 32, &gradient(32, 32)).expect("publish");
    let mut stream = TcpStream::connect(addr).expect("connect");
    stream.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    stream.write_all(b"GET /camera.mjpg HTTP/1.1\r\n\r\n").expect("request");
    let publisher = Arc::clone(&feed);
    let more = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(200));
        publisher.publish_frame(32, 32, &vec![200; 32 * 32]).expect("publish");
    });
    let mut seen = Vec::new();
    let mut buffer = [0u8; 4096];
    // Two JPEG parts: two start-of-image markers after part headers.
    while seen.windows(2).filter(|w| *w == [0xFF, 0xD8]).count() < 2 {
        let n = stream.read(&mut buffer).expect("stream data");
        assert!(n > 0, "stream ended early");
        seen.extend_from_slice(&buffer[..n]);
    }
    more.join().expect("publisher");
    let text = String::from_utf8_lossy(&seen);
    assert!(text.starts_with("HTTP/1.1 200"), "{}", &text[..40.min(text.len())]);
    assert!(text.contains("multipart/x-mixed-replace; boundary=climbsimframe"));
    assert_eq!(text.matches("--climbsimframe\r\nContent-Type: image/jpeg").count(), 2);
}

/// One answer off a kept connection: (status line, headers, body), read by its Content-Length.
fn read_answer(reader: &mut std::io::BufReader<TcpStream>) -> (String, String, Vec<u8>) {
    use std::io::BufRead as _;
    let mut head = String::new();
    while !head.ends_with("\r\n\r\n") {
        assert!(reader.read_line(&mut head).expect("head line") > 0, "the connection ended inside a head: {head:?}");
    }
    let (status, headers) = head.trim_end().split_once("\r\n").unwrap_or((head.trim_end(), ""));
    let length: usize = headers.lines().find_map(|l| l.strip_prefix("Content-Length: ")).expect("Content-Length").parse().expect("a length");
    let mut body = vec![0; length];
    reader.read_exact(&mut body).expect("body");
    (status.to_owned(), headers.to_owned(), body)
}

#[test]
fn a_client_that_asks_keeps_its_connection_for_request_after_request_and_a_close_ends_it() {
    let (addr, feed) = start();
    feed.publish_line(1.5, -0.012, 0.05, true);
    let stream = TcpStream::connect(addr).expect("connect");
    stream.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    let mut writer = stream.try_clone().expect("clone");
    let mut reader = std::io::BufReader::new(stream);
    // One at a time, then two sent at once (pipelined): each answered, in order, on the one
    // connection, which the server says it keeps.
    write!(writer, "GET /line HTTP/1.1\r\nHost: localhost\r\nConnection: keep-alive\r\n\r\n").expect("request");
    let (status, headers, body) = read_answer(&mut reader);
    assert!(status.contains("200") && headers.contains("Connection: keep-alive"), "{status} {headers}");
    assert_eq!(serde_json::from_slice::<serde_json::Value>(&body).expect("JSON")["t"], 1.5);
    feed.publish_line(2.0, 0.0, 0.0, false);
    write!(writer, "GET /line HTTP/1.1\r\nconnection: Keep-Alive\r\n\r\nGET /nothing HTTP/1.1\r\nConnection: keep-alive\r\n\r\n").expect("two requests");
    let (status, _, body) = read_answer(&mut reader);
    assert!(status.contains("200"), "{status}");
    assert_eq!(serde_json::from_slice::<serde_json::Value>(&body).expect("JSON")["t"], 2.0, "the latest line, not the first");
    assert!(read_answer(&mut reader).0.contains("404"));
    // A request without the ask is the connection's last: answered, then the end of the stream.
    write!(writer, "GET /line HTTP/1.1\r\nHost: localhost\r\n\r\n").expect("request");
    let (status, headers, _) = read_answer(&mut reader);
    assert!(status.contains("200") && headers.contains("Connection: close"), "{status} {headers}");
    let mut rest = Vec::new();
    reader.read_to_end(&mut rest).expect("the end of the stream");
    assert!(rest.is_empty(), "{rest:?}");
}
