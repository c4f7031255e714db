//! An external controller's run (`run`, `check`, `sweep`): the world on the wall clock (or N ×
//! it with `--speed N`), the servos on a pty, the sensor server on localhost, and the
//! controller's own process, watched: a controller that dies, a world that could not keep its
//! pace, or a capture that failed is a failed run.

use std::path::Path;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use serde_json::json;
use tracing::{info, warn};

use climbsim::bus::Timing;
use climbsim::robot::RobotDescription;
use climbsim::bus::Bus;
use climbsim::scenario::run::{Observer, RunOutcome, plan_pose, robot_relative, settings_json, write_outputs};
use climbsim::scenario::view::{LiveAddress, ViewOptions};
use climbsim::scenario::{ExternalController, Scenario};
use climbsim::sensor_server::{SensorFeed, SensorServer};
use climbsim::sim::RobotWorld;
use climbsim::transport::{BusHandle, Clock, VirtualPort};

use super::controller::{Controller, Launch, param_env, resolve_command};
use super::pacer::{Pacer, TickHook};
use super::replay::RecordSpec;

/// The external controller's bus timing report in a run's output folder.
const TIMING_JSON: &str = "timing.json";
/// How often the controller process is polled for an early exit (wall clock).
const EXIT_POLL: Duration = Duration::from_millis(5);

/// How fast a wall-clock world runs, and how late it may fall behind before the run fails.
#[derive(Debug, Clone, Copy)]
pub struct Pace {
    /// Simulated seconds per wall-clock second (`--speed`).
    pub speed: f64,
    /// The 99th-percentile lateness (simulated time) of the world's ticks and of replies beyond
    /// which the run did not keep its pace (`--pace-tolerance-ms`).
    pub tolerance: Duration,
}

/// An external controller's run besides its scenario.
pub struct ExternalRun<'a> {
    pub timing: Timing,
    pub link: Option<&'a Path>,
    pub record: Option<&'a RecordSpec>,
    pub pace: Pace,
    /// Print the port, sensor URL and controller as they start (`run`; not `check`/`sweep`).
    pub announce: bool,
    /// Serve the run live to Foxglove here (`run --foxglove`).
    pub live: Option<LiveAddress>,
}

/// The bus of `scenario`'s world and its observer (see [`climbsim::scenario::run::scenario_bus`]).
pub fn scenario_bus(scenario: &Scenario, robot: &RobotDescription, timing: Timing, baud: Option<u32>) -> Result<(Bus, Observer)> {
    Ok(climbsim::scenario::run::scenario_bus(scenario, robot, timing, baud)?)
}

/// How the controller's process ended, and when (simulated seconds).
struct Exit {
    status: std::process::ExitStatus,
    at_s: f64,
    /// It ended by itself before the run's end (not stopped by climbsim).
    early: bool,
}

