//! The second layer: system calls, whatever made them. A seccomp filter raises SIGSYS for every
//! call of the families climbsim follows that was made anywhere but the shim's own page
//! (`native.rs`): by libc internally, libstdc++, Rust std, a JIT, an inline `syscall`. The
//! handler here runs it on simulated time, on the registers the kernel saved, and writes the
//! result where the caller will find it. The preloaded symbols stay in front as the fast path;
//! what they do not see, this catches.
//!
//! What is trapped is chosen so that a program exec'd under the filter (which it inherits, and
//! which no one can remove) survives until its own shim has loaded: the loader and libc's start
//! make only memory, file and thread-setup calls, none of them trapped here (checked with strace
//! for Python, sh, Node.js and Java). The exec itself is trapped, and puts the shim into the new
//! program's environment if it was dropped.
//!
//! The handler keeps SIGSYS deliverable everywhere: a trapped call while SIGSYS is blocked would
//! be fatal, so the program's signal masks (sigprocmask, sigaction's masks) never include it,
//! and nobody can replace the handler (its wish is remembered and reported back to it).

use core::ffi::{c_int, c_long, c_void};
use core::sync::atomic::Ordering;

use crate::handlers::{self, SIG_SETMASK, context};
use crate::native;
use crate::sys::{self, nr};

/// The system calls the filter traps (x86_64).
#[cfg(target_arch = "x86_64")]
const TRAPPED: &[i64] = &[
    nr::RT_SIGACTION,
    nr::RT_SIGPROCMASK,
    nr::NANOSLEEP,
    nr::EXECVE,
    nr::GETTIMEOFDAY,
    nr::TIME,
    nr::TIMES,
    nr::FUTEX,
    nr::CLOCK_GETTIME,
    nr::CLOCK_NANOSLEEP,
    nr::EXECVEAT,
    nr::SCHED_YIELD,
    nr::IO_URING_SETUP,
    nr::ALARM,
    nr::SETITIMER,
    nr::GETITIMER,
    nr::TIMER_CREATE,
    nr::TIMER_SETTIME,
    nr::TIMER_GETTIME,
    nr::TIMER_GETOVERRUN,
    nr::TIMER_DELETE,
    nr::PAUSE,
    nr::RT_SIGSUSPEND,
    nr::RT_SIGTIMEDWAIT,
    nr::KILL,
    nr::TGKILL,
    nr::TKILL,
    nr::WAIT4,
    nr::WAITID,
    nr::SEMOP,
    nr::SEMTIMEDOP,
    nr::MQ_TIMEDSEND,
    nr::MQ_TIMEDRECEIVE,
    nr::FUTEX_WAITV,
];

/// What the main program's own code traps for besides (see `install_own_text_filter`): the
/// calls a runtime that bypasses libc makes itself (Go; Rust's `rustix`).
#[cfg(target_arch = "x86_64")]
const OWN_CALLS: &[i64] =
    &[nr::READ, nr::WRITE, nr::WRITEV, nr::CLOSE, nr::IOCTL, nr::POLL, nr::PPOLL, nr::SELECT, nr::EPOLL_WAIT, nr::EPOLL_CTL, nr::EPOLL_PWAIT, nr::EPOLL_PWAIT2, nr::RECVFROM, nr::SENDTO];

/// clone's flag for a thread of the same process: only those clones trap (see `clone_thread`).
const CLONE_THREAD: u32 = 0x0001_0000;
const CLONE_VM: i64 = 0x0000_0100;
const CLONE_SETTLS: i64 = 0x0008_0000;
const CLONE_CHILD_CLEARTID: i64 = 0x0020_0000;

const ENOSYS: c_long = 38;

/// Install the SIGSYS handler and the filter; whether system calls are now followed. Called from
/// the constructor, single-threaded, once the block is mapped.
#[cfg(target_arch = "x86_64")]
pub(crate) fn install() -> Result<(), &'static [u8]> {
    if !native::map_page() {
        return Err(b"cannot map the shim's system-call page");
    }
    handlers::install_sigsys(on_sigsys as *const () as usize)?;
    install_filter()
}

/// Whether this process runs under a seccomp filter it inherited (an exec from a followed
/// program).
pub(crate) fn inherited() -> bool {
    const PR_GET_SECCOMP: c_long = 21;
    const SECCOMP_MODE_FILTER: c_long = 2;
    native::call1(nr::PRCTL, PR_GET_SECCOMP) == SECCOMP_MODE_FILTER
}

