//! The shared-memory block's layout: what the block holds and who writes each field (C =
//! climbsim, S = the shim). A slot's state is changed only by `protocol.rs`.
//!
//! Every field is an atomic: the block is a file mapped `MAP_SHARED` by processes that do not
//! trust one another's timing. A zero-filled file is a valid, empty block.

use core::sync::atomic::{AtomicI32, AtomicI64, AtomicU8, AtomicU32, AtomicU64};

/// "CLMBVT" and the layout's version.
pub const MAGIC: u64 = u64::from_le_bytes(*b"CLMBVT\0\x01");
/// Bumped with every change of this file.
pub const ABI: u32 = 22;
/// Controller threads that can be followed at once (all processes together). Far more than a
/// controller runs (a JVM starts about 20, Node.js about 12): the block is a sparse file, and
/// every scan stops at the highest slot used so far (`Header::slots_high`). Past it the run
/// fails, naming the limit, never a thread left unfollowed.
pub const SLOTS: usize = 4096;
/// epoll registrations followed per process (all its epoll instances together).
pub const EPOLL_ENTRIES: usize = 1024;
/// The descriptor numbers below which a timerfd is followed: a process may have as many as it
/// may have descriptors (below 1 048 576, Linux's default `fs.nr_open`), and one wait may wait
/// on all of them.
pub const TIMERFD_DESCRIPTORS: usize = 1 << 20;
/// Sensor-server connections followed at once: one for each local port an address has, so
/// every connection the kernel can make to the server. The block is a sparse file, and every
/// scan stops at the highest entry used so far (`Header::conns_high`).
pub const CONNS: usize = 1 << 16;
/// Signal timers (`alarm`, `setitimer`, `timer_create`) followed at once, all processes
/// together.
pub const SIG_TIMERS: usize = 256;
/// Simulated time a thread may run (charged calls, its CPU time with `--controller-cpu`)
/// before it gives up its turn, as a kernel's time slice: a loop that polls what is ready and
/// never blocks would otherwise keep every other thread from running.
pub const TURN_QUANTUM_NS: u64 = 1_000_000;
/// How long (wall time) one parked thread at a time spins, where `Header::spin.park_spin_ns` lets
/// threads spin at all, instead of that: a single-threaded controller's wait for its replies
/// outlasts the world's ticks up to them (half a millisecond or more), and a thread woken from
/// its futex then costs tens of microseconds more than one that spun.
pub const LONG_PARK_SPIN_NS: u64 = 2_000_000;
/// The CPU time (the thread's own, as the kernel counts it) a running thread may compute
/// without a followed call before climbsim asks it to give way (`Slot::give_way_asked`,
/// [`GIVE_WAY_SIGNAL`]), by default (`--preempt-after-ms`, `Clock::give_way_after_ns`); and the
/// simulated time it is charged at most when it does and time must move for anything to change
/// (`Shared::give_way`): the host's rate.
pub const COMPUTE_QUANTUM_NS: u64 = 10_000_000;
/// The signal climbsim sends a thread it asks to give way (`tgkill`): the shim's handler, which
/// the program can neither replace nor block (its wishes are kept and reported back to it, as
/// for SIGSYS; the same signal from anyone else goes where the program wished). SIGWINCH: its
/// default action is to ignore it, so that a thread asked just as it execs (the new program's
/// handlers are the defaults until its shim starts) is not killed; and a controller's output is
/// a log, not a terminal, whose size changes would send it.
pub const GIVE_WAY_SIGNAL: i32 = 28;
/// `Slot::tid` of a slot reserved for a thread that a trapped clone creates (libc's own thread
/// creation, a runtime's raw clone): the thread claims it at its first followed call, finding
/// it by its TLS pointer (`Slot::clone_tls`; 0: any such thread of the process).
pub const RAW_CLONE_TID: i32 = -2;
/// `Slot::tid` of a slot reserved for a thread the shim's `pthread_create` is about to create.
pub const RESERVED_THREAD_TID: i32 = -1;
/// "No deadline" / "nothing due".
pub const NEVER: u64 = u64::MAX;
/// Reply bytes written to the port ahead of their time, in at most this many runs (each
/// visible from its own instant).
pub const HELD_RUNS: usize = 64;
/// Bytes the controller has written to the port that climbsim has not taken yet, at most (see
/// `Shared::port_tx_ring`). At 1 Mbps a second of the wire is 100 KB; a controller runs into it
/// only by writing that much without ever waiting, and its write then waits for climbsim.
pub const PORT_TX_RING: usize = 1 << 20;

