//! A pseudo-terminal that looks like a USB-RS485 adapter to the controller.
//!
//! climbsim keeps its own descriptor of the slave side open for its whole life: without it the
//! master reads EIO (and epoll spins on HUP) whenever the controller closes the port, and the
//! next open would find a different terminal state. With it the port survives any number of
//! close/reopen cycles, exactly like a real adapter.

use std::io;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, OwnedFd, RawFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll, ready};
use std::time::{Duration, Instant};

use nix::fcntl::{OFlag, open};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::{PtyMaster, grantpt, posix_openpt, ptsname_r, unlockpt};
use nix::sys::stat::Mode;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use thiserror::Error;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, Interest, ReadBuf};
use tracing::{debug, info, warn};

use super::busy_poll::BusyPoll;
use super::{LineSettings, queued_bytes};
use crate::virtual_time::{PTY_FULL_FOR, PTY_HAND_OVER_WITHIN, PortLedger, await_pty_hand_over};

/// How long a read waits in poll(2) before parking on the reactor.
const QUICK_WAIT_MS: u8 = 1;

#[derive(Debug, Error)]
pub enum PtyError {
    #[error("cannot create a pseudo-terminal: {0}")]
    Create(nix::Error),
    #[error("link path {0} is busy (it exists and is not a stale climbsim link); choose another --link or remove it")]
    LinkBusy(PathBuf),
    #[error("cannot create link {path}: {source}")]
    Link { path: PathBuf, source: io::Error },
    #[error("pseudo-terminal I/O setup: {0}")]
    Io(#[from] io::Error),
}

/// The emulator's end of a virtual serial port.
pub struct VirtualPort {
    /// Non-blocking; registered with a reactor only by [`VirtualPort::stream`], in the runtime of
    /// the thread that serves it.
    master: PtyMaster,
    /// Held open for the port's whole life (see the module comment).
    slave: OwnedFd,
    slave_path: PathBuf,
    link: Option<PathBuf>,
}

impl VirtualPort {
    /// Open a pty in raw mode, mode 0600, with an optional stable symlink to it. Must be called
    /// inside a tokio runtime (the master is registered with its reactor).
    pub fn open(link: Option<&Path>) -> Result<Self, PtyError> {
        let master = posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_NONBLOCK | OFlag::O_CLOEXEC).map_err(PtyError::Create)?;
        grantpt(&master).map_err(PtyError::Create)?;
        unlockpt(&master).map_err(PtyError::Create)?;
        let slave_path = PathBuf::from(ptsname_r(&master).map_err(PtyError::Create)?);
        let slave = open(&slave_path, OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_CLOEXEC, Mode::empty()).map_err(PtyError::Create)?;
        let mut termios = tcgetattr(&slave).map_err(PtyError::Create)?;
        cfmakeraw(&mut termios);
        tcsetattr(&slave, SetArg::TCSANOW, &termios).map_err(PtyError::Create)?;
        std::fs::set_permissions(&slave_path, std::os::unix::fs::PermissionsExt::from_mode(0o600))?;
        let link = match link {
            Some(path) => {
                make_link(path, &slave_path)?;
                Some(path.to_owned())
            }
            None => None,
        };
        info!(slave = %slave_path.display(), link = ?link, "virtual serial port ready");
        Ok(Self { master, slave, slave_path, link })
    }

    /// The path a controller opens: the link if there is one, else the /dev/pts node.
    pub fn path(&self) -> &Path {
        self.link.as_deref().unwrap_or(&self.slave_path)
    }

    pub fn slave_path(&self) -> &Path {
        &self.slave_path
    }

    /// Bytes written to the controller that it has not read yet.
    pub fn unread_by_controller(&self) -> usize {
        queued_bytes(self.slave.as_raw_fd()).unwrap_or(0)
    }

    /// Wait (up to `limit`) until the controller has read every reply, so that closing the master
    /// does not throw away a last answer.
    pub async fn drain(&self, limit: Duration) {
        let deadline = Instant::now() + limit;
        while self.unread_by_controller() > 0 && Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    }

    /// The master's descriptor, for a caller that polls it itself (`climbsim tap`'s bridge).
    pub fn raw_master(&self) -> RawFd {
        self.master.as_raw_fd()
    }

