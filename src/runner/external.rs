//! An external controller's run (`run`, `check`, `sweep`): the world on the wall clock (or N ×
//! it with `--speed N`) or on virtual time (`--clock virtual`), the servos on a pty, the sensor server on localhost, and the
//! controller's own process, watched: a controller that dies, a world that could not keep its
//! pace, or a capture that failed is a failed run.

use std::ops::ControlFlow;
use std::os::unix::process::ExitStatusExt as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use serde_json::json;
use tracing::{info, warn};

use crate::bus::Timing;
use crate::robot::RobotDescription;
use crate::runner::view::{LiveAddress, ViewOptions};
use crate::scenario::{ExternalController, Scenario};
use crate::sensor_server::SensorFeed;
use crate::transport::{Adapter, BusHandle, Clock as BusClock, VirtualPort};

use super::clock::Pace;
use super::feed::{WorldFailed, observer_hook};
use super::observe::{require_line, scenario_bus};
use super::outputs::{RunOutcome, failures, fault_summary, finish_timing_report, record_failure, settings_json, write_outputs};
use super::process::{Controller, Launch, param_env, resolve_command};
use super::recording::{RecordSpec, finish_recording, record_sensor_reads, start_recording};
use super::serve::pty::{after_the_run, serve_after_the_run, serve_pty};
use super::ticks::{HandleTicks, Ticked, run_ticks};
use super::time_base::{TickSource, Timekeeping, spawn_logged};
use super::{Console, During as _, Result, RunnerError};

/// The external controller's bus timing report in a run's output folder.
const TIMING_JSON: &str = "timing.json";

/// An external controller's run besides its scenario.
pub struct ExternalRun<'a> {
    pub timing: Timing,
    pub link: Option<&'a Path>,
    pub record: Option<&'a RecordSpec>,
    pub pace: Pace,
    /// Say the port, sensor URL and controller as they start (`run`; not `check`/`sweep`).
    pub announce: bool,
    /// Serve the run live to Foxglove here (`run --foxglove`).
    pub live: Option<LiveAddress>,
}

/// How long (wall time) the run's end waits for a controller thread that ran on past the
/// world's last tick to park (it does within microseconds, unless it computes without calls).
const PARKED_AT_THE_END_WITHIN: Duration = Duration::from_secs(1);

/// How the controller's process ended, and when (simulated seconds).
struct Exit {
    status: std::process::ExitStatus,
    at_s: f64,
    /// It ended by itself before the run's end (not stopped by climbsim).
    early: bool,
}

/// The world's ticks, each followed by a look at the controller's process: a controller that
/// ended by itself ends the run (as does a world the watch gave up on: see [`observer_hook`]).
struct WatchedTicks<'a> {
    world: HandleTicks,
    controller: &'a mut Controller,
    clock: BusClock,
    time: TickSource,
    exit: Option<Exit>,
    error: Option<RunnerError>,
    /// Under virtual time, the controller's process went on without the shim (it exec'd with
    /// LD_PRELOAD dropped): watched as on the wall clock from then on.
    unfollowed: bool,
}

impl Ticked for WatchedTicks<'_> {
    fn next_due(&mut self, now: Duration) -> Option<Duration> {
        self.world.next_due(now)
    }

    fn tick(&mut self, at: Duration) -> ControlFlow<()> {
        if self.world.tick(at).is_break() {
            return ControlFlow::Break(());
        }
        // Under virtual time the exit is seen when the shim saw it (at one simulated instant on
        // every run), not whenever the kernel's reaping comes round on the wall clock.
        // A process that went on without the shim is watched as on the wall clock.
        let (status, seen_at) = match self.time.controller_ended_before(at).filter(|_| !self.unfollowed) {
            None => (self.controller.try_wait(), self.clock.now()),
            // Seen at the first tick after the exit's own simulated time (the world may be
            // catching up with a controller that ran ahead): at that tick's instant, which the
            // bus clock may have passed by the host's race (0.101 or 0.102 s in 1 run of 30).
            Some(true) => {
                let status = self.controller.wait_for_ending();
                self.unfollowed = matches!(status, Ok(None));
                (status, at)
            }
            Some(false) => (Ok(None), at),
        };
        match status {
            Ok(None) => ControlFlow::Continue(()),
            Ok(Some(status)) => {
                self.exit = Some(Exit { status, at_s: seen_at.as_secs_f64(), early: true });
                ControlFlow::Break(())
            }
            Err(error) => {
                self.error = Some(error);
                ControlFlow::Break(())
            }
        }
    }

    fn resync(&mut self, now: Duration) {
        self.world.resync(now);
    }
}