/// The handler alone, for a dormant shim under an inherited filter: every trapped call goes
/// to the kernel as it is.
#[cfg(target_arch = "x86_64")]
pub(crate) fn install_passthrough() -> Result<(), &'static [u8]> {
    if !native::map_page() {
        return Err(b"cannot map the shim's system-call page under an inherited filter");
    }
    handlers::install_sigsys(on_sigsys as *const () as usize)
}

#[cfg(not(target_arch = "x86_64"))]
pub(crate) fn install_passthrough() -> Result<(), &'static [u8]> {
    Ok(())
}

#[cfg(not(target_arch = "x86_64"))]
pub(crate) fn install() -> Result<(), &'static [u8]> {
    Err(b"system calls are followed on x86_64 only")
}

const LD_W_ABS: u16 = 0x20;
const JEQ_K: u16 = 0x15;
const JGE_K: u16 = 0x35;
const JSET_K: u16 = 0x45;
const RET_K: u16 = 0x06;
const AUDIT_ARCH_X86_64: u32 = 0xc000_003e;
const RET_ALLOW: u32 = 0x7fff_0000;
/// The shim's filters trap with their own data (`SHIM_TRAP`), which the kernel hands the
/// handler as si_errno: a trap with other data is a filter of the program's own (a sandbox),
/// for the program's handler.
const RET_TRAP: u32 = 0x0003_0000 | SHIM_TRAP as u32;
const SHIM_TRAP: c_int = 0x5c1;
const RET_ERRNO: u32 = 0x0005_0000;
/// Offsets into `struct seccomp_data`: the call's number, its ABI, the instruction pointer's
/// low and high words, the first argument's low word.
const NR: u32 = 0;
const ARCH: u32 = 4;
const IP_LOW: u32 = 8;
const IP_HIGH: u32 = 12;
const ARG0_LOW: u32 = 16;

/// One classic BPF instruction.
#[repr(C)]
#[derive(Clone, Copy)]
struct Insn {
    code: u16,
    jt: u8,
    jf: u8,
    k: u32,
}

/// A filter program being written, then installed (the kernel copies it).
struct Filter {
    program: [Insn; 64],
    len: usize,
}

impl Filter {
    fn new() -> Self {
        Filter { program: [Insn { code: 0, jt: 0, jf: 0, k: 0 }; 64], len: 0 }
    }

    fn push(&mut self, code: u16, jt: u8, jf: u8, k: u32) {
        self.program[self.len] = Insn { code, jt, jf, k };
        self.len += 1;
    }

    /// Calls of other ABIs (32-bit) are not followed: allowed.
    fn allow_other_abis(&mut self) {
        self.push(LD_W_ABS, 0, 0, ARCH);
        self.push(JEQ_K, 1, 0, AUDIT_ARCH_X86_64);
        self.push(RET_K, 0, 0, RET_ALLOW);
    }

    /// Five instructions: on to `inside` instructions past them when the call was made from
    /// [start, end) (one 4 GiB range), else `outside` past them.
    fn if_made_from(&mut self, start: u64, end: u64, inside: u8, outside: u8) {
        let (start_high, end_high, end_low) = ((start >> 32) as u32, (end >> 32) as u32, end as u32);
        self.push(LD_W_ABS, 0, 0, IP_HIGH);
        if end_high == start_high {
            self.push(JEQ_K, 0, 3 + outside, start_high);
            self.push(LD_W_ABS, 0, 0, IP_LOW);
            self.push(JGE_K, 0, 1 + outside, start as u32);
            self.push(JGE_K, outside, inside, end_low);
        } else if end_low == 0 {
            // It ends at a 4 GiB boundary: past its start in its own 4 GiB is inside.
            self.push(JEQ_K, 0, 2 + outside, start_high);
            self.push(LD_W_ABS, 0, 0, IP_LOW);
            self.push(JGE_K, inside, outside, start as u32);
        } else {
            // Across one boundary (a position-independent program's text lies where address
            // randomisation put it): past its start in the first 4 GiB, or before its end in
            // the next. `install_own_text_filter` refuses a range wider than that.
            self.push(JEQ_K, 0, 2, start_high);
            self.push(LD_W_ABS, 0, 0, IP_LOW);
            self.push(JGE_K, 3 + inside, 3 + outside, start as u32);
            self.push(JEQ_K, 0, 2 + outside, end_high);
            self.push(LD_W_ABS, 0, 0, IP_LOW);
            self.push(JGE_K, outside, inside, end_low);
        }
    }

