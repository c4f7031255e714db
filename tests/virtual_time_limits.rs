//! `--clock virtual`'s limits: what it waits for (a computation at start, a stopped process),
//! what it refuses (a static program, io_uring) and what fails the run naming the thread
//! (computing past the limit, blocked in a call it does not follow, a livelock). Each is a
//! real process; none may hang.

use std::path::Path;
use std::time::Duration;

mod support;

use support::output_text;
use support::vt::{compiled_c, compiled_c_source, controller_log_repeated, log_repeated_in, run_virtual, run_virtual_with, scenario, summary};

#[test]
fn a_busy_loop_fails_the_run_naming_the_thread_past_the_compute_limit() {
    let dir = support::scratch_dir("vt-busy");
    let path = scenario(&dir, "busy", 10.0, &["tests/vt/busy.py"], false);
    let (output, wall) = run_virtual_with(&path, &dir.join("out"), &["--compute-limit-s", "3"]);
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    let failures = summary(&dir.join("out"))["failures"].to_string();
    assert!(failures.contains("has computed for 3 s of wall time without a call climbsim follows"), "{failures}");
    assert!(failures.contains("past --compute-limit-s 3"), "{failures}");
    assert!(failures.contains("busy.py") || failures.contains("python"), "{failures}");
    assert!(wall < Duration::from_secs(20), "{wall:?}");
}

#[test]
fn a_stopped_controller_stops_the_world_and_is_no_failure() {
    let dir = support::scratch_dir("vt-stopped");
    let path = scenario(&dir, "stopped", 5.0, &["tests/vt/stopped.py"], true);
    let (output, wall) = run_virtual(&path, &dir.join("out"));
    assert_eq!(output.status.code(), Some(0), "{}", output_text(&output));
    let log = std::fs::read_to_string(dir.join("out/controller.log")).expect("controller.log");
    let stopped: f64 = log.split("stopped for ").nth(1).and_then(|rest| rest.split(' ').next()).and_then(|s| s.parse().ok()).unwrap_or_else(|| panic!("{log}"));
    // About 3 s of wall time stopped; the world's clock did not move meanwhile.
    assert!(stopped < 0.01, "{log}");
    assert!(wall >= Duration::from_secs(3), "the helper did not keep it stopped: {wall:?}");
}

#[test]
fn a_statically_linked_controller_is_refused() {
    let Some(ldconfig) = ["/sbin/ldconfig", "/usr/sbin/ldconfig"].into_iter().find(|p| Path::new(p).exists()) else {
        panic!("this test needs Debian's static /sbin/ldconfig");
    };
    let dir = support::scratch_dir("vt-static");
    let path = scenario(&dir, "static", 2.0, &[ldconfig, "-p"], true);
    let (output, _) = run_virtual(&path, &dir.join("out"));
    assert_eq!(output.status.code(), Some(2), "{}", output_text(&output));
    assert!(output_text(&output).contains("statically linked"), "{}", output_text(&output));
}

#[test]
fn a_static_go_controller_is_refused_before_it_runs() {
    let dir = support::scratch_dir("vt-go-static");
    let program = support::vt::compiled_go(&dir, ".", false);
    let path = scenario(&dir, "go-static", 2.0, &[program.to_str().expect("utf-8 path")], true);
    let (output, _) = run_virtual(&path, &dir.join("out"));
    assert_eq!(output.status.code(), Some(2), "{}", output_text(&output));
    assert!(output_text(&output).contains("is statically linked"), "{}", output_text(&output));
}

#[test]
fn a_controller_blocked_in_a_call_climbsim_does_not_follow_fails_naming_it() {
    let dir = support::scratch_dir("vt-fifo-open");
    // Opening a FIFO for reading that nobody opens for writing: blocked in the kernel's open.
    let script = support::executable_script(&dir, "fifo_open.py", "#!/usr/bin/env python3\nimport os, sys, time\ntime.sleep(0.1)\npath = sys.argv[1]\nos.mkfifo(path)\nos.open(path, os.O_RDONLY)\n");
    let fifo = dir.join("fifo");
    let path = scenario(&dir, "fifo-open", 10.0, &[script.to_str().expect("utf-8 path"), fifo.to_str().expect("utf-8 path")], false);
    let (output, wall) = run_virtual(&path, &dir.join("out"));
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    let failures = summary(&dir.join("out"))["failures"].to_string();
    assert!(failures.contains("blocked for 2 s of wall time in system call 257 (openat)"), "{failures}");
    assert!(failures.contains("last followed call: "), "{failures}");
    assert!(wall < Duration::from_secs(20), "{wall:?}");
}

