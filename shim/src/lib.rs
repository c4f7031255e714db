//! climbsim's preload for `--clock virtual`: it puts an unchanged controller process (every
//! thread, every child that keeps `LD_PRELOAD`) on the simulation's clock.
//!
//! - Clock reads answer from the shared block (`abi/`), no system call.
//! - Sleeps and waits publish "blocked until T, waiting on the port / a sensor connection" and
//!   sleep on a futex until climbsim releases them: at T, or when their data is there.
//! - Every other intercepted call costs a small charge of simulated time, so that a loop that
//!   only spins still moves time (Shadow's `model_unblocked_syscall_latency`); a zero-timeout
//!   poll of an empty port jumps to the next reply byte due.
//!
//! Dormant (every call goes straight to libc) unless `CLIMBSIM_VT` names a block. The model and
//! what is intercepted: docs/virtual-time.md.
//!
//! Rules for this code: never call anything that is itself intercepted (std's time, sleep, I/O)
//! except through `real!`; no allocation; thread-locals are `const`-initialised plain cells.

#![allow(clippy::missing_safety_doc)]

pub mod abi;
mod children;
mod epoll;
mod futex;
mod handlers;
mod held;
mod io;
mod maps;
mod native;
mod net;
mod now;
mod park;
mod port_ring;
mod program;
mod seccomp;
#[cfg(target_arch = "x86_64")]
mod signals;
/// Signals are followed with the system calls, on x86_64 only.
#[cfg(not(target_arch = "x86_64"))]
mod signals {
    pub(crate) fn take_due(_: &crate::abi::Slot) -> bool {
        false
    }
    pub(crate) fn slot_claimed(_: &crate::abi::Slot) {}
    pub(crate) fn delete_posix_timers_of(_: i32) {}
}
mod spawn;
mod sync;
mod sys;
mod time;
mod timerfd;
#[cfg(target_arch = "x86_64")]
mod tsc;
/// rdtsc is answered on x86_64 only.
#[cfg(not(target_arch = "x86_64"))]
mod tsc {
    pub(crate) fn around_exec(_: bool) {}
}
mod wait;

use core::cell::Cell;
use core::ffi::{c_char, c_int, c_void};
use core::sync::atomic::{AtomicPtr, AtomicU32, Ordering};

use abi::{Shared, Slot, mode, state};
use park::{
    Look, Looked, advance_within_horizon, await_release, await_turn, charge, look_at_kernel, note_call, notify_scheduler, park, publish_parked, publish_waiting_on_kernel, reset_computation,
    resume_after_kernel_wake, took_turn, wait_looking, yield_turn,
};
use sys::real;

/// The block, once mapped.
static SHARED: AtomicPtr<Shared> = AtomicPtr::new(core::ptr::null_mut());
/// This process's id (kept up to date across fork), to find its descriptors' entries.
static PID: core::sync::atomic::AtomicI32 = core::sync::atomic::AtomicI32::new(0);
/// The pthread key whose destructor marks a thread's slot exited.
static EXIT_KEY: AtomicU32 = AtomicU32::new(u32::MAX);

const NO_SLOT: u32 = u32::MAX;

thread_local! {
    /// This thread's slot in the block (NO_SLOT until its first intercepted call).
    static SLOT: Cell<u32> = const { Cell::new(NO_SLOT) };
    /// Non-zero while the shim itself is at work in this thread (in the trap handler, or
    /// calling libc for a thread): its system calls go to the kernel as they are.
    static OWN_CALLS: Cell<u32> = const { Cell::new(0) };
    /// Set while the shim's pthread_create creates a thread (it reserved its slot already).
    static CREATING_THREAD: Cell<bool> = const { Cell::new(false) };
}

/// Whether the shim is at work in this thread (see `OWN_CALLS`).
fn in_shim() -> bool {
    OWN_CALLS.with(Cell::get) != 0
}

/// Marks the shim at work in this thread while it lives.
struct OwnCalls;

