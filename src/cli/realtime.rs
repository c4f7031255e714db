//! `climbsim run` with an external controller: the world on the wall clock, the servos on a
//! pty, the sensor server on localhost, and the controller's own process.

use std::path::Path;
use std::process::{Child, Stdio};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use serde_json::json;
use tracing::{info, warn};

use climbsim::bus::Timing;
use climbsim::robot::RobotDescription;
use climbsim::bus::Bus;
use climbsim::scenario::run::{Observer, RunError, RunOutcome, settings_json, write_outputs};
use climbsim::scenario::Scenario;
use climbsim::sensor_server::{SensorFeed, SensorServer};
use climbsim::sim::RobotWorld;
use climbsim::transport::{BusHandle, VirtualPort};

use super::replay::RecordSpec;
use super::{Pacer, TickHook};

/// How long a controller gets to stop after SIGTERM before it is killed.
const STOP_GRACE: Duration = Duration::from_secs(3);

/// Resolve `./` and `../` arguments against the scenario's folder, so a scenario can name a
/// controller beside it whatever the working directory.
fn resolve_command(command: &[String], scenario: &Path) -> Vec<String> {
    let base = scenario.parent().unwrap_or(Path::new("."));
    command.iter().map(|arg| if arg.starts_with("./") || arg.starts_with("../") { base.join(arg).display().to_string() } else { arg.clone() }).collect()
}

/// The bus of `scenario`'s world and its observer (see [`climbsim::scenario::run::scenario_bus`]).
pub fn scenario_bus(scenario: &Scenario, robot: &RobotDescription, timing: Timing, baud: Option<u32>) -> Result<(Bus, Option<Observer>)> {
    Ok(climbsim::scenario::run::scenario_bus(scenario, robot, timing, baud)?)
}

/// Run `scenario` in real time with the external controller `command`.
/// The external controller's bus timing report in a run's output folder.
const TIMING_JSON: &str = "timing.json";