    /// The listed calls trap, everything else is allowed: ends the program.
    fn trap_listed(&mut self, calls: &[i64]) {
        let count = calls.len() as u8;
        self.push(LD_W_ABS, 0, 0, NR);
        for (index, &number) in calls.iter().enumerate() {
            // Jump to the RET_TRAP after the list when equal.
            self.push(JEQ_K, count - index as u8, 0, number as u32);
        }
        self.push(RET_K, 0, 0, RET_ALLOW);
        self.push(RET_K, 0, 0, RET_TRAP);
    }

    fn install(&self) -> Result<(), &'static [u8]> {
        #[repr(C)]
        struct Program {
            len: u16,
            filter: *const Insn,
        }
        let filter = Program { len: self.len as u16, filter: self.program.as_ptr() };
        const PR_SET_NO_NEW_PRIVS: c_long = 38;
        const SECCOMP_SET_MODE_FILTER: c_long = 1;
        const SECCOMP_FILTER_FLAG_TSYNC: c_long = 1;
        if native::call2(nr::PRCTL, PR_SET_NO_NEW_PRIVS, 1) != 0 {
            return Err(b"cannot set no_new_privs for the seccomp filter");
        }
        if native::call3(nr::SECCOMP, SECCOMP_SET_MODE_FILTER, SECCOMP_FILTER_FLAG_TSYNC, &filter as *const Program as c_long) != 0 {
            return Err(b"the kernel refused the seccomp filter");
        }
        Ok(())
    }
}

/// The filter: a classic BPF program over `struct seccomp_data`.
#[cfg(target_arch = "x86_64")]
fn install_filter() -> Result<(), &'static [u8]> {
    let mut filter = Filter::new();
    filter.allow_other_abis();
    // 3: calls from the shim's page go through.
    let page = native::PAGE_ADDRESS as u64;
    filter.if_made_from(page, page + native::PAGE_BYTES as u64, 0, 1);
    filter.push(RET_K, 0, 0, RET_ALLOW);
    // 9: a clone that makes a thread traps (a fork's goes through).
    filter.push(LD_W_ABS, 0, 0, NR);
    filter.push(JEQ_K, 0, 3, nr::CLONE as u32);
    filter.push(LD_W_ABS, 0, 0, ARG0_LOW);
    filter.push(JSET_K, 0, 1, CLONE_THREAD);
    filter.push(RET_K, 0, 0, RET_TRAP);
    // 14: clone3 fails with ENOSYS, as on a kernel before 5.3: glibc then uses clone, whose
    // flags, unlike clone3's, are in a register the filter can read. Answered by the filter
    // itself: glibc tries clone3 again at every thread's creation, and a trap costs microseconds.
    filter.push(LD_W_ABS, 0, 0, NR);
    filter.push(JEQ_K, 0, 1, nr::CLONE3 as u32);
    filter.push(RET_K, 0, 0, RET_ERRNO | ENOSYS as u32);
    // 17: the followed calls trap; everything else goes through.
    filter.trap_listed(TRAPPED);
    filter.install()?;
    match crate::program::own_text() {
        Some((start, end)) => install_own_text_filter(start, end),
        None => Ok(()),
    }
}

/// The main program's own reads, writes, closes, ioctls and waits (made with its own `syscall`
/// instructions, from its text: a Go program's, or a position-independent program's, see
/// `program::own_text`) trap too; the same calls made anywhere else (libc's, the loader's after
/// an exec) do not. A second filter: the kernel runs both, and a trap wins over an allow.
#[cfg(target_arch = "x86_64")]
fn install_own_text_filter(start: u64, end: u64) -> Result<(), &'static [u8]> {
    if (end >> 32).saturating_sub(start >> 32) > 1 {
        return Err(b"the program's text is larger than 4 GiB");
    }
    let mut filter = Filter::new();
    filter.allow_other_abis();
    filter.if_made_from(start, end, 1, 0);
    filter.push(RET_K, 0, 0, RET_ALLOW);
    filter.trap_listed(OWN_CALLS);
    filter.install()
}

