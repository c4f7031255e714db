//! A real serial device: a USB–RS485/TTL adapter with a controller board on its far side, an
//! on-chip UART, or the pseudo-terminal a firmware emulator (Renode, QEMU) exposes.
//!
//! The wire is physical here: the bus does not add modelled wire time to what the host already
//! waited for, and each reply is written Return Delay Time after the request's last byte as
//! the host saw it (the device's UART then takes the reply's real wire time to send it).
//!
//! The port is opened with the `serialport` crate (exclusive: TIOCEXCL and an flock, 8N1, no
//! flow control, raw), which knows every platform's termios quirks, and then served without
//! blocking through tokio's reactor like the pty. Baud changes after opening use Linux's
//! termios2 (any rate, standard or not), which `serialport` would need a second descriptor
//! for, and dropping a second descriptor clears the exclusive flag of the first.

use std::collections::VecDeque;
use std::io;
use std::os::fd::{AsFd, AsRawFd, FromRawFd, IntoRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::task::{Context, Poll, ready};
use std::time::{Duration, Instant};

use thiserror::Error;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tracing::{info, warn};

use super::LineSettings;
use super::echo::{Echo, EchoFilter};
use super::rs485::{Rs485Delays, SerialRs485};

#[derive(Debug, Error)]
pub enum SerialError {
    #[error("--device {0}: no such device (is the adapter plugged in? `ls -l /dev/serial/by-id/` lists the ones that are)")]
    NotFound(PathBuf),
    #[error("--device {0}: permission denied (add your user to the group that owns it, usually `dialout`: sudo usermod -aG dialout $USER, then log in again)")]
    Permission(PathBuf),
    #[error("--device {0}: in use by another program (climbsim opens it exclusively; close the other one: a serial monitor, ModemManager, another climbsim)")]
    Busy(PathBuf),
    #[error("--device {path}: cannot open it as a serial port: {message}")]
    Open { path: PathBuf, message: String },
    #[error("--device {path}: cannot set {bps} bps: {source}")]
    Baud { path: PathBuf, bps: u32, source: io::Error },
    #[error("--device {path}: {source}")]
    Io { path: PathBuf, source: io::Error },
    #[error("--device {path} --rs485: its driver has no RS-485 mode ({source}); USB–RS485 adapters switch direction by themselves: leave --rs485 off for them")]
    NoRs485 { path: PathBuf, source: io::Error },
}

/// How to run the device, beyond its path and baud.
#[derive(Debug, Clone, Copy, Default)]
pub struct DeviceSettings {
    pub echo: Echo,
    /// Set ASYNC_LOW_LATENCY (the latency timer itself is in sysfs: see [`super::latency`]).
    pub low_latency: bool,
    /// Put an on-chip UART into Linux's RS-485 mode with these delays.
    pub rs485: Option<Rs485Delays>,
}

/// An open serial device.
pub struct SerialDevice {
    fd: AsyncFd<OwnedFd>,
    path: PathBuf,
    baud: AtomicU32,
    received: Mutex<Received>,
    /// ASYNC_LOW_LATENCY before `--low-latency` set it, where the driver has the flag.
    low_latency_was: Option<bool>,
    /// The RS-485 settings before `--rs485`.
    rs485_was: Option<SerialRs485>,
}

impl Drop for SerialDevice {
    fn drop(&mut self) {
        if self.low_latency_was == Some(false) {
            super::latency::set_async_low_latency(self.fd.get_ref().as_raw_fd(), false);
        }
        if let Some(previous) = &self.rs485_was {
            super::rs485::restore(self.fd.get_ref().as_raw_fd(), previous);
        }
    }
}

/// What the device has received, through its echo filter.
struct Received {
    echo: EchoFilter,
    /// The controller's bytes that did not fit the caller's buffer.
    ready: VecDeque<u8>,
    scratch: Vec<u8>,
}

impl Received {
    /// `n` bytes were read into `scratch`: the controller's ones join `ready`.
    fn accept(&mut self, n: usize) {
        let mut controller = Vec::with_capacity(n);
        self.echo.received(&self.scratch[..n], &mut controller);
        self.ready.extend(controller);
    }
}

impl SerialDevice {
    /// Open `path` exclusively at `baud`, 8N1, no flow control, raw. Must be called inside a
    /// tokio runtime (the descriptor is registered with its reactor).
    pub fn open(path: &Path, baud: u32, settings: &DeviceSettings) -> Result<Self, SerialError> {
        let builder = serialport::new(path.to_string_lossy(), baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None);
        let port = serialport::TTYPort::open(&builder).map_err(|error| open_error(path, error))?;
        // The descriptor keeps TIOCEXCL and the flock; from here on it is ours to close.
        // SAFETY: `into_raw_fd` hands over the open descriptor and forgets the port.
        let fd = unsafe { OwnedFd::from_raw_fd(port.into_raw_fd()) };
        let io_error = |source| SerialError::Io { path: path.to_owned(), source };
        let flags = nix::fcntl::fcntl(&fd, nix::fcntl::FcntlArg::F_GETFL).map_err(|e| io_error(e.into()))?;
        let flags = nix::fcntl::OFlag::from_bits_retain(flags) | nix::fcntl::OFlag::O_NONBLOCK;
        nix::fcntl::fcntl(&fd, nix::fcntl::FcntlArg::F_SETFL(flags)).map_err(|e| io_error(e.into()))?;
        // SAFETY: the OwnedFd is moved into the AsyncFd, which keeps it open for its whole life.
        let fd = unsafe { AsyncFd::register(fd) }.map_err(|e| io_error(e.into()))?;
        info!(device = %path.display(), baud, ?settings, "serial device open");
        // Put back on close: the flag outlives the descriptor in the driver.
        let raw = fd.get_ref().as_raw_fd();
        let rs485_was = match settings.rs485 {
            Some(delays) => Some(super::rs485::enable(raw, delays).map_err(|source| SerialError::NoRs485 { path: path.to_owned(), source })?),
            None => None,
        };
        let low_latency_was = if settings.low_latency { super::latency::set_async_low_latency(raw, true) } else { None };
        let received = Received { echo: EchoFilter::new(settings.echo), ready: VecDeque::new(), scratch: vec![0; 4096] };
        Ok(Self { fd, path: path.to_owned(), baud: AtomicU32::new(baud), received: Mutex::new(received), low_latency_was, rs485_was })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The rate the device's UART is set to.
    pub fn baud(&self) -> u32 {
        self.baud.load(Ordering::Relaxed)
    }

    /// The descriptor, for a caller that polls it itself (`climbsim tap`'s bridge: no echo
    /// filter, every byte as it came).
    pub fn raw_fd(&self) -> std::os::fd::RawFd {
        self.fd.get_ref().as_raw_fd()
    }

    /// Switch the UART to `bps` once everything written has left it (TCSETSW2), as a servo
    /// switches only after its reply.
    pub fn set_baud(&self, bps: u32) -> Result<(), SerialError> {
        let fd = self.fd.get_ref().as_raw_fd();
        let error = |source| SerialError::Baud { path: self.path.clone(), bps, source };
        // SAFETY: termios2 is plain data; TCGETS2/TCSETSW2 read and write one through a pointer
        // valid for the call.
        let mut termios: libc::termios2 = unsafe { std::mem::zeroed() };
        // SAFETY: TCGETS2 fills the termios2 above through a pointer valid for the call.
        if unsafe { libc::ioctl(fd, libc::TCGETS2, &mut termios) } != 0 {
            return Err(error(io::Error::last_os_error()));
        }
        termios.c_cflag &= !libc::CBAUD;
        termios.c_cflag |= libc::BOTHER;
        termios.c_ispeed = bps;
        termios.c_ospeed = bps;
        // SAFETY: TCSETSW2 reads the termios2 above through a pointer valid for the call.
        if unsafe { libc::ioctl(fd, libc::TCSETSW2, &termios) } != 0 {
            return Err(error(io::Error::last_os_error()));
        }
        self.baud.store(bps, Ordering::Relaxed);
        info!(device = %self.path.display(), bps, "serial device switched baud");
        Ok(())
    }

    /// The device as an `AsyncRead + AsyncWrite` stream.
    pub fn stream(self: &Arc<Self>) -> DeviceStream {
        DeviceStream(Arc::clone(self))
    }

    fn poll_read_device(&self, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        let mut received = self.received.lock().unwrap_or_else(PoisonError::into_inner);
        let received = &mut *received;
        loop {
            if !received.ready.is_empty() {
                let n = received.ready.len().min(buf.remaining());
                let (front, back) = received.ready.as_slices();
                let from_front = n.min(front.len());
                buf.put_slice(&front[..from_front]);
                buf.put_slice(&back[..n - from_front]);
                received.ready.drain(..n);
                return Poll::Ready(Ok(()));
            }
            let mut guard = ready!(self.fd.poll_read_ready(cx))?;
            let scratch = &mut received.scratch;
            match guard.try_io(|fd| nix::unistd::read(fd.get_ref().as_fd(), scratch).map_err(io::Error::from)) {
                Ok(Ok(0)) => return Poll::Ready(Ok(())), // hung up: the end of the stream
                // Nothing but our own echo (or bytes held as maybe echo) leaves `ready` empty:
                // read on.
                Ok(Ok(n)) => received.accept(n),
                Ok(Err(error)) => return Poll::Ready(Err(error)),
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_write_device(&self, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.fd.poll_write_ready(cx))?;
            match guard.try_io(|fd| nix::unistd::write(fd.get_ref(), data).map_err(io::Error::from)) {
                Ok(Ok(n)) => {
                    self.received.lock().unwrap_or_else(PoisonError::into_inner).echo.sent(&data[..n]);
                    return Poll::Ready(Ok(n));
                }
                Ok(Err(error)) => return Poll::Ready(Err(error)),
                Err(_would_block) => continue,
            }
        }
    }

    /// Read what the device has received without waiting, through the echo filter; how many of
    /// the controller's bytes are ready. Readiness of the descriptor alone does not say that the
    /// controller sent anything: it may be our own echo.
    fn pump(&self) -> usize {
        let mut received = self.received.lock().unwrap_or_else(PoisonError::into_inner);
        let received = &mut *received;
        let fd = self.fd.get_ref().as_fd();
        while let Ok(n) = nix::unistd::read(fd, &mut received.scratch) {
            if n == 0 {
                break;
            }
            received.accept(n);
        }
        received.ready.len()
    }

    /// Echoes of its own sends dropped so far, and sends whose echo did not come.
    pub fn echo_counts(&self) -> (u64, u64) {
        let received = self.received.lock().unwrap_or_else(PoisonError::into_inner);
        (received.echo.echoes(), received.echo.missing())
    }

    /// Line settings as the bus sees them.
    pub fn line(self: &Arc<Self>) -> DeviceLine {
        DeviceLine(Arc::clone(self))
    }
}

fn open_error(path: &Path, error: serialport::Error) -> SerialError {
    let path = path.to_owned();
    match error.kind() {
        serialport::ErrorKind::Io(io::ErrorKind::NotFound) => SerialError::NotFound(path),
        serialport::ErrorKind::Io(io::ErrorKind::PermissionDenied) => SerialError::Permission(path),
        // serialport reports a TIOCEXCL or flock refusal as NoDevice.
        serialport::ErrorKind::NoDevice => SerialError::Busy(path),
        _ => SerialError::Open { path, message: error.description },
    }
}

/// The device as a byte stream.
pub struct DeviceStream(Arc<SerialDevice>);

impl AsyncRead for DeviceStream {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        self.0.poll_read_device(cx, buf)
    }
}

impl AsyncWrite for DeviceStream {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        self.0.poll_write_device(cx, data)
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

/// What the bus needs to know of the device: its baud, and that its wire is real.
pub struct DeviceLine(Arc<SerialDevice>);

impl LineSettings for DeviceLine {
    fn baud(&self) -> Option<u32> {
        Some(self.0.baud())
    }

    fn physical_wire(&self) -> bool {
        true
    }

    fn waiting_from_controller(&self) -> Option<usize> {
        Some(self.0.pump())
    }

    fn wait_for_controller(&self, timeout: Duration) -> Option<bool> {
        let deadline = Instant::now() + timeout;
        loop {
            if self.0.pump() > 0 {
                return Some(true);
            }
            let now = Instant::now();
            if now >= deadline || !super::ppoll_readable(self.0.fd.get_ref().as_raw_fd(), deadline - now) {
                return Some(false);
            }
        }
    }

    fn servo_bauds_changed(&self, servos: &[(u8, Option<u32>)]) {
        follow_servos(&self.0, servos);
    }
}

/// After a transaction changed a servo's baud: the device follows the rate most servos are at
/// (the controller switched them and will switch its own port), and names the servos left at
/// another rate, which no longer hear the device.
fn follow_servos(device: &SerialDevice, servos: &[(u8, Option<u32>)]) {
    let current = device.baud();
    let Some(majority) = majority_baud(servos.iter().filter_map(|&(_, bps)| bps), Some(current)) else { return };
    if majority != current
        && let Err(error) = device.set_baud(majority)
    {
        warn!(%error, "the servos moved to {majority} bps but the device could not follow");
        return;
    }
    let deaf: Vec<String> =
        servos.iter().filter(|&&(_, bps)| bps != Some(device.baud())).map(|&(id, bps)| format!("ID {id} at {}", bps.map_or("an invalid rate".to_owned(), |b| format!("{b} bps")))).collect();
    if !deaf.is_empty() {
        warn!(device = %device.path.display(), device_bps = device.baud(), "servos at another baud than the device no longer hear it (went deaf): {}", deaf.join(", "));
    }
}

/// The baud most of `bauds` are at; a tie goes to `prefer` if it is among the tied, else to
/// whichever came first.
pub fn majority_baud(bauds: impl IntoIterator<Item = u32>, prefer: Option<u32>) -> Option<u32> {
    let mut rates: Vec<(u32, usize)> = Vec::new();
    for bps in bauds {
        match rates.iter_mut().find(|(rate, _)| *rate == bps) {
            Some((_, count)) => *count += 1,
            None => rates.push((bps, 1)),
        }
    }
    // max_by_key keeps the last of equal keys: walk backwards so the first seen wins a tie.
    rates.iter().rev().max_by_key(|&&(rate, count)| (count, Some(rate) == prefer)).map(|&(rate, _)| rate)
}

#[cfg(test)]
mod tests {
    use super::majority_baud;

    #[test]
    fn the_majority_baud_wins_and_a_tie_goes_to_the_preferred_rate() {
        assert_eq!(majority_baud([57_600, 1_000_000, 1_000_000], None), Some(1_000_000));
        assert_eq!(majority_baud([57_600, 1_000_000], Some(1_000_000)), Some(1_000_000));
        assert_eq!(majority_baud([57_600, 1_000_000], None), Some(57_600));
        assert_eq!(majority_baud([], Some(57_600)), None);
    }
}