/// `Header::mode`.
pub mod mode {
    /// The clock is climbsim's: every intercepted call follows virtual time.
    pub const VIRTUAL: u32 = 1;
    /// The run is over: calls go to the real kernel again, clocks go on from where virtual time
    /// stopped at the wall clock's rate, so a controller's clean-up cannot hang.
    pub const ENDING: u32 = 2;
}

/// `Header::refused`: something the controller did that virtual time cannot follow (a table
/// of the block or of a shim had no room left, an io_uring); the run fails naming it.
pub mod refused {
    pub const SLOTS: u32 = 1;
    pub const EPOLL: u32 = 2;
    pub const TIMERFDS: u32 = 4;
    pub const CONNS: u32 = 8;
    pub const IO_URING: u32 = 16;
    pub const SIG_TIMERS: u32 = 32;
    pub const KILLED_BY_SIGSYS: u32 = 64;
    pub const SHARED_TLS: u32 = 128;

    /// The run's failure, in words.
    pub fn describe(bits: u32) -> Option<String> {
        let (what, limit) = if bits & SLOTS != 0 {
            ("threads at once (all the controller's processes together)", super::SLOTS - 1)
        } else if bits & EPOLL != 0 {
            ("epoll registrations in one process", super::EPOLL_ENTRIES)
        } else if bits & TIMERFDS != 0 {
            return Some(format!(
                "virtual time follows timerfds numbered below {} (Linux's default fs.nr_open), and the controller made one past \
                 it (or the shim found no memory for the timerfds of one wait): it could not be followed (run it with --clock wall)",
                super::TIMERFD_DESCRIPTORS
            ));
        } else if bits & CONNS != 0 {
            ("connections to the sensor server at once", super::CONNS)
        } else if bits & SIG_TIMERS != 0 {
            ("signal timers at once (alarm, setitimer, timer_create; all the controller's processes together)", super::SIG_TIMERS)
        } else if bits & KILLED_BY_SIGSYS != 0 {
            return Some(
                "a process of the controller was killed by SIGSYS, as its parent's wait found: a statically linked program it ran \
                 inherits the run's seccomp filter but cannot load the shim that answers it, and its first followed call (a sleep, \
                 a clock read through the kernel, a futex) kills it; link that program dynamically, or run the controller with \
                 --clock wall (or a seccomp filter of the program's own killed it)"
                    .to_owned(),
            );
        } else if bits & SHARED_TLS != 0 {
            return Some(
                "a thread of the controller made by a raw clone without a thread pointer of its own (no CLONE_SETTLS) made a \
                 followed call: it shares its creator's thread-local storage, where climbsim's shim keeps which thread is which, so \
                 its calls cannot be told from its creator's; create it with pthread_create (or give it a TLS of its own), or run \
                 the controller with --clock wall"
                    .to_owned(),
            );
        } else if bits & IO_URING != 0 {
            return Some(
                "virtual time cannot follow io_uring (the controller and the kernel share its rings, with no system call to see): \
                 the controller's io_uring_setup was refused (ENOSYS, which most libraries take for an old kernel and fall back from); \
                 run it with --clock wall"
                    .to_owned(),
            );
        } else {
            return None;
        };
        Some(format!("virtual time follows at most {limit} {what}, and the controller needed more: the one past them could not be followed (run it with --clock wall)"))
    }
}