#[test]
fn a_controller_that_computes_for_seconds_at_start_is_waited_for() {
    let dir = support::scratch_dir("vt-compute");
    let path = scenario(&dir, "compute", 5.0, &["tests/vt/compute_at_start.py"], true);
    let (output, wall) = run_virtual(&path, &dir.join("out"));
    // Longer than the 2 s after which a thread blocked in a call climbsim does not follow fails.
    assert_eq!(output.status.code(), Some(0), "{}", output_text(&output));
    let log = std::fs::read_to_string(dir.join("out/controller.log")).expect("controller.log");
    assert!(log.contains("slept 1.0000"), "{log}");
    assert!(wall >= Duration::from_secs(3), "{wall:?}");
}

#[test]
fn threads_that_only_hand_a_lock_back_and_forth_move_the_clock() {
    let dir = support::scratch_dir("vt-handoffs");
    let program = compiled_c(&dir, "handoffs");
    let path = scenario(&dir, "handoffs", 2.0, &[program.to_str().expect("utf-8 path"), "2000"], true);
    let log = controller_log_repeated(&path, &dir);
    // Each of the 4000 hand-overs costs a call (1 µs): the clock moved about 4 ms.
    let simulated: f64 = log.split(" in ").nth(1).and_then(|rest| rest.split(' ').next()).and_then(|s| s.parse().ok()).unwrap_or_else(|| panic!("{log}"));
    assert!((0.0039..0.0041).contains(&simulated), "{log}");
}

#[test]
fn a_controller_that_starts_a_thread_every_period_keeps_its_periods() {
    // hil/bench/vt-thread-rate.sh's controller: a thread created and joined every millisecond.
    let dir = support::scratch_dir("vt-thread-rate");
    let program = compiled_c_source(&dir, "hil/bench/thread_per_period.c");
    let path = scenario(&dir, "thread-rate", 1.0, &[program.to_str().expect("utf-8 path"), "1000", "0.3", "1"], true);
    let log = controller_log_repeated(&path, &dir);
    assert!(log.contains("300 periods of 1000 us, a thread created and joined in each"), "{log}");
    // Each thread costs no simulated time: the controller ends at its last period's instant,
    // 0.3 s, which is also a world tick's; its end is seen at the next tick, on every run
    // (seen at 0.300 or 0.301 as the host raced, before the exit's instant was kept).
    for run in ["a", "b"] {
        let ended = summary(&dir.join(run))["controller_exited_at_s"].as_f64().unwrap_or(f64::NAN);
        assert_eq!(ended, 0.301, "run {run}");
    }
}

#[test]
fn a_sched_yield_loop_lets_the_thread_it_waits_for_run_and_moves_the_clock() {
    let dir = support::scratch_dir("vt-yield");
    let program = compiled_c(&dir, "yield_wait");
    let path = scenario(&dir, "yield", 2.0, &[program.to_str().expect("utf-8 path")], true);
    let log = controller_log_repeated(&path, &dir);
    // It spun from 0 to the setter's 300 ms, each yield a call's 1 µs.
    assert!(log.contains(" yields, 0.3000"), "{log}");
}

/// `tests/vt/spin_wait.c MODE…` run twice on virtual time: its log (the same in both runs) and
/// the first run's summary.
fn spin_wait_log(name: &str, mode: &[&str]) -> (String, serde_json::Map<String, serde_json::Value>) {
    let dir = support::scratch_dir(&format!("vt-spin-{name}"));
    let program = compiled_c(&dir, "spin_wait");
    let mut command = vec![program.to_str().expect("utf-8 path")];
    command.extend_from_slice(mode);
    let path = scenario(&dir, name, 2.0, &command, true);
    let log = controller_log_repeated(&path, &dir);
    (log, summary(&dir.join("a")))
}

#[test]
fn a_thread_spinning_on_a_flag_gives_way_to_the_ready_thread_that_sets_it() {
    // Without preemption the spinner kept the turn, the setter never ran, and the run failed at
    // the compute limit.
    let (log, summary) = spin_wait_log("ready", &["ready"]);
    assert!(log.contains("flag seen 0.000000 s after the start"), "{log}");
    assert_eq!(summary["virtual_time.threads_gave_way"], true, "{summary:?}");
}