#[cfg(target_arch = "x86_64")]
unsafe extern "C" fn on_sigsys(_signal: c_int, info: *mut c_void, context: *mut c_void) {
    // Only the filter's traps (si_code SYS_SECCOMP) carry a call; a SIGSYS sent with kill(2) or
    // raised by the program is the program's own.
    const SYS_SECCOMP: c_int = 1;
    // SAFETY: the kernel's siginfo: si_signo, si_errno, si_code are its first three ints.
    let (data, code) = unsafe { (*info.cast::<c_int>().add(1), *info.cast::<c_int>().add(2)) };
    if code != SYS_SECCOMP {
        // Sent (kill, raise): the program's, as if the shim were not there.
        // SAFETY: the kernel's arguments of this signal.
        unsafe { crate::handlers::forward_sent(handlers::SIGSYS, info, context) };
        return;
    }
    if data != SHIM_TRAP {
        // A trap of the program's own filter (its data in si_errno): its handler's, or the
        // end the kernel forces. (Run here, the call would go to the kernel from the shim's
        // page, which the program's filter traps too: the handler recursed until the stack
        // overflowed.)
        // SAFETY: the kernel's arguments of this signal.
        unsafe { crate::handlers::forward_forced(handlers::SIGSYS, info, context) };
        return;
    }
    let saved_errno = sys::errno();
    // SAFETY: the kernel's ucontext for this signal, x86_64 layout.
    let gregs = unsafe { context.cast::<u8>().add(context::GREGS).cast::<i64>() };
    // SAFETY: as above.
    let sigmask = unsafe { &mut *context.cast::<u8>().add(context::SIGMASK).cast::<u64>() };
    // SAFETY: reading saved registers within the ucontext.
    let reg = |index: usize| unsafe { *gregs.add(index) };
    let number = reg(context::RAX);
    let args = [reg(context::RDI), reg(context::RSI), reg(context::RDX), reg(context::R10), reg(context::R8), reg(context::R9)];
    if number == nr::CLONE {
        // SAFETY: the kernel's ucontext and siginfo for this signal.
        unsafe { clone_thread(gregs, info, args) };
        sys::set_errno(saved_errno);
        return;
    }
    // A thread a trapped clone created claims its slot at its first trapped call.
    if crate::schedule::block::shared().is_some_and(|s| s.header.raw_clones.load(Ordering::Acquire) > 0) {
        match crate::schedule::slot::claimed_slot() {
            None if !crate::sys::in_shim() => {
                crate::schedule::slot::my_slot();
            }
            Some(slot) if crate::schedule::slot::shares_thread_locals(slot) => {
                // Made by a clone without a thread pointer of its own (no CLONE_SETTLS, and none
                // set since): the shim's thread-locals, where it keeps which slot is whose, are
                // its creator's. Its calls cannot be told from its creator's: the run fails
                // saying so, and this one goes to the kernel as it is.
                crate::schedule::slot::refuse_shared_thread_locals();
                // SAFETY: the return value goes where the caller's `syscall` leaves it.
                unsafe { *gregs.add(context::RAX) = native_call(number, args) };
                sys::set_errno(saved_errno);
                return;
            }
            _ => {}
        }
    }
    let outer = crate::handlers::entered_trap(*sigmask);
    let result = dispatch(number, args, sigmask);
    crate::handlers::left_trap(outer);
    if result == sys::RESTART_CALL {
        // Back onto the `syscall` instruction (two bytes), its number in place again: the
        // interrupting signal's handler runs as this one returns, and then the call is made
        // again, as the kernel restarts it (its arguments are still in their registers).
        // SAFETY: the saved registers within the ucontext.
        unsafe {
            *gregs.add(context::RIP) -= 2;
            *gregs.add(context::RAX) = number;
        }
    } else {
        // SAFETY: the return value goes where the caller's `syscall` leaves it.
        unsafe { *gregs.add(context::RAX) = result };
    }
    sys::set_errno(saved_errno);
}