/// `Slot::waits`: what a blocked or yielded thread waits on.
///
/// The encoding of `protocol::Wait`, private to `abi`: the shim and climbsim read and write a
/// thread's wait as that type.
pub(super) mod waits {
    /// Readable bytes on the servo port.
    pub const PORT: u32 = 1;
    /// A response on a sensor-server connection (those whose `Conn::waiters` name the slot).
    pub const CONN: u32 = 2;
    /// Descriptors climbsim does not model: polled for real, on the wall clock.
    pub const OTHER: u32 = 4;
    /// A zero-timeout poll of the port that found nothing: resume at the next byte due on it
    /// (or after the spin cap if none is).
    pub const SPIN: u32 = 8;
    /// A child process's end (waitpid and kin), which the kernel itself wakes;
    /// `Slot::awaited_child` holds the pid waited for (≤ 0: any child).
    pub const CHILD: u32 = 16;
    /// Another thread (a condition variable, a semaphore, a join): `Slot::peer` holds what is
    /// waited on; the waking thread makes it ready.
    pub const PEER: u32 = 32;
    /// A futex (a system call, whatever library made it): `Slot::futex_addr` and
    /// `Slot::futex_space` say which; the thread that wakes it makes it ready.
    pub const FUTEX: u32 = 64;
    /// A running thread that gave up its turn after [`super::TURN_QUANTUM_NS`]: when it is
    /// ready again, the threads ready for any other reason run first.
    pub const TURN: u32 = 128;
}

/// `Slot::release`: why climbsim let a thread go.
pub mod release {
    pub const DEADLINE: u32 = 1;
    pub const DATA: u32 = 2;
    pub const ENDING: u32 = 3;
    /// A signal timer fired for this thread (`Slot::signals_due`): it sends itself the signal,
    /// and its wait ends with EINTR if the signal interrupts it.
    pub const SIGNAL: u32 = 4;
}

/// `Slot::last_call`: the intercepted call a thread made last (for the watchdog's report).
pub mod call {
    pub const NONE: u32 = 0;
    pub const CLOCK: u32 = 1;
    pub const SLEEP: u32 = 2;
    pub const POLL: u32 = 3;
    pub const SELECT: u32 = 4;
    pub const WRITE: u32 = 5;
    pub const READ: u32 = 6;
    pub const NET: u32 = 7;
    pub const WAIT_CHILD: u32 = 8;
    pub const PEER: u32 = 9;
    pub const FUTEX: u32 = 10;
    pub const YIELD: u32 = 11;
    pub const SIGNAL_WAIT: u32 = 12;
    pub const TIMER: u32 = 13;
    pub const IPC: u32 = 14;

    pub fn name(call: u32) -> &'static str {
        match call {
            CLOCK => "a clock read",
            SLEEP => "a sleep",
            POLL => "poll",
            SELECT => "select",
            WRITE => "write",
            READ => "read",
            NET => "a socket call",
            WAIT_CHILD => "waitpid",
            PEER => "a wait for another thread",
            FUTEX => "futex",
            YIELD => "sched_yield",
            SIGNAL_WAIT => "a wait for a signal",
            TIMER => "a signal timer's call",
            IPC => "a semaphore or message queue wait",
            _ => "nothing yet",
        }
    }
}

#[repr(C)]
pub struct Header {
    pub magic: AtomicU64,
    pub abi: AtomicU32,
    /// C: see [`mode`].
    pub mode: AtomicU32,
    /// C: climbsim's process: a shim whose climbsim is gone leaves virtual time.
    pub climbsim_pid: AtomicI32,
    /// S: see [`refused`].
    pub refused: AtomicU32,
    /// Simulated time and what the controller's calls cost in it.
    pub clock: Clock,
    /// Whose turn it is (see `protocol::Shared::who_decides`).
    pub turns: Turns,
    /// The looks at the kernel that climbsim asks for after threads ran.
    pub looks: Looks,
    /// Who spins while parked, instead of sleeping on its futex.
    pub spin: Spin,
    /// The servo port's two streams.
    pub port: PortStream,
    /// C: the sensor server's TCP port and IPv4 address (network order), 0 before there is one.
    pub sensor_port: AtomicU32,
    pub sensor_ip: AtomicU32,
    /// C: the inode of the pipe climbsim copies the controller's output (stdout and stderr)
    /// from, 0 before there is one: drained by climbsim in real time, a write to it waits in the
    /// kernel (see the shim's `io::write_with_room`).
    pub output_pipe: AtomicU64,
    /// S: every intercepted call, all threads: the watchdog's sign of life.
    pub calls: AtomicU64,
    /// S: threads in a wait for another thread (wakers look for them only when there are some).
    pub peer_waiters: AtomicU32,
    /// S: the lock over every slot's futex queue fields (0 free, 1 held, 2 held with sleepers).
    pub futex_lock: AtomicU32,
    /// S: the last futex ticket handed out.
    pub futex_tickets: AtomicU64,
    /// S (and C for slot 0): one past the highest slot ever taken; raised before a slot is, so
    /// that a scan up to it never misses a thread.
    pub slots_high: AtomicU32,
    /// S: one past the highest signal timer used so far (scans stop there).
    pub sig_timers_high: AtomicU32,
    /// S: slots reserved for threads created by a trapped clone and not claimed yet (see
    /// [`RAW_CLONE_TID`]).
    pub raw_clones: AtomicU32,
    /// S: one past the highest sensor connection ever followed (scans stop there); raised
    /// before the entry is taken.
    pub conns_high: AtomicU32,
}

