//! The SocketCAN transport (`serve --can IFACE`): each Dynamixel packet one ISO-TP message.

use std::sync::Arc;

use crate::transport::BusHandle;
use crate::transport::can::CanIds;

use crate::runner::Result;

/// `--can IFACE` with its CAN ID pair and padding.
#[derive(Debug, Clone)]
#[cfg_attr(not(all(feature = "can", target_os = "linux")), allow(dead_code))]
pub struct CanOptions {
    pub iface: String,
    pub ids: CanIds,
    /// The byte every frame the bus sends is padded to 8 bytes with; `None`: the shortest frames.
    pub padding: Option<u8>,
}

/// Open the CAN interface on a thread of its own (precise reply timing spins, like the pty's) and
/// serve the bus there; returns once the socket is open.
#[cfg(all(feature = "can", target_os = "linux"))]
pub async fn start(options: CanOptions, handle: Arc<BusHandle>) -> Result<std::thread::JoinHandle<()>> {
    use tracing::{info, warn};

    use crate::runner::{During as _, RunnerError};
    use crate::transport::can::{SocketCanPort, isotp, serve_can};

    let (opened_tx, opened_rx) = tokio::sync::oneshot::channel();
    let thread = std::thread::Builder::new()
        .name("can".into())
        .spawn(move || {
            let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(runtime) => runtime,
                Err(error) => return drop(opened_tx.send(Err(RunnerError::during("cannot start the CAN thread's runtime", error)))),
            };
            runtime.block_on(async move {
                // The socket registers with this thread's runtime, so it is opened here.
                let port = match SocketCanPort::open(&options.iface, options.ids.request) {
                    Ok(port) => port,
                    Err(error) => return drop(opened_tx.send(Err(RunnerError::during(format!("--can {}", options.iface), error)))),
                };
                let _ = opened_tx.send(Ok(()));
                let config = isotp::Config { padding: options.padding, ..isotp::Config::default() };
                let session = tokio::spawn(serve_can(port, options.ids, config, handle));
                match session.await {
                    Ok(Ok(())) => info!(iface = options.iface, "CAN session ended"),
                    Ok(Err(error)) => warn!(iface = options.iface, %error, "CAN session ended"),
                    Err(error) => warn!(iface = options.iface, %error, "CAN session failed"),
                }
            });
        })
        .during(|| "cannot start the CAN thread".to_owned())?;
    opened_rx.await.map_err(|_| RunnerError::Invalid("the CAN thread ended before opening its socket".to_owned()))??;
    Ok(thread)
}

#[cfg(not(all(feature = "can", target_os = "linux")))]
pub async fn start(_options: CanOptions, _handle: Arc<BusHandle>) -> Result<std::thread::JoinHandle<()>> {
    Err(crate::runner::RunnerError::Invalid("--can needs SocketCAN: this climbsim was built without the `can` feature or not for Linux".to_owned()))
}
