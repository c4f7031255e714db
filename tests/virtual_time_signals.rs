//! Signals on `--clock virtual`: alarm, setitimer and POSIX timers fire at their simulated
//! instants, a signal one controller process or thread sends another arrives at the sender's
//! instant, and the waits for a signal (pause, sigsuspend, sigtimedwait, a sleep a signal
//! interrupts) end there, in C and in Python, the same in every run. Each is a real process.

mod support;

use support::output_text;
use support::vt::{assert_log_has, compiled_c, controller_log_repeated, run_virtual, scenario, summary};

#[test]
fn c_signal_timers_and_the_waits_for_them_keep_simulated_time_exactly() {
    let dir = support::scratch_dir("vt-alarm-c");
    let program = compiled_c(&dir, "alarm");
    let path = scenario(&dir, "alarm", 3.0, &[program.to_str().expect("utf-8 path")], true);
    let log = controller_log_repeated(&path, &dir);
    // Each wait ends 1 µs (the call's charge) after its instant at most.
    assert_log_has(
        &log,
        &[
            "alarm: pause returned -1 (Interrupted system call) at 1000.001 ms, handler at 1000.001 ms",
            "setitimer: 10 expirations of 20 ms in 200.002 ms",
            "nanosleep: returned -1 (Interrupted system call) after 50.001 ms, 950.000 ms left",
            "getitimer: 0.000000 s left",
            "timer_create: signal SIGRTMIN, value 42, code SI_TIMER, at +5.001 ms",
            "timer_create: signal SIGRTMIN, value 42, code SI_TIMER, at +20.001 ms",
            // glibc's own helper thread takes the signal and starts the callback's thread: both are
            // followed from their creation (a clone the shim traps).
            "SIGEV_THREAD: callback with value 7 at +12.001 ms",
            "sigsuspend: returned -1 (Interrupted system call) after 30.001 ms, 1 alarm",
            "sigtimedwait: returned -1 (Resource temporarily unavailable) after 10.000 ms",
            // A loop that only reads the clock gets the signal when its clock passes the instant.
            "spin: the handler ran at +7.001 ms, after many clock reads",
        ],
    );
}

#[test]
fn python_signal_timers_interrupt_sleeps_pause_and_sigtimedwait_at_their_instants() {
    let dir = support::scratch_dir("vt-alarm-py");
    let path = scenario(&dir, "alarm", 3.0, &["tests/vt/alarm.py"], true);
    let log = controller_log_repeated(&path, &dir);
    assert_log_has(
        &log,
        &[
            // The handler runs during the sleep, which goes on to its end (PEP 475); the other
            // thread's sleep is not disturbed.
            "setitimer: ticks at 20.003, 40.003, 60.003, 80.003, 100.003 ms; the main thread slept until 100.005 ms, the other until 50.002 ms",
            "alarm: pause returned after 1000.001 ms, the handler ran at +1000.001 ms",
            "sigtimedwait: signal SIGALRM after 30.001 ms",
            "sigtimedwait: None after a 10 ms timeout, at +40.001 ms",
            // A signal the kernel raises (not a timer's) ends pause() too, at its instant.
            "SIGCHLD: pause ended by the child's exit at +50.000 ms",
        ],
    );
}

#[test]
fn a_signal_one_controller_process_or_thread_sends_another_arrives_at_the_senders_instant() {
    let dir = support::scratch_dir("vt-kill");
    let program = compiled_c(&dir, "kill");
    let path = scenario(&dir, "kill", 2.0, &[program.to_str().expect("utf-8 path")], true);
    let log = controller_log_repeated(&path, &dir);
    assert_log_has(
        &log,
        &[
            "parent: sent SIGUSR1 at 35.001 ms",
            "child: SIGUSR1 at 35.001 ms, after 4 naps",
            "parent: pthread_kill at 70.001 ms",
            // A thread in pause() (followed on simulated time) is let go by the signal: before
            // kill was followed it waited for ever, the signal blocked inside the shim's wait.
            "thread: pause ended at 70.002 ms, the handler ran at 70.002 ms",
        ],
    );
}

#[test]
fn an_alarm_nobody_handles_kills_the_controller_at_its_instant_and_fails_the_run() {
    let dir = support::scratch_dir("vt-alarm-kill");
    let script = support::executable_script(&dir, "unhandled_alarm.py", "#!/usr/bin/env python3\nimport signal, time\nsignal.alarm(1)\ntime.sleep(5)\nprint('not reached')\n");
    let path = scenario(&dir, "unhandled", 3.0, &[script.to_str().expect("utf-8 path")], true);
    let (output, _) = run_virtual(&path, &dir.join("out"));
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    let summary = summary(&dir.join("out"));
    assert_eq!(summary["controller_exit"], "signal: 14 (SIGALRM)", "{summary:?}");
    let exited_at = summary["controller_exited_at_s"].as_f64().unwrap_or(f64::NAN);
    assert!((1.0..=1.001).contains(&exited_at), "exited at {exited_at} s, not at the alarm's 1 s (or the world tick after it): {summary:?}");
}

#[test]
fn a_posix_timer_survives_a_spawned_childs_exec_and_goes_with_its_own() {
    let dir = support::scratch_dir("vt-timer-spawn");
    let program = compiled_c(&dir, "posix_timer_spawn");
    let path = scenario(&dir, "timer-spawn", 1.0, &[program.to_str().expect("utf-8 path")], true);
    let log = controller_log_repeated(&path, &dir);
    // The child's exec (from a clone sharing the parent's memory) had deleted the parent's
    // timer: no tick came after the spawn.
    assert_log_has(&log, &["ticks before the spawn 5, in the 100 ms after it 10", "after the exec: 0 ticks in 100 ms"]);
}
