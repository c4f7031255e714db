//! The few C types, libc functions and raw system calls the shim needs, declared here because the
//! shim has no dependencies (climbsim's build.rs compiles it with rustc alone).

#![allow(non_camel_case_types)]

use core::cell::Cell;
use core::ffi::{c_char, c_int, c_long, c_void};
use core::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, AtomicUsize, Ordering};

use crate::native;
pub use crate::native::{errno, set_errno};

pub type time_t = i64;
pub type clockid_t = c_int;
pub type nfds_t = u64;

#[repr(C)]
#[derive(Clone, Copy)]
pub struct timespec {
    pub tv_sec: time_t,
    pub tv_nsec: c_long,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct timeval {
    pub tv_sec: time_t,
    pub tv_usec: c_long,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct pollfd {
    pub fd: c_int,
    pub events: i16,
    pub revents: i16,
}

/// glibc's fd_set: 1024 bits.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct fd_set {
    pub bits: [u64; 16],
}

#[repr(C)]
pub struct iovec {
    pub iov_base: *mut c_void,
    pub iov_len: usize,
}

/// What a trapped call's emulation returns for "make the call again once the handler of the
/// signal that interrupted it has run", as the kernel restarts a call after an `SA_RESTART`
/// handler (no call returns it: errors are -1 to -4095).
pub const RESTART_CALL: c_long = c_long::MIN;
pub const POLLIN: i16 = 0x1;
pub const F_GETFL: c_int = 3;
pub const O_NONBLOCK: c_int = 0o4000;
pub const O_ACCMODE: c_int = 0o3;
pub const O_WRONLY: c_int = 0o1;
pub const O_PATH: c_int = 0o10000000;
pub const POLLPRI: i16 = 0x2;
pub const POLLOUT: i16 = 0x4;

pub const CLOCK_REALTIME: clockid_t = 0;
pub const CLOCK_MONOTONIC: clockid_t = 1;
pub const CLOCK_MONOTONIC_RAW: clockid_t = 4;
pub const CLOCK_REALTIME_COARSE: clockid_t = 5;
pub const CLOCK_MONOTONIC_COARSE: clockid_t = 6;
pub const CLOCK_BOOTTIME: clockid_t = 7;
pub const CLOCK_REALTIME_ALARM: clockid_t = 8;
pub const CLOCK_BOOTTIME_ALARM: clockid_t = 9;
pub const CLOCK_TAI: clockid_t = 11;
pub const TIMER_ABSTIME: c_int = 1;

pub const EINVAL: c_int = 22;
pub const EFAULT: c_int = 14;
pub const EOPNOTSUPP: c_int = 95;
pub const EINTR: c_int = 4;
pub const EAGAIN: c_int = 11;
/// A path relative to the working directory, for the `*at` calls.
pub const AT_FDCWD: c_long = -100;

const RTLD_NEXT: *mut c_void = -1isize as *mut c_void;

/// The system calls the shim makes or follows, by number (one table per architecture).
#[cfg(target_arch = "x86_64")]
pub mod nr {
    pub const READ: i64 = 0;
    pub const WRITE: i64 = 1;
    pub const WRITEV: i64 = 20;
    pub const SENDTO: i64 = 44;
    pub const RECVFROM: i64 = 45;
    pub const CLOSE: i64 = 3;
    pub const FSTAT: i64 = 5;
    pub const POLL: i64 = 7;
    pub const MMAP: i64 = 9;
    pub const MUNMAP: i64 = 11;
    pub const MPROTECT: i64 = 10;
    pub const RT_SIGACTION: i64 = 13;
    pub const RT_SIGPROCMASK: i64 = 14;
    pub const IOCTL: i64 = 16;
    pub const SELECT: i64 = 23;
    pub const SCHED_YIELD: i64 = 24;
    pub const PAUSE: i64 = 34;
    pub const NANOSLEEP: i64 = 35;
    pub const GETITIMER: i64 = 36;
    pub const ALARM: i64 = 37;
    pub const SETITIMER: i64 = 38;
    pub const GETPID: i64 = 39;
    pub const CLONE: i64 = 56;
    pub const EXECVE: i64 = 59;
    pub const WAIT4: i64 = 61;
    pub const KILL: i64 = 62;
    pub const WAITID: i64 = 247;
    pub const GETTIMEOFDAY: i64 = 96;
    pub const GETPPID: i64 = 110;
    pub const TIMES: i64 = 100;
    pub const GETUID: i64 = 102;
    pub const RT_SIGPENDING: i64 = 127;
    pub const RT_SIGTIMEDWAIT: i64 = 128;
    pub const RT_SIGQUEUEINFO: i64 = 129;
    pub const RT_SIGSUSPEND: i64 = 130;
    pub const PRCTL: i64 = 157;
    pub const ARCH_PRCTL: i64 = 158;
    pub const GETTID: i64 = 186;
    pub const TKILL: i64 = 200;
    pub const TIME: i64 = 201;
    pub const FUTEX: i64 = 202;
    pub const TIMER_CREATE: i64 = 222;
    pub const TIMER_SETTIME: i64 = 223;
    pub const TIMER_GETTIME: i64 = 224;
    pub const TIMER_GETOVERRUN: i64 = 225;
    pub const TIMER_DELETE: i64 = 226;
    pub const CLOCK_GETTIME: i64 = 228;
    pub const GET_ROBUST_LIST: i64 = 274;
    pub const CLOCK_NANOSLEEP: i64 = 230;
    pub const EPOLL_WAIT: i64 = 232;
    pub const EPOLL_CTL: i64 = 233;
    pub const TGKILL: i64 = 234;
    pub const OPENAT: i64 = 257;
    pub const EPOLL_PWAIT: i64 = 281;
    pub const PPOLL: i64 = 271;
    pub const EPOLL_PWAIT2: i64 = 441;
    pub const RT_TGSIGQUEUEINFO: i64 = 297;
    pub const SECCOMP: i64 = 317;
    pub const EXECVEAT: i64 = 322;
    pub const MEMFD_CREATE: i64 = 319;
    pub const PRLIMIT64: i64 = 302;
    pub const PROCESS_VM_READV: i64 = 310;
    pub const FCNTL: i64 = 72;
    pub const READLINKAT: i64 = 267;
    pub const IO_URING_SETUP: i64 = 425;
    pub const CLONE3: i64 = 435;
    pub const SEMOP: i64 = 65;
    pub const GETSOCKOPT: i64 = 55;
    pub const PWRITEV2: i64 = 328;
    pub const SEMCTL: i64 = 66;
    pub const SEMTIMEDOP: i64 = 220;
    pub const MQ_TIMEDSEND: i64 = 242;
    pub const MQ_TIMEDRECEIVE: i64 = 243;
    pub const FUTEX_WAITV: i64 = 449;
    /// struct stat: st_mode's and st_rdev's offsets.
    pub const ST_MODE: usize = 24;
    pub const ST_RDEV: usize = 40;
}

#[cfg(target_arch = "aarch64")]
pub mod nr {
    pub const OPENAT: i64 = 56;
    pub const CLOSE: i64 = 57;
    pub const READ: i64 = 63;
    pub const WRITE: i64 = 64;
    pub const FSTAT: i64 = 80;
    pub const FUTEX: i64 = 98;
    pub const GET_ROBUST_LIST: i64 = 100;
    pub const NANOSLEEP: i64 = 101;
    pub const SCHED_YIELD: i64 = 124;
    pub const CLOCK_GETTIME: i64 = 113;
    pub const CLOCK_NANOSLEEP: i64 = 115;
    pub const RT_SIGACTION: i64 = 134;
    pub const RT_SIGPROCMASK: i64 = 135;
    pub const PRCTL: i64 = 167;
    pub const GETTIMEOFDAY: i64 = 169;
    pub const GETPID: i64 = 172;
    pub const GETPPID: i64 = 173;
    pub const GETTID: i64 = 178;
    pub const EXECVE: i64 = 221;
    pub const MMAP: i64 = 222;
    pub const MUNMAP: i64 = 215;
    pub const SECCOMP: i64 = 277;
    pub const EXECVEAT: i64 = 281;
    pub const MEMFD_CREATE: i64 = 279;
    pub const PRLIMIT64: i64 = 261;
    pub const PROCESS_VM_READV: i64 = 270;
    pub const FCNTL: i64 = 25;
    pub const GETSOCKOPT: i64 = 209;
    pub const PWRITEV2: i64 = 287;
    pub const READLINKAT: i64 = 78;
    pub const IO_URING_SETUP: i64 = 425;
    pub const ST_MODE: usize = 16;
    pub const ST_RDEV: usize = 32;
}

unsafe extern "C" {
    pub fn fcntl(fd: c_int, command: c_int, ...) -> c_int;
    pub fn dlsym(handle: *mut c_void, symbol: *const c_char) -> *mut c_void;
    pub fn getenv(name: *const c_char) -> *mut c_char;
    pub fn open(path: *const c_char, flags: c_int, ...) -> c_int;
    pub fn mmap(addr: *mut c_void, len: usize, prot: c_int, flags: c_int, fd: c_int, offset: i64) -> *mut c_void;
    pub fn __cxa_atexit(func: unsafe extern "C" fn(*mut c_void), arg: *mut c_void, dso: *mut c_void) -> c_int;
    pub fn pthread_key_create(key: *mut u32, destructor: Option<unsafe extern "C" fn(*mut c_void)>) -> c_int;
    pub fn pthread_setspecific(key: u32, value: *const c_void) -> c_int;
    pub fn pthread_self() -> usize;
    pub fn pthread_testcancel();
    pub fn __register_atfork(prepare: Option<unsafe extern "C" fn()>, parent: Option<unsafe extern "C" fn()>, child: Option<unsafe extern "C" fn()>, dso: *mut c_void) -> c_int;
}

/// The next definition of `name` (NUL-terminated) after the shim's: libc's own. A missing one is
/// fatal, so that a shim that cannot call through never fakes a result.
pub fn next_symbol(cache: &AtomicUsize, name: &'static [u8]) -> usize {
    let cached = cache.load(Ordering::Relaxed);
    if cached != 0 {
        return cached;
    }
    // SAFETY: `name` is a NUL-terminated symbol name; dlsym has no other precondition.
    let found = unsafe { dlsym(RTLD_NEXT, name.as_ptr().cast()) } as usize;
    if found == 0 {
        say(b"climbsim shim: libc has no ");
        say(&name[..name.len() - 1]);
        say(b"; cannot go on\n");
        std::process::abort();
    }
    cache.store(found, Ordering::Relaxed);
    found
}

/// libc's definition of a function the shim replaces, as a typed function pointer.
macro_rules! real {
    ($name:ident : fn($($arg:ty),*) -> $ret:ty) => {{
        static CACHE: core::sync::atomic::AtomicUsize = core::sync::atomic::AtomicUsize::new(0);
        let address = $crate::sys::next_symbol(&CACHE, concat!(stringify!($name), "\0").as_bytes());
        // SAFETY: `address` is libc's definition of the symbol, whose C signature this is.
        unsafe { core::mem::transmute::<usize, unsafe extern "C" fn($($arg),*) -> $ret>(address) }
    }};
}
pub(crate) use real;

/// A line on standard error, without going through anything the shim intercepts.
pub fn say(text: &[u8]) {
    native::call3(nr::WRITE, 2, text.as_ptr() as c_long, text.len() as c_long);
}

/// glibc's signal for a thread's cancellation.
pub const SIGCANCEL: c_int = 32;

/// Signals pending for this thread or its process (made natively: a trapped call).
pub fn pending_signals() -> u64 {
    let mut set = 0u64;
    native::call2(nr::RT_SIGPENDING, &mut set as *mut u64 as c_long, 8);
    set
}

pub fn gettid() -> i32 {
    native::call0(nr::GETTID) as i32
}

pub fn getppid() -> i32 {
    native::call0(nr::GETPPID) as i32
}

pub fn getpid() -> i32 {
    native::call0(nr::GETPID) as i32
}

/// Whether process `pid` exists (kill with signal 0, made natively: libc's kill traps).
pub fn process_lives(pid: i32) -> bool {
    const ESRCH: c_long = 3;
    pid > 0 && native::call2(nr::KILL, pid as c_long, 0) != -ESRCH
}

const FUTEX_WAIT: c_long = 0;
const FUTEX_WAKE: c_long = 1;

/// Sleep while `word` still holds `expected`, at most `timeout_ns` (shared futex: the word lives
/// in memory mapped by climbsim too).
pub fn futex_wait(word: &AtomicU32, expected: u32, timeout_ns: u64) {
    let timeout = timespec { tv_sec: (timeout_ns / 1_000_000_000) as time_t, tv_nsec: (timeout_ns % 1_000_000_000) as c_long };
    // Native (never the emulated futex): the word is the shim's own, shared with climbsim.
    native::call4(nr::FUTEX, word.as_ptr() as c_long, FUTEX_WAIT, expected as c_long, &timeout as *const timespec as c_long);
}

pub fn futex_wake(word: &AtomicU32) {
    native::call3(nr::FUTEX, word.as_ptr() as c_long, FUTEX_WAKE, i32::MAX as c_long);
}

/// This process's id (kept up to date across fork), to find its descriptors' entries and to
/// read its memory ([`copy_from_program`]).
static PID: AtomicI32 = AtomicI32::new(0);

/// This process's id, as the shim last noted it (at start, and in a forked child).
pub(crate) fn noted_pid() -> i32 {
    PID.load(Ordering::Relaxed)
}

/// Note this process's id (at start, and in a forked child).
pub(crate) fn note_pid() {
    PID.store(getpid(), Ordering::Relaxed);
}

/// Copy `len` bytes of the program's memory at `from` to `to`, as the kernel copies a call's
/// arguments in (`copy_from_user`); false if any of it is not readable, where Linux answers
/// EFAULT. The shim reads a call's arguments before the kernel sees them, and a bad pointer must
/// be the program's EFAULT, not a crash inside the shim.
///
/// The kernel itself tells, one 8-byte window in each page of the range, natively and without
/// a side effect: `rt_sigprocmask` with an invalid `how` copies the new mask in first (EFAULT if
/// it cannot) and only then refuses the `how` (EINVAL), changing nothing. Natively 87 ns a window against
/// 800 ns for `process_vm_readv` (which pins the pages it copies;
/// `hil/bench/argument_probe.c`, 2026-12-07), and every poll and select of an SDK's read loop pays it:
/// `process_vm_readv` asks only for ranges shorter than a window.
pub fn copy_from_program(from: *const u8, to: *mut u8, len: usize) -> bool {
    if len == 0 {
        return true;
    }
    if from.is_null() || !program_readable(from as usize, len) {
        return false;
    }
    // SAFETY: every page of the range is mapped readable (just asked).
    unsafe { core::ptr::copy_nonoverlapping(from, to, len) };
    true
}

/// Whether the program's `len` bytes at `start` are readable (see [`copy_from_program`]).
fn program_readable(start: usize, len: usize) -> bool {
    const PAGE: usize = 4096;
    const WINDOW: usize = 8;
    const INVALID_HOW: c_long = -1;
    let Some(end) = start.checked_add(len) else { return false };
    if len < WINDOW {
        return process_vm_readable(start, len);
    }
    let mut page = start & !(PAGE - 1);
    while page < end {
        // A window inside the range that reaches into this page.
        let window = page.max(start).min(end - WINDOW);
        let rc = native::call4(nr::RT_SIGPROCMASK, INVALID_HOW, window as c_long, 0, WINDOW as c_long);
        if rc == -c_long::from(EFAULT) {
            return false;
        }
        page += PAGE;
    }
    true
}

/// Whether `len` bytes at `start` can be read, asked with `process_vm_readv` on this process
/// (a range too short for [`program_readable`]'s window). Where that is refused (a sandbox's
/// own filter), the memory is taken as readable, as the program's own code takes it.
fn process_vm_readable(start: usize, len: usize) -> bool {
    let mut scratch = [0u8; 8];
    let local = iovec { iov_base: scratch.as_mut_ptr().cast(), iov_len: len.min(scratch.len()) };
    let remote = iovec { iov_base: start as *mut c_void, iov_len: len.min(scratch.len()) };
    // The noted id, not getpid: a vfork child's is its parent's, whose memory it shares; a
    // forked child notes its own before it runs on.
    let pid = match noted_pid() {
        0 => getpid(),
        pid => pid,
    };
    let rc = native::call6(nr::PROCESS_VM_READV, pid as c_long, &local as *const iovec as c_long, 1, &remote as *const iovec as c_long, 1, 0);
    rc == local.iov_len as c_long || !(rc >= 0 || rc == -c_long::from(EFAULT))
}

/// The program's value of type `T` at `from`, copied as [`copy_from_program`] does (`None`:
/// not readable, EFAULT).
pub fn read_from_program<T: Copy>(from: *const T) -> Option<T> {
    let mut value = core::mem::MaybeUninit::<T>::uninit();
    // SAFETY: on success every byte of `value` was written.
    copy_from_program(from.cast(), value.as_mut_ptr().cast(), core::mem::size_of::<T>()).then(|| unsafe { value.assume_init() })
}

/// Which of a socket's timeouts: SO_RCVTIMEO, SO_SNDTIMEO.
pub const SO_RCVTIMEO: c_long = 20;
pub const SO_SNDTIMEO: c_long = 21;

/// A socket's receive or send timeout (`which`) in ns; None: not a socket, or no timeout.
pub fn socket_timeout(fd: c_int, which: c_long) -> Option<u64> {
    const SOL_SOCKET: c_long = 1;
    let mut timeout = timeval { tv_sec: 0, tv_usec: 0 };
    let mut size = core::mem::size_of::<timeval>() as u32;
    let rc = native::call6(nr::GETSOCKOPT, fd as c_long, SOL_SOCKET, which, &mut timeout as *mut timeval as c_long, &mut size as *mut u32 as c_long, 0);
    (rc == 0).then(|| timeval_ns(&timeout)).flatten().filter(|&ns| ns > 0)
}

/// What one `fstat` of a descriptor says that the shim asks: its kind, device and inode.
#[derive(Clone, Copy)]
pub struct FileStat {
    /// st_mode's S_IFMT bits.
    kind: u32,
    rdev: u64,
    inode: u64,
}

/// What a blocking write may wait in for room.
#[derive(Clone, Copy)]
pub struct PipeOrSocket {
    /// A pipe (or FIFO), not a socket.
    pub pipe: bool,
    pub inode: u64,
}

impl FileStat {
    /// The character device number, if it is one.
    pub fn char_device(self) -> Option<u64> {
        const S_IFCHR: u32 = 0o020000;
        (self.kind == S_IFCHR).then_some(self.rdev)
    }