impl OwnCalls {
    fn enter() -> Self {
        OWN_CALLS.with(|c| c.set(c.get() + 1));
        OwnCalls
    }
}

impl Drop for OwnCalls {
    fn drop(&mut self) {
        OWN_CALLS.with(|c| c.set(c.get().saturating_sub(1)));
    }
}

/// Set once climbsim is found gone: the process goes on as after the run's end.
static ORPHANED: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

/// The block if virtual time is on (the run has not ended, climbsim is there).
fn active() -> Option<&'static Shared> {
    let shared = shared()?;
    (shared.header.mode.load(Ordering::Acquire) == mode::VIRTUAL && !ORPHANED.load(Ordering::Relaxed)).then_some(shared)
}

/// climbsim's process has gone without ending the run (killed): nobody will let parked
/// threads go, so they stop waiting for it.
fn climbsim_gone(shared: &Shared) -> bool {
    let pid = shared.header.climbsim_pid.load(Ordering::Relaxed);
    let gone = pid > 0 && !sys::process_lives(pid);
    if gone && !ORPHANED.swap(true, Ordering::AcqRel) {
        // Clocks go on from here at the wall clock's rate, as after a run's end.
        ORPHANED_AT.store(time::real_monotonic_ns(), Ordering::Relaxed);
    }
    gone
}

/// The wall clock (CLOCK_MONOTONIC) when climbsim was found gone.
static ORPHANED_AT: core::sync::atomic::AtomicU64 = core::sync::atomic::AtomicU64::new(0);

/// Whether climbsim was found gone, and when (wall clock).
fn orphaned_at() -> Option<u64> {
    ORPHANED.load(Ordering::Relaxed).then(|| ORPHANED_AT.load(Ordering::Relaxed))
}

/// The block, whatever its mode.
fn shared() -> Option<&'static Shared> {
    let pointer = SHARED.load(Ordering::Acquire);
    // SAFETY: set once to a mapping of the whole block that is never unmapped.
    (!pointer.is_null()).then(|| unsafe { &*pointer })
}

/// Map the block named by `CLIMBSIM_VT`. Runs before `main` in every process that preloads the
/// shim, with the arguments glibc's loader gives every `.init_array` entry.
extern "C" fn init(_argc: c_int, _argv: *const *const c_char, envp: *const *const c_char) {
    // SAFETY: getenv with a NUL-terminated name; the result is a C string or null.
    let path = unsafe { sys::getenv(c"CLIMBSIM_VT".as_ptr()) };
    if path.is_null() {
        // Dormant; but a program exec'd by a followed one that dropped CLIMBSIM_VT (to run on
        // the wall clock) inherits the seccomp filter, and its trapped calls need the handler.
        if seccomp::inherited() {
            // First: climbsim holds time until the exec that started this program is over.
            spawn::close_inherited_exec_marker();
            program::inspect(envp, false);
            spawn::remember_shim_environment();
            if let Err(why) = seccomp::install_passthrough() {
                say_failure(why, b"");
            }
        }
        return;
    }
    PID.store(sys::getpid(), Ordering::Relaxed);
    if let Err(why) = map(path) {
        say_failure(why, b"; the controller runs on the wall clock, which climbsim will report");
        return;
    }
    // SAFETY: registering plain C callbacks.
    unsafe {
        let mut key = 0u32;
        if sys::pthread_key_create(&mut key, Some(thread_exited)) == 0 {
            EXIT_KEY.store(key, Ordering::Relaxed);
        }
        sys::__register_atfork(None, None, Some(forked_child), core::ptr::null_mut());
        sys::__cxa_atexit(process_exiting, core::ptr::null_mut(), core::ptr::null_mut());
    }
    // A new program (after an exec) has no POSIX timers: those its earlier image made go.
    signals::delete_posix_timers_of(sys::getpid());
    spawn::resolve_exec_functions();
    spawn::remember_shim_environment();
    program::inspect(envp, true);
    if let Err(why) = seccomp::install() {
        say_failure(why, b"; only calls through libc's symbols are followed");
    }
    #[cfg(target_arch = "x86_64")]
    if let Err(why) = tsc::install() {
        say_failure(why, b"; the time-stamp counter is the host's");
    }
    // The main thread is followed from the start: before its first call it is already running.
    my_slot();
}

