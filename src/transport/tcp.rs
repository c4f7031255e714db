//! TCP transport: the same byte stream as the serial line, for controllers that reach the bus
//! through a serial-to-network bridge. As a server (`--tcp`) it binds to 127.0.0.1 unless told
//! otherwise; as a client (`--tcp-connect`) it connects to an emulator's serial port.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::Arc;
use std::time::Duration;

use tokio::net::{TcpListener, TcpStream};
use tracing::{info, warn};

use super::{BusHandle, LineSettings, TransportError, serve_stream};

/// `PORT` or `HOST:PORT`; a bare port binds to 127.0.0.1.
/// A server to connect to (`--tcp-connect`): [`parse_tcp_addr`], refusing port 0 and an
/// unspecified address, which name no server (a connect to them would be retried forever).
pub fn parse_tcp_server_addr(text: &str) -> Result<SocketAddr, String> {
    let addr = parse_tcp_addr(text)?;
    if addr.port() == 0 || addr.ip().is_unspecified() {
        return Err(format!("{addr} names no server to connect to (give the HOST:PORT the controller listens on)"));
    }
    Ok(addr)
}

pub fn parse_tcp_addr(text: &str) -> Result<SocketAddr, String> {
    if let Ok(port) = text.parse::<u16>() {
        return Ok(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port));
    }
    if let Ok(addr) = text.parse::<SocketAddr>() {
        return Ok(addr);
    }
    // A host name (`localhost:5000`): resolved here, once, preferring IPv4 as a bare port does.
    use std::net::ToSocketAddrs as _;
    let resolved: Vec<SocketAddr> = text.to_socket_addrs().map_err(|e| format!("`{text}` is not PORT or HOST:PORT ({e})"))?.collect();
    resolved.iter().find(|a| a.is_ipv4()).or_else(|| resolved.first()).copied().ok_or_else(|| format!("`{text}` resolves to no address"))
}

pub struct TcpServer {
    listener: TcpListener,
}

impl TcpServer {
    pub async fn bind(addr: SocketAddr) -> Result<Self, TransportError> {
        let listener = TcpListener::bind(addr).await.map_err(TransportError::Tcp)?;
        Ok(Self { listener })
    }

    pub fn local_addr(&self) -> Result<SocketAddr, TransportError> {
        self.listener.local_addr().map_err(TransportError::Tcp)
    }

    /// Accept controllers forever; each one is served on its own thread so that the precise
    /// reply timing of one never stalls another.
    pub async fn run(self, handle: Arc<BusHandle>) -> Result<(), TransportError> {
        loop {
            let (stream, peer) = self.listener.accept().await.map_err(TransportError::Tcp)?;
            stream.set_nodelay(true).map_err(TransportError::Tcp)?;
            let stream = stream.into_std().map_err(TransportError::Tcp)?;
            let handle = Arc::clone(&handle);
            info!(%peer, "controller connected over TCP");
            std::thread::spawn(move || {
                let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                    Ok(runtime) => runtime,
                    Err(error) => return warn!(%error, "cannot start a TCP session runtime"),
                };
                let result = runtime.block_on(async move {
                    let stream = tokio::net::TcpStream::from_std(stream)?;
                    let line = TcpLine::of(&stream);
                    serve_stream(stream, handle, &line).await
                });
                match result {
                    Ok(()) => info!(%peer, "controller disconnected"),
                    Err(error) => warn!(%peer, %error, "TCP session ended"),
                }
            });
        }
    }
}

/// How long a packet begun on a TCP stream may wait for its next bytes. A byte stream has no
/// baud, so the servos' 1.5 ms inter-byte timeout means nothing on it: an emulator's UART hands
/// each byte to its socket as it is written, and with Nagle on the rest of a packet waits for
/// the first byte's ACK, and the reading thread's own wake-up lands on the gap too. Long
/// enough for a delayed ACK (40-200 ms on Linux), short enough that a packet cut by a
/// controller that died mid-write does not linger.
pub const TCP_INTER_BYTE_TIMEOUT: Duration = Duration::from_millis(500);

/// A TCP stream as a line: no baud, its own inter-byte timeout, and quick ACKs.
pub struct TcpLine {
    fd: std::os::fd::RawFd,
}