/// A clone that creates a thread: the handler cannot make it (the new thread, on its own
/// stack, could not return through this handler's frame), so it reserves the thread's slot and
/// has the call made again, from the shim's page, once the handler has returned (see
/// `native::CLONE_OFFSET`). The new thread goes back to the program with a `ret` from its new
/// stack; the parent from the words put where this signal's siginfo lies, which the kernel's
/// sigreturn does not read (unlike the rest of the frame, and unlike the red zone above it).
#[cfg(target_arch = "x86_64")]
unsafe fn clone_thread(gregs: *mut i64, info: *mut c_void, a: [i64; 6]) {
    let (flags, stack, tls) = (a[0], a[1], a[4]);
    // SAFETY: reading and writing saved registers within the ucontext.
    let (rip, rsp) = unsafe { (*gregs.add(context::RIP), *gregs.add(context::RSP)) };
    if stack == 0 {
        // No stack of its own (never so from libc or a runtime): made here, where the new
        // thread shares this frame, as the kernel would have it.
        let rc = native_call(nr::CLONE, a);
        // A raw fork's child is a process of its own: it notes its id before it runs on (libc's
        // fork does again, in its handler).
        if rc == 0 && flags & CLONE_VM == 0 {
            crate::schedule::block::note_pid();
        }
        // SAFETY: the return value goes where the caller's `syscall` leaves it.
        unsafe { *gregs.add(context::RAX) = rc };
        return;
    }
    let clear_tid = if flags & CLONE_CHILD_CLEARTID != 0 { a[3] as usize } else { 0 };
    if crate::schedule::slot::creating_a_thread() {
        // The shim's pthread_create reserved the thread's slot: `clear_tid`, the word the
        // thread's end clears, is noted for its joins (see `sync::learn_clear_tid`).
        crate::sync::note_clone_clear_tid(clear_tid);
    } else {
        crate::schedule::slot::reserve_raw_clone(if flags & CLONE_SETTLS != 0 { tls as u64 } else { 0 });
    }
    let child_stack = (stack - 8) as *mut i64;
    let parent_words = info.cast::<i64>();
    // SAFETY: the caller's new stack (the word below its top is free: the stack grows down) and
    // this signal's siginfo (128 bytes, ours to use).
    unsafe {
        *child_stack = rip;
        *parent_words = rip;
        *parent_words.add(1) = rsp;
        *gregs.add(context::RSI) = child_stack as i64;
        *gregs.add(context::RSP) = parent_words as i64;
        *gregs.add(context::RAX) = nr::CLONE;
        *gregs.add(context::RIP) = (native::PAGE_ADDRESS + native::CLONE_OFFSET) as i64;
    }
}

#[cfg(not(target_arch = "x86_64"))]
unsafe extern "C" fn on_sigsys(_signal: c_int, _info: *mut c_void, _context: *mut c_void) {}

fn native_call(number: i64, a: [i64; 6]) -> c_long {
    native::call6(number, a[0], a[1], a[2], a[3], a[4], a[5])
}