/// A line on stderr: what the shim could not do at start (`why`), and what follows from it.
fn say_failure(why: &[u8], so: &[u8]) {
    sys::say(b"climbsim shim: ");
    sys::say(why);
    sys::say(so);
    sys::say(b"\n");
}

#[used]
#[unsafe(link_section = ".init_array")]
static INIT: extern "C" fn(c_int, *const *const c_char, *const *const c_char) = init;

fn map(path: *const c_char) -> Result<(), &'static [u8]> {
    const O_RDWR: c_int = 2;
    const O_CLOEXEC: c_int = 0o2000000;
    const PROT_READ_WRITE: c_int = 3;
    const MAP_SHARED: c_int = 1;
    // SAFETY: a NUL-terminated path from the environment.
    let fd = unsafe { sys::open(path, O_RDWR | O_CLOEXEC) };
    if fd < 0 {
        return Err(b"cannot open the block CLIMBSIM_VT names");
    }
    // SAFETY: mapping the file's first SHARED_BYTES, which climbsim sized so.
    let mapped = unsafe { sys::mmap(core::ptr::null_mut(), abi::SHARED_BYTES, PROT_READ_WRITE, MAP_SHARED, fd, 0) };
    let close = real!(close: fn(c_int) -> c_int);
    // SAFETY: closing our own descriptor; the mapping stays.
    unsafe { close(fd) };
    if mapped as isize == -1 {
        return Err(b"cannot map the block CLIMBSIM_VT names");
    }
    let block = mapped.cast::<Shared>();
    // SAFETY: the mapping holds a whole block.
    let header = unsafe { &(*block).header };
    if header.magic.load(Ordering::Acquire) != abi::MAGIC || header.abi.load(Ordering::Acquire) != abi::ABI {
        return Err(b"CLIMBSIM_VT names a block of another climbsim version");
    }
    SHARED.store(block, Ordering::Release);
    Ok(())
}

/// This thread's slot if it has claimed one (never claims).
fn claimed_slot() -> Option<&'static Slot> {
    let index = SLOT.with(Cell::get);
    if index == NO_SLOT {
        return None;
    }
    shared()?.slots.get(index as usize)
}