pub fn run_external(scenario: &Scenario, robot: &RobotDescription, command: &[String], timing: Timing, link: Option<&Path>, out_dir: &Path, record: Option<&RecordSpec>) -> Result<RunOutcome> {
    std::fs::create_dir_all(out_dir).with_context(|| format!("cannot create {}", out_dir.display()))?;
    let (bus, observer) = scenario_bus(scenario, robot, timing, None)?;
    let observer = Arc::new(Mutex::new(observer.ok_or_else(|| RunError::NoLine { path: scenario.path.clone() })?));
    let recorder = record.map(|spec| super::replay::start_recording(spec, "run", scenario, robot, &bus, None)).transpose()?;
    let handle = BusHandle::recording(bus, None, recorder);
    let feed = Arc::new(SensorFeed::default());
    super::replay::record_sensor_reads(&handle, &feed);

    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    let (port, sensors_url) = runtime.block_on(async {
        let url = start_sensor_server(Arc::clone(&feed)).await?;
        let port = Arc::new(VirtualPort::open(link)?);
        let session = tokio::spawn(super::serve_pty(Arc::clone(&port), Arc::clone(&handle)));
        tokio::spawn(async move {
            if let Ok(Err(error)) = session.await {
                warn!(%error, "pty session ended");
            }
        });
        Ok::<_, anyhow::Error>((port, url))
    })?;

    let capture_errors = Arc::new(Mutex::new(None::<String>));
    let pacer = Pacer::start_with(Arc::clone(&handle), observer_hook(Arc::clone(&observer), Arc::clone(&feed), Arc::clone(&capture_errors)));

    let command = resolve_command(command, &scenario.path);
    let (program, args) = command.split_first().context("the external controller's command is empty")?;
    let log_path = out_dir.join("controller.log");
    let log = std::fs::File::create(&log_path).with_context(|| format!("cannot create {}", log_path.display()))?;
    let started = Instant::now();
    let mut child = std::process::Command::new(program)
        .args(args)
        .env("DXL_PORT", port.path())
        .env("DXL_BAUD", robot.bus.baud_bps.to_string())
        .env("CLIMBSIM_SENSORS", &sensors_url)
        .env("CLIMBSIM_TARGET_SPEED_MM_MIN", scenario.speed.target_mm_min.to_string())
        .stdin(Stdio::null())
        .stdout(log.try_clone()?)
        .stderr(log)
        .spawn()
        .with_context(|| format!("cannot start the controller `{}`", command.join(" ")))?;
    info!(pid = child.id(), port = %port.path().display(), sensors = %sensors_url, "controller started");
    println!("port: {}\nsensors: {sensors_url}\ncontroller: {} (pid {})", port.path().display(), command.join(" "), child.id());

    let duration = Duration::from_secs_f64(scenario.world.duration_s);
    let mut exited_early = None;
    while started.elapsed() < duration && !super::interrupt::requested() {
        if let Some(status) = child.try_wait()? {
            exited_early = Some(status);
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let status = stop_child(&mut child)?;
    runtime.block_on(port.drain(Duration::from_millis(200)));
    let (ticks, overruns) = pacer.stop();
    port.remove_link();
    super::finish_timing_report(&handle, (ticks, overruns), Some(&out_dir.join(TIMING_JSON)))?;
    super::replay::finish_recording(&handle, (ticks, overruns))?;
    let wall_s = started.elapsed().as_secs_f64();
    if let Some(status) = exited_early {
        eprintln!("climbsim: the controller exited after {wall_s:.1} s with {status}; see {}", log_path.display());
    }
    if let Some(error) = capture_errors.lock().unwrap_or_else(PoisonError::into_inner).take() {
        anyhow::bail!("capturing the run failed: {error}");
    }
    let observer = Arc::try_unwrap(observer).ok().context("observer still shared")?.into_inner().unwrap_or_else(PoisonError::into_inner);
    let sim_s = handle.clock().now().as_secs_f64();
    let mut summary = observer.summary(scenario.capture.on_line_tolerance_m);
    summary.insert("realtime_factor".to_owned(), json!(sim_s / wall_s.max(1e-9)));
    summary.insert("physics_ticks".to_owned(), json!(ticks));
    summary.insert("physics_overruns".to_owned(), json!(overruns));
    summary.insert("controller_exit".to_owned(), json!(status.map(|s| s.to_string())));
    summary.extend(handle.with_bus(|bus| climbsim::scenario::run::fault_summary(bus)));
    let interrupted = super::interrupt::requested();
    if interrupted {
        summary.insert("interrupted_at_s".to_owned(), json!(sim_s));
    }
    let outcome = RunOutcome { series: observer.into_series(scenario.capture.signals.as_deref()), summary, settings: settings_json(scenario, robot), sim_s, wall_s };
    write_outputs(&outcome, out_dir)?;
    if interrupted {
        anyhow::bail!("interrupted at t = {sim_s:.1} s; the outputs in {} cover the run up to then", out_dir.display());
    }
    Ok(outcome)
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

/// What the pacer does after each tick of a world with a line: events, camera and detector
/// (publishing each new frame, line measurement and ground truth), and the time series. The
/// first error is kept in `errors` (the pacer thread cannot return one).
pub fn observer_hook(observer: Arc<Mutex<Observer>>, feed: Arc<SensorFeed>, errors: Arc<Mutex<Option<String>>>) -> TickHook {
    Box::new(move |bus, now| {
        let mut observer = observer.lock().unwrap_or_else(PoisonError::into_inner);
        let t_s = now.as_secs_f64();
        let observation = observer.on_tick(bus, now);
        let Some(world) = bus.plant::<RobotWorld>() else { return };
        if let Some(error) = observation.error {
            errors.lock().unwrap_or_else(PoisonError::into_inner).get_or_insert(error.to_string());
        }
        if observation.new_frame {
            if let Some(latest) = observer.latest().copied() {
                feed.publish_line(t_s, f64::from(latest.d_m), f64::from(latest.psi_rad), latest.valid);
            }
            if let Some(frame) = observer.camera().latest()
                && let Err(error) = feed.publish_frame(frame.width, frame.height, &frame.pixels)
            {
                warn!(%error, "camera frame not published");
            }
            let pose = world.chassis_pose();
            let truth = observer.ground_truth(world);
            feed.publish_state(json!({
                "t": t_s,
                "x": pose.translation.x, "y": pose.translation.y, "z": pose.translation.z,
                "d_err_m": truth.d_err_m, "psi_err_rad": truth.psi_err_rad, "speed_m_s": truth.speed_m_s,
            }));
        }
    })
}

/// SIGTERM, a grace period, then SIGKILL; the exit status if it could be had.
fn stop_child(child: &mut Child) -> Result<Option<std::process::ExitStatus>> {
    if let Some(status) = child.try_wait()? {
        return Ok(Some(status));
    }
    let pid = nix::unistd::Pid::from_raw(i32::try_from(child.id()).context("pid out of range")?);
    let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
    let deadline = Instant::now() + STOP_GRACE;
    while Instant::now() < deadline {
        if let Some(status) = child.try_wait()? {
            return Ok(Some(status));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    warn!("the controller ignored SIGTERM for {STOP_GRACE:?}; killing it");
    child.kill()?;
    Ok(Some(child.wait()?))
}
