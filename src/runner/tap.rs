//! `climbsim tap`: a recording bridge between an unchanged controller and real servos. The
//! controller opens a pseudo-terminal as it would the adapter; every byte is forwarded to the
//! serial device as soon as it is read, and every byte back, unaltered (nothing dropped, added
//! or reordered). Both directions are framed and paired ([`crate::real_bus`]) and written as a
//! real bus's transcript, with a timing report of the servos at the end, shown in Foxglove
//! if asked ([`super::tap_view`]), and re-enacted live in a scenario's world if asked
//! ([`super::tap_world`]).
//!
//! One thread polls both descriptors with poll(2) (no reactor between the two: a byte read is
//! written to the other side within the same wake-up). The controller's rate is followed: when
//! its port's rate changes, the device switches before the bytes sent after the change.

use std::io;
use std::os::fd::{BorrowedFd, RawFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use nix::errno::Errno;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use tracing::{info, warn};

use crate::real_bus::{Event, Pairing, RealHeader, RealRecord, TimingReport, TimingTally};
use crate::transcript::{Recorder, nanos};
use crate::transport::latency::{self, LowLatencyGuard};
use crate::transport::{DeviceSettings, Echo, LineSettings, SerialDevice, VirtualPort, queued_bytes};

use super::compare::CompareReport;
use super::tap_view::{TapView, TapViewOptions};
use super::tap_world::{TapWorld, TapWorldOptions};
use super::{Result, RunnerError};

/// How often the loop looks at the stop flag while both sides are quiet.
const QUIET_POLL: Duration = Duration::from_millis(50);
/// How long after bytes passed the loop spins on both sides' queues instead of sleeping in
/// poll(2): the other side's answer (a reply, the controller's next request) usually follows
/// within a millisecond, and a wake-up from poll costs tens of microseconds on a VM whose idle
/// CPUs halt (`cargo bench --bench tap_latency`: docs/performance.md). Not on one CPU.
const SPIN_AFTER_TRAFFIC: Duration = Duration::from_millis(2);

#[derive(Debug, Clone)]
pub struct TapOptions {
    /// The serial device the servos are on.
    pub device: PathBuf,
    /// The port the controller opens (a symlink to the pseudo-terminal).
    pub link: PathBuf,
    /// The transcript.
    pub record: PathBuf,
    /// The timing report (JSON).
    pub report: PathBuf,
    /// The rate the device (and the port, until the controller sets one) starts at.
    pub baud: u32,
    /// The adapter's latency timer to 1 ms and ASYNC_LOW_LATENCY, both put back on exit.
    pub low_latency: bool,
    /// Show the real servos in Foxglove, live or recorded (`--foxglove`, `--mcap`).
    pub view: Option<TapViewOptions>,
    /// Re-enact the session live in a scenario's world, and compare (`--scenario`; the
    /// comparison goes into the options' `out`).
    pub world: Option<TapWorldOptions>,
}

/// How the session went.
#[derive(Debug, Clone)]
pub struct TapOutcome {
    /// Why it ended: interrupted, or the device went away.
    pub ended: String,
    pub from_controller: u64,
    pub from_servos: u64,
    pub report: TimingReport,
    /// The live comparison with the world (`--scenario`).
    pub comparison: Option<CompareReport>,
}

/// The default timing report's path: beside the transcript, `NAME.timing.json`.
pub fn default_report_path(record: &Path) -> PathBuf {
    beside_transcript(record, "timing.json")
}

/// `NAME.suffix` beside the transcript `record` (NAME: its name without its extension).
pub fn beside_transcript(record: &Path, suffix: &str) -> PathBuf {
    let stem = record.file_stem().map_or_else(|| "tap".into(), |s| s.to_string_lossy().into_owned());
    record.with_file_name(format!("{stem}.{suffix}"))
}

/// Where the tap shows what it does, once it is ready: the port the controller opens, and the
/// live views' URLs (the real servos; the world re-enacting them).
pub struct TapReady<'a> {
    pub port: &'a Path,
    pub servos_url: Option<&'a str>,
    pub world_url: Option<&'a str>,
}

