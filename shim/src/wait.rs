//! poll, ppoll, select and pselect on simulated time.
//!
//! Each first asks the kernel with a zero timeout; what is ready is returned at once. Otherwise:
//! - a zero timeout over the port is a spin: the thread yields until the next reply byte is due
//!   (or the spin cap), then asks again;
//! - a wait on the port or with no descriptors at all blocks until climbsim releases it: at its
//!   deadline, or when bytes are there for it;
//! - a wait that includes descriptors climbsim does not model (pipes, other sockets, anything
//!   written) is polled for real in 1 ms slices of wall time while the thread counts as
//!   blocked: it follows the real world's wake-ups, and its deadline is simulated time.

use core::ffi::c_int;
use core::sync::atomic::Ordering;

use crate::abi::{self, Shared, Wait, call, release};
use crate::growing::GrowingList;
use crate::schedule::block::active;
use crate::schedule::park::Looked;
use crate::schedule::park::{charge, note_call, park_blocked, spin_on_port};
use crate::schedule::slot::my_slot;
use crate::sys::{self, fd_set, nfds_t, pollfd, program_timespec, program_timeval, real, timespec, timeval};
use crate::time::{from_ns, sim_now};

/// How long a timer set to fire at once may take to show on its descriptor (wall time).
const TIMER_SHOWN_WITHIN_NS: u64 = 10_000_000;

/// What a wait waits on.
#[derive(Default)]
pub(crate) struct Interest {
    port: bool,
    /// The port's descriptor, when waited on (its readiness is masked while its bytes are held).
    pub(crate) port_fd: Option<c_int>,
    /// Sensor connections: their indices in `Shared::conns` (as many as the wait names).
    conns: GrowingList<u32>,
    /// Timers on simulated time: their descriptors (as many as the wait names; one named twice
    /// is looked at twice, which changes nothing).
    timers: GrowingList<c_int>,
    other: bool,
    /// The epoll wait this is (its results are taken by a look: see `wait_on_real_world`).
    pub(crate) epoll: Option<EpollCall>,
}

impl Interest {
    pub(crate) fn add(&mut self, shared: &'static Shared, fd: c_int, read: bool, write_or_error: bool) {
        if crate::timerfd::timer_of(fd).is_some() {
            if read && !self.timers.push(fd) {
                crate::schedule::block::refuse(abi::refused::TIMERFDS);
            }
            if !write_or_error {
                return;
            }
        }
        // Writability is the kernel's to say: a wait for it looks at the real world.
        if write_or_error || !read {
            self.other = true;
            if !read {
                return;
            }
        }
        // Go's netpoller registers the port for both: its reads are still the port's.
        if is_port(shared, fd) {
            self.port = true;
            self.port_fd = Some(fd);
        } else if let Some((index, _)) = crate::net::conn_of(shared, fd) {
            if !self.conns.push(index as u32) {
                // (No memory for the list: the wait looks at the kernel for it instead.)
                self.other = true;
            }
        } else {
            self.other = true;
        }
    }

    /// Something climbsim does not model.
    pub(crate) fn add_other(&mut self) {
        self.other = true;
    }

    /// The earliest expiry among the timers waited on (simulated ns; NEVER: none).
    fn timer_deadline(&self) -> u64 {
        self.timers.as_slice().iter().map(|&fd| crate::timerfd::expiry(fd)).min().unwrap_or(crate::abi::NEVER)
    }

    /// Make the timers that have expired readable for real; whether any had to be.
    fn show_expired_timers(&self, shared: &Shared) -> bool {
        let mut shown = false;
        for &fd in self.timers.as_slice() {
            shown |= crate::timerfd::show_if_expired(shared, fd);
        }
        shown
    }

    /// A wait for what climbsim models among these descriptors.
    fn data(&self) -> Wait {
        Wait::Data { port: self.port, conns: !self.conns.is_empty() }
    }

    /// The wait with the real world's descriptors among them (see `wait_on_real_world`).
    fn kernel(&self) -> Wait {
        Wait::Kernel { port: self.port, conns: !self.conns.is_empty() }
    }
}