#[cfg(target_arch = "x86_64")]
fn dispatch(number: i64, a: [i64; 6], sigmask: &mut u64) -> c_long {
    match number {
        // Never under the shim's own-calls mark: in a vfork child an exec that succeeds never
        // comes back to clear it, and the mark is the parent's thread-local.
        nr::EXECVE | nr::EXECVEAT => {
            // The new program inherits the signal mask in force at the exec: the program's own,
            // not the handler's (which blocks everything).
            use_program_mask(sigmask);
            return match number {
                nr::EXECVE => crate::spawn::exec_trapped(a[0] as usize, a[1] as usize, a[2] as usize, None),
                _ => crate::spawn::exec_trapped(a[1] as usize, a[2] as usize, a[3] as usize, Some((a[0], a[4]))),
            };
        }
        // (The filter answers it itself; a trap of it would come from a shim of another
        // build, whose traps carry other data and are not taken here.)
        nr::CLONE3 => return -ENOSYS,
        nr::RT_SIGPROCMASK => {
            let result = handlers::sigprocmask(a, sigmask);
            crate::signals::mask_changed(*sigmask);
            return result;
        }
        nr::RT_SIGACTION => return handlers::sigaction_call(a),
        // A wait for a child made inside libc (`system`, `posix_spawn`'s callers) or raw: the
        // parent counts as blocked while the kernel waits, as through the symbols. The shim's
        // own symbols make theirs as the shim's calls, with the program's mask.
        nr::WAIT4 | nr::WAITID if !crate::sys::in_shim() => return crate::children::trapped_wait(number, a, || native_as_program_for_now(number, a, sigmask)),
        nr::WAIT4 | nr::WAITID => return native_as_program(number, a, sigmask),
        // The program's own reads, writes and waits (only those trap: see OWN_CALLS).
        // Its other signals wait meanwhile, as in a trapped futex wait.
        _ if OWN_CALLS.contains(&number) && !crate::sys::in_shim() => return own_io_call(number, a),
        // Not under the own-calls mark either: a handler that sigsuspend runs is the program's.
        nr::ALARM
        | nr::SETITIMER
        | nr::GETITIMER
        | nr::TIMER_CREATE
        | nr::TIMER_SETTIME
        | nr::TIMER_GETTIME
        | nr::TIMER_GETOVERRUN
        | nr::TIMER_DELETE
        | nr::PAUSE
        | nr::RT_SIGSUSPEND
        | nr::RT_SIGTIMEDWAIT
        | nr::KILL
        | nr::TGKILL
        | nr::TKILL
            if !crate::sys::in_shim() =>
        {
            return crate::signals::trapped(number, a, *sigmask).unwrap_or_else(|| match number {
                nr::PAUSE => pause_as_program(sigmask),
                _ => native_as_program(number, a, sigmask),
            });
        }
        _ => {}
    }
    if crate::sys::in_shim() {
        return native_call(number, a);
    }
    let _own = crate::sys::OwnCalls::enter();
    let handled = match number {
        nr::FUTEX => crate::futex::emulate(&crate::futex::Args { uaddr: a[0] as usize, op: a[1] as i32, val: a[2] as u32, timeout_or_val2: a[3] as usize, uaddr2: a[4] as usize, val3: a[5] as u32 }),
        nr::SEMOP => crate::ipc::semtimedop(a[0], a[1] as usize, a[2], 0),
        nr::SEMTIMEDOP => crate::ipc::semtimedop(a[0], a[1] as usize, a[2], a[3] as usize),
        nr::MQ_TIMEDSEND | nr::MQ_TIMEDRECEIVE => crate::ipc::mq_timed(number, a),
        nr::FUTEX_WAITV => crate::ipc::futex_waitv(),
        nr::CLOCK_GETTIME => crate::time::answer_clock_gettime(a[0] as c_int, a[1] as *mut sys::timespec).map(c_long::from),
        nr::GETTIMEOFDAY => crate::time::answer_gettimeofday(a[0] as *mut sys::timeval, a[1] as *mut c_void).map(c_long::from),
        nr::TIME => crate::time::answer_time(a[0] as *mut sys::time_t),
        nr::TIMES => crate::time::answer_times(a[0] as *mut c_void),
        nr::NANOSLEEP => crate::time::clock_nanosleep_virtual(sys::CLOCK_MONOTONIC, 0, a[0] as *const sys::timespec, a[1] as *mut sys::timespec).map(|e| -c_long::from(e)),
        nr::CLOCK_NANOSLEEP => crate::time::clock_nanosleep_virtual(a[0] as c_int, a[1] as c_int, a[2] as *const sys::timespec, a[3] as *mut sys::timespec).map(|e| -c_long::from(e)),
        nr::SCHED_YIELD => crate::schedule::block::active().map(|shared| {
            crate::schedule::park::yield_turn(shared);
            0
        }),
        // Its rings are shared memory that the kernel reads and writes with no system call to
        // follow: refused (the run fails saying so) before any I/O goes through it.
        nr::IO_URING_SETUP => crate::schedule::block::active().map(|_| {
            crate::schedule::block::refuse(crate::abi::refused::IO_URING);
            -ENOSYS
        }),
        _ => None,
    };
    handled.unwrap_or_else(|| native_as_program(number, a, sigmask))
}

