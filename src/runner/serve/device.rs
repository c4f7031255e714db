//! `serve --device`: the bus on a real serial device, with a controller on its far side.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use crate::transport::latency::{self, LowLatencyGuard};
use crate::transport::rs485::Rs485Delays;
use crate::transport::{BusHandle, DeviceSettings, Echo, SerialDevice, SerialError, majority_baud, serve_stream};
use tokio::sync::Notify;
use tracing::{info, warn};

use crate::runner::{Result, RunnerError};

/// How often a device that disappeared (USB unplugged) is looked for again.
const REOPEN_EVERY: Duration = Duration::from_millis(500);
/// How long shutdown waits for the device thread to put the adapter's settings back.
const STOP_WAIT: Duration = Duration::from_secs(2);

#[derive(Debug, Clone)]
pub struct DeviceOptions {
    pub path: PathBuf,
    pub echo: Echo,
    /// `--low-latency`: the adapter's latency timer to 1 ms and ASYNC_LOW_LATENCY, both put back
    /// on exit.
    pub low_latency: bool,
    /// `--rs485`: an on-chip UART in Linux's RS-485 mode.
    pub rs485: Option<Rs485Delays>,
}

/// The device's thread, serving it until stopped.
pub struct DeviceService {
    thread: std::thread::JoinHandle<()>,
    stop: Arc<Notify>,
    /// The rate it opened at.
    pub baud: u32,
}

impl DeviceService {
    pub fn is_finished(&self) -> bool {
        self.thread.is_finished()
    }

    /// End the session, close the device and put its latency settings back.
    pub fn stop(self) {
        self.stop.notify_one();
        let deadline = std::time::Instant::now() + STOP_WAIT;
        while !self.thread.is_finished() && std::time::Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        if self.thread.is_finished() {
            let _ = self.thread.join();
        } else {
            warn!("the device thread did not stop; the adapter's latency settings may not be restored");
        }
    }
}

/// The baud most servos listen at: what the device opens at.
fn servo_baud(handle: &BusHandle) -> Option<u32> {
    handle.with_bus(|bus| majority_baud(bus.servos().iter().filter_map(|servo| servo.baud_bps()), None))
}

/// The adapter's latency timer: said at start, and set to 1 ms with `--low-latency`.
fn latency_timer(options: &DeviceOptions) -> Result<Option<LowLatencyGuard>, latency::LatencyError> {
    let sysfs = latency::sysfs_root();
    if options.low_latency {
        return latency::set_low(&options.path, &sysfs).map(Some);
    }
    if let Some(timer) = latency::read_timer(&options.path, &sysfs) {
        latency::warn_if_slow(&options.path, &timer);
    }
    Ok(None)
}

/// The device with its latency settings.
struct Opened {
    device: Arc<SerialDevice>,
    // Dropped after the device: the timer is put back once the descriptor is closed.
    _timer: Option<LowLatencyGuard>,
}

/// Why the device could not be opened (or reopened).
#[derive(Debug, thiserror::Error)]
enum OpenError {
    #[error(transparent)]
    Serial(#[from] SerialError),
    #[error(transparent)]
    Latency(#[from] latency::LatencyError),
}

fn open(options: &DeviceOptions, handle: &BusHandle) -> Result<Opened, OpenError> {
    let baud = servo_baud(handle).unwrap_or(57_600);
    let settings = DeviceSettings { echo: options.echo, low_latency: options.low_latency, rs485: options.rs485 };
    let device = SerialDevice::open(&options.path, baud, &settings)?;
    // After the device: while it is unplugged its sysfs entry is gone too.
    let timer = latency_timer(options)?;
    Ok(Opened { device: Arc::new(device), _timer: timer })
}

/// Open the device on a thread of its own (precise reply timing waits there, like the pty's)
/// and serve the bus on it; returns once it is open. A device that goes away is reopened when
/// it comes back; the bus and every other transport carry on meanwhile.
pub async fn start_device(options: DeviceOptions, handle: Arc<BusHandle>) -> Result<DeviceService> {
    let (opened_tx, opened_rx) = tokio::sync::oneshot::channel();
    let stop = Arc::new(Notify::new());
    let stop_thread = Arc::clone(&stop);
    let thread = std::thread::Builder::new()
        .name("device".into())
        .spawn(move || {
            let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(runtime) => runtime,
                Err(error) => return drop(opened_tx.send(Err(RunnerError::during("cannot start the device thread's runtime", error)))),
            };
            runtime.block_on(async move {
                // The device registers with this thread's runtime, so it is opened here.
                let mut opened = match open(&options, &handle) {
                    Ok(opened) => opened,
                    Err(error) => return drop(opened_tx.send(Err(RunnerError::during(format!("--device {}", options.path.display()), error)))),
                };
                let _ = opened_tx.send(Ok(opened.device.baud()));
                loop {
                    // Spawned, not run in `block_on`: see the pty thread in `serve`.
                    let mut session = tokio::spawn(serve_on(Arc::clone(&opened.device), Arc::clone(&handle)));
                    tokio::select! {
                        () = stop_thread.notified() => return session.abort(),
                        ended = &mut session => match ended {
                            Ok(Ok(())) => warn!(device = %options.path.display(), "the device hung up"),
                            Ok(Err(error)) => warn!(device = %options.path.display(), %error, "the device failed (unplugged?)"),
                            Err(error) => warn!(device = %options.path.display(), %error, "the device session failed"),
                        },
                    }
                    let (echoes, missing) = opened.device.echo_counts();
                    info!(echoes, missing, "echo of own sends on the device so far");
                    drop(opened);
                    opened = tokio::select! {
                        () = stop_thread.notified() => return,
                        back = reopen(&options, &handle) => back,
                    };
                }
            });
        })
        .map_err(|error| RunnerError::during("cannot start the device thread", error))?;
    let baud = opened_rx.await.map_err(|_| RunnerError::Invalid("the device thread ended before opening the device".to_owned()))??;
    Ok(DeviceService { thread, stop, baud })
}

async fn serve_on(device: Arc<SerialDevice>, handle: Arc<BusHandle>) -> Result<(), crate::transport::TransportError> {
    let line = device.line();
    serve_stream(device.stream(), handle, &line).await
}

/// Wait for the device to come back and open it again, at the servos' baud as it is now.
async fn reopen(options: &DeviceOptions, handle: &BusHandle) -> Opened {
    let mut said = None::<String>;
    loop {
        tokio::time::sleep(REOPEN_EVERY).await;
        match open(options, handle) {
            Ok(opened) => {
                warn!(device = %options.path.display(), baud = opened.device.baud(), "the device is back; serving it again");
                return opened;
            }
            Err(error) => {
                let text = crate::runner::describe(&error);
                // Said once per kind of failure, not every half second.
                if said.as_deref() != Some(&text) {
                    if matches!(error, OpenError::Serial(SerialError::NotFound(_))) {
                        info!(device = %options.path.display(), "waiting for the device to come back");
                    } else {
                        warn!(error = %text, "cannot reopen the device yet");
                    }
                    said = Some(text);
                }
            }
        }
    }
}