/// While a thread waits on sensor connections, each of them names it among its waiters, so
/// that climbsim lets it go when a response comes on one (and only then).
struct WaitingOnConns<'a> {
    shared: &'static Shared,
    slot: Option<usize>,
    conns: &'a [u32],
}

impl<'a> WaitingOnConns<'a> {
    fn start(shared: &'static Shared, conns: &'a [u32]) -> Self {
        let slot = if conns.is_empty() { None } else { my_slot().and_then(|slot| shared.slot_index(slot)) };
        let waiting = WaitingOnConns { shared, slot, conns };
        waiting.each(abi::Conn::start_waiting);
        waiting
    }

    fn each(&self, act: fn(&abi::Conn, usize)) {
        if let Some(slot) = self.slot {
            for &index in self.conns {
                if let Some(conn) = self.shared.conns.get(index as usize) {
                    act(conn, slot);
                }
            }
        }
    }
}

impl Drop for WaitingOnConns<'_> {
    fn drop(&mut self) {
        self.each(abi::Conn::stop_waiting);
    }
}

/// An epoll wait's own arguments (where its events go, how many fit), and how epoll.rs adds
/// what is ready in the thread's turn to the `first` events a look took.
#[derive(Clone, Copy)]
pub(crate) struct EpollCall {
    pub(crate) epfd: c_int,
    pub(crate) events: *mut core::ffi::c_void,
    pub(crate) max: c_int,
    pub(crate) collect_more: fn(shared: &Shared, call: EpollCall, first: c_int, port_fd: Option<c_int>) -> c_int,
}

/// The descriptor is the servo port (the pty slave climbsim serves).
pub(crate) fn is_port(shared: &Shared, fd: c_int) -> bool {
    is_port_device(shared, sys::char_device(fd))
}

/// A descriptor that is the character device `rdev` (None: not one) is the servo port.
pub(crate) fn is_port_device(shared: &Shared, rdev: Option<u64>) -> bool {
    let port = shared.header.port.rdev.load(Ordering::Relaxed);
    port != 0 && rdev == Some(port)
}

/// The real call with a wall-clock timeout (`None`: no timeout); its result and errno.
type RealWait<'a> = &'a mut dyn FnMut(Option<u64>) -> c_int;

/// One wait of the poll family on simulated time (`timeout_ns`: `None` waits forever).
pub(crate) fn wait(shared: &'static Shared, what: u32, interest: &Interest, timeout_ns: Option<u64>, real_wait: RealWait<'_>) -> c_int {
    // A look at the kernel that does not wait. A timer that expired in simulated time fires for
    // real first: the kernel shows it within microseconds (the guard only covers a slow one).
    let look_now = |real_wait: RealWait<'_>| real_wait(Some(if interest.show_expired_timers(shared) { TIMER_SHOWN_WITHIN_NS } else { 0 }));
    note_call(shared, what);
    let ready = look_now(real_wait);
    if ready != 0 {
        charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
        return ready;
    }
    let now = sim_now(shared);
    let asked = timeout_ns.map_or(crate::abi::NEVER, |t| now.saturating_add(t));
    let deadline = asked.min(interest.timer_deadline());
    // Ended by a timer's expiry (or sooner): its descriptor is then ready.
    let timer_first = !interest.timers.is_empty() && deadline < asked;
    if deadline <= now && !timer_first {
        if interest.port {
            spin_on_port(shared, now);
            return real_wait(Some(0));
        }
        charge(shared, shared.header.clock.syscall_ns.load(Ordering::Relaxed));
        return 0;
    }
    let _waiting = WaitingOnConns::start(shared, interest.conns.as_slice());
    if interest.other {
        let ready = wait_on_real_world(shared, deadline, interest, real_wait);
        return if ready == 0 && timer_first { look_now(real_wait) } else { ready };
    }
    match (park_blocked(shared, deadline, interest.data()), timer_first) {
        (release::DEADLINE, true) => look_now(real_wait),
        (release::SIGNAL, _) => interrupted(),
        (release::ENDING, _) => real_wait(rest_on_the_wall(deadline, || sim_now(shared))),
        // Climbsim made the bytes visible before it released us; the guard only covers a kernel
        // that is slow to show them (or the timer's).
        (release::DATA, _) | (_, true) => real_wait(Some(1_000_000_000)),
        _ => real_wait(Some(0)),
    }
}