/// This thread's slot, claimed at its first intercepted call: the slot of a program this
/// thread was before an exec, the one climbsim reserved for the process it starts, or a free
/// one. None if all are taken (the thread then runs unfollowed).
fn my_slot() -> Option<&'static Slot> {
    let shared = shared()?;
    let index = SLOT.with(Cell::get);
    if index != NO_SLOT {
        return shared.slots.get(index as usize);
    }
    let (tid, pid) = (sys::gettid(), sys::getpid());
    let claim = |index: usize, slot: &'static Slot| {
        slot.futex_queued.store(0, Ordering::Release);
        slot.pid.store(pid, Ordering::Relaxed);
        slot.tid.store(tid, Ordering::Relaxed);
        slot.parent.store(sys::getppid(), Ordering::Relaxed);
        // SAFETY: pthread_self has no preconditions.
        slot.thread.store(unsafe { sys::pthread_self() } as u64, Ordering::Relaxed);
        signals::slot_claimed(slot);
        SLOT.with(|s| s.set(index as u32));
        took_turn(shared);
        if tid != pid {
            watch_thread_exit();
        }
        Some(slot)
    };
    // After an exec the thread is the same task: its old slot (or the one it reserved before
    // the exec) is still running. A child of posix_spawn finds the one its parent reserved.
    let parent = sys::getppid();
    for (index, slot) in shared.live_slots().iter().enumerate() {
        let held = slot.state();
        let slot_tid = slot.tid.load(Ordering::Relaxed);
        let mine = matches!(held, state::RUNNING | state::RESERVED) && slot_tid == tid;
        let spawned_for_me = held == state::RESERVED && slot_tid == 0 && slot.pid.load(Ordering::Relaxed) == parent;
        if (mine || spawned_for_me) && (held == state::RUNNING || slot.claim_reservation()) {
            let claimed = claim(index, slot);
            // A program a followed process started (posix_spawn, fork, a vfork child's exec)
            // starts in its turn, as a thread does (below).
            if held == state::RESERVED && followed(shared, parent) {
                start_in_turn(slot);
            }
            return claimed;
        }
    }
    if tid != pid
        && shared.header.raw_clones.load(Ordering::Acquire) > 0
        && let Some((index, slot)) = raw_clone_reservation(shared, pid)
    {
        shared.header.raw_clones.fetch_sub(1, Ordering::AcqRel);
        let claimed = claim(index, slot);
        // It starts in its turn, as a thread from the shim's pthread_create does.
        start_in_turn(slot);
        return claimed;
    }
    let first = &shared.slots[0];
    if tid == pid && first.claim_reservation() {
        return claim(0, first);
    }
    // A free slot, or one whose thread has ended (a shell's children come and go).
    let (index, slot) = take_free_slot(shared, Slot::claim_unused)?;
    let claimed = claim(index, slot);
    notify_scheduler(shared);
    // A thread whose creation the shim did not see (libc's own thread creation, such as the
    // thread glibc starts for a SIGEV_THREAD timer's callback; a runtime's raw clone), and a
    // process a followed one started (a forked child, a vfork child's exec), start in their
    // turn: their creator runs on until it parks. Otherwise the two ran at once: the callback's
    // instant, and the order of a parent's and a spawned child's lines, differed from run to
    // run.
    if tid != pid || followed(shared, parent) {
        start_in_turn(slot);
    }
    claimed
}

/// Whether process `pid` is followed (one of its threads has a slot).
fn followed(shared: &Shared, pid: i32) -> bool {
    shared.live_slots().iter().any(|s| s.pid.load(Ordering::Relaxed) == pid && !matches!(s.state(), state::FREE | state::EXITED))
}

/// A thread that has just claimed `slot` waits, ready, for its turn (without climbsim, or
/// after the run's end, it simply runs).
fn start_in_turn(slot: &Slot) {
    match active() {
        Some(shared) => {
            // Its creator has usually parked by now (in a join, say): the turn is then this
            // thread's at once, without climbsim.
            let hand = park::hand_on(shared, slot);
            if slot.start_in_turn() {
                hand.finish();
                await_turn(shared, slot);
            }
        }
        None => {
            // A reservation is this thread's (a claimed slot runs already).
            let _ = slot.claim_reservation();
        }
    }
}

/// A trapped clone is about to create a thread whose TLS pointer is `tls` (0: none given): a
/// slot is reserved for it, so that climbsim counts it as running, and decides nothing, until
/// the thread has claimed it (at its first followed call) and waits for its turn. Not for a
/// thread the shim's pthread_create creates, which reserved its own (`clear_tid`, the word the
/// thread's end clears, is noted for its joins then: see `sync::learn_clear_tid`).
pub(crate) fn reserve_raw_clone(tls: u64, clear_tid: usize) {
    if CREATING_THREAD.with(Cell::get) {
        sync::note_clone_clear_tid(clear_tid);
        return;
    }
    let Some(shared) = active() else { return };
    let Some((_, slot)) = take_free_slot(shared, Slot::reserve_unused) else { return };
    slot.pid.store(pid(), Ordering::Relaxed);
    slot.clone_tls.store(tls, Ordering::Relaxed);
    slot.tid.store(abi::RAW_CLONE_TID, Ordering::Release);
    shared.header.raw_clones.fetch_add(1, Ordering::AcqRel);
}