/// Run `scenario` with its external controller; writes the outputs into `out_dir`. The summary's
/// `failures` lists why the run failed (controller, pace), if it did; an interruption is an error
/// after the outputs are written.
pub fn run_external(scenario: &Scenario, external: &ExternalController, robot: &RobotDescription, options: &ExternalRun<'_>, out_dir: &Path) -> Result<RunOutcome> {
    std::fs::create_dir_all(out_dir).with_context(|| format!("cannot create {}", out_dir.display()))?;
    let baud = scenario.bus.baud_bps;
    climbsim::scenario::run::require_line(scenario)?;
    let (mut bus, mut observer) = scenario_bus(scenario, robot, options.timing, baud)?;
    observer.stream_to(out_dir)?;
    let view = ViewOptions::of_run(&scenario.capture, Some(out_dir), options.live.clone());
    let foxglove_url = observer.start_view(&view, &mut bus)?;
    let observer = Arc::new(Mutex::new(observer));
    let recorder = options.record.map(|spec| super::replay::start_recording(spec, "run", scenario, robot, &bus, baud)).transpose()?;
    let clock = Clock::scaled(options.pace.speed);
    let handle = BusHandle::with_clock(bus, None, recorder, clock);
    let feed = Arc::new(SensorFeed::default());
    super::replay::record_sensor_reads(&handle, &feed);

    // The pty session and the sensor server each get a thread: the session waits for a reply's
    // due time in a blocking ppoll, and the controller's HTTP reads every period must neither
    // wait for that nor delay a reply (sharing one thread cost replies milliseconds of lateness).
    let sensor_runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).thread_name("sensors").enable_all().build()?;
    let sensors_url = sensor_runtime.block_on(start_sensor_server(Arc::clone(&feed)))?;
    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).thread_name("pty").enable_all().build()?;
    let port = runtime.block_on(async {
        let port = Arc::new(VirtualPort::open(options.link)?);
        let session = tokio::spawn(super::serve_pty(Arc::clone(&port), Arc::clone(&handle), climbsim::transport::Adapter::Ideal));
        tokio::spawn(async move {
            if let Ok(Err(error)) = session.await {
                warn!(%error, "pty session ended");
            }
        });
        Ok::<_, anyhow::Error>(port)
    })?;

    let command = external.substituted_command().map_err(|message| anyhow::anyhow!("scenario {}: [controller]: {message}", scenario.path.display()))?;
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
    let launch = Launch { command: &command, env, speed: options.pace.speed, log_path: &log_path };
    // The world starts with the controller: a controller that cannot start leaves no half run.
    let capture_errors = Arc::new(Mutex::new(None::<String>));
    let pacer = Pacer::start_with(Arc::clone(&handle), observer_hook(Arc::clone(&observer), Arc::clone(&feed), Arc::clone(&capture_errors)));
    let mut controller = match Controller::start(&launch) {
        Ok(controller) => controller,
        Err(error) => {
            pacer.stop();
            port.remove_link();
            return Err(error);
        }
    };
    let started = Instant::now();
    info!(pid = controller.id(), port = %port.path().display(), sensors = %sensors_url, speed = options.pace.speed, "controller started");
    if options.announce {
        println!("port: {}\nsensors: {sensors_url}\ncontroller: {} (pid {})", port.path().display(), controller.description, controller.id());
        if let Some(url) = &foxglove_url {
            println!("foxglove: {url}");
        }
    }

    let duration = Duration::from_secs_f64(scenario.world.duration_s);
    let mut early_exit = None;
    while clock.now() < duration && !super::interrupt::requested() {
        if let Some(status) = controller.try_wait()? {
            early_exit = Some(Exit { status, at_s: clock.now().as_secs_f64(), early: true });
            break;
        }
        if observer.lock().unwrap_or_else(PoisonError::into_inner).world_failure().is_some() {
            break;
        }
        std::thread::sleep(EXIT_POLL);
    }
    // The world (and its capture) ends here; only then is the controller stopped, so that the
    // series never holds a robot whose controller was already gone.
    let pace = pacer.stop();
    let sim_s = clock.now().as_secs_f64();
    let exit = match early_exit {
        Some(exit) => exit,
        None => Exit { status: controller.stop()?, at_s: sim_s, early: false },
    };
    runtime.block_on(port.drain(Duration::from_millis(200)));
    port.remove_link();
    let report = super::finish_timing_report(&handle, &pace, Some(&out_dir.join(TIMING_JSON)))?;
    super::replay::finish_recording(&handle, &pace)?;
    let wall_s = started.elapsed().as_secs_f64();
    if let Some(error) = capture_errors.lock().unwrap_or_else(PoisonError::into_inner).take() {
        anyhow::bail!("capturing the run failed: {error}");
    }
    let observer = Arc::try_unwrap(observer).ok().context("observer still shared")?.into_inner().unwrap_or_else(PoisonError::into_inner);
    let mut summary = observer.summary(scenario.capture.on_line_tolerance_m);
    if let Some(failure) = observer.world_failure() {
        climbsim::scenario::run::record_failure(&mut summary, failure);
    }
    summary.insert("realtime_factor".to_owned(), json!(sim_s / wall_s.max(1e-9)));
    summary.insert("physics_ticks".to_owned(), json!(pace.ticks));
    summary.insert("physics_overruns".to_owned(), json!(pace.overruns));
    summary.insert("controller_exit".to_owned(), json!(exit.status.to_string()));
    summary.insert("controller_exit_code".to_owned(), json!(exit.status.code()));
    summary.insert("controller_exited_at_s".to_owned(), json!(exit.at_s));
    let pace_problems = report.pace_problems(options.pace.tolerance);
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
    summary.extend(handle.with_bus(|bus| climbsim::scenario::run::fault_summary(bus)));
    let interrupted = super::interrupt::requested();
    if interrupted {
        summary.insert("interrupted_at_s".to_owned(), json!(sim_s));
    }
    let mut failures = controller_failures(&exit, external, scenario.world.duration_s, &controller.log_tail(), &log_path);
    if !interrupted {
        failures.extend(pace_problems);
    }
    if !failures.is_empty() {
        failures.splice(0..0, climbsim::scenario::run::failures(&summary));
        summary.entry("failure_at_s".to_owned()).or_insert(json!(exit.at_s));
        summary.insert("failures".to_owned(), json!(failures));
    }
    let (series, track) = observer.finish()?;
    let outcome = RunOutcome { series, track, summary, settings: settings_json(scenario, robot), sim_s, wall_s };
    write_outputs(&outcome, out_dir)?;
    if interrupted {
        return Err(super::Verdict::Interrupted(format!("interrupted at t = {sim_s:.1} s; the outputs in {} cover the run up to then", out_dir.display())).into());
    }
    Ok(outcome)
}