/// What is left of a wait until `deadline` once the run has ended (simulated time read by
/// `now`, only for a wait with one), as the kernel's timeout: none for a wait without one
/// (`NEVER`), which must not come back empty-handed.
fn rest_on_the_wall(deadline: u64, now: impl FnOnce() -> u64) -> Option<u64> {
    (deadline != crate::abi::NEVER).then(|| deadline.saturating_sub(now()))
}

/// A wait of the poll family that a signal interrupted (its handler has run): EINTR, as the
/// kernel answers whatever SA_RESTART says.
fn interrupted() -> c_int {
    refused(sys::EINTR)
}

/// A wait of the poll family (`wait`) as the cancellation point it is (see
/// `handlers::cancellation_point`): a cancellation asked before it acts at once, one asked while it
/// waited (which ended the wait) as it returns. (With the thread's cancellation off, that wait
/// ends with EINTR, where natively it would have gone on.)
pub(crate) fn as_cancellation_point(wait: impl FnOnce() -> c_int) -> c_int {
    crate::handlers::cancellation_point();
    let rc = wait();
    if rc == -1 && sys::errno() == sys::EINTR {
        crate::handlers::cancellation_point();
    }
    rc
}

/// A wait of the pselect family, `wait`, with the signal mask it asks for (`sigmask`; see
/// `signals::WaitMask`); or Linux's answer to an unreadable mask (EFAULT).
pub(crate) fn with_wait_mask(sigmask: *const core::ffi::c_void, wait: impl FnOnce() -> c_int) -> c_int {
    let mask = match crate::signals::WaitMask::enter(sigmask) {
        Ok(mask) => mask,
        Err(errno) => return refused(errno),
    };
    let rc = wait();
    mask.leave(rc)
}

/// A wait that includes descriptors climbsim does not model (a pipe, an eventfd, a socket of
/// its own): blocked (in simulated time) until one is ready or climbsim releases the thread.
/// The kernel is asked without waiting, at climbsim's request and every millisecond of wall
/// time: climbsim bumps the check epoch whenever threads ran since the last decision, and waits
/// until every such thread has looked again before it gives a turn or moves time. So a write by
/// another followed thread (tokio's eventfd, asyncio's self-pipe, a child's output) wakes this
/// one at the instant it was made, not whenever the host got round to it.
fn wait_on_real_world(shared: &'static Shared, deadline: u64, interest: &Interest, real_wait: RealWait<'_>) -> c_int {
    let Some(slot) = my_slot() else { return real_wait(rest_on_the_wall(deadline, || sim_now(shared))) };
    let publish = || crate::schedule::park::publish_waiting_on_kernel(shared, slot, deadline, interest.kernel());
    publish();
    loop {
        let looked = crate::schedule::park::wait_looking(shared, slot, &publish, |take| {
            if let (Some(call), false) = (interest.epoll, take) {
                // A peek (see `look_at_kernel`): an epoll instance is readable while events
                // wait in it, and they stay there. Not while the port it watches has bytes in
                // the kernel: the instance is readable for them, whose instants climbsim keeps
                // (it lets this thread go when they show). Told then, climbsim asked every
                // waiter at an instant the host chose, and this one, at a reply's instant, woke
                // by its own look or by climbsim's release as the two raced, and the schedule
                // would depend on the host (docs/performance-virtual-time.md measured it).
                let port_bytes_in_kernel = interest.port && {
                    let stream = crate::schedule::held::stream_now(shared);
                    stream.written > stream.taken
                };
                return if !port_bytes_in_kernel && readable_now(call.epfd) { crate::schedule::park::Look::Peeked } else { crate::schedule::park::Look::Nothing };
            }
            let ready = real_wait(Some(0));
            // The port masked as empty (bytes not visible yet) costs nothing here: the kernel
            // is never waited in.
            crate::schedule::held::take_masked();
            crate::schedule::park::Look::taking_nothing((ready != 0).then_some(ready), take)
        });
        let ready = match looked {
            Looked::Released(release::SIGNAL) => return interrupted(),
            // Let go as the run ended: the rest of the wait on the wall clock (a wait with no
            // timeout that returned nothing would break its caller: libuv asserts on it).
            Looked::Released(release::ENDING) | Looked::Ended => return real_wait(rest_on_the_wall(deadline, || sim_now(shared))),
            Looked::Released(why) => return real_wait(Some(if why == release::DATA { 1_000_000_000 } else { 0 })),
            Looked::Found(ready) => ready,
        };
        // Woken by the real world, and only now, in our turn, saying what is ready. The look
        // may have come while another thread ran (and moved the clock), and what it found then
        // depends on the host; in our turn everything else is parked. An epoll wait's look took
        // its events (edge-triggered ones are not reported twice): what is ready now is added
        // to them.
        let ready = match interest.epoll {
            Some(call) if ready > 0 => (call.collect_more)(shared, call, ready, interest.port_fd),
            _ => real_wait(Some(0)),
        };
        crate::schedule::held::take_masked();
        if ready != 0 || crate::schedule::block::active().is_none() {
            return ready;
        }
        // Taken by a thread that ran first: wait on.
        publish();
    }
}

