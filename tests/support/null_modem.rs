//! Two pseudo-terminals joined like a null-modem cable: what one end's program writes, the
//! other end's reads. They stand in for a USB adapter and the board on its far side (a
//! controller, or the servos: `climbsim serve --device`). The helper holds both slave ends open
//! (raw), as a cable's ends exist whether or not a program has them open; `unplug_a` pulls end
//! A out like a USB adapter.

use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use nix::poll::{PollFd, PollFlags, PollTimeout, poll};

pub struct NullModem {
    a: PathBuf,
    b: PathBuf,
    /// The ends' masters and held slaves; end A's are dropped by `unplug_a`.
    ends: Arc<Mutex<Ends>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

struct Ends {
    a: Option<(OwnedFd, OwnedFd)>,
    b: (OwnedFd, OwnedFd),
}

fn raw_pty() -> (OwnedFd, OwnedFd, PathBuf) {
    let pty = nix::pty::openpty(None, None).expect("openpty");
    for fd in [&pty.master, &pty.slave] {
        // SAFETY: fcntl on a descriptor we own: keep them out of the programs under test.
        assert_eq!(unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_SETFD, libc::FD_CLOEXEC) }, 0);
    }
    let mut termios = nix::sys::termios::tcgetattr(&pty.slave).expect("tcgetattr");
    nix::sys::termios::cfmakeraw(&mut termios);
    nix::sys::termios::tcsetattr(&pty.slave, nix::sys::termios::SetArg::TCSANOW, &termios).expect("tcsetattr");
    let path = std::fs::read_link(format!("/proc/self/fd/{}", pty.slave.as_raw_fd())).expect("the slave's path");
    (pty.master, pty.slave, path)
}

impl NullModem {
    pub fn new() -> Self {
        let (master_a, slave_a, a) = raw_pty();
        let (master_b, slave_b, b) = raw_pty();
        let ends = Arc::new(Mutex::new(Ends { a: Some((master_a, slave_a)), b: (master_b, slave_b) }));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (ends, stop) = (Arc::clone(&ends), Arc::clone(&stop));
            std::thread::Builder::new().name("null-modem".into()).spawn(move || carry(&ends, &stop)).expect("spawn the cable")
        };
        Self { a, b, ends, stop, thread: Some(thread) }
    }

    /// End A's device path.
    pub fn a(&self) -> &Path {
        &self.a
    }

    /// End B's device path.
    pub fn b(&self) -> &Path {
        &self.b
    }

    /// The rate end A's program set (TCGETS2).
    pub fn baud_a(&self) -> Option<u32> {
        let ends = self.ends.lock().expect("ends");
        let (_, slave) = ends.a.as_ref()?;
        // SAFETY: termios2 is plain data filled by the kernel through a valid pointer.
        let mut termios: libc::termios2 = unsafe { std::mem::zeroed() };
        (unsafe { libc::ioctl(slave.as_raw_fd(), libc::TCGETS2, &mut termios) } == 0).then_some(termios.c_ospeed)
    }

    /// Pull end A out: its program's descriptor hangs up.
    pub fn unplug_a(&self) {
        self.ends.lock().expect("ends").a = None;
    }
}

impl Drop for NullModem {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Copy each master's bytes to the other until stopped.
fn carry(ends: &Mutex<Ends>, stop: &AtomicBool) {
    let mut buf = [0u8; 4096];
    while !stop.load(Ordering::Relaxed) {
        let guard = ends.lock().expect("ends");
        let Some((master_a, _)) = guard.a.as_ref() else {
            drop(guard);
            std::thread::sleep(std::time::Duration::from_millis(5));
            continue;
        };
        let master_b = &guard.b.0;
        let mut fds = [PollFd::new(master_a.as_fd(), PollFlags::POLLIN), PollFd::new(master_b.as_fd(), PollFlags::POLLIN)];
        // Short, so that `unplug_a` (which takes the lock) is never held up for long.
        if !matches!(poll(&mut fds, PollTimeout::from(2u8)), Ok(n) if n > 0) {
            continue;
        }
        let ready: Vec<bool> = fds.iter().map(|fd| fd.revents().is_some_and(|r| r.contains(PollFlags::POLLIN))).collect();
        for (from, to, is_ready) in [(master_a, master_b, ready[0]), (master_b, master_a, ready[1])] {
            if !is_ready {
                continue;
            }
            if let Ok(n) = nix::unistd::read(from.as_fd(), &mut buf)
                && n > 0
            {
                let mut data = &buf[..n];
                while !data.is_empty() {
                    match nix::unistd::write(to.as_fd(), data) {
                        Ok(written) => data = &data[written..],
                        Err(nix::errno::Errno::EAGAIN | nix::errno::Errno::EINTR) => std::thread::yield_now(),
                        Err(_) => break,
                    }
                }
            }
        }
    }
}
