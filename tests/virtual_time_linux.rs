//! Linux's answers on `--clock virtual`: a call the shim follows answers a wrong argument as the
//! kernel does (EBADF, EFAULT, EINVAL, EOPNOTSUPP) and at once, and the corner cases of the
//! timers and signals it follows behave as Linux's. One C program asks each in turn; its lines
//! were read natively on Linux 6.18 with glibc 2.36 (2026-12-07) (`cc tests/vt/linux_answers.c && ./a.out`)
//! and must read the same on virtual time, in every run.

mod support;

use std::path::PathBuf;

use support::vt::{compiled_c, log_repeated_in};

/// `tests/vt/NAME.c` compiled and run twice as a controller that ends by itself, in a world
/// `duration_s` long, with identical outputs: its scratch folder (runs `a` and `b`) and its log.
fn c_program_repeated(scratch: &str, name: &str, duration_s: f64) -> (PathBuf, String) {
    let dir = support::scratch_dir(scratch);
    let program = compiled_c(&dir, name);
    let log = log_repeated_in(&dir, name, duration_s, &[program.to_str().expect("utf-8 path")]);
    (dir, log)
}

/// What `tests/vt/linux_answers.c` prints natively.
const LINUX_SAYS: &str = "\
read of a pipe's write end: -1 EBADF at once
raw read of a pipe's write end: -1 EBADF at once
write to a pipe's read end: -1 EBADF at once
read of a closed descriptor: -1 EBADF at once
poll(NULL, 1, 0): -1 EFAULT at once
poll(16, 1, 10): -1 EFAULT at once
ppoll(NULL, 1, 0): -1 EFAULT at once
poll of an array past its mapping's end: -1 EFAULT at once
poll of the same array inside it: 0 at once
select of an unmapped set: -1 EFAULT at once
poll(NULL, 0, 10): 0 after a while
poll of 2^30 descriptors: -1 EINVAL at once
select(-1): -1 EINVAL at once
select with tv_usec -1: -1 EINVAL at once
nanosleep of 1e9 ns: -1 EINVAL at once
nanosleep of -1 s: -1 EINVAL at once
nanosleep(NULL): -1 EFAULT at once
epoll_pwait2 with an unmapped timeout: -1 EFAULT at once
epoll_pwait2 with a timeout of 1e9 ns: -1 EINVAL at once
clock_nanosleep(CLOCK_MONOTONIC_RAW, 10 ms): -1 EOPNOTSUPP at once
clock_nanosleep(CLOCK_MONOTONIC_COARSE, 10 ms): -1 EOPNOTSUPP at once
clock_nanosleep(CLOCK_REALTIME_COARSE, 10 ms): -1 EOPNOTSUPP at once
clock_nanosleep(CLOCK_THREAD_CPUTIME_ID, 10 ms): -1 EINVAL at once
clock_nanosleep(clock 99, 10 ms): -1 EINVAL at once
clock_nanosleep(CLOCK_BOOTTIME, 10 ms): 0 after a while
clock_nanosleep(CLOCK_MONOTONIC, 1e9 ns): -1 EINVAL at once
clock_gettime(clock 99): -1 EINVAL at once
clock_getres(clock 99): -1 EINVAL at once
setitimer with a zero value and a 10 ms interval: 0 alarms in 50 ms; getitimer says value 0.000000 interval 0.000000
setitimer with tv_usec 1e6: -1 EINVAL at once
setitimer(99): -1 EINVAL at once
raise(SIGSYS): the handler ran 1 time(s)
kill(self, SIGSYS): the handler ran 2 time(s)
";

/// What `tests/vt/vdso_clocks.c` prints natively.
const LINUX_CLOCKS_SAY: &str = "\
timespec_get: 1.50 s after the start
ftime: 1.50 s after the start
times: 1.50 s after the start
times with a buffer: answered
the vDSO's clock_gettime: 1.50 s after the start
its monotonic clock against libc's: 0.00 s apart
the vDSO's gettimeofday: 1.50 s after the start, time zone filled: yes
the vDSO's time: the same second as clock_gettime
the vDSO's thread CPU clock: 0, read
the vDSO's clock -1: -22
";