/// `Header::clock`: simulated time, and what the controller's calls cost in it.
#[repr(C)]
pub struct Clock {
    /// C (and S within the horizon): simulated time, ns since the run's start.
    pub now_ns: AtomicU64,
    /// C: a thread may move `now_ns` itself (charging its calls) up to here, not beyond.
    pub horizon_ns: AtomicU64,
    /// C: CLOCK_REALTIME at simulated time 0.
    pub realtime_epoch_ns: AtomicU64,
    /// C: CLOCK_MONOTONIC at simulated time 0.
    pub monotonic_base_ns: AtomicU64,
    /// C: the wall clock's CLOCK_MONOTONIC when the run ended (for [`mode::ENDING`]).
    pub ending_wall_ns: AtomicU64,
    /// C: what a clock read costs a thread in simulated time.
    pub clock_read_ns: AtomicU64,
    /// C: what any other intercepted call that did not block costs.
    pub syscall_ns: AtomicU64,
    /// C: charges are applied once they reach this much.
    pub batch_ns: AtomicU64,
    /// C: the longest jump of a spin on an empty port with nothing due on it.
    pub spin_cap_ns: AtomicU64,
    /// C: each thread's CPU time is also charged, × this / 1e6 (`--controller-cpu`; 0: free).
    pub cpu_factor_ppm: AtomicU64,
    /// C: the quantum of a thread that computes without a followed call (see
    /// [`COMPUTE_QUANTUM_NS`]; 0: never asked to give way).
    pub give_way_after_ns: AtomicU64,
}

/// `Header::turns`: whose turn it is, and the hand-overs between threads.
#[repr(C)]
pub struct Turns {
    /// S bumps it (and wakes climbsim's scheduler) whenever a thread blocks, yields or exits.
    pub sched_word: AtomicU32,
    /// C (and S handing on): bumped each time a thread is given its turn: a parked thread stops
    /// spinning once another has it (it would take the CPU that thread needs).
    pub given: AtomicU32,
    /// S: hand-overs of the turn from a parking thread to the next ready one (see
    /// [`Shared::next_turn`]) begun, and ended. climbsim reads `hand_ons_ended` before it looks
    /// at the slots and `hand_ons_begun` after: if they differ, a hand-over overlapped its look,
    /// and it decides nothing on it, as if a thread ran.
    pub hand_ons_begun: AtomicU64,
    pub hand_ons_ended: AtomicU64,
    /// S: turns a parking thread handed on itself, without climbsim.
    pub handed: AtomicU64,
    /// S: times a thread gave way when climbsim asked (see [`COMPUTE_QUANTUM_NS`]).
    pub gave_way: AtomicU64,
}

/// `Header::looks`: the looks at the kernel that climbsim asks for after threads ran.
#[repr(C)]
pub struct Looks {
    /// C: bumped when a scheduling decision is due after threads ran: every thread waiting on
    /// descriptors climbsim does not model (a pipe, an eventfd) looks at them again first, and
    /// says so in `Slot::checked_epoch`, since what a thread that ran wrote may have woken it.
    pub check_epoch: AtomicU32,
    /// S bumps it (and wakes the futex) when a thread has looked again for `check_epoch`.
    pub checks_word: AtomicU32,
}

/// `Header::spin`: who spins while parked, instead of sleeping on its futex.
#[repr(C)]
pub struct Spin {
    /// C: how long (wall time) a parked thread spins before it sleeps on its futex: 0 on one
    /// CPU or where the machine is busy (a spin would take the CPU from the very thread it waits
    /// for). climbsim alone decides, for both sides.
    pub park_spin_ns: AtomicU64,
    /// S: until when (CLOCK_MONOTONIC, ns) the thread that took the long spin
    /// ([`LONG_PARK_SPIN_NS`]) spins; a thread that parks takes it when this has passed, and
    /// gives it back (0) when it stops spinning. A thread killed while it spins holds it only
    /// until then.
    pub long_spin_until: AtomicU64,
}