/// The slot a trapped clone reserved for this thread (found by its TLS pointer), taken.
fn raw_clone_reservation(shared: &Shared, pid: i32) -> Option<(usize, &Slot)> {
    const ARCH_GET_FS: i64 = 0x1003;
    let mut fs: u64 = 0;
    native::call2(sys::nr::ARCH_PRCTL, ARCH_GET_FS, &mut fs as *mut u64 as i64);
    let reserved = |slot: &Slot, key: u64| {
        slot.state() == state::RESERVED && slot.tid.load(Ordering::Acquire) == abi::RAW_CLONE_TID && slot.pid.load(Ordering::Relaxed) == pid && slot.clone_tls.load(Ordering::Relaxed) == key
    };
    for key in [fs, 0] {
        for (index, slot) in shared.live_slots().iter().enumerate() {
            if reserved(slot, key) && slot.claim_reservation() {
                return Some((index, slot));
            }
        }
    }
    None
}

/// While the shim's pthread_create creates a thread (see `reserve_raw_clone`).
pub(crate) fn creating_thread<T>(create: impl FnOnce() -> T) -> T {
    CREATING_THREAD.with(|c| c.set(true));
    let result = create();
    CREATING_THREAD.with(|c| c.set(false));
    result
}

/// Something the controller did cannot be followed (`abi::refused`: a table had no room, an
/// io_uring): the run fails naming it.
fn refuse(which: u32) {
    if let Some(shared) = shared() {
        shared.header.refused.fetch_or(which, Ordering::AcqRel);
        notify_scheduler(shared);
    }
}

/// A slot nobody uses (slot 0 is climbsim's to reserve), taken by `take` (`Slot::reserve_unused`
/// or `Slot::claim_unused`). None if every one is in use: the table is then marked full, which
/// fails the run naming it, rather than leave a thread unfollowed without a word.
fn take_free_slot(shared: &Shared, take: fn(&Slot) -> bool) -> Option<(usize, &Slot)> {
    for (index, slot) in shared.slots.iter().enumerate().skip(1) {
        if !matches!(slot.state(), state::FREE | state::EXITED) || !spawn::exec_over(slot) {
            continue;
        }
        // Scans stop at the high-water mark: it is raised before the slot is taken.
        shared.header.slots_high.fetch_max(index as u32 + 1, Ordering::AcqRel);
        if take(slot) {
            return Some((index, slot));
        }
    }
    refuse(abi::refused::SLOTS);
    None
}

unsafe extern "C" fn thread_exited(_: *mut c_void) {
    sync::thread_ending();
    if let Some(slot) = claimed_slot() {
        exit_slot(slot);
    }
}

/// Reserve a slot for a thread about to be created (the creator runs on meanwhile).
fn reserve_thread_slot() -> Option<usize> {
    let shared = shared()?;
    let (index, slot) = take_free_slot(shared, Slot::reserve_unused)?;
    slot.pid.store(pid(), Ordering::Relaxed);
    // Not 0, which marks a process's reservation (see `my_slot`).
    slot.tid.store(-1, Ordering::Relaxed);
    Some(index)
}

fn unreserve_slot(index: usize) {
    if let Some(shared) = shared()
        && let Some(slot) = shared.slots.get(index)
        && slot.unreserve()
    {
        // A thread that parked meanwhile left the decision to this one (see `park::HandOn`).
        notify_scheduler(shared);
    }
}