/// Whether `fd` is readable now, or the poll failed (the caller's own call then says why): a
/// poll that does not wait.
fn readable_now(fd: c_int) -> bool {
    let poll = real!(poll: fn(*mut pollfd, nfds_t, c_int) -> c_int);
    let mut entry = pollfd { fd, events: crate::sys::POLLIN, revents: 0 };
    // SAFETY: one pollfd of ours; a zero timeout.
    unsafe { poll(&mut entry, 1, 0) != 0 }
}

/// Whether a read of `fd` may wait in the kernel. Not if the call fails at once, which the read
/// itself then says as Linux does: no such descriptor (EBADF), one not open for reading (a
/// pipe's write end, an `O_PATH` descriptor: EBADF). Nor in non-blocking mode, where the read
/// says what there is.
fn read_may_block(fd: c_int) -> bool {
    sys::status_flags(fd).is_some_and(|flags| flags & sys::O_NONBLOCK == 0 && flags & sys::O_ACCMODE != sys::O_WRONLY && flags & sys::O_PATH == 0)
}

/// A blocking read (or receive) of a descriptor other than the port, about to be made: if the
/// kernel has nothing for it yet, wait for that on simulated time first, so that the thread
/// counts as blocked (a pipe's reader: a shell's `$(…)`, Python's `subprocess`, a pipe to a
/// child) and wakes at the instant the writer wrote, rather than sitting in the kernel where
/// climbsim cannot see it. A sensor connection waits for climbsim's response the same way.
/// A socket's receive timeout (SO_RCVTIMEO) is simulated time too: `Err(errno)` if the read is
/// not to be made, and is to fail with that errno as Linux's does: EAGAIN when the timeout
/// passed with nothing to read, EINTR when a signal's handler ran meanwhile, unless it was
/// installed with SA_RESTART and the descriptor has no timeout (then the wait goes on, as
/// Linux restarts the read).
pub(crate) fn await_readable(shared: &'static Shared, fd: c_int) -> Result<(), c_int> {
    let saved = crate::sys::errno();
    if readable_now(fd) || !read_may_block(fd) {
        crate::sys::set_errno(saved);
        return Ok(());
    }
    let timeout = sys::socket_timeout(fd, sys::SO_RCVTIMEO);
    let result = loop {
        match (wait_on_descriptor(shared, fd, sys::POLLIN, timeout), timeout) {
            (0, Some(_)) => break Err(sys::EAGAIN),
            (-1, Some(_)) => break Err(sys::EINTR),
            (-1, None) => match crate::schedule::delivery::interrupted_by() {
                Some(signo) if !crate::handlers::restarts(signo) => break Err(sys::EINTR),
                // Restarted (or a signal the kernel raised, whose handler is not known here).
                _ => {}
            },
            _ => break Ok(()),
        }
    };
    crate::sys::set_errno(saved);
    result
}