/// `Header::port`: the servo port's two streams, the controller's requests (tx) and the
/// replies (rx), as offsets both sides count.
#[repr(C)]
pub struct PortStream {
    /// C: the servo port's device number (the pty slave's st_rdev); 0 before there is one.
    pub rdev: AtomicU64,
    /// S: bytes the controller has written to the port.
    pub tx_total: AtomicU64,
    /// C: of those, the bytes climbsim has read (and so time-stamped).
    pub tx_read: AtomicU64,
    /// S: of `tx_total`, the bytes that went through `Shared::port_tx_ring` (the ring's stream
    /// offset).
    pub tx_ring_written: AtomicU64,
    /// C: of those, the bytes climbsim has taken from the ring.
    pub tx_ring_read: AtomicU64,
    /// S: threads writing into the ring now. A writer counts itself, then looks at `mode`;
    /// climbsim sets [`mode::ENDING`], then waits for this to be 0 before it takes what the
    /// ring holds for the clean-up's servos.
    pub tx_ring_writers: AtomicU32,
    /// C: odd while climbsim rewrites `held_runs` (a sequence lock: the shim reads them again).
    pub held_seq: AtomicU32,
    /// C: when the next reply byte is due on the port ([`NEVER`]: none is).
    pub next_due_ns: AtomicU64,
    /// C: reply bytes climbsim has written to the port, in all (a stream offset).
    pub rx_written: AtomicU64,
    /// S: of those, the bytes the controller has read, or flushed while they were visible.
    pub rx_taken: AtomicU64,
    /// C: replies written ahead of their time: the bytes from `HeldRun::start` on become visible
    /// at `HeldRun::due_ns` (and not before the runs ahead of them in the stream). The shim hides
    /// what is not visible yet from reads, polls and FIONREAD, so that a Sync Read's eight
    /// replies cost one write and no hand-over each. Unused runs have `due_ns` 0.
    pub held_runs: [HeldRun; HELD_RUNS],
}

impl Header {
    /// The port's stream of `written` bytes at simulated time `now` as the held runs say: how
    /// much of it is visible (a stream offset), and when more becomes visible ([`NEVER`]:
    /// nothing is held). Bytes come in order: the first run in the stream still due hides all
    /// after it. (The shim reads the runs under `held_seq`; climbsim, their only writer, as
    /// they are.)
    pub fn port_visible_at(&self, written: u64, now: u64) -> (u64, u64) {
        let (mut visible, mut next_due) = (written, NEVER);
        for run in &self.port.held_runs {
            let due = run.due_ns.load(core::sync::atomic::Ordering::Relaxed);
            let start = run.start.load(core::sync::atomic::Ordering::Relaxed);
            if due > now && start < visible {
                visible = start;
                next_due = due;
            }
        }
        (visible, next_due)
    }
}

/// Bytes of the port's stream, from `start` up to the next run's start (or the end of what was
/// written), that become visible at `due_ns`.
#[repr(C)]
pub struct HeldRun {
    pub start: AtomicU64,
    pub due_ns: AtomicU64,
}