/// A call the program made itself (Go, `rustix`): what its libc symbol does in the shim, as if
/// the program had called libc, and the result in the kernel's convention (a negative errno).
#[cfg(target_arch = "x86_64")]
fn own_io_call(number: i64, a: [i64; 6]) -> c_long {
    let fd = a[0] as c_int;
    // SAFETY: each the shim's own libc-compatible symbol, with the caller's arguments.
    let result = unsafe {
        match number {
            nr::READ => crate::io::read(fd, a[1] as *mut c_void, a[2] as usize) as c_long,
            nr::WRITE => crate::io::write(fd, a[1] as *const u8, a[2] as usize) as c_long,
            nr::WRITEV => crate::io::writev(fd, a[1] as *const sys::iovec, a[2] as c_int) as c_long,
            nr::RECVFROM => crate::io::recvfrom(fd, a[1] as *mut c_void, a[2] as usize, a[3] as c_int, a[4] as *mut c_void, a[5] as *mut u32) as c_long,
            nr::SENDTO => crate::room::sendto(fd, a[1] as *const c_void, a[2] as usize, a[3] as c_int, a[4] as *const c_void, a[5] as u32) as c_long,
            nr::CLOSE => c_long::from(crate::io::close(fd)),
            nr::IOCTL => c_long::from(crate::io::ioctl(fd, a[1] as u64, a[2] as *mut c_void)),
            nr::POLL => c_long::from(crate::wait::poll(a[0] as *mut sys::pollfd, a[1] as sys::nfds_t, a[2] as c_int)),
            // The kernel's sigset size (the fifth argument) is what libc passes for itself.
            nr::PPOLL => c_long::from(crate::wait::ppoll(a[0] as *mut sys::pollfd, a[1] as sys::nfds_t, a[2] as *const sys::timespec, a[3] as *const sys::fd_set)),
            nr::SELECT => c_long::from(crate::wait::select(fd, a[1] as *mut sys::fd_set, a[2] as *mut sys::fd_set, a[3] as *mut sys::fd_set, a[4] as *mut sys::timeval)),
            nr::EPOLL_WAIT => c_long::from(crate::epoll::epoll_wait(fd, a[1] as *mut c_void, a[2] as c_int, a[3] as c_int)),
            nr::EPOLL_CTL => c_long::from(crate::epoll::epoll_ctl(fd, a[1] as c_int, a[2] as c_int, a[3] as *mut c_void)),
            // The kernel's sigset size (the sixth argument) is what libc passes for itself.
            nr::EPOLL_PWAIT => c_long::from(crate::epoll::epoll_pwait(fd, a[1] as *mut c_void, a[2] as c_int, a[3] as c_int, a[4] as *const c_void)),
            nr::EPOLL_PWAIT2 => c_long::from(crate::epoll::epoll_pwait2(fd, a[1] as *mut c_void, a[2] as c_int, a[3] as *const sys::timespec, a[4] as *const c_void)),
            _ => return native_call(number, a),
        }
    };
    if result == -1 { -c_long::from(sys::errno()) } else { result }
}

/// A trapped call that goes to the kernel as it is (a clock climbsim does not answer, after the
/// run's end, a dormant shim's): made with the program's own signal mask, not the handler's, so
/// that a signal interrupts it (EINTR) and its handler runs as it would have without the shim.
fn native_as_program(number: i64, a: [i64; 6], sigmask: &u64) -> c_long {
    use_program_mask(sigmask);
    native_call(number, a)
}

/// The kernel's `pause` (after the run, or for a thread without a slot), made as `sigsuspend`
/// with the program's mask: the mask and the wait change at once, so that a signal already
/// pending (the run's SIGTERM, sent while the thread was in the trap) ends the wait. Made as
/// `pause` after putting the program's mask back, the signal was taken as the mask changed and
/// the pause then waited for ever (a controller ending on SIGTERM in `pause()` was killed).
fn pause_as_program(sigmask: &u64) -> c_long {
    let mask = *sigmask as c_long;
    native::call2(nr::RT_SIGSUSPEND, &mask as *const c_long as c_long, 8)
}

/// [`native_as_program`] for the call only: the handler's own mask again afterwards, for the
/// shim goes on after it (a thread woken from a wait for its child waits for its turn, where no
/// handler of the program may run).
fn native_as_program_for_now(number: i64, a: [i64; 6], sigmask: &u64) -> c_long {
    let mut handler_mask = 0u64;
    native::call4(nr::RT_SIGPROCMASK, SIG_SETMASK, sigmask as *const u64 as c_long, &mut handler_mask as *mut u64 as c_long, 8);
    let result = native_call(number, a);
    native::call4(nr::RT_SIGPROCMASK, SIG_SETMASK, &handler_mask as *const u64 as c_long, 0, 8);
    result
}

/// From here on, inside the handler, the program's own signal mask (the one the kernel saved).
fn use_program_mask(sigmask: &u64) {
    native::call4(nr::RT_SIGPROCMASK, SIG_SETMASK, sigmask as *const u64 as c_long, 0, 8);
}

#[cfg(not(target_arch = "x86_64"))]
fn dispatch(number: i64, a: [i64; 6], _sigmask: &mut u64) -> c_long {
    native_call(number, a)
}
