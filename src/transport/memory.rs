//! In-memory transport: a tokio duplex pipe with the bus on the far end, for tests and for the
//! in-process controller. No baud: every servo hears every packet.

use std::sync::Arc;

use tokio::io::DuplexStream;
use tracing::warn;

use super::{BusHandle, NoLine, serve_stream};

/// Buffer of the in-memory pipe in each direction; larger than any packet the SDKs send.
const PIPE_CAPACITY: usize = 64 * 1024;

/// Spawn the bus side on the current tokio runtime and return the controller's end.
pub fn connect(handle: Arc<BusHandle>) -> DuplexStream {
    let (controller, bus_side) = tokio::io::duplex(PIPE_CAPACITY);
    tokio::spawn(async move {
        if let Err(error) = serve_stream(bus_side, handle, &NoLine).await {
            warn!(%error, "in-memory session ended");
        }
    });
    controller
}