#[test]
fn a_thread_spinning_on_a_flag_lets_time_move_to_the_sleeping_setter() {
    // Charged a quantum (10 ms) at a time, up to the setter's own instant: seen at 300 ms
    // exactly, not at the quantum after it.
    let (log, _) = spin_wait_log("sleeper", &["sleeper"]);
    assert!(log.contains("flag seen 0.300000 s after the start"), "{log}");
}

#[test]
fn a_lone_thread_spinning_on_a_flag_its_signal_handler_sets_lets_the_timer_fire() {
    // setitimer's 50 ms, after the 1 µs that the call itself costs.
    let (log, _) = spin_wait_log("alarm", &["alarm"]);
    assert!(log.contains("flag seen 0.050001 s after the start"), "{log}");
}

#[test]
fn the_programs_own_sigwinch_reaches_it_and_preemption_goes_on() {
    // Raised first with the default action (ignored, and the shim's handler stays), then with
    // a handler of the program's own; the spin after it is still preempted.
    let (log, _) = spin_wait_log("winch", &["winch"]);
    assert!(log.contains("own SIGWINCH handled 1 time(s)\nflag seen 0.300000 s after the start"), "{log}");
}

#[test]
fn with_preemption_off_a_spinning_thread_keeps_its_turn_until_the_compute_limit() {
    let dir = support::scratch_dir("vt-spin-off");
    let program = compiled_c(&dir, "spin_wait");
    let path = scenario(&dir, "off", 2.0, &[program.to_str().expect("utf-8 path"), "ready"], true);
    let (output, _) = run_virtual_with(&path, &dir.join("out"), &["--preempt-after-ms", "0", "--compute-limit-s", "1"]);
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    let failures = summary(&dir.join("out"))["failures"].to_string();
    assert!(failures.contains("without a call climbsim follows") && failures.contains("past --compute-limit-s 1"), "{failures}");
}

#[test]
fn a_thread_asked_to_give_way_while_it_creates_threads_runs_on_under_controller_cpu_too() {
    // 5000 threads created in one loop: the creator computes for quanta, and is asked to give
    // way half-way through pthread_create (a slot reserved, the thread not yet made). Charging
    // its CPU time there parked it, and the run failed for the wrong reason ("did not load
    // climbsim's shim") instead of naming the limit.
    let dir = support::scratch_dir("vt-give-way-creating");
    let program = compiled_c(&dir, "many_threads");
    let path = scenario(&dir, "creating", 2.0, &[program.to_str().expect("utf-8 path"), "5000"], true);
    let (output, _) = run_virtual_with(&path, &dir.join("out"), &["--controller-cpu", "1", "--preempt-after-ms", "1"]);
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    assert!(output_text(&output).contains("virtual time follows at most 4095 threads at once"), "{}", output_text(&output));
}

#[test]
fn two_threads_handing_a_token_back_and_forth_by_spinning_both_get_their_turns() {
    let (log, _) = spin_wait_log("pingpong", &["pingpong", "20"]);
    // Computation is free: twenty rounds at the instant they started.
    assert!(log.contains("20 rounds played, 0.000000 s after the start"), "{log}");
}

#[test]
fn io_uring_is_refused_naming_it() {
    let dir = support::scratch_dir("vt-io-uring");
    let program = compiled_c(&dir, "io_uring");
    let path = scenario(&dir, "ring", 2.0, &[program.to_str().expect("utf-8 path")], true);
    let (output, _) = run_virtual(&path, &dir.join("out"));
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    assert!(output_text(&output).contains("virtual time cannot follow io_uring"), "{}", output_text(&output));
    let log = std::fs::read_to_string(dir.join("out/controller.log")).expect("controller.log");
    assert!(log.contains("io_uring_setup: Function not implemented"), "{log}");
}

#[test]
fn a_livelock_fails_within_seconds_naming_each_thread() {
    // With calls made free (a hidden knob), two threads handing a lock back and forth never
    // move the clock: the livelock the watchdog must catch, whatever the threads do.
    let dir = support::scratch_dir("vt-livelock");
    let program = compiled_c(&dir, "handoffs");
    let path = scenario(&dir, "livelock", 2.0, &[program.to_str().expect("utf-8 path"), "1000000000"], true);
    let (output, wall) = run_virtual_with(&path, &dir.join("out"), &["--vt-syscall-ns", "0"]);
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    let failures = summary(&dir.join("out"))["failures"].to_string();
    assert!(failures.contains("simulated time has stood still at t = "), "{failures}");
    assert!(failures.contains("for 5 s of wall time"), "{failures}");
    assert_eq!(failures.matches("controller thread `handoffs`").count(), 2, "{failures}");
    assert!(failures.contains("last futex at t = "), "{failures}");
    assert!(wall < Duration::from_secs(30), "{wall:?}");
}