/// A blocking write to `fd` (a pipe or a socket) found no room: wait on simulated time until
/// the kernel has some (or the reader is gone), as a pipe's reader waits for data (see
/// [`await_readable`]): blocked, so that the reader runs and time moves. A socket's send
/// timeout (SO_SNDTIMEO) is simulated time too. `Err(errno)`: the write is to end, with what it
/// wrote or this errno: EAGAIN when the send timeout passed, EINTR when a signal's handler ran.
pub(crate) fn await_writable(shared: &'static Shared, fd: c_int) -> Result<(), c_int> {
    let saved = crate::sys::errno();
    let timeout = sys::socket_timeout(fd, sys::SO_SNDTIMEO);
    let ready = wait_on_descriptor(shared, fd, sys::POLLOUT, timeout);
    crate::sys::set_errno(saved);
    match ready {
        -1 => Err(sys::EINTR),
        0 if timeout.is_some() => Err(sys::EAGAIN),
        _ => Ok(()),
    }
}

/// One wait on simulated time for `fd` to be readable (POLLIN) or writable (POLLOUT, `events`),
/// as a poll of it alone would wait: what the wait returned.
fn wait_on_descriptor(shared: &'static Shared, fd: c_int, events: i16, timeout: Option<u64>) -> c_int {
    let poll = real!(poll: fn(*mut pollfd, nfds_t, c_int) -> c_int);
    let mut entry = pollfd { fd, events, revents: 0 };
    let mut interest = Interest::default();
    interest.add(shared, fd, events & sys::POLLIN != 0, events & sys::POLLOUT != 0);
    let what = if events & sys::POLLIN != 0 { call::READ } else { call::WRITE };
    wait(shared, what, &interest, timeout, &mut |wall| {
        entry.revents = 0;
        // SAFETY: one pollfd of ours, with the wait's timeout.
        unsafe { poll(&mut entry, 1, wall_ms(wall)) }
    })
}

pub(crate) fn ms_timeout(timeout_ms: c_int) -> Option<u64> {
    (timeout_ms >= 0).then(|| timeout_ms as u64 * 1_000_000)
}

pub(crate) fn wall_ms(wall_ns: Option<u64>) -> c_int {
    wall_ns.map_or(-1, |ns| ns.div_ceil(1_000_000).min(i32::MAX as u64) as c_int)
}

/// What a poll of the caller's `count` entries at `fds` waits on; or Linux's answer to its
/// arguments (an errno): more entries than the process may have descriptors, EINVAL; an array
/// that is not readable, EFAULT.
fn poll_interest(shared: &'static Shared, fds: *mut pollfd, count: nfds_t) -> Result<Interest, c_int> {
    // (A limit below 64 is met by the kernel's own answer to the first real call.)
    if count > 64 && count > sys::open_files_limit() {
        return Err(sys::EINVAL);
    }
    let mut interest = Interest::default();
    // Read as the kernel reads it, a page's worth at a time (see `copy_from_program`).
    const CHUNK: usize = 256;
    let mut chunk = [pollfd { fd: -1, events: 0, revents: 0 }; CHUNK];
    let count = count as usize;
    let mut start = 0;
    while start < count {
        let len = (count - start).min(CHUNK);
        if !sys::copy_from_program(fds.wrapping_add(start).cast(), chunk.as_mut_ptr().cast(), len * core::mem::size_of::<pollfd>()) {
            return Err(sys::EFAULT);
        }
        for entry in chunk[..len].iter().filter(|entry| entry.fd >= 0) {
            let read = entry.events & (sys::POLLIN | sys::POLLPRI) != 0;
            interest.add(shared, entry.fd, read, entry.events & sys::POLLOUT != 0);
        }
        start += len;
    }
    Ok(interest)
}

