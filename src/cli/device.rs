//! `serve --device`: the bus on a real serial device, with a controller on its far side.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use climbsim::transport::{BusHandle, Echo, SerialDevice, SerialError, serve_stream};
use tracing::{info, warn};

/// How often a device that disappeared (USB unplugged) is looked for again.
const REOPEN_EVERY: Duration = Duration::from_millis(500);

#[derive(Debug, Clone)]
pub struct DeviceOptions {
    pub path: PathBuf,
    pub echo: Echo,
}

/// The baud most servos listen at: what the device opens at.
fn servo_baud(handle: &BusHandle) -> Option<u32> {
    handle.with_bus(|bus| {
        let mut counts: Vec<(u32, usize)> = Vec::new();
        for bps in bus.servos().iter().filter_map(|servo| servo.baud_bps()) {
            match counts.iter_mut().find(|(rate, _)| *rate == bps) {
                Some((_, count)) => *count += 1,
                None => counts.push((bps, 1)),
            }
        }
        counts.into_iter().max_by_key(|&(_, count)| count).map(|(bps, _)| bps)
    })
}

/// Open the device on a thread of its own (precise reply timing waits there, like the pty's)
/// and serve the bus on it; returns the device's baud once it is open. A device that goes away
/// is reopened when it comes back; the bus and every other transport carry on meanwhile.
pub async fn start_device(options: DeviceOptions, handle: Arc<BusHandle>) -> Result<(std::thread::JoinHandle<()>, u32)> {
    let (opened_tx, opened_rx) = tokio::sync::oneshot::channel();
    let thread = std::thread::Builder::new().name("device".into()).spawn(move || {
        let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
            Ok(runtime) => runtime,
            Err(error) => return drop(opened_tx.send(Err(anyhow::Error::from(error)))),
        };
        runtime.block_on(async move {
            let baud = servo_baud(&handle).unwrap_or(57_600);
            // The device registers with this thread's runtime, so it is opened here.
            let device = match SerialDevice::open(&options.path, baud, options.echo) {
                Ok(device) => Arc::new(device),
                Err(error) => return drop(opened_tx.send(Err(error.into()))),
            };
            let _ = opened_tx.send(Ok(baud));
            let mut device = device;
            loop {
                // Spawned, not run in `block_on`: see the pty thread in `serve`.
                let session = tokio::spawn(serve_on(Arc::clone(&device), Arc::clone(&handle)));
                match session.await {
                    Ok(Ok(())) => warn!(device = %options.path.display(), "the device hung up"),
                    Ok(Err(error)) => warn!(device = %options.path.display(), %error, "the device failed (unplugged?)"),
                    Err(error) => warn!(device = %options.path.display(), %error, "the device session failed"),
                }
                let (echoes, missing) = device.echo_counts();
                info!(echoes, missing, "echo of own sends on the device so far");
                drop(device);
                device = reopen(&options, &handle).await;
            }
        });
    })?;
    let baud = opened_rx.await.context("the device thread ended before opening the device")??;
    Ok((thread, baud))
}

async fn serve_on(device: Arc<SerialDevice>, handle: Arc<BusHandle>) -> Result<(), climbsim::transport::TransportError> {
    let line = device.line();
    serve_stream(device.stream(), handle, &line).await
}

/// Wait for the device to come back and open it again, at the servos' baud as it is now.
async fn reopen(options: &DeviceOptions, handle: &BusHandle) -> Arc<SerialDevice> {
    let mut said = None::<String>;
    loop {
        tokio::time::sleep(REOPEN_EVERY).await;
        let baud = servo_baud(handle).unwrap_or(57_600);
        match SerialDevice::open(&options.path, baud, options.echo) {
            Ok(device) => {
                warn!(device = %options.path.display(), baud, "the device is back; serving it again");
                return Arc::new(device);
            }
            Err(error) => {
                let text = error.to_string();
                // Said once per kind of failure, not every half second.
                if said.as_deref() != Some(&text) {
                    if !matches!(error, SerialError::NotFound(_)) {
                        warn!(%error, "cannot reopen the device yet");
                    } else {
                        info!(device = %options.path.display(), "waiting for the device to come back");
                    }
                    said = Some(text);
                }
            }
        }
    }
}