/// A new thread's first act: the slot its creator reserved is its own.
fn claim_reserved(index: usize) {
    let Some(slot) = shared().and_then(|s| s.slots.get(index)) else { return };
    // A thread that made a followed call before its start routine (glibc's "stopped start",
    // for explicit scheduling attributes, waits on a lock first) claimed a slot of its own
    // then: that one goes, or it would count as running for ever.
    let before = SLOT.with(Cell::get);
    if before != NO_SLOT
        && before as usize != index
        && let Some(old) = shared().and_then(|s| s.slots.get(before as usize))
    {
        old.futex_queued.store(0, Ordering::Release);
        old.exit();
    }
    slot.futex_queued.store(0, Ordering::Release);
    let tid = sys::gettid();
    slot.pid.store(pid(), Ordering::Relaxed);
    slot.tid.store(tid, Ordering::Relaxed);
    slot.parent.store(sys::getppid(), Ordering::Relaxed);
    // SAFETY: pthread_self has no preconditions.
    slot.thread.store(unsafe { sys::pthread_self() } as u64, Ordering::Relaxed);
    signals::slot_claimed(slot);
    SLOT.with(|s| s.set(index as u32));
    park::forget_charges();
    watch_thread_exit();
    // It starts in its turn: its creator runs on until it parks.
    start_in_turn(slot);
}

/// This thread's end runs `thread_exited` (the exit key's destructor runs only for a thread
/// that set a value for it).
fn watch_thread_exit() {
    let key = EXIT_KEY.load(Ordering::Relaxed);
    if key != u32::MAX {
        // SAFETY: a key from pthread_key_create; the value only has to be non-null.
        unsafe { sys::pthread_setspecific(key, core::ptr::dangling::<c_void>()) };
    }
}

/// The process is ending (exit or return from main): every thread of it stops with it.
unsafe extern "C" fn process_exiting(_: *mut c_void) {
    let Some(shared) = shared() else { return };
    let pid = sys::getpid();
    children::wake_waiting_parent(shared, pid, sys::getppid());
    // This thread's own slot last: until then it runs, so climbsim decides nothing on a
    // process half marked (it would move time to the deadline of a thread not yet marked).
    let own = my_slot();
    for slot in shared.live_slots() {
        if slot.pid.load(Ordering::Relaxed) == pid && slot.state() != state::FREE && !own.is_some_and(|own| core::ptr::eq(own, slot)) {
            exit_slot(slot);
        }
    }
    if let Some(own) = own {
        exit_slot(own);
    }
}

/// `_exit` (and C's `_Exit`): the process ends without its atexit handlers, so it says first
/// that its threads are gone. Otherwise climbsim finds out only from `/proc` (every 50 ms), and
/// each such child cost its parent's waitpid that much wall time.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn _exit(status: c_int) -> ! {
    leaving_without_atexit();
    let next = real!(_exit: fn(c_int) -> !);
    // SAFETY: libc's _exit with the caller's status.
    unsafe { next(status) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn _Exit(status: c_int) -> ! {
    leaving_without_atexit();
    let next = real!(_Exit: fn(c_int) -> !);
    // SAFETY: libc's _Exit with the caller's status.
    unsafe { next(status) }
}

fn leaving_without_atexit() {
    // A vfork child shares its parent's memory (this thread's slot is its parent's): its
    // parent goes on as the kernel resumes it; the child says it goes in a slot of its own.
    if pid() == sys::getpid() {
        // SAFETY: the same callback atexit would have run.
        unsafe { process_exiting(core::ptr::null_mut()) };
    } else {
        spawn::vfork_child_exits();
    }
}

fn exit_slot(slot: &Slot) {
    let Some(shared) = shared() else {
        slot.exit();
        return;
    };
    let hand = park::hand_on(shared, slot);
    slot.exited_ns.store(now::sim_now(shared), Ordering::Relaxed);
    slot.exit();
    hand.finish();
}

/// A forked child is a new process: its threads claim slots of their own. It starts in its
/// turn, as a new thread does: its parent runs on until it parks, so that what the two do
/// (print to one log, say) does not interleave as the host scheduled them.
unsafe extern "C" fn forked_child() {
    PID.store(sys::getpid(), Ordering::Relaxed);
    SLOT.with(|s| s.set(NO_SLOT));
    park::forget_charges();
    // Its slot, claimed now, waits for its turn there.
    my_slot();
}

fn pid() -> i32 {
    PID.load(Ordering::Relaxed)
}