/// Run `scenario` with its external controller; writes the outputs into `out_dir`. The summary's
/// `failures` lists why the run failed (controller, pace), if it did; an interruption (`stop`
/// set) is an error after the outputs are written.
pub fn run_external(
    scenario: &Scenario,
    external: &ExternalController,
    robot: &RobotDescription,
    options: &ExternalRun<'_>,
    out_dir: &Path,
    stop: &AtomicBool,
    console: &dyn Console,
) -> Result<RunOutcome> {
    std::fs::create_dir_all(out_dir).during(|| format!("cannot create {}", out_dir.display()))?;
    let baud = scenario.bus.baud_bps;
    require_line(scenario)?;
    let (mut bus, mut observer) = scenario_bus(scenario, robot, options.timing, baud)?;
    observer.stream_to(out_dir)?;
    let view = ViewOptions::of_run(&scenario.capture, Some(out_dir), options.live.clone());
    let foxglove_url = observer.start_view(&view, &mut bus)?;
    let observer = Arc::new(Mutex::new(observer));
    let recorder = options.record.map(|spec| start_recording(spec, "run", scenario, robot, &bus, baud)).transpose()?;
    let time = Timekeeping::assemble(&options.pace)?;
    let clock = time.bus_clock();
    let handle = BusHandle::with_clock(bus, None, recorder, clock.clone());
    let feed = Arc::new(SensorFeed::default());
    record_sensor_reads(&handle, &feed);

    // The pty session and the sensor server each get a thread: the session waits for a reply's
    // due time in a blocking ppoll, and the controller's HTTP reads every period must neither
    // wait for that nor delay a reply (sharing one thread cost replies milliseconds of lateness).
    let runtime = |name: &str| tokio::runtime::Builder::new_multi_thread().worker_threads(1).thread_name(name).enable_all().build().during(|| format!("cannot start the {name} thread"));
    let sensor_runtime = runtime("sensors")?;
    let sensors_url = sensor_runtime.block_on(time.start_sensor_server(Arc::clone(&feed)))?;
    let pty_runtime = runtime("pty")?;
    let port = pty_runtime.block_on(async {
        let port = Arc::new(VirtualPort::open(options.link).during(|| "cannot open the pty".to_owned())?);
        time.serve_pty(Arc::clone(&port), Arc::clone(&handle), Adapter::Ideal, |port, handle, adapter| {
            spawn_logged("pty session", serve_pty(port, handle, adapter));
            Ok(())
        })?;
        Ok::<_, RunnerError>(port)
    })?;

    let command = external.substituted_command().map_err(|message| RunnerError::Invalid(format!("scenario {}: [controller]: {message}", scenario.path.display())))?;
    let command = resolve_command(&command, &scenario.path);
    let log_path = out_dir.join("controller.log");
    let mut env = vec![
        ("DXL_PORT".to_owned(), port.path().display().to_string()),
        ("DXL_BAUD".to_owned(), baud.unwrap_or(robot.bus.baud_bps).to_string()),
        ("CLIMBSIM_SENSORS".to_owned(), sensors_url.clone()),
        ("CLIMBSIM_TARGET_SPEED_MM_MIN".to_owned(), scenario.speed.target_mm_min.to_string()),
        ("CLIMBSIM_DURATION_S".to_owned(), scenario.world.duration_s.to_string()),
        ("CLIMBSIM_SPEED".to_owned(), options.pace.speed.to_string()),
        ("CLIMBSIM_OUT".to_owned(), out_dir.display().to_string()),
    ];
    env.extend(param_env(&external.param_text()));
    env.extend(time.controller_env()?);
    time.before_launch();
    let launch = Launch { command: &command, env, speed: time.controller_speed(), virtual_time: time.is_virtual(), log_path: &log_path, output_pipe: &|inode| time.controller_output(inode) };
    // The world starts with the controller: a controller that cannot start leaves no half run.
    let capture_errors = Arc::new(Mutex::new(None::<String>));
    let mut controller = match Controller::start(&launch) {
        Ok(controller) => controller,
        Err(error) => {
            port.remove_link();
            return Err(error);
        }
    };
    time.launched(controller.id());
    let started = Instant::now();
    info!(pid = controller.id(), port = %port.path().display(), sensors = %sensors_url, speed = options.pace.speed, "controller started");
    if options.announce {
        console.say(&format!("port: {}\nsensors: {sensors_url}\ncontroller: {} (pid {})", port.path().display(), controller.description, controller.id()));
        if let Some(url) = &foxglove_url {
            console.say(&format!("foxglove: {url}"));
        }
    }

    // The world (and its capture) ends at the scenario's end or with the controller; only then
    // is the controller stopped, so that the series never holds a robot whose controller was
    // already gone.
    let duration = Duration::from_secs_f64(scenario.world.duration_s);
    let hook = observer_hook(Arc::clone(&observer), Arc::clone(&feed), Arc::clone(&capture_errors), WorldFailed::Ends);
    let ticks_on = time.tick_source();
    let mut ticks = WatchedTicks {
        world: HandleTicks::new(Arc::clone(&handle), hook, Some(duration)),
        controller: &mut controller,
        clock: clock.clone(),
        time: ticks_on.clone(),
        exit: None,
        error: None,
        unfollowed: false,
    };
    let ended = run_ticks(&mut *ticks_on.clock(stop), &mut ticks, stop);
    let (early_exit, error) = (ticks.exit.take(), ticks.error.take());
    drop(ticks);
    // A controller thread may have run on past the world's last tick: the time the run ended
    // at and the stop signal wait for it to park, so that neither depends on the race. (Not
    // after a failure or an interruption: the threads may never park then.)
    if ended.clock_failure.is_none() && !ended.interrupted && !time.await_parked(PARKED_AT_THE_END_WITHIN, stop) {
        warn!("a controller thread still ran {PARKED_AT_THE_END_WITHIN:?} after the world's last tick (computing without calls?): it is asked to stop as it runs");
    }
    let pace = ended.pace;
    // The world's time at the end: the scenario's end at most (under virtual time the clock may
    // have jumped past it to a controller thread's deadline, which the world never reached).
    let sim_s = clock.now().min(duration).as_secs_f64();
    // The controller's clean-up runs on the wall clock: it can neither hang nor move the world.
    // It is asked to stop first, while parked at the run's last instant.
    let mut clean_up = None;
    if time.is_virtual() {
        controller.ask_to_stop()?;
    }
    if let Some(unread) = time.end() {
        // The servos still answer while it cleans up (they do on a real robot): on the wall
        // clock, on a bus of their own, so that nothing of it reaches the run's outputs.
        match after_the_run(&handle) {
            Ok(servos) => {
                let session = serve_after_the_run(Arc::clone(&port), servos, unread);
                clean_up = Some(pty_runtime.spawn(async move {
                    if let Err(error) = session.await {
                        warn!(%error, "the pty session after the run ended");
                    }
                }));
            }
            Err(error) => warn!(%error, "the controller's clean-up goes unanswered"),
        }
    }
    // Stopped either way: a controller that ended by itself may have left children running.
    let stopped = controller.stop()?;
    if let Some(session) = clean_up {
        session.abort();
    }
    let exit = early_exit.unwrap_or(Exit { status: stopped, at_s: sim_s, early: false });
    pty_runtime.block_on(port.drain(Duration::from_millis(200)));
    port.remove_link();
    if let Some(error) = error {
        return Err(error);
    }
    let report = finish_timing_report(&handle, &pace, Some(&out_dir.join(TIMING_JSON)), console)?;
    finish_recording(&handle, &pace, console)?;
    let wall_s = started.elapsed().as_secs_f64();
    if let Some(error) = capture_errors.lock().unwrap_or_else(PoisonError::into_inner).take() {
        return Err(RunnerError::Failed(format!("capturing the run failed: {error}")));
    }
    let observer = Arc::try_unwrap(observer).map_err(|_| RunnerError::Invalid("the observer is still shared at the run's end".to_owned()))?.into_inner().unwrap_or_else(PoisonError::into_inner);
    let mut summary = observer.summary(scenario.capture.on_line_tolerance_m);
    let world_failure = observer.world_failure();
    if let Some(failure) = world_failure {
        record_failure(&mut summary, failure);
    }
    summary.insert("realtime_factor".to_owned(), json!(sim_s / wall_s.max(1e-9)));
    summary.insert("physics_ticks".to_owned(), json!(pace.ticks));
    summary.insert("physics_overruns".to_owned(), json!(pace.overruns));
    summary.insert("controller_exit".to_owned(), json!(exit.status.to_string()));
    summary.insert("controller_exit_code".to_owned(), json!(exit.status.code()));
    summary.insert("controller_exited_at_s".to_owned(), json!(exit.at_s));
    time.summarise(&mut summary);
    if let Some(counts) = time.scheduler_counts() {
        crate::report::write_scheduler_json(out_dir, &counts)?;
    }
    // Under virtual time nothing is late by construction: there is no pace to keep.
    let pace_problems = if time.is_virtual() { Vec::new() } else { report.pace_problems(options.pace.tolerance) };
    summary.insert("pace.speed".to_owned(), json!(options.pace.speed));
    summary.insert("pace.tolerance_ms".to_owned(), json!(options.pace.tolerance.as_secs_f64() * 1e3));
    summary.insert("pace.tick_late_p99_ms".to_owned(), json!(report.physics_lateness_us.map(|q| q.p99_us / 1e3)));
    summary.insert("pace.reply_late_p99_ms".to_owned(), json!(report.delivery_lateness_us.map(|q| q.p99_us / 1e3)));
    summary.insert("pace.kept".to_owned(), json!(pace_problems.is_empty()));
    // What the controller did on the bus, for thresholds such as "the loop keeps its period".
    summary.insert("bus.utilisation_pct".to_owned(), json!(report.bus_utilisation_pct));
    if let Some(loop_report) = &report.controller_loop {
        summary.insert("controller.period_p50_ms".to_owned(), json!(loop_report.period_ms.p50));
        summary.insert("controller.period_p99_ms".to_owned(), json!(loop_report.period_ms.p99));
    }
    summary.extend(handle.with_bus(|bus| fault_summary(bus)));
    // A signal during the controller's stop or the drain counts too: the run did not end as asked.
    let interrupted = ended.interrupted || stop.load(std::sync::atomic::Ordering::Relaxed);
    if interrupted {
        summary.insert("interrupted_at_s".to_owned(), json!(sim_s));
    }
    // The scenario ran to its end (not cut short by an interruption, a clock that could not go
    // on, or a world the robot cannot be in): only then is a controller still running late.
    let reached_end = !interrupted && ended.clock_failure.is_none() && world_failure.is_none();
    let mut run_failures = controller_failures(&exit, external, scenario.world.duration_s, reached_end, &controller.log_tail(), &log_path);
    if let Some(why) = &ended.clock_failure {
        run_failures.insert(0, why.clone());
    }
    if !interrupted {
        run_failures.extend(pace_problems);
    }
    if !run_failures.is_empty() {
        run_failures.splice(0..0, failures(&summary));
        summary.entry("failure_at_s".to_owned()).or_insert(json!(exit.at_s));
        summary.insert("failures".to_owned(), json!(run_failures));
    }
    let (series, track) = observer.finish()?;
    let outcome = RunOutcome { series, track, summary, settings: settings_json(scenario, robot), sim_s, wall_s };
    write_outputs(&outcome, out_dir)?;
    if interrupted {
        return Err(RunnerError::Interrupted(format!("interrupted at t = {sim_s:.1} s; the outputs in {} cover the run up to then", out_dir.display())));
    }
    Ok(outcome)
}