/// Why the controller's exit fails the run: any early exit of a controller that should run to
/// the end, a non-zero exit or a signal of one that ends by itself.
fn controller_failures(exit: &Exit, external: &ExternalController, duration_s: f64, log_tail: &str, log_path: &Path) -> Vec<String> {
    if !exit.early {
        return Vec::new();
    }
    if external.ends_by_itself && exit.status.success() {
        return Vec::new();
    }
    let why = if external.ends_by_itself { "failed" } else { "ended before the scenario did" };
    let mut message = format!("controller {why}: {} at t = {:.2} s of {duration_s} s (simulated)", exit.status, exit.at_s);
    if log_tail.trim().is_empty() {
        message.push_str(&format!("; {} is empty", log_path.display()));
    } else {
        message.push_str(&format!("; last lines of {}:\n      {}", log_path.display(), log_tail.lines().collect::<Vec<_>>().join("\n      ")));
    }
    vec![message]
}

/// Serve `feed` on an ephemeral localhost port (on the current runtime); its base URL.
pub async fn start_sensor_server(feed: Arc<SensorFeed>) -> Result<String> {
    let server = SensorServer::bind("127.0.0.1:0".parse()?).await?;
    let url = server.url()?;
    tokio::spawn(async move {
        if let Err(error) = server.run(feed).await {
            warn!(%error, "sensor server stopped");
        }
    });
    Ok(url)
}

/// How often `/state` is published in a world without a weld line (with one, it comes with each
/// camera frame).
const STATE_RATE_HZ: f64 = 30.0;

/// What the pacer does after each tick of a world: events, camera and detector (publishing each
/// new frame, line measurement and ground truth), the time series and the view. The first error
/// is kept in `errors` (the pacer thread cannot return one).
pub fn observer_hook(observer: Arc<Mutex<Observer>>, feed: Arc<SensorFeed>, errors: Arc<Mutex<Option<String>>>) -> TickHook {
    let mut next_state_s = 0.0;
    let mut lidar_published = None;
    let mut welds_published = false;
    Box::new(move |bus, now| {
        let mut observer = observer.lock().unwrap_or_else(PoisonError::into_inner);
        let t_s = now.as_secs_f64();
        let observation = observer.on_tick(bus, now);
        let Some(world) = bus.plant::<RobotWorld>() else { return };
        if let Some(error) = observation.error {
            errors.lock().unwrap_or_else(PoisonError::into_inner).get_or_insert(error.to_string());
        }
        if observation.new_frame {
            // In the run's one convention (as timeseries.csv's d_m): the robot relative to the
            // line, + = robot left of it.
            if let Some(latest) = observer.latest().copied() {
                let line = robot_relative(&latest);
                feed.publish_line(t_s, line.d_err_m, line.psi_err_rad, latest.valid);
            }
            if let Some(frame) = observer.camera().latest()
                && let Err(error) = feed.publish_frame(frame.width, frame.height, &frame.pixels)
            {
                warn!(%error, "camera frame not published");
            }
        }
        if !welds_published {
            welds_published = true;
            feed.publish_welds(observer.welds_json());
        }
        if let Some(scan) = observer.lidar_scan().filter(|scan| lidar_published != Some(scan.t)) {
            lidar_published = Some(scan.t);
            feed.publish_lidar(scan.to_json());
        }
        // Without a line there are no frames: the state keeps its own rate.
        if observation.new_frame || (!observer.has_line() && t_s >= next_state_s) {
            next_state_s = t_s + 1.0 / STATE_RATE_HZ;
            let pose = world.chassis_pose();
            let truth = observer.ground_truth(world);
            feed.publish_state(json!({
                "t": t_s,
                "x": pose.translation.x, "y": pose.translation.y, "z": pose.translation.z,
                "heading_rad": plan_pose(world).heading_rad,
                "d_err_m": truth.d_err_m, "psi_err_rad": truth.psi_err_rad, "speed_m_s": truth.speed_m_s,
                "weld": truth.weld,
            }));
        }
    })
}
