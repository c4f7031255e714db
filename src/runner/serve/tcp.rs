//! The TCP transports: a listener controllers connect to (`--tcp`), and a client that connects
//! to a controller that is a TCP server, such as firmware in an emulator (`--tcp-connect`).

use std::net::SocketAddr;
use std::sync::Arc;

use tracing::warn;

use crate::transport::{BusHandle, TcpServer, connect_forever};

use crate::runner::{During as _, Result};

/// Listen on `addr` (on the current runtime) and serve every controller that connects; the
/// address it listens on.
pub async fn listen(addr: SocketAddr, handle: Arc<BusHandle>) -> Result<SocketAddr> {
    let server = TcpServer::bind(addr).await.during(|| format!("cannot listen on {addr}"))?;
    let bound = server.local_addr().during(|| format!("cannot listen on {addr}"))?;
    tokio::spawn(async move {
        if let Err(error) = server.run(handle).await {
            warn!(%error, "TCP listener stopped");
        }
    });
    Ok(bound)
}

/// Connect to the controller at `addr` on a thread of its own, again whenever it goes away.
pub fn connect(addr: SocketAddr, handle: Arc<BusHandle>) -> Result<()> {
    connect_forever(addr, handle).during(|| format!("--tcp-connect {addr}"))?;
    Ok(())
}