    /// Set the port's rate as a controller would (TCSETS2, any rate): the rate a controller
    /// that never sets one finds.
    pub fn set_controller_baud(&self, bps: u32) -> io::Result<()> {
        let slave = self.slave.as_raw_fd();
        // SAFETY: termios2 is plain data; TCGETS2/TCSETS2 read and write one through a pointer
        // valid for the call.
        let mut termios: libc::termios2 = unsafe { std::mem::zeroed() };
        // SAFETY: TCGETS2 fills the termios2 above through a pointer valid for the call.
        if unsafe { libc::ioctl(slave, libc::TCGETS2, &mut termios) } != 0 {
            return Err(io::Error::last_os_error());
        }
        termios.c_cflag = (termios.c_cflag & !libc::CBAUD) | libc::BOTHER;
        termios.c_ispeed = bps;
        termios.c_ospeed = bps;
        // SAFETY: TCSETS2 reads the termios2 above through a pointer valid for the call.
        if unsafe { libc::ioctl(slave, libc::TCSETS2, &termios) } != 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(())
    }

    /// A handle reporting the baud the controller set on the port.
    pub fn line(&self) -> PtyLine {
        PtyLine { slave: self.slave.as_raw_fd(), master: self.master.as_raw_fd() }
    }

    /// Remove the link if it still points at this port (idempotent).
    pub fn remove_link(&self) {
        if let Some(link) = &self.link
            && std::fs::read_link(link).is_ok_and(|target| target == self.slave_path)
            && let Err(error) = std::fs::remove_file(link)
        {
            warn!(link = %link.display(), %error, "could not remove link");
        }
    }

    /// A byte stream over the master, registered with the current runtime's reactor: call it on
    /// the thread that serves the port. Registered anywhere else, every reply written would wake
    /// that other thread (each write makes the master writable again, an edge for its epoll) and
    /// each read readiness would cross threads (measured: docs/performance.md, pty latency).
    ///
    /// With `spin_for_requests` the stream spins for a tight-looping controller's next request
    /// (see [`BusyPoll`]): for `--timing off`, where the reply's latency is the point. Under the
    /// wire model it does not: a reply is due hundreds of microseconds later anyway, and on two
    /// cores the spinning thread takes the CPU the kernel's pty worker and the controller need to
    /// get the reply across (measured +25 µs per round trip at 1 and 4 Mbps).
    pub fn stream(self: &Arc<Self>, spin_for_requests: bool) -> Result<PortStream, PtyError> {
        // SAFETY: the descriptor is the port's master, which `MasterFd` keeps open (it holds the
        // port) and which never changes for the port's life.
        let registered = unsafe { AsyncFd::register_with_interest(MasterFd(Arc::clone(self)), Interest::READABLE | Interest::WRITABLE) }.map_err(|e| PtyError::Io(e.into()))?;
        Ok(PortStream { master: registered, busy_poll: spin_for_requests.then(BusyPoll::default) })
    }

    /// A byte stream over the master for a session inside the virtual-time scheduler
    /// ([`crate::virtual_time::VirtualTime::drive`]): reads and writes never wait on a reactor, and the scheduler
    /// polls the session whenever the controller is parked.
    pub fn virtual_stream(self: &Arc<Self>, ledger: Arc<PortLedger>) -> VirtualTimeStream {
        ledger.attach(self.master.as_raw_fd(), self.slave.as_raw_fd());
        VirtualTimeStream { port: Arc::clone(self), ledger }
    }

    fn master_fd(&self) -> BorrowedFd<'_> {
        self.master.as_fd()
    }
}

/// The master side under virtual time. A read that finds nothing is `Pending` without a waker
/// (the scheduler polls again once the controller has written); every byte read is counted, so
/// that the scheduler knows when it has all the controller wrote. A write returns once the
/// controller can see the bytes: the kernel's pty worker hands them over a little later, and
/// the controller, parked now, must find them as soon as it is let go.
pub struct VirtualTimeStream {
    port: Arc<VirtualPort>,
    ledger: Arc<PortLedger>,
}

/// A hand-over slower than this is reported (with what it waited for).
const SLOW_HAND_OVER: Duration = Duration::from_millis(100);

impl AsyncRead for VirtualTimeStream {
    fn poll_read(self: Pin<&mut Self>, _cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        // What the shim saw written is in the block's ring (and then nothing counted waits in
        // the pty before it); the rest, in the pty.
        let taken = self.ledger.take_ring(buf.initialize_unfilled());
        if taken > 0 {
            buf.advance(taken);
            return Poll::Ready(Ok(()));
        }
        match nix::unistd::read(self.port.master_fd(), buf.initialize_unfilled()) {
            Ok(n) => {
                buf.advance(n);
                self.ledger.read(n);
                Poll::Ready(Ok(()))
            }
            Err(nix::errno::Errno::EAGAIN | nix::errno::Errno::EIO) => Poll::Pending,
            Err(e) => Poll::Ready(Err(e.into())),
        }
    }
}