/// Why the controller's exit fails the run: any early exit of a controller that should run to
/// the end, a non-zero exit or a signal of one that ends by itself, one that ends by itself
/// still running at the scenario's end, and a crash as it was stopped.
fn controller_failures(exit: &Exit, external: &ExternalController, duration_s: f64, reached_end: bool, log_tail: &str, log_path: &Path) -> Vec<String> {
    let crashed = exit.status.signal().is_some_and(|signal| CRASH_SIGNALS.contains(&signal));
    if !exit.early && !reached_end {
        // The run stopped before the scenario's end for a reason of its own (said first): of
        // the controller, only a crash is worth saying, without claiming when it came.
        return if crashed { vec![with_log_tail(format!("controller ended with {} (seen as the run stopped at t = {:.2} s)", exit.status, exit.at_s), log_tail, log_path)] } else { Vec::new() };
    }
    if !exit.early && external.ends_by_itself {
        // A program that finishes a scripted task and had not: blocked for good, or slower than
        // the scenario allows. Stopped, it is no pass.
        let message = format!(
            "controller still running at the scenario's end (t = {duration_s} s, simulated), though it ends by itself (ends_by_itself = true): it had not finished its task by then; it was stopped ({})",
            exit.status
        );
        return vec![with_log_tail(message, log_tail, log_path)];
    }
    if !exit.early {
        // Asked to stop at the scenario's end (SIGTERM), it may end as it likes (0, 143, the
        // signal itself) but not crash: a controller that dies in its own ending (an assertion,
        // a segfault) loses what it does there (its final report, the servos' torque off).
        return if crashed { vec![with_log_tail(format!("controller crashed as it stopped at the scenario's end (asked with SIGTERM): {}", exit.status), log_tail, log_path)] } else { Vec::new() };
    }
    if external.ends_by_itself && exit.status.success() {
        return Vec::new();
    }
    let why = if external.ends_by_itself { "failed" } else { "ended before the scenario did" };
    let message = format!("controller {why}: {} at t = {:.2} s of {duration_s} s (simulated)", exit.status, exit.at_s);
    vec![with_log_tail(message, log_tail, log_path)]
}

/// The signals a program dies of when it crashes (not those it is stopped with).
const CRASH_SIGNALS: [i32; 7] = [libc::SIGABRT, libc::SIGSEGV, libc::SIGBUS, libc::SIGFPE, libc::SIGILL, libc::SIGSYS, libc::SIGTRAP];

/// `message`, then the controller's last lines (or that its log is empty).
fn with_log_tail(mut message: String, log_tail: &str, log_path: &Path) -> String {
    if log_tail.trim().is_empty() {
        message.push_str(&format!("; {} is empty", log_path.display()));
    } else {
        message.push_str(&format!("; last lines of {}:\n      {}", log_path.display(), log_tail.lines().collect::<Vec<_>>().join("\n      ")));
    }
    message
}