/// Run the bridge until `stop` is set or the device goes away; `ready` is called once the
/// controller's port can be opened, with where everything is shown. The
/// transcript ends with an `end` line and the timing report is written whichever way the
/// session ends.
pub fn tap(options: &TapOptions, stop: &AtomicBool, ready: impl FnOnce(&TapReady<'_>)) -> Result<TapOutcome> {
    // The device and the port register with a reactor when opened; this thread never polls it
    // (it polls the descriptors itself), but they need one to exist.
    let runtime = tokio::runtime::Builder::new_current_thread().enable_io().build().map_err(|e| RunnerError::during("cannot start the tap's runtime", e))?;
    let _entered = runtime.enter();
    let settings = DeviceSettings { echo: Echo::Off, low_latency: options.low_latency, rs485: None };
    let device = SerialDevice::open(&options.device, options.baud, &settings).map_err(|e| RunnerError::during(format!("tap --device {}", options.device.display()), e))?;
    let _timer: Option<LowLatencyGuard> =
        if options.low_latency { Some(latency::set_low(&options.device, &latency::sysfs_root()).map_err(|e| RunnerError::during("tap --low-latency", e))?) } else { None };
    let port = VirtualPort::open(Some(&options.link)).map_err(|e| RunnerError::during("tap --link", e))?;
    port.set_controller_baud(options.baud).map_err(|e| RunnerError::during("tap: setting the port's rate", e))?;
    let started_unix_ns = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, nanos);
    let header = RealHeader::new(&options.device, &options.link, options.baud, started_unix_ns);
    let recorder = Recorder::create(&options.record, &header).map_err(|e| RunnerError::during("tap --record", e))?;
    let view = options.view.as_ref().map(TapView::start).transpose()?;
    let world = options.world.as_ref().map(|compare| TapWorld::start(&options.record, compare)).transpose()?;
    info!(device = %options.device.display(), link = %port.path().display(), baud = options.baud, "tap ready");
    ready(&TapReady { port: port.path(), servos_url: view.as_ref().and_then(TapView::live_url), world_url: world.as_ref().and_then(TapWorld::live_url) });

    let mut bridge = Bridge {
        device: &device,
        port: &port,
        recorder: &recorder,
        view,
        world,
        pairing: Pairing::default(),
        tally: TimingTally::default(),
        started: Instant::now(),
        baud: options.baud,
        from_controller: 0,
        from_servos: 0,
    };
    let ended = bridge.run(stop);
    let at = bridge.started.elapsed();
    for event in bridge.pairing.finish(at) {
        bridge.record(&event);
    }
    let (from_controller, from_servos) = (bridge.from_controller, bridge.from_servos);
    let report = bridge.tally.report();
    let finished = recorder.finish_with(&RealRecord::end(at, &ended, from_controller, from_servos));
    let view_finished = bridge.view.take().map_or(Ok(()), TapView::finish);
    write_report(&options.report, &report)?;
    finished.map_err(|e| RunnerError::during("tap --record", e))?;
    view_finished?;
    // Last: the transcript and the timing report are complete whatever the world makes of it.
    let comparison = bridge.world.take().map(TapWorld::finish).transpose()?;
    Ok(TapOutcome { ended, from_controller, from_servos, report, comparison })
}

fn write_report(path: &Path, report: &TimingReport) -> Result<()> {
    let text = serde_json::to_string_pretty(report).map_err(|e| RunnerError::during("the timing report", e))?;
    std::fs::write(path, text + "\n").map_err(|e| RunnerError::during(format!("writing {}", path.display()), e))
}

struct Bridge<'a> {
    device: &'a SerialDevice,
    port: &'a VirtualPort,
    recorder: &'a Recorder,
    /// Where the events are shown too, if anywhere.
    view: Option<TapView>,
    /// The world re-enacting the session, if asked: it gets every record written.
    world: Option<TapWorld>,
    pairing: Pairing,
    tally: TimingTally,
    started: Instant,
    /// The line's rate as the controller last set it.
    baud: u32,
    from_controller: u64,
    from_servos: u64,
}