#[test]
fn wrong_arguments_and_timer_corners_get_linuxs_answers_at_once() {
    let (_, log) = c_program_repeated("vt-linux-answers", "linux_answers", 2.0);
    // Line by line, so that a failure names the call.
    for (virtual_line, linux_line) in log.lines().zip(LINUX_SAYS.lines()) {
        assert_eq!(virtual_line, linux_line, "on virtual time (left) against Linux (right); the whole log:\n{log}");
    }
    assert_eq!(log.lines().count(), LINUX_SAYS.lines().count(), "the program stopped early; its log:\n{log}");
}

/// Clock reads around libc's `clock_gettime` (glibc's own through the vDSO, the vDSO called
/// directly as a runtime that finds it itself does, `times`) read simulated time, as the
/// kernel's clock natively: each read the host's clock before, a silent wrong answer.
#[test]
fn clock_reads_through_the_vdso_and_times_tell_simulated_time() {
    let (_, log) = c_program_repeated("vt-vdso-clocks", "vdso_clocks", 3.0);
    assert_eq!(log, LINUX_CLOCKS_SAY, "on virtual time (left) against Linux (right)");
}

/// System calls made with the program's own `syscall` instruction (Rust's rustix, Go) are
/// followed as libc's are: the raw read of a pipe a forked child writes waits for the child on
/// simulated time (it kept the turn, and the run failed after 2 s "blocked in system call 0"),
/// and raw timeouts are simulated time.
#[test]
fn raw_system_calls_from_the_programs_own_code_are_followed() {
    let (_, log) = c_program_repeated("vt-raw-calls", "raw_calls", 2.0);
    assert_eq!(
        log,
        "raw read of a pipe the child writes at 100 ms: 1 after 100.000 ms\n\
         raw poll(NULL, 0, 50): 0 after 50.000 ms\n\
         raw ppoll(NULL, 0, 20 ms): 0 after 20.000 ms\n\
         raw epoll_wait of an empty pipe, 30 ms: 0 after 30.000 ms\n\
         raw read of a pipe's write end: -EBADF after 0.000 ms\n\
         raw write to the pipe: 1 after 0.000 ms\n\
         raw read of it: 1 after 0.000 ms\n"
    );
}

/// A process that ends through a raw `exit_group` (Go's way, or a fatal signal) while another
/// of its threads sleeps ends at its instant: not when that sleep would have ended, which lay
/// past the scenario's end and made the run last to it.
#[test]
fn a_process_that_ends_by_a_raw_exit_group_while_a_thread_sleeps_ends_at_its_instant() {
    let (dir, log) = c_program_repeated("vt-raw-exit", "raw_exit", 5.0);
    assert_eq!(log, "done at 1000.100\n");
    let summary = support::vt::summary(&dir.join("a"));
    let ended = summary["controller_exited_at_s"].as_f64().expect("controller_exited_at_s");
    assert!((0.1..0.11).contains(&ended), "ended at {ended} s: {summary:?}");
}

/// `system()`: glibc waits for its shell with a `wait4` inside libc, which is followed as the
/// symbols are; the shell's own sleep then moves the clock. It failed after 2 s "blocked in
/// system call 61 (wait4)".
#[test]
fn system_waits_for_its_shell_on_simulated_time() {
    let (_, log) = c_program_repeated("vt-system", "system_call", 2.0);
    assert_eq!(log, "from the shell\nsystem returned 0 after 200 ms\n");
}

/// A main thread that ends with `pthread_exit` while another thread works on: the process ends
/// with its last thread, and every run says so at the same instant.
#[test]
fn a_process_whose_main_thread_exits_first_ends_with_its_last_thread_in_every_run() {
    let (dir, log) = c_program_repeated("vt-pthread-exit", "pthread_exit_main", 2.0);
    assert_eq!(log, "main ends its thread\nworker done at 100.000 ms\n");
    let (a, b) = (support::vt::repeatable(&dir.join("a")), support::vt::repeatable(&dir.join("b")));
    assert_eq!(a["controller_exited_at_s"], b["controller_exited_at_s"], "{a:?}\n{b:?}");
    let ended = a["controller_exited_at_s"].as_f64().expect("controller_exited_at_s");
    assert!((0.1..0.102).contains(&ended), "{ended}");
}