    /// If it is a pipe (or FIFO) or a socket: which, and its inode.
    pub fn pipe_or_socket(self) -> Option<PipeOrSocket> {
        const S_IFIFO: u32 = 0o010000;
        const S_IFSOCK: u32 = 0o140000;
        (self.kind == S_IFIFO || self.kind == S_IFSOCK).then_some(PipeOrSocket { pipe: self.kind == S_IFIFO, inode: self.inode })
    }
}

/// `fstat` of `fd`; None: not open.
pub fn file_stat(fd: c_int) -> Option<FileStat> {
    const S_IFMT: u32 = 0o170000;
    /// struct stat's st_ino (after st_dev), on both architectures.
    const ST_INO: usize = 8;
    let mut stat = [0u8; 256];
    // fstat writes at most sizeof(struct stat) (144 or 128 bytes) into the buffer.
    let rc = native::call2(nr::FSTAT, fd as c_long, stat.as_mut_ptr() as c_long);
    if rc != 0 {
        return None;
    }
    let word = |at: usize| {
        let mut bytes = [0u8; 8];
        bytes.copy_from_slice(&stat[at..at + 8]);
        u64::from_ne_bytes(bytes)
    };
    let mode = u32::from_ne_bytes([stat[nr::ST_MODE], stat[nr::ST_MODE + 1], stat[nr::ST_MODE + 2], stat[nr::ST_MODE + 3]]);
    Some(FileStat { kind: mode & S_IFMT, rdev: word(nr::ST_RDEV), inode: word(ST_INO) })
}

/// If `fd` is a pipe (or FIFO) or a socket: which, and its inode.
pub fn pipe_or_socket(fd: c_int) -> Option<PipeOrSocket> {
    file_stat(fd)?.pipe_or_socket()
}

/// "/proc/TID/fd/N" (`tid` None: "/proc/self/fd/N"), NUL-terminated, without the heap (the
/// caller may be a vfork child, or in a signal handler).
pub fn fd_path(tid: Option<i32>, fd: c_int) -> [u8; 40] {
    let mut path = [0u8; 40];
    let mut len = 0;
    let mut digits = [[0u8; 10]; 2];
    let [task_digits, fd_digits] = &mut digits;
    let task: &[u8] = match tid {
        Some(tid) => decimal(tid as u32, task_digits),
        None => b"self",
    };
    for text in [&b"/proc/"[..], task, b"/fd/", decimal(fd as u32, fd_digits)] {
        path[len..len + text.len()].copy_from_slice(text);
        len += text.len();
    }
    path
}

/// `number` in decimal, in `digits`.
fn decimal(mut number: u32, digits: &mut [u8; 10]) -> &[u8] {
    let mut start = digits.len();
    loop {
        start -= 1;
        digits[start] = b'0' + (number % 10) as u8;
        number /= 10;
        if number == 0 {
            return &digits[start..];
        }
    }
}

/// `count` bytes at `buf` written to the pipe `fd` without waiting, through a file description
/// of its own opened non-blocking (`/proc/self/fd/N`): for a pipe opened by name, which takes
/// no RWF_NOWAIT. The kernel's convention (bytes written, or a negative errno); None if that
/// description cannot be opened.
pub fn write_pipe_without_waiting(fd: c_int, buf: *const u8, count: usize) -> Option<isize> {
    const O_WRONLY: c_long = 1;
    const O_CLOEXEC: c_long = 0o2000000;
    let path = fd_path(None, fd);
    let own = native::call4(nr::OPENAT, AT_FDCWD, path.as_ptr() as c_long, O_WRONLY | O_NONBLOCK as c_long | O_CLOEXEC, 0);
    if own < 0 {
        return None;
    }
    let written = native::call3(nr::WRITE, own, buf as c_long, count as c_long) as isize;
    native::call1(nr::CLOSE, own);
    Some(written)
}

/// The file status flags of `fd` (fcntl F_GETFL); None: not open.
pub fn status_flags(fd: c_int) -> Option<c_int> {
    let flags = native::call2(nr::FCNTL, fd as c_long, F_GETFL as c_long);
    (flags >= 0).then_some(flags as c_int)
}

/// Whether `fd` is open and blocking (no O_NONBLOCK).
pub fn blocking(fd: c_int) -> bool {
    status_flags(fd).is_some_and(|flags| flags & O_NONBLOCK == 0)
}

/// The character device number of `fd`, if it is one.
pub fn char_device(fd: c_int) -> Option<u64> {
    file_stat(fd)?.char_device()
}

thread_local! {
    /// Non-zero while the shim itself is at work in this thread (in the trap handler, or
    /// calling libc for a thread): its system calls go to the kernel as they are.
    static OWN_CALLS: Cell<u32> = const { Cell::new(0) };
}

/// Whether the shim is at work in this thread (see `OWN_CALLS`).
pub(crate) fn in_shim() -> bool {
    OWN_CALLS.with(Cell::get) != 0
}

/// Marks the shim at work in this thread while it lives.
pub(crate) struct OwnCalls;

impl OwnCalls {
    pub(crate) fn enter() -> Self {
        OWN_CALLS.with(|c| c.set(c.get() + 1));
        OwnCalls
    }
}

impl Drop for OwnCalls {
    fn drop(&mut self) {
        OWN_CALLS.with(|c| c.set(c.get().saturating_sub(1)));
    }
}

/// The host's monotonic clock (ns).
pub(crate) fn real_monotonic_ns() -> u64 {
    host_clock_ns(CLOCK_MONOTONIC)
}

/// This thread's CPU time (the kernel's, ns).
pub(crate) fn thread_cpu_ns() -> u64 {
    const CLOCK_THREAD_CPUTIME_ID: clockid_t = 3;
    host_clock_ns(CLOCK_THREAD_CPUTIME_ID)
}

/// Set once the vDSO's clocks are not the host's in this process: patched to the shim's
/// (`vdso.rs`), or executing an `rdtsc` that faults (`tsc.rs`: a Go program), whose handler
/// answers simulated ticks — and once the run has ended reads the host's clock itself, which
/// would fault again without end (docs/performance-virtual-time.md has the incident). The
/// shim's own reads of the host's clocks then go to the kernel: 160 ns against the vDSO's 22
/// on the reference machine, which is why the shim's spins read the clock only every few turns.
static HOST_CLOCKS_BY_SYSCALL: AtomicBool = AtomicBool::new(false);

/// From here on the shim reads the host's clocks with the system call (see
/// [`HOST_CLOCKS_BY_SYSCALL`]).
pub(crate) fn host_clocks_by_syscall() {
    HOST_CLOCKS_BY_SYSCALL.store(true, Ordering::Relaxed);
}

/// The host's `clock`, read as the shim's own call: should libc fall back to the system call
/// (the vDSO does for the CPU-time clocks), it goes to the kernel, not to the trap.
fn host_clock_ns(clock: clockid_t) -> u64 {
    let mut ts = timespec { tv_sec: 0, tv_nsec: 0 };
    if HOST_CLOCKS_BY_SYSCALL.load(Ordering::Relaxed) {
        native::call2(nr::CLOCK_GETTIME, clock as c_long, &mut ts as *mut timespec as c_long);
        return to_ns(&ts);
    }
    let _own = OwnCalls::enter();
    let clock_gettime = real!(clock_gettime: fn(clockid_t, *mut timespec) -> c_int);
    // SAFETY: a valid timespec for the call.
    unsafe { clock_gettime(clock, &mut ts) };
    to_ns(&ts)
}

/// A time argument in ns if Linux takes it as valid (0 <= tv_sec, 0 <= tv_nsec < 1e9; else the
/// call is EINVAL).
pub(crate) fn timespec_ns(ts: &timespec) -> Option<u64> {
    (ts.tv_sec >= 0 && (0..1_000_000_000).contains(&ts.tv_nsec)).then(|| to_ns(ts))
}

/// [`timespec_ns`] for a `timeval` (0 <= tv_usec < 1e6).
pub(crate) fn timeval_ns(tv: &timeval) -> Option<u64> {
    (tv.tv_sec >= 0 && (0..1_000_000).contains(&tv.tv_usec)).then(|| (tv.tv_sec as u64).saturating_mul(1_000_000_000).saturating_add(tv.tv_usec as u64 * 1000))
}

/// The program's timeout at `from` in ns, as Linux takes a call's timeout: none (`None`) for a
/// null pointer; EFAULT if it is not readable; EINVAL if it is not valid ([`timespec_ns`]).
pub(crate) fn program_timespec(from: *const timespec) -> Result<Option<u64>, c_int> {
    program_time(from, timespec_ns)
}

/// [`program_timespec`] for a `timeval` (select's).
pub(crate) fn program_timeval(from: *const timeval) -> Result<Option<u64>, c_int> {
    program_time(from, timeval_ns)
}

fn program_time<T: Copy>(from: *const T, ns: fn(&T) -> Option<u64>) -> Result<Option<u64>, c_int> {
    if from.is_null() {
        return Ok(None);
    }
    ns(&read_from_program(from).ok_or(EFAULT)?).map(Some).ok_or(EINVAL)
}

/// The most descriptors this process may have open (RLIMIT_NOFILE's soft limit), past which a
/// poll is EINVAL. Asked only for an array longer than any limit Linux allows below (64).
pub(crate) fn open_files_limit() -> u64 {
    const RLIMIT_NOFILE: c_long = 7;
    let mut limit = [u64::MAX; 2];
    native::call4(nr::PRLIMIT64, 0, RLIMIT_NOFILE, 0, limit.as_mut_ptr() as c_long);
    limit[0]
}

/// Zeroed, writable pages of at least `bytes` (an anonymous mapping, made natively).
pub(crate) fn fresh_pages(bytes: usize) -> Option<*mut u8> {
    const PROT_READ_WRITE: c_long = 3;
    const MAP_PRIVATE_ANONYMOUS: c_long = 0x22;
    let address = native::call6(nr::MMAP, 0, bytes as c_long, PROT_READ_WRITE, MAP_PRIVATE_ANONYMOUS, -1, 0);
    (address > 0).then_some(address as *mut u8)
}

/// Give back pages [`fresh_pages`] made (`bytes` as asked then).
pub(crate) fn release_pages(pages: *mut u8, bytes: usize) {
    native::call2(nr::MUNMAP, pages as c_long, bytes as c_long);
}

/// A timespec in ns (negative parts as 0).
pub(crate) fn to_ns(ts: &timespec) -> u64 {
    (ts.tv_sec.max(0) as u64).saturating_mul(1_000_000_000).saturating_add(ts.tv_nsec.max(0) as u64)
}