#[test]
fn a_controller_that_traces_its_own_child_fails_naming_the_tracer_instead_of_hanging() {
    let dir = support::scratch_dir("vt-tracer");
    let program = compiled_c(&dir, "tracer");
    let path = scenario(&dir, "tracer", 5.0, &[program.to_str().expect("utf-8 path")], true);
    let (output, wall) = run_virtual(&path, &dir.join("out"));
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    let failures = summary(&dir.join("out"))["failures"].to_string();
    assert!(failures.contains("is stopped by its tracer, pid"), "{failures}");
    assert!(failures.contains("one of the controller's own processes"), "{failures}");
    assert!(wall < Duration::from_secs(20), "{wall:?}");
}

/// A controller that writes over virtual time's shared block (a stray pointer, a program that
/// maps it itself) and aborts: nothing read back from the block can be trusted, and the run
/// fails saying so, every time. It used to fail, or once in two runs pass, with whatever the
/// scribbled words said (a thread limit hit, a controller still running, an end at
/// 18 446 744 073 s), and climbsim's own summary overflowed on a count read back from it.
#[test]
fn a_controller_that_writes_over_the_shared_block_fails_the_run_saying_so() {
    let dir = support::scratch_dir("vt-scribbler");
    let program = compiled_c(&dir, "scribbler");
    let path = scenario(&dir, "scribbler", 3.0, &[program.to_str().expect("utf-8 path")], true);
    for run in ["a", "b", "c"] {
        let (output, wall) = run_virtual(&path, &dir.join(run));
        assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
        let failures = summary(&dir.join(run))["failures"].as_array().expect("failures").clone();
        assert!(failures[0].as_str().is_some_and(|f| f.contains("the controller wrote over virtual time's shared block")), "{failures:?}");
        assert!(wall < Duration::from_secs(20), "{wall:?}");
        // Nor does a count read back from the block say that threads were preempted, or how
        // many turns they handed on.
        assert_eq!(summary(&dir.join(run))["virtual_time.threads_gave_way"], false, "run {run}");
        let counts: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join(run).join("scheduler.json")).expect("scheduler.json")).expect("json");
        for read_back in ["turns", "turns_handed", "gave_way"] {
            assert!(counts[read_back].is_null(), "run {run}: {read_back} in {counts}");
        }
    }
}

/// As many timerfds as the program opens (300; 64 per process were followed before, and the
/// 65th failed the run naming the limit): read one after another, 20 polled at once, 50 in an
/// epoll set, all 300 in one poll and 250 in one epoll set (64 in one wait were followed
/// before), each expiry at its simulated instant, in every run (each `timerfd_settime` is a
/// call that costs 1 µs: the timers were armed that far apart).
#[test]
fn timerfds_are_followed_as_many_as_the_program_opens() {
    let dir = support::scratch_dir("vt-many-timerfds");
    let program = compiled_c(&dir, "many_timerfds");
    let log = log_repeated_in(&dir, "many-timerfds", 2.0, &[program.to_str().expect("utf-8 path")]);
    assert_eq!(
        log,
        "read 300 timers, 300 expirations, the last at 300.299 ms\n\
         poll of 20: 1 ready after 59.999 ms (the last one's, readable)\n\
         epoll of 50: 1 ready after 450.999 ms (timer 49)\n\
         poll of 300: 1 ready after 68.705 ms (timer 5 readable)\n\
         poll of 300: 1 ready after 69.837 ms (timer 137 readable)\n\
         epoll of 250: 1 ready after 39.980 ms (timer 230)\n"
    );
}