/// What `tests/vt/timed_waits.c` prints on virtual time: each wait ends at the instant another
/// thread acted (plus the microsecond its call costs: a signal sent, a semaphore posted, a
/// message sent), or at its own timeout, in simulated time (the timerfd's 30 ms count from its
/// setting, two clock reads before the wait began; the late writer was started, and the timer
/// set, a microsecond's call before the read). Natively the same within a
/// millisecond, but for `futex_waitv`, which is not followed and answers as a kernel without it.
const TIMED_WAITS_SAY: &str = "\
select for 100 ms, written at 30 ms: 1 after 30.000 ms, 70.000 ms left
pselect letting SIGUSR1 through, sent at 20 ms: -1 EINTR after 20.001 ms
ppoll letting SIGUSR1 through, sent at 20 ms: -1 EINTR after 20.001 ms
epoll_pwait letting SIGUSR1 through, sent at 20 ms: -1 EINTR after 20.001 ms
SIGUSR1 handled 3 times, blocked again after: yes
ppoll letting an ignored, pending SIGPIPE through, 50 ms: 0 after 50.000 ms
read of an empty pipe, SIGALRM at 15 ms without SA_RESTART: -1 EINTR after 15.000 ms
read of a pipe written at 40 ms, SIGALRM at 15 ms with SA_RESTART: 1 after 39.999 ms
sleep(10), SIGALRM at 15 ms: 9 seconds left, errno EINTR, after 15.000 ms
pthread_timedjoin_np of a thread ending at 40 ms, 200 ms allowed: 0 after 40.000 ms
pthread_timedjoin_np of a thread ending at 500 ms, 50 ms allowed: -1 ETIMEDOUT after 50.000 ms
pthread_clockjoin_np of it then, 1 s allowed: 0 after 450.000 ms
pthread_timedjoin_np with tv_nsec 1e9 of a thread ending at 30 ms: 0 after 30.000 ms
semtimedop for 60 ms, nothing posted: -1 EAGAIN after 60.000 ms
semtimedop for 60 ms, posted at 25 ms: 0 after 25.001 ms
semop, posted at 25 ms: 0 after 25.001 ms
semtimedop for 60 ms, SIGALRM at 15 ms with SA_RESTART: -1 EINTR after 15.000 ms
mq_timedreceive for 70 ms, nothing sent: -1 ETIMEDOUT after 70.000 ms
mq_timedreceive for 70 ms, sent at 35 ms: 5 after 35.001 ms
mq_timedreceive for 70 ms, SIGALRM at 15 ms with SA_RESTART, sent at 35 ms: 5 after 35.001 ms
recv with an 80 ms SO_RCVTIMEO, nothing sent: -1 EAGAIN after 80.000 ms
read of it, nothing sent: -1 EAGAIN after 80.000 ms
send of 1 MiB with a 40 ms SO_SNDTIMEO, nobody reading: part of it after 40.000 ms
another, the socket full: -1 EAGAIN after 40.000 ms
recv of it, sent at 10 ms: 1 after 10.000 ms
epoll_wait of an epoll watching a 30 ms timerfd: 1 after 29.999 ms
a 1 ms timer's blocked signal taken after 50 ms: overrun 49
futex_waitv for 10 ms: -1 ENOSYS
";

/// Waits with a timeout or a signal mask of their own (select's time left, the masks of
/// pselect/ppoll/epoll_pwait, timed joins, System V semaphores, POSIX message queues, a
/// socket's SO_RCVTIMEO and SO_SNDTIMEO, a timerfd inside a nested epoll) end at simulated instants, with
/// Linux's answers; each once said something else with exit 0.
#[test]
fn waits_with_their_own_timeouts_and_masks_end_at_simulated_instants() {
    let (_, log) = c_program_repeated("vt-timed-waits", "timed_waits", 5.0);
    for (virtual_line, linux_line) in log.lines().zip(TIMED_WAITS_SAY.lines()) {
        assert_eq!(virtual_line, linux_line, "on virtual time (left) against what it should say (right); the whole log:\n{log}");
    }
    assert_eq!(log.lines().count(), TIMED_WAITS_SAY.lines().count(), "the program stopped early; its log:\n{log}");
}

/// A blocking write larger than a pipe (or a socket) holds waits on simulated time for room,
/// so that a reader that sleeps between its reads moves the clock: blocked in the kernel, the
/// writer held time still and the run failed after 2 s. Natively (`cc tests/vt/full_pipe.c`)
/// the writes end after about 805 ms.
#[test]
fn a_write_to_a_full_pipe_waits_on_simulated_time_for_room() {
    let (_, log) = c_program_repeated("vt-full-pipe-write", "full_pipe", 10.0);
    assert_eq!(
        log,
        "write to a pipe of 1048576 bytes: 1048576 after 800.000 ms\n  the child read 1048576 bytes\n\
         raw write to a pipe of 1048576 bytes: 1048576 after 800.000 ms\n  the child read 1048576 bytes\n\
         write to a FIFO of 1048576 bytes: 1048576 after 800.000 ms\n  the child read 1048576 bytes\n\
         send of 1048576 bytes to a socket: 1048576 after 800.000 ms\n  the thread read 1048576 bytes\n"
    );
}