#[repr(C)]
pub struct Slot {
    /// See [`super::protocol`]: private to `abi`, changed only by its transitions.
    pub(super) state: AtomicU32,
    /// C bumps it (and wakes the futex) to release a blocked or yielded thread.
    pub wake_word: AtomicU32,
    pub pid: AtomicI32,
    pub tid: AtomicI32,
    /// S: a blocked thread's wake-up, a yielded thread's resume (simulated ns; [`NEVER`]).
    pub deadline_ns: AtomicU64,
    /// S: what a parked thread waits on (`protocol::Wait`, encoded: see [`waits`]).
    pub(super) waits: AtomicU32,
    /// C: see [`release`].
    pub release: AtomicU32,
    /// S: the child a thread in waitpid waits for (≤ 0: any child of its process).
    pub(super) awaited_child: AtomicI64,
    /// S: what a wait for another thread waits on: a condition's or semaphore's address, or
    /// the joined thread's `pthread_t`.
    pub(super) peer: AtomicU64,
    /// S: the TLS pointer of the thread a trapped clone reserved this slot for (see
    /// [`RAW_CLONE_TID`]).
    pub clone_tls: AtomicU64,
    /// S: see [`call`].
    pub last_call: AtomicU32,
    /// S: the parent process of the slot's process (a waitpid is a real wait only while a
    /// followed child lives).
    pub parent: AtomicI32,
    /// S: this thread's intercepted calls.
    pub calls: AtomicU64,
    /// S: simulated time of the last call.
    pub last_call_ns: AtomicU64,
    /// S, under `Header::futex_lock`: the futex this thread waits in (`futex.rs`): its address
    /// in its process, and which wake-ups it takes (FUTEX_WAIT_BITSET's mask).
    pub futex_addr: AtomicU64,
    pub futex_bitset: AtomicU32,
    /// S, under `Header::futex_lock`: the address space `futex_addr` is in (`futex.rs`'s key:
    /// the process, or the file a shared mapping maps).
    pub futex_space: AtomicU64,
    /// S, under `Header::futex_lock`: 1 while queued on `futex_addr`; a waker takes it to 0.
    pub futex_queued: AtomicU32,
    /// S, under `Header::futex_lock`: the order it queued in (wake-ups go first come, first
    /// served, as the kernel's do among equal priorities).
    pub futex_ticket: AtomicU64,
    /// S: the last `Header::looks.check_epoch` at which this thread, waiting on descriptors climbsim
    /// does not model, found none of them ready.
    pub checked_epoch: AtomicU32,
    /// C: signal timers fired for this thread that it has not sent itself yet (see
    /// `SigTimer::fired`); it looks whenever it parks or is let go.
    pub signals_due: AtomicU32,
    /// S: the program's signal mask for this thread (bit n-1: signal n), as its last
    /// sigprocmask left it (during sigsuspend: the mask it suspends with).
    pub sig_blocked: AtomicU64,
    /// S: the signals a sigtimedwait of this thread waits for (0: none).
    pub sig_waiting: AtomicU64,
    /// S: a wait on the port is for bytes past this offset of its stream only (an
    /// edge-triggered epoll registration has reported those before; 0: any unread byte).
    pub port_seen: AtomicU64,
    /// S: the thread's `pthread_t` (what `pthread_self` returns in it): a join names the
    /// thread it waits for by it.
    pub thread: AtomicU64,
    /// S: 1 while the thread hands its turn on (see `Header::turns.hand_ons_begun`): set before the
    /// hand-over is counted as begun, cleared after it is counted as ended, so that a hand-over
    /// whose thread was killed in it can be found (the slot's thread is gone) and written off.
    pub handing: AtomicU32,
    /// S: the simulated time the thread ended at, written before `state` says EXITED: climbsim
    /// sees a controller's end at the first world tick after it, on every run (a tick at that
    /// very instant may run beside the thread, which ends while it does or after).
    pub exited_ns: AtomicU64,
    /// S: while the thread's task execs a program that will not load the shim's clock (it
    /// leaves the followed world; its state says EXITED): a descriptor of its own named
    /// [`EXEC_MARKER_NAME`], which the exec keeps open and the new program's shim closes as it
    /// starts, once the kernel has released what the exec closed. climbsim waits until it is
    /// gone before it asks the threads waiting on the real world to look again: the end of a
    /// pipe the exec closes then wakes its reader at the exec's simulated instant. climbsim
    /// takes it back to 0 once it has seen the exec over; an exec that failed does so itself
    /// before it closes the marker (0: none).
    pub exec_marker_fd: AtomicI32,
    /// C: 1 + the thread's `calls` when climbsim asked it to give way (it had computed for
    /// [`COMPUTE_QUANTUM_NS`] of CPU time since its last followed call; 0: not asked). The
    /// thread gives way only if it has made no call since (`Shared::give_way`).
    pub give_way_asked: AtomicU64,
    /// S: times the thread gave way when asked (climbsim measures its next quantum from then).
    pub gave_way: AtomicU64,
}

/// The name of an exec's marker descriptor (`Slot::exec_marker_fd`), a memfd: its link in
/// /proc reads `/memfd:` and this name.
pub const EXEC_MARKER_NAME: &core::ffi::CStr = c"climbsim-exec";

