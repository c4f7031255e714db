//! TCP transport: the same byte stream as the serial line, for controllers that reach the bus
//! through a serial-to-network bridge. Binds to 127.0.0.1 unless told otherwise.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::Arc;

use tokio::net::TcpListener;
use tracing::{info, warn};

use super::{BusHandle, NoLine, TransportError, serve_stream};

/// `PORT` or `HOST:PORT`; a bare port binds to 127.0.0.1.
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
                    serve_stream(stream, handle, &NoLine).await
                });
                match result {
                    Ok(()) => info!(%peer, "controller disconnected"),
                    Err(error) => warn!(%peer, %error, "TCP session ended"),
                }
            });
        }
    }
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