/// A program with a seccomp filter of its own, whose SIGSYS handler answers the calls its
/// filter traps: each trap goes to the handler whose filter asked for it (the shim's carry the
/// shim's data), and the program's sleeps are still followed. The shim took the program's trap
/// for its own, and the process died with SIGSEGV.
#[test]
fn a_program_with_its_own_seccomp_filter_gets_its_own_traps() {
    let (_, log) = c_program_repeated("vt-own-seccomp", "own_seccomp", 2.0);
    assert_eq!(log, "getppid under the program's own filter: 4242, trapped with data 7 for call 110\nthen a 10 ms sleep: slept\n");
}

/// A service's way to end: `pause()` until SIGTERM, whose handler lets it write its last
/// report and exit 0. The run's SIGTERM came while the thread was in the trapped pause: the
/// kernel's pause, made after the program's mask was put back, had taken the signal already and
/// waited for ever, and the controller was killed with SIGKILL, its report lost.
#[test]
fn a_controller_that_pauses_until_sigterm_ends_with_its_handler() {
    let dir = support::scratch_dir("vt-pause-sigterm");
    let program = compiled_c(&dir, "pause_sigterm");
    let path = support::vt::scenario(&dir, "pause-sigterm", 1.0, &[program.to_str().expect("utf-8 path")], false);
    for run in ["a", "b"] {
        let (output, _) = support::vt::run_virtual(&path, &dir.join(run));
        assert_eq!(output.status.code(), Some(0), "{}", support::output_text(&output));
        let log = std::fs::read_to_string(dir.join(run).join("controller.log")).expect("controller.log");
        assert_eq!(log, "waiting for SIGTERM\nSIGTERM handled, final report written\n");
        assert_eq!(support::vt::summary(&dir.join(run))["controller_exit_code"], 0, "run {run}");
    }
}

/// A robust mutex whose owner ends holding it: the kernel hands it on as the owner exits
/// (EOWNERDEAD for the next locker), but the waiters are in the shim's queues, which it cannot
/// see: a locker already waiting waited for ever, and the run failed at its end. Now it gets
/// EOWNERDEAD at the owner's end, as natively (within a millisecond), in every run.
#[test]
fn a_robust_mutex_whose_owner_ends_is_handed_on_at_that_instant() {
    let (_, log) = c_program_repeated("vt-robust-mutex", "robust_mutex", 2.0);
    assert_eq!(
        log,
        "lock after its owner thread ended: EOWNERDEAD\n\
         lock waiting for an owner thread that ends at 30 ms: EOWNERDEAD after 30.000 ms\n\
         lock of a shared one waiting for an owner process that dies at 30 ms: EOWNERDEAD after 30.000 ms\n\
         lock of a shared one held by another thread of a process that exits at 30 ms: EOWNERDEAD after 30.000 ms\n"
    );
}

/// A thread canceled while it waits where the shim waits for it (a sleep, the poll family) was
/// in no asynchronous cancellation window of glibc's, which sent it nothing: it slept on to its
/// deadline (10 s), and the run failed. A condition wait's cancellation, which glibc signals,
/// was taken for an ordinary signal and waited on. Now each ends at the cancel's instant, its
/// cleanup run; one whose cancellation is off sleeps on, and acts on it at its next
/// cancellation point, as natively (within a few milliseconds).
#[test]
fn a_thread_canceled_in_a_wait_ends_at_that_instant() {
    let (_, log) = c_program_repeated("vt-cancel", "cancel", 2.0);
    let waits = ["sleep", "nanosleep", "pthread_cond_wait", "poll", "select", "epoll_wait"];
    let mut expected: String = waits.iter().map(|wait| format!("canceled in {wait} at 20 ms: canceled, 1 cleanup, joined after 20.001 ms\n")).collect();
    expected.push_str("canceled at 20 ms with cancellation off until 30 ms, then usleep: canceled after 30.000 ms\n");
    assert_eq!(log, expected);
}