impl AsyncWrite for VirtualTimeStream {
    fn poll_write(self: Pin<&mut Self>, _cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        let slave = self.port.slave.as_raw_fd();
        let before = queued_bytes(slave).unwrap_or(0);
        let taken_before = self.ledger.taken_total();
        let mut fds = [PollFd::new(self.port.master_fd(), PollFlags::POLLOUT)];
        let deadline = Instant::now() + PTY_FULL_FOR;
        let written = loop {
            match nix::unistd::write(self.port.master_fd(), data) {
                Ok(n) => break n,
                // The terminal's buffer is full: a controller that does not read. As an
                // adapter's buffer would, it loses what does not fit.
                Err(nix::errno::Errno::EAGAIN) if Instant::now() > deadline => {
                    warn!(bytes = data.len(), "reply bytes lost: the controller does not read the port and its buffer is full");
                    return Poll::Ready(Ok(data.len()));
                }
                Err(nix::errno::Errno::EAGAIN) => {
                    let _ = poll(&mut fds, PollTimeout::from(10u8));
                }
                Err(e) => return Poll::Ready(Err(e.into())),
            }
        };
        let handing_over = Instant::now();
        // What the controller took meanwhile (a read or a flush the shim counted) was handed over.
        let handed_over = || queued_bytes(slave).unwrap_or(0) as u64 + (self.ledger.taken_total() - taken_before);
        if !await_pty_hand_over(|| handed_over() >= (before + written) as u64) {
            warn!(
                bytes = written,
                before,
                queued = queued_bytes(slave).unwrap_or(0),
                taken_meanwhile = self.ledger.taken_total() - taken_before,
                threads = self.ledger.threads_now(),
                "reply bytes not visible to the controller after {PTY_HAND_OVER_WITHIN:?} (the kernel's pty worker did not run)"
            );
            self.ledger.hand_over_never_came(written, "reply");
        }
        if handing_over.elapsed() > SLOW_HAND_OVER {
            warn!(
                waited_ms = handing_over.elapsed().as_secs_f64() * 1e3,
                queued = queued_bytes(slave).unwrap_or(0),
                before,
                written,
                "the kernel took this long to hand reply bytes over to the controller's side of the pty (a loaded machine)"
            );
        } else if handing_over.elapsed() > Duration::from_millis(5) {
            debug!(waited_ms = handing_over.elapsed().as_secs_f64() * 1e3, queued = queued_bytes(slave).unwrap_or(0), before, written, "the pty's hand-over was slow");
        }
        self.ledger.written(&data[..written]);
        Poll::Ready(Ok(written))
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

/// The master's descriptor as the reactor sees it, holding the port (its owner) open.
struct MasterFd(Arc<VirtualPort>);

impl AsRawFd for MasterFd {
    fn as_raw_fd(&self) -> RawFd {
        self.0.master.as_raw_fd()
    }
}

impl PortStream {
    fn poll_read_master(&mut self, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        let read = self.read_master(cx, buf);
        if matches!(read, Poll::Ready(Ok(())))
            && let Some(busy_poll) = &mut self.busy_poll
        {
            busy_poll.request_read(Instant::now());
        }
        read
    }

    fn read_master(&self, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        let master = self.master.get_ref().0.master_fd();
        if let Some(until) = self.busy_poll.as_ref().and_then(BusyPoll::spin_until) {
            // A controller in a tight loop: its request is due within microseconds (see
            // [`BusyPoll`]). Spin on FIONREAD, not on read(2): a read of an empty pty waits for
            // the kernel's flush worker if it has bytes queued (flush_work), which is the sleep
            // and wake-up this spin is meant to avoid (measured: docs/performance.md, loop rate).
            while Instant::now() < until {
                if queued_bytes(master.as_raw_fd()) == Some(0) {
                    std::hint::spin_loop();
                    continue;
                }
                match nix::unistd::read(master, buf.initialize_unfilled()) {
                    Ok(n) => {
                        buf.advance(n);
                        return Poll::Ready(Ok(()));
                    }
                    Err(nix::errno::Errno::EAGAIN) => std::hint::spin_loop(),
                    Err(_) => break,
                }
            }
        }
        // Fast path for the dedicated pty thread: wait briefly in poll(2) and read directly. A
        // controller's next request usually follows within a millisecond, and this skips the
        // reactor's epoll round trip and wake-up (measured: see docs/performance.md, pty latency). Only
        // after a quiet millisecond does the task park on the reactor like any other.
        let mut fds = [PollFd::new(master, PollFlags::POLLIN)];
        if matches!(poll(&mut fds, PollTimeout::from(QUICK_WAIT_MS)), Ok(n) if n > 0) {
            match nix::unistd::read(master, buf.initialize_unfilled()) {
                Ok(n) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Err(nix::errno::Errno::EAGAIN | nix::errno::Errno::EIO) => {}
                Err(e) => return Poll::Ready(Err(e.into())),
            }
        }
        loop {
            let mut guard = ready!(self.master.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            match guard.try_io(|_| nix::unistd::read(master, unfilled).map_err(io::Error::from)) {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                // EIO only happens if no slave is open, which the held slave prevents; treat it
                // like "no data yet" rather than end the port.
                Ok(Err(e)) if e.raw_os_error() == Some(libc::EIO) => return Poll::Pending,
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_write_master(&mut self, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        let written = self.write_master(cx, data);
        if matches!(written, Poll::Ready(Ok(_)))
            && let Some(busy_poll) = &mut self.busy_poll
        {
            busy_poll.reply_written(Instant::now());
        }
        written
    }

    fn write_master(&self, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        let master = self.master.get_ref().0.master_fd();
        // Write straight away: the master is almost always writable, and the reactor's readiness
        // may not have been reported yet (it is read only when the thread parks).
        match nix::unistd::write(master, data) {
            Ok(n) => return Poll::Ready(Ok(n)),
            Err(nix::errno::Errno::EAGAIN) => {}
            Err(e) => return Poll::Ready(Err(e.into())),
        }
        loop {
            let mut guard = ready!(self.master.poll_write_ready(cx))?;
            match guard.try_io(|_| nix::unistd::write(master, data).map_err(io::Error::from)) {
                Ok(result) => return Poll::Ready(result),
                Err(_would_block) => continue,
            }
        }
    }
}

/// The master side as an `AsyncRead + AsyncWrite` stream.
pub struct PortStream {
    master: AsyncFd<MasterFd>,
    busy_poll: Option<BusyPoll>,
}

impl Drop for VirtualPort {
    fn drop(&mut self) {
        self.remove_link();
    }
}

fn make_link(link: &Path, target: &Path) -> Result<(), PtyError> {
    if let Ok(meta) = std::fs::symlink_metadata(link) {
        // A dangling symlink into /dev/pts is what a killed climbsim leaves behind: replace it.
        let stale = meta.file_type().is_symlink() && std::fs::read_link(link).is_ok_and(|t| t.starts_with("/dev/pts")) && std::fs::metadata(link).is_err();
        if !stale {
            return Err(PtyError::LinkBusy(link.to_owned()));
        }
        warn!(link = %link.display(), "replacing a stale link");
        std::fs::remove_file(link).map_err(|source| PtyError::Link { path: link.to_owned(), source })?;
    }
    std::os::unix::fs::symlink(target, link).map_err(|source| PtyError::Link { path: link.to_owned(), source })
}

/// Reads the controller's baud from the slave's termios (TCGETS2 reports any rate, standard or
/// not, as the number pyserial or serial2 set).
#[derive(Debug, Clone, Copy)]
pub struct PtyLine {
    slave: i32,
    master: i32,
}

impl LineSettings for PtyLine {
    fn baud(&self) -> Option<u32> {
        // SAFETY: termios2 is plain data; TCGETS2 fills it and the pointer is valid for the call.
        let mut termios: libc::termios2 = unsafe { std::mem::zeroed() };
        // SAFETY: TCGETS2 fills the termios2 above through a pointer valid for the call.
        let rc = unsafe { libc::ioctl(self.slave, libc::TCGETS2, &mut termios) };
        (rc == 0).then_some(termios.c_ospeed)
    }

    fn waiting_from_controller(&self) -> Option<usize> {
        queued_bytes(self.master)
    }

    fn unread_by_controller(&self) -> Option<usize> {
        queued_bytes(self.slave)
    }

    fn wait_for_controller(&self, timeout: Duration) -> Option<bool> {
        Some(super::ppoll_readable(self.master, timeout))
    }

    fn batches_replies(&self) -> bool {
        true
    }
}

impl AsyncRead for PortStream {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        self.get_mut().poll_read_master(cx, buf)
    }
}

impl AsyncWrite for PortStream {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        self.get_mut().poll_write_master(cx, data)
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}