/// Whether `link`, what a descriptor's /proc link reads, names an exec's marker (both sides
/// look: the shim before it takes a slot, climbsim before it writes an exec off).
pub fn is_exec_marker_link(link: &[u8]) -> bool {
    link.strip_prefix(&b"/memfd:"[..]).is_some_and(|name| name.starts_with(EXEC_MARKER_NAME.to_bytes()))
}

/// `SigTimer::state`.
pub mod timer_state {
    pub const FREE: u32 = 0;
    /// Created (timer_create) and not armed.
    pub const DISARMED: u32 = 1;
    pub const ARMED: u32 = 2;
    /// S: being changed by its process (climbsim leaves it alone).
    pub const BUSY: u32 = 3;
}

/// `SigTimer::kind`.
pub mod timer_kind {
    /// The process's ITIMER_REAL (`alarm`, `setitimer`): SIGALRM, sent as the kernel sends it.
    pub const ITIMER_REAL: u32 = 1;
    /// A POSIX timer (`timer_create`): its signal carries SI_TIMER, the timer's id and value.
    pub const POSIX: u32 = 2;
    /// Not a timer: a signal one followed thread sent another (`kill`, `tgkill`, `tkill`),
    /// waiting for its taker to send it to itself in its turn (`value`: the sender's pid, and
    /// its uid in the upper half). Freed once sent.
    pub const SENT: u32 = 3;
}

/// A signal timer on simulated time. The shim of its process creates and arms it; climbsim
/// fires it at its instant: it picks the thread that takes the signal, counts the expiration in
/// `fired` and lets that thread go (`release::SIGNAL`); the thread sends itself the signal, so
/// that it arrives in its turn, at a point of its run that does not depend on the host.
#[repr(C)]
pub struct SigTimer {
    /// See [`timer_state`].
    pub state: AtomicU32,
    /// See [`timer_kind`].
    pub kind: AtomicU32,
    /// S: the process.
    pub pid: AtomicI32,
    /// S: the thread the signal goes to (SIGEV_THREAD_ID); 0: the process (climbsim picks).
    pub tid: AtomicI32,
    /// S: the signal; 0 (SIGEV_NONE): none is sent.
    pub signo: AtomicU32,
    /// S: the clock it was created on (an absolute setting is read on it).
    pub clock: AtomicI32,
    /// S: 1 once a POSIX timer's signal was sent, until it is seen taken (no longer pending):
    /// expirations meanwhile are its overrun.
    pub queued: AtomicU32,
    /// C: the thread climbsim picked for the expirations in `fired`.
    pub deliver_tid: AtomicI32,
    /// S (arming), C (firing): the next expiration, simulated ns.
    pub deadline_ns: AtomicU64,
    /// S: the period (0: one shot).
    pub interval_ns: AtomicU64,
    /// S: sigev_value, handed to the signal (si_value).
    pub value: AtomicU64,
    /// C adds expirations, the delivering thread takes them (the expirations past the first
    /// are the signal's overrun).
    pub fired: AtomicU32,
    /// S: the overrun of the last signal sent (timer_getoverrun).
    pub overrun: AtomicU32,
}

/// One connection from the controller to the sensor server, seen from both ends.
#[repr(C)]
pub struct Conn {
    /// S: the controller's end's local TCP port; 0 = free.
    pub client_port: AtomicU32,
    /// S: the process and descriptor of the controller's end.
    pub pid: AtomicI32,
    pub fd: AtomicI32,
    pub _pad0: AtomicU32,
    /// S: request bytes sent.
    pub sent: AtomicU64,
    /// C: request bytes the server has read (and answered, once a request is whole).
    pub read: AtomicU64,
    /// C: response bytes written, plus 1 once the server has closed its end.
    pub resp_written: AtomicU64,
    /// S: response bytes the controller has received, plus 1 at the end of the stream.
    pub resp_taken: AtomicU64,
    /// S: the threads blocked in a wait that includes this connection (bit `i % 64` of word
    /// `i / 64`: `Shared::slots[i]`). Written and read by `protocol.rs` only.
    pub(super) waiters: [AtomicU64; SLOTS / 64],
}