impl TcpLine {
    pub fn of(stream: &TcpStream) -> Self {
        use std::os::fd::AsRawFd as _;
        let line = Self { fd: stream.as_raw_fd() };
        line.quick_ack();
        line
    }

    /// TCP_QUICKACK: acknowledge at once, so that a sender holding the rest of a packet until
    /// its first byte is acknowledged (Nagle) is not held for a delayed ACK. Linux clears it
    /// again after a while, so it is set after every read.
    fn quick_ack(&self) {
        let on: libc::c_int = 1;
        // SAFETY: setsockopt with a valid socket descriptor (the stream outlives the session
        // that calls this) and a c_int option value of the right size.
        unsafe {
            libc::setsockopt(self.fd, libc::IPPROTO_TCP, libc::TCP_QUICKACK, (&raw const on).cast(), std::mem::size_of::<libc::c_int>() as libc::socklen_t);
        }
    }
}

impl LineSettings for TcpLine {
    fn baud(&self) -> Option<u32> {
        None
    }

    fn inter_byte_timeout(&self) -> Option<Duration> {
        Some(TCP_INTER_BYTE_TIMEOUT)
    }

    fn read_done(&self) {
        self.quick_ack();
    }
}

/// How often `--tcp-connect` tries again while nothing listens.
const RECONNECT_EVERY: Duration = Duration::from_millis(500);

/// Connect out to `addr` and serve the bus there, reconnecting whenever the connection ends or
/// cannot be made: for firmware in an emulator whose UART is a TCP server (QEMU `-serial
/// tcp::PORT,server`, Renode's `CreateServerSocketTerminal`), which may start after climbsim
/// and restart any number of times. Runs on a thread of its own for the process's life.
pub fn connect_forever(addr: SocketAddr, handle: Arc<BusHandle>) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new().name("tcp-connect".into()).spawn(move || {
        let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
            Ok(runtime) => runtime,
            Err(error) => return warn!(%error, "cannot start the TCP client runtime"),
        };
        runtime.block_on(async move {
            let mut said: Option<String> = None;
            loop {
                match TcpStream::connect(addr).await {
                    Ok(stream) => {
                        said = None;
                        if let Err(error) = stream.set_nodelay(true) {
                            warn!(%error, "TCP_NODELAY");
                        }
                        info!(%addr, "connected to the controller over TCP");
                        let line = TcpLine::of(&stream);
                        // Spawned, not run in `block_on`: see the pty thread in `serve`.
                        let handle = Arc::clone(&handle);
                        let session = tokio::spawn(async move { serve_stream(stream, handle, &line).await });
                        match session.await {
                            Ok(Ok(())) => warn!(%addr, "the controller closed the TCP connection; reconnecting"),
                            Ok(Err(error)) => warn!(%addr, %error, "the TCP connection failed; reconnecting"),
                            Err(error) => warn!(%addr, %error, "the TCP session failed; reconnecting"),
                        }
                    }
                    Err(error) => {
                        // Said once per kind of failure, not every half second.
                        let text = error.to_string();
                        if said.as_deref() != Some(text.as_str()) {
                            // At the default level: a user waiting on a wrong address sees why.
                            warn!(%addr, %error, "cannot connect yet; trying every {} ms", RECONNECT_EVERY.as_millis());
                            said = Some(text);
                        }
                    }
                }
                tokio::time::sleep(RECONNECT_EVERY).await;
            }
        });
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tcp_addresses_take_a_port_an_address_or_a_host_name() {
        assert_eq!(parse_tcp_addr("5000"), Ok(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 5000)));
        assert_eq!(parse_tcp_addr("0.0.0.0:5000"), Ok(SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), 5000)));
        // `localhost:5000` was refused: a host name is resolved.
        let resolved = parse_tcp_addr("localhost:5000").expect("localhost resolves");
        assert!(resolved.ip().is_loopback() && resolved.port() == 5000, "{resolved}");
        assert!(parse_tcp_addr("localhost").is_err());
        assert!(parse_tcp_addr("no-such-host.invalid:1").is_err());
    }
}
