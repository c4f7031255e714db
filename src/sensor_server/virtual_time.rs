//! The sensor server under virtual time: no thread and no reactor of its own; the scheduler
//! polls it (it is a future that never ends) whenever the controller is parked, so that every
//! request is answered at the simulated instant it was sent, from that instant's snapshot. Each
//! connection's bytes are reported to the scheduler: read (time may move once the server has
//! them all) and answered (a thread waiting for the answer may run).

use std::future::Future;
use std::io::{Read as _, Write as _};
use std::net::{Ipv4Addr, SocketAddrV4, TcpListener, TcpStream};
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use tracing::debug;

use super::{Answer, SensorFeed, SensorServerError, answer, response, take_request};
use crate::virtual_time::SensorLedger;

pub struct VirtualSensorServer {
    listener: TcpListener,
    clients: Vec<Client>,
    feed: Arc<SensorFeed>,
    ledger: Arc<SensorLedger>,
}

struct Client {
    stream: TcpStream,
    port: u16,
    /// What the client sent that is not answered yet.
    buffer: Vec<u8>,
}

impl VirtualSensorServer {
    /// Listen on an ephemeral localhost port; the URL controllers get.
    pub fn bind(feed: Arc<SensorFeed>, ledger: Arc<SensorLedger>) -> Result<(Self, String), SensorServerError> {
        let addr = SocketAddrV4::new(Ipv4Addr::LOCALHOST, 0);
        let listener = TcpListener::bind(addr).map_err(|source| SensorServerError::Bind { addr: addr.into(), source })?;
        listener.set_nonblocking(true)?;
        let std::net::SocketAddr::V4(local) = listener.local_addr()? else {
            return Err(SensorServerError::Io(std::io::Error::other("an IPv4 listener has an IPv4 address")));
        };
        ledger.attach_server(local);
        Ok((Self { listener, clients: Vec::new(), feed, ledger }, format!("http://{local}")))
    }

    /// Accept, read and answer whatever is there, without waiting.
    fn step(&mut self) {
        // A look first: a failed accept costs the kernel a socket made and freed (about 10 µs
        // on a VM), and the server is polled at every exchange of a kept connection.
        while connection_waiting(&self.listener)
            && let Ok((stream, peer)) = self.listener.accept()
        {
            if stream.set_nonblocking(true).is_ok() {
                self.clients.push(Client { stream, port: peer.port(), buffer: Vec::new() });
            }
        }
        let (feed, ledger) = (&self.feed, &self.ledger);
        self.clients.retain_mut(|client| serve(client, feed, ledger));
    }
}

/// Whether a connection waits to be accepted (the listener is readable), asked without waiting.
fn connection_waiting(listener: &TcpListener) -> bool {
    use std::os::fd::AsFd as _;
    // An error (none is expected on a listener) falls back to trying the accept.
    poll(&mut [PollFd::new(listener.as_fd(), PollFlags::POLLIN)], PollTimeout::ZERO) != Ok(0)
}

/// Read what the client sent and answer every whole request in it; whether to keep the
/// connection.
fn serve(client: &mut Client, feed: &SensorFeed, ledger: &SensorLedger) -> bool {
    let mut chunk = [0u8; 2048];
    let mut read = 0;
    let mut keep = loop {
        match client.stream.read(&mut chunk) {
            Ok(0) => break false,
            Ok(n) => {
                read += n;
                client.buffer.extend_from_slice(&chunk[..n]);
            }
            Err(error) if error.kind() == std::io::ErrorKind::WouldBlock => break true,
            Err(error) => {
                debug!(%error, "sensor client gone");
                break false;
            }
        }
    };
    while keep {
        let Some(head) = take_request(&mut client.buffer) else { break };
        let (status, content_type, body, keep_alive) = match answer(&head, feed, false) {
            Answer::Reply { status, content_type, body, keep_alive } => (status, content_type, body, keep_alive),
            Answer::Mjpeg => ("501 Not Implemented", "text/plain", b"not under --clock virtual\n".to_vec(), false),
        };
        let bytes = response(status, content_type, &body, keep_alive);
        // Written whole (and the end, when it is the last) before anything else happens.
        let written = write_whole(&mut client.stream, &bytes).and_then(|()| if keep_alive { Ok(()) } else { client.stream.shutdown(std::net::Shutdown::Write) });
        if let Err(error) = &written {
            debug!(%error, "sensor client gone before its answer");
        }
        ledger.response_written(client.port, bytes.len(), !keep_alive);
        keep = keep_alive && written.is_ok();
    }
    // A kept connection is looked at on every poll and mostly has nothing new.
    if read > 0 {
        ledger.request_read(client.port, read);
    }
    keep
}

/// `bytes` written whole to a non-blocking stream: at once when the socket's buffer takes them
/// (an answer of a few hundred bytes always fits), else the rest blocking.
fn write_whole(stream: &mut TcpStream, bytes: &[u8]) -> std::io::Result<()> {
    let done = match stream.write(bytes) {
        Ok(n) => n,
        Err(error) if error.kind() == std::io::ErrorKind::WouldBlock => 0,
        Err(error) => return Err(error),
    };
    if done < bytes.len() {
        stream.set_nonblocking(false)?;
        stream.write_all(&bytes[done..])?;
        stream.set_nonblocking(true)?;
    }
    Ok(())
}

impl Future for VirtualSensorServer {
    type Output = ();

    fn poll(mut self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<()> {
        self.step();
        Poll::Pending
    }
}
