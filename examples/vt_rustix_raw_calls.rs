//! A helper written on `rustix`, for the virtual-time tests: rustix's Linux backend makes its
//! system calls with its own `syscall` instructions, not through libc, as Go does. It starts a
//! shell that answers after 100 ms and reads the answer with `rustix::io::read`, then waits on an
//! empty pipe with `rustix::event::poll` (the `ppoll` system call) for 30 ms. On virtual time
//! both instants are simulated; before these calls were followed, the read kept the turn and
//! the child never ran.

use std::os::fd::AsFd;
use std::process::{Command, Stdio};
use std::time::Instant;

use rustix::event::{PollFd, PollFlags, Timespec};

fn main() {
    let start = Instant::now();
    let mut child = Command::new("sh").args(["-c", "sleep 0.1; echo ready"]).stdout(Stdio::piped()).spawn().expect("start sh");
    let answer = child.stdout.take().expect("the child's stdout, piped");
    let mut bytes = [0u8; 64];
    let read = rustix::io::read(answer.as_fd(), &mut bytes).expect("read the child's answer");
    let said = String::from_utf8_lossy(&bytes[..read]);
    println!("read {:?} after {:.3} ms", said.trim(), start.elapsed().as_secs_f64() * 1e3);
    let status = child.wait().expect("wait for sh");
    println!("the child ended: {status}");

    let (empty, _writer) = rustix::pipe::pipe().expect("a pipe");
    let mut watched = [PollFd::new(&empty, PollFlags::IN)];
    let start = Instant::now();
    let ready = rustix::event::poll(&mut watched, Some(&Timespec { tv_sec: 0, tv_nsec: 30_000_000 })).expect("poll");
    println!("poll of an empty pipe: {ready} ready after {:.3} ms", start.elapsed().as_secs_f64() * 1e3);
}