#[repr(C)]
pub struct Shared {
    pub header: Header,
    pub slots: [Slot; SLOTS],
    pub conns: [Conn; CONNS],
    pub sig_timers: [SigTimer; SIG_TIMERS],
    /// S writes, C takes: what the controller writes to the port, where the shim sees the write
    /// (byte `i` of the ring's stream at `i % PORT_TX_RING`). Through the pty each request
    /// woke the kernel's pty worker, whose hand-over climbsim then waited for with the world
    /// stopped; here climbsim finds the bytes in memory. Writes the shim does not see (stdio's,
    /// a process not followed) still go through the pty, which climbsim reads as well.
    pub port_tx_ring: [AtomicU8; PORT_TX_RING],
}

impl Shared {
    /// Bytes in the port's ring that climbsim has not taken.
    pub fn port_tx_ring_unread(&self) -> u64 {
        use core::sync::atomic::Ordering::Acquire;
        let read = self.header.port.tx_ring_read.load(Acquire);
        self.header.port.tx_ring_written.load(Acquire).saturating_sub(read)
    }

    /// The ring's place for byte `offset` of its stream (both sides count the stream, the ring
    /// wraps it).
    pub fn port_tx_ring_at(&self, offset: u64) -> &AtomicU8 {
        &self.port_tx_ring[(offset % PORT_TX_RING as u64) as usize]
    }

    /// The slots that have ever been taken (those past them are free): what every scan looks at.
    pub fn live_slots(&self) -> &[Slot] {
        let high = self.header.slots_high.load(core::sync::atomic::Ordering::Acquire) as usize;
        &self.slots[..high.clamp(1, SLOTS)]
    }

    /// The thread of process `pid` that takes signal `signo` (`tid`: the one named, as a
    /// `SIGEV_THREAD_ID` timer or `tgkill` names it), as the kernel would pick it: one waiting
    /// for it in sigtimedwait, else the main thread unless it blocks it, else the first that
    /// does not; if all block it, the main thread (the shim then leaves it pending on the
    /// process). A thread parked where the shim waits comes before one blocked in the kernel's
    /// waitpid, which would take it only when it returns.
    pub fn signal_taker(&self, pid: i32, tid: i32, signo: u32) -> Option<&Slot> {
        use core::sync::atomic::Ordering::Relaxed;
        let live = |s: &&Slot| s.is_live() && s.tid.load(Relaxed) > 0;
        let threads = || self.live_slots().iter().filter(move |s| s.pid.load(Relaxed) == pid).filter(live);
        if tid != 0 {
            return threads().find(|s| s.tid.load(Relaxed) == tid);
        }
        let bit = 1u64.checked_shl(signo.saturating_sub(1)).unwrap_or(0);
        let in_kernel = |s: &&Slot| s.in_waitpid();
        let waits_for = |s: &&Slot| s.sig_waiting.load(Relaxed) & bit != 0;
        let lets_through = |s: &&Slot| s.sig_blocked.load(Relaxed) & bit == 0;
        let main = |s: &&Slot| s.tid.load(Relaxed) == pid;
        threads()
            .find(waits_for)
            .or_else(|| threads().filter(|s| !in_kernel(s)).find(|s| main(s) && lets_through(s)))
            .or_else(|| threads().filter(|s| !in_kernel(s)).find(lets_through))
            .or_else(|| threads().find(|s| main(s) && lets_through(s)))
            .or_else(|| threads().find(lets_through))
            .or_else(|| threads().find(main))
            .or_else(|| threads().next())
    }

    /// The sensor connections that have ever been followed (those past them are free).
    pub fn live_conns(&self) -> &[Conn] {
        let high = self.header.conns_high.load(core::sync::atomic::Ordering::Acquire) as usize;
        &self.conns[..high.min(CONNS)]
    }

    /// Whether request bytes the controller sent on a sensor connection wait for climbsim (by
    /// the shim's count): simulated time cannot move past them.
    pub fn requests_unread(&self) -> bool {
        use core::sync::atomic::Ordering::Acquire;
        self.live_conns().iter().any(|c| c.is_followed() && c.sent.load(Acquire) != c.read.load(Acquire))
    }

    /// The signal timers that have ever been taken (those past them are free).
    pub fn live_sig_timers(&self) -> &[SigTimer] {
        let high = self.header.sig_timers_high.load(core::sync::atomic::Ordering::Acquire) as usize;
        &self.sig_timers[..high.min(SIG_TIMERS)]
    }
}

/// The block's size in bytes, for the file climbsim creates.
pub const SHARED_BYTES: usize = core::mem::size_of::<Shared>();