/// As many connections to the sensor server as the program opens (64 at once were followed
/// before, and the 65th failed the run naming the limit): 100 asked at once and answered in
/// one poll loop; and a thread waiting on the 70th of 70 open connections is let go by its own
/// answer, not by the 6th's (a 64-bit mask, as the table had, mixed the two up).
#[test]
fn sensor_connections_are_followed_as_many_as_the_program_opens() {
    let dir = support::scratch_dir("vt-many-connections");
    let program = compiled_c(&dir, "many_connections");
    let log = log_repeated_in(&dir, "many-connections", 2.0, &[program.to_str().expect("utf-8 path")]);
    assert_eq!(
        log,
        "100 connections at once: 100 answered, all within 0.001 ms\n\
         connection 6 answered (1 answer); the thread on connection 70 woke after 101.000 ms with 1 ready\n"
    );
}

/// A statically linked child inherits the run's seccomp filter but cannot load the shim that
/// answers it: its first followed call (a sleep) kills it with SIGSYS. Its parent exits 0, and
/// the run passed; now it fails, saying what happened and what to do.
#[test]
fn a_child_killed_by_the_filter_it_inherited_fails_the_run_saying_why() {
    let dir = support::scratch_dir("vt-static-child");
    let parent = compiled_c(&dir, "static_child");
    let child = support::vt::compiled_c_as(&dir, "tests/vt/static_child.c", "static_child_static", &["-static"]);
    let path = scenario(&dir, "static-child", 2.0, &[parent.to_str().expect("utf-8 path"), child.to_str().expect("utf-8 path")], true);
    let (output, wall) = run_virtual(&path, &dir.join("out"));
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    // (The run fails as the parent's wait returns: whether the parent wrote its line first
    // depends on the host.)
    let failures = summary(&dir.join("out"))["failures"].to_string();
    assert!(failures.contains("was killed by SIGSYS"), "{failures}");
    assert!(failures.contains("statically linked"), "{failures}");
    assert!(wall < Duration::from_secs(20), "{wall:?}");
}

/// An exec from a second thread while the main thread waits in a join: Linux ends the main
/// thread and the new program takes the process. Its blocked main thread's slot was never
/// exited, and climbsim waited for its look for ever: the run failed as "a livelock". Now the
/// new program runs, at its instant.
/// The same in a forked child whose followed parent waits for it (the new program then starts
/// in its turn).
#[test]
fn an_exec_from_a_second_thread_runs_the_new_program_at_its_instant() {
    let dir = support::scratch_dir("vt-exec-from-thread");
    let program = compiled_c(&dir, "exec_from_thread");
    let program = program.to_str().expect("utf-8 path");
    for (name, command, said) in [("main", vec![program], "exec-done"), ("in-a-child", vec![program, "in-a-child"], "exec-done\nchild status 0")] {
        let path = scenario(&dir, name, 2.0, &command, true);
        let dir = dir.join(name);
        let (output, wall) = run_virtual(&path, &dir.join("out"));
        assert_eq!(output.status.code(), Some(0), "{name}: {}", output_text(&output));
        let log = std::fs::read_to_string(dir.join("out/controller.log")).expect("controller.log");
        assert_eq!(log.trim(), said, "{name}: {log}");
        // 50 ms before the exec, 100 ms of the new program's sleep, and the calls between.
        let ended = summary(&dir.join("out"))["controller_exited_at_s"].as_f64().expect("controller_exited_at_s");
        assert!((0.15..0.16).contains(&ended), "{name}: {ended}");
        assert!(wall < Duration::from_secs(20), "{name}: {wall:?}");
    }
}

/// A thread made by a raw clone without a thread pointer of its own shares its creator's
/// thread-locals, where the shim keeps which slot is whose: its calls cannot be told from its
/// creator's. The run failed after 2 s saying the process "did not load climbsim's shim" (a
/// statically linked program); now it fails at once, naming the real cause.
#[test]
fn a_raw_clone_thread_that_shares_its_creators_thread_locals_fails_the_run_saying_so() {
    let dir = support::scratch_dir("vt-raw-clone-tls");
    let program = compiled_c(&dir, "raw_clone_shared_tls");
    let path = scenario(&dir, "raw-clone-tls", 2.0, &[program.to_str().expect("utf-8 path")], true);
    let (output, wall) = run_virtual(&path, &dir.join("out"));
    assert_eq!(output.status.code(), Some(1), "{}", output_text(&output));
    let failures = summary(&dir.join("out"))["failures"].to_string();
    assert!(failures.contains("without a thread pointer of its own (no CLONE_SETTLS)"), "{failures}");
    assert!(!failures.contains("did not load climbsim's shim"), "{failures}");
    assert!(wall < Duration::from_secs(20), "{wall:?}");
}