/// A call refused with `errno` before it did anything, as Linux refuses it.
pub(crate) fn refused(errno: c_int) -> c_int {
    sys::set_errno(errno);
    -1
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn poll(fds: *mut pollfd, count: nfds_t, timeout_ms: c_int) -> c_int {
    let next = real!(poll: fn(*mut pollfd, nfds_t, c_int) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(fds, count, timeout_ms) };
    };
    let interest = match poll_interest(shared, fds, count) {
        Ok(interest) => interest,
        Err(errno) => return refused(errno),
    };
    let port_fd = interest.port_fd;
    as_cancellation_point(|| {
        // SAFETY: the caller's arguments, with our timeout.
        wait(shared, call::POLL, &interest, ms_timeout(timeout_ms), &mut |wall| crate::schedule::held::mask_poll(shared, fds, count, unsafe { next(fds, count, wall_ms(wall)) }, port_fd))
    })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn ppoll(fds: *mut pollfd, count: nfds_t, timeout: *const timespec, sigmask: *const sys::fd_set) -> c_int {
    let next = real!(ppoll: fn(*mut pollfd, nfds_t, *const timespec, *const sys::fd_set) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(fds, count, timeout, sigmask) };
    };
    // Linux's order: the timeout (EFAULT, then EINVAL), the count, the array.
    let asked = match program_timespec(timeout) {
        Ok(asked) => asked,
        Err(errno) => return refused(errno),
    };
    let interest = match poll_interest(shared, fds, count) {
        Ok(interest) => interest,
        Err(errno) => return refused(errno),
    };
    let port_fd = interest.port_fd;
    as_cancellation_point(|| {
        with_wait_mask(sigmask.cast(), || {
            wait(shared, call::POLL, &interest, asked, &mut |wall| {
                let limit = wall.map(from_ns);
                let limit_ptr = limit.as_ref().map_or(core::ptr::null(), |t| t as *const timespec);
                // SAFETY: the caller's arguments, with our timeout.
                crate::schedule::held::mask_poll(shared, fds, count, unsafe { next(fds, count, limit_ptr, sigmask) }, port_fd)
            })
        })
    })
}

/// The sets of a select, saved so that each real call starts from the caller's own: the words
/// that hold `count` bits of each, as the kernel reads them (a program may allocate no more).
struct SelectSets {
    sets: [*mut fd_set; 3],
    saved: [Option<fd_set>; 3],
    /// The descriptors the call looks at: those below `count`.
    count: usize,
}

impl SelectSets {
    /// The caller's sets, or Linux's answer (an errno): EINVAL for a negative count, EFAULT for
    /// a set that is not readable.
    fn new(count: c_int, read: *mut fd_set, write: *mut fd_set, error: *mut fd_set) -> Result<Self, c_int> {
        if count < 0 {
            return Err(sys::EINVAL);
        }
        let count = (count as usize).min(1024);
        let words = Self::words_for(count);
        let copy = |set: *mut fd_set| -> Result<Option<fd_set>, c_int> {
            if set.is_null() {
                return Ok(None);
            }
            let mut saved = fd_set { bits: [0; 16] };
            sys::copy_from_program(set.cast(), saved.bits.as_mut_ptr().cast(), words * 8).then_some(Some(saved)).ok_or(sys::EFAULT)
        };
        Ok(Self { sets: [read, write, error], saved: [copy(read)?, copy(write)?, copy(error)?], count })
    }

    /// The 64-bit words of a set that hold `count` descriptors.
    fn words_for(count: usize) -> usize {
        count.div_ceil(64)
    }