impl Bridge<'_> {
    /// Forward until stopped or the device goes; why it ended.
    fn run(&mut self, stop: &AtomicBool) -> String {
        let (master, device) = (self.port.raw_master(), self.device.raw_fd());
        let mut buf = vec![0u8; 4096];
        let spins = std::thread::available_parallelism().is_ok_and(|n| n.get() > 1);
        let mut spin_until = Instant::now();
        loop {
            if stop.load(Ordering::Relaxed) {
                return "interrupted".to_owned();
            }
            let spinning = spins && Instant::now() < spin_until;
            if spinning {
                // FIONREAD, not read(2): a read of an empty pty waits for the kernel's flush
                // worker when it has bytes queued. A side that cannot say goes to poll.
                let waiting = [queued_bytes(master), queued_bytes(device)];
                if waiting.iter().all(|n| *n == Some(0)) {
                    std::hint::spin_loop();
                    continue;
                }
            }
            // SAFETY: both descriptors stay open for the bridge's life (the port and the device
            // outlive it).
            let (master_fd, device_fd) = unsafe { (BorrowedFd::borrow_raw(master), BorrowedFd::borrow_raw(device)) };
            let mut fds = [PollFd::new(master_fd, PollFlags::POLLIN), PollFd::new(device_fd, PollFlags::POLLIN)];
            let timeout = if spinning { PollTimeout::ZERO } else { PollTimeout::try_from(QUIET_POLL).unwrap_or(PollTimeout::MAX) };
            match poll(&mut fds, timeout) {
                Ok(0) | Err(Errno::EINTR) => continue,
                Ok(_) => {}
                Err(error) => return format!("poll failed: {error}"),
            }
            let master_ready = fds[0].revents().unwrap_or(PollFlags::empty());
            let device_ready = fds[1].revents().unwrap_or(PollFlags::empty());
            if device_ready.contains(PollFlags::POLLIN) {
                match read(device, &mut buf) {
                    Ok(0) => return "the device went away (end of file)".to_owned(),
                    Ok(n) => {
                        let at = self.started.elapsed();
                        if let Err(error) = write_all(master, &buf[..n], stop) {
                            return format!("writing to the controller's port failed: {error}");
                        }
                        self.from_servos += n as u64;
                        spin_until = Instant::now() + SPIN_AFTER_TRAFFIC;
                        for event in self.pairing.from_servos(at, &buf[..n]) {
                            self.record(&event);
                        }
                    }
                    Err(Errno::EAGAIN | Errno::EINTR) => {}
                    Err(error) => return format!("the device went away ({error})"),
                }
            } else if device_ready.intersects(PollFlags::POLLHUP | PollFlags::POLLERR | PollFlags::POLLNVAL) {
                return "the device went away (hung up)".to_owned();
            }
            if master_ready.contains(PollFlags::POLLIN) {
                match read(master, &mut buf) {
                    Ok(n) if n > 0 => {
                        let at = self.started.elapsed();
                        self.follow_baud(at);
                        if let Err(error) = write_all(device, &buf[..n], stop) {
                            return format!("the device went away ({error})");
                        }
                        let forwarded = self.started.elapsed();
                        self.from_controller += n as u64;
                        spin_until = Instant::now() + SPIN_AFTER_TRAFFIC;
                        for event in self.pairing.from_controller(at, forwarded, self.baud, &buf[..n]) {
                            self.record(&event);
                        }
                    }
                    // The held slave keeps the master from EIO; anything else is not the
                    // controller's doing and the next poll tells.
                    Ok(_) | Err(_) => {}
                }
            }
        }
    }

    /// The controller set its port to another rate: the device follows before the bytes sent
    /// after the change.
    fn follow_baud(&mut self, at: Duration) {
        let Some(baud) = self.port.line().baud() else { return };
        if baud == self.baud || baud == 0 {
            return;
        }
        match self.device.set_baud(baud) {
            Ok(()) => {
                info!(baud, "the controller switched its port's rate; the device follows");
                self.baud = baud;
                self.append(&RealRecord::Baud { t: nanos(at), baud });
            }
            Err(error) => warn!(%error, "cannot follow the controller's rate"),
        }
    }

    fn record(&mut self, event: &Event) {
        self.tally.add(event);
        self.append(&RealRecord::from_event(event));
        if let Some(view) = &mut self.view {
            view.send(event);
        }
    }

    /// A record into the transcript, and to the world.
    fn append(&self, record: &RealRecord) {
        self.recorder.append(record);
        if let Some(world) = &self.world {
            world.send(record);
        }
    }
}

fn read(fd: RawFd, buf: &mut [u8]) -> std::result::Result<usize, Errno> {
    // SAFETY: a descriptor the bridge holds open (see `Bridge::run`).
    nix::unistd::read(unsafe { BorrowedFd::borrow_raw(fd) }, buf)
}

/// Write all of `bytes` to a non-blocking descriptor, waiting for room as long as it takes
/// (unless stopped: a controller that stopped reading holds the servos' side up, as it would
/// hold up its own adapter).
fn write_all(fd: RawFd, mut bytes: &[u8], stop: &AtomicBool) -> io::Result<()> {
    // SAFETY: a descriptor the bridge holds open (see `Bridge::run`).
    let borrowed = unsafe { BorrowedFd::borrow_raw(fd) };
    while !bytes.is_empty() {
        match nix::unistd::write(borrowed, bytes) {
            Ok(n) => bytes = &bytes[n..],
            Err(Errno::EAGAIN) => {
                if stop.load(Ordering::Relaxed) {
                    return Err(io::Error::new(io::ErrorKind::Interrupted, "stopped while the other side was full"));
                }
                let mut fds = [PollFd::new(borrowed, PollFlags::POLLOUT)];
                let _ = poll(&mut fds, PollTimeout::try_from(QUIET_POLL).unwrap_or(PollTimeout::MAX));
            }
            Err(Errno::EINTR) => {}
            Err(error) => return Err(error.into()),
        }
    }
    Ok(())
}