    fn restore(&self) {
        for (set, saved) in self.sets.into_iter().zip(self.saved) {
            if let Some(saved) = saved {
                // SAFETY: the caller's set, readable (we copied it) and the call's to write.
                unsafe { core::ptr::copy_nonoverlapping(saved.bits.as_ptr(), set.cast::<u64>(), Self::words_for(self.count)) };
            }
        }
    }

    fn is_set(&self, which: usize, fd: usize) -> bool {
        self.saved[which].is_some_and(|set| set.bits[fd / 64] & (1 << (fd % 64)) != 0)
    }

    fn interest(&self, shared: &'static Shared) -> Interest {
        let mut interest = Interest::default();
        for fd in 0..self.count {
            let (read, write, error) = (self.is_set(0, fd), self.is_set(1, fd), self.is_set(2, fd));
            if read || write || error {
                interest.add(shared, fd as c_int, read, write || error);
            }
        }
        interest
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn select(count: c_int, read: *mut fd_set, write: *mut fd_set, error: *mut fd_set, timeout: *mut timeval) -> c_int {
    let next = real!(select: fn(c_int, *mut fd_set, *mut fd_set, *mut fd_set, *mut timeval) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(count, read, write, error, timeout) };
    };
    // Linux's order: the timeout (EFAULT, then EINVAL), the count, the sets.
    let (asked, sets) = match program_timeval(timeout).and_then(|asked| Ok((asked, SelectSets::new(count, read, write, error)?))) {
        Ok(checked) => checked,
        Err(errno) => return refused(errno),
    };
    let interest = sets.interest(shared);
    let port_fd = interest.port_fd;
    let started = sim_now(shared);
    let result = as_cancellation_point(|| {
        wait(shared, call::SELECT, &interest, asked, &mut |wall| {
            sets.restore();
            let mut limit = wall.map(|ns| timeval { tv_sec: (ns / 1_000_000_000) as i64, tv_usec: (ns % 1_000_000_000).div_ceil(1000) as i64 });
            let limit_ptr = limit.as_mut().map_or(core::ptr::null_mut(), |t| t as *mut timeval);
            // SAFETY: the caller's sets, with our timeout.
            crate::schedule::held::mask_select(shared, read, unsafe { next(count, read, write, error, limit_ptr) }, port_fd)
        })
    });
    if let Some(asked) = asked {
        // Linux reports the time left (in whole microseconds, rounded down), whatever ended the
        // wait; a select that timed out has none.
        let left = if result == 0 { 0 } else { asked.saturating_sub(sim_now(shared).saturating_sub(started)) };
        // SAFETY: the caller's timeval (read above: it is there).
        unsafe { *timeout = timeval { tv_sec: (left / 1_000_000_000) as i64, tv_usec: (left % 1_000_000_000 / 1000) as i64 } };
    }
    result
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn pselect(count: c_int, read: *mut fd_set, write: *mut fd_set, error: *mut fd_set, timeout: *const timespec, sigmask: *const fd_set) -> c_int {
    let next = real!(pselect: fn(c_int, *mut fd_set, *mut fd_set, *mut fd_set, *const timespec, *const fd_set) -> c_int);
    let Some(shared) = active() else {
        // SAFETY: passing the caller's arguments through.
        return unsafe { next(count, read, write, error, timeout, sigmask) };
    };
    let (asked, sets) = match program_timespec(timeout).and_then(|asked| Ok((asked, SelectSets::new(count, read, write, error)?))) {
        Ok(checked) => checked,
        Err(errno) => return refused(errno),
    };
    let interest = sets.interest(shared);
    let port_fd = interest.port_fd;
    as_cancellation_point(|| {
        with_wait_mask(sigmask.cast(), || {
            wait(shared, call::SELECT, &interest, asked, &mut |wall| {
                sets.restore();
                let limit = wall.map(from_ns);
                let limit_ptr = limit.as_ref().map_or(core::ptr::null(), |t| t as *const timespec);
                // SAFETY: the caller's sets, with our timeout.
                crate::schedule::held::mask_select(shared, read, unsafe { next(count, read, write, error, limit_ptr, sigmask) }, port_fd)
            })
        })
    })
}
