//! A built-in controller's run: the reference controller talks to the real codec and bus
//! in-process, once per control period, and the world advances one firmware tick at a time
//! between its periods. On a [`LockstepClock`] the run goes as fast as the CPU allows and is
//! deterministic; shown live in Foxglove it goes on a [`WallClock`] at `speed` × real time.

use std::ops::ControlFlow;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use foxglove::messages::log::Level as LogLevel;
use serde_json::json;
use tracing::info_span;

use crate::bus::BusFaults;
use crate::control::{ControlError, ControlSample, Leg, ReferenceConfig, ReferenceController, Senses, WallSighting};
use crate::device::Servo;
use crate::robot::RobotDescription;
use crate::runner::observe::watch::{RunFailure, WorldWatch};
use crate::runner::view::{LiveAddress, ViewOptions};
use crate::scenario::{ControllerSection, Scenario};
use crate::sim::Lockstep;
use crate::sim::lidar::LidarScan;

use super::RunError;
use super::clock::{Clock, LockstepClock, WallClock};
use super::observe::{Observer, check_world, plan_pose, require_line};
use super::outputs::{RunOutcome, fault_summary, record_failure, settings_json, write_outputs};
use super::ticks::{Ticked, run_ticks};
use super::{Console, During as _, Result, RunnerError};

/// Run a scenario with the built-in controller in lockstep, as fast as the CPU allows; the
/// captured rows are kept in the outcome.
pub fn run_lockstep(scenario: &Scenario, robot: &RobotDescription) -> Result<RunOutcome, RunError> {
    run_lockstep_until(scenario, robot, &AtomicBool::new(false), None, None)
}

/// A built-in controller's run shown live in Foxglove: where the server listens, and at what
/// multiple of real time the run goes (a lockstep run is otherwise as fast as the CPU allows,
/// too fast to watch).
pub struct LiveRun<'a> {
    pub address: LiveAddress,
    pub speed: f64,
    /// Told the server's URL once it listens, before the run starts.
    pub console: &'a dyn Console,
}

/// `climbsim run SCENARIO` with a built-in controller (shown `live` in Foxglove if asked): the
/// run and its outputs in `out_dir`; an interruption is an error after the outputs are written.
pub fn run_builtin(scenario: &Scenario, robot: &RobotDescription, out_dir: &Path, stop: &AtomicBool, live: Option<&LiveRun<'_>>) -> Result<RunOutcome> {
    // The lockstep bus has no wire, but a baud the servos cannot take is still a wrong scenario.
    if let Some(bps) = scenario.bus.baud_bps {
        robot.servos(Some(bps)).during(|| format!("{}: [bus] baud_bps = {bps}", scenario.path.display()))?;
    }
    std::fs::create_dir_all(out_dir).during(|| format!("cannot create {}", out_dir.display()))?;
    let outcome = run_lockstep_until(scenario, robot, stop, Some(out_dir), live)?;
    write_outputs(&outcome, out_dir).during(|| format!("writing outputs to {}", out_dir.display()))?;
    if let Some(at) = outcome.summary.get("interrupted_at_s") {
        return Err(RunnerError::Interrupted(format!("interrupted at t = {at} s; the outputs in {} cover the run up to then", out_dir.display())));
    }
    Ok(outcome)
}

/// [`run_lockstep`], ending early when `stop` is set (e.g. by SIGINT): the outcome then covers
/// the run up to that moment and its summary says where it stopped (`interrupted_at_s`). With
/// `out_dir`, the captured rows go into its `timeseries.csv` as they come (complete when this
/// returns, interrupted or not) and the outcome holds none: [`write_outputs`] into the same
/// folder then writes the rest.
pub fn run_lockstep_until(scenario: &Scenario, robot: &RobotDescription, stop: &AtomicBool, out_dir: Option<&Path>, live: Option<&LiveRun<'_>>) -> Result<RunOutcome, RunError> {
    let ControllerSection::Builtin(config) = &scenario.controller else {
        return Err(RunError::NeedsRealTime { path: scenario.path.clone() });
    };
    require_line(scenario)?;
    // Rows are captured once per control period: a faster capture would repeat them.
    let control_hz = 1.0 / config.period().as_secs_f64();
    if scenario.capture.rate_hz > control_hz * (1.0 + 1e-9) {
        let why = format!("a built-in controller's run captures once per control period, {} s; lower rate_hz or controller.period_s", config.period().as_secs_f64());
        return Err(RunError::CaptureRate { path: scenario.path.clone(), rate_hz: scenario.capture.rate_hz, max_hz: (control_hz * 1e6).round() / 1e6, why });
    }
    let _span = info_span!("scenario", path = %scenario.path.display()).entered();
    let started = Instant::now();
    // Shown live, the run keeps to `speed` × real time from its start for the person watching.
    let wall_clock = live.map(|live| WallClock::scaled(live.speed));
    let mut sim = Lockstep::new(robot, scenario.world_config()?)?;
    check_world(scenario, sim.world(), &sim.bus().servos().iter().map(Servo::id).collect::<Vec<_>>())?;
    sim.bus_mut().set_faults(BusFaults::new(scenario.faults(), scenario.world.seed));
    // The servos' own profile, not a second parse of the file.
    let profile = sim.bus().servos().first().map(|s| std::sync::Arc::clone(s.profile())).ok_or(ControlError::MissingServo("servo on the bus"))?;
    // Runs start one firmware tick in, with the world settled for a step (the recorded figures
    // come from such runs). Draping does not need it: RobotWorld::new already made the terrain
    // queryable.
    sim.run(Duration::from_millis(1));
    let mut observer = Observer::new(scenario, robot, sim.world())?;
    if let Some(out_dir) = out_dir {
        observer.stream_to(out_dir)?;
    }
    let view = ViewOptions::of_run(&scenario.capture, out_dir, live.map(|l| l.address.clone()));
    if let (Some(url), Some(live)) = (observer.start_view(&view, sim.bus_mut())?, live) {
        live.console.say(&format!("foxglove: {url}"));
    }
    let mut controller = ReferenceController::new(robot, &profile, config.clone(), observer.target_speed_m_s(0.0))?;
    if let Some(relocation) = observer.relocation_plan() {
        controller = controller.with_relocation(relocation);
    }
    controller.start(&mut sim)?;
    let mut run = BuiltinTicks::new(sim, observer, controller, config, Duration::from_secs_f64(scenario.world.duration_s));
    let mut clock: Box<dyn Clock> = match wall_clock {
        Some(clock) => Box::new(clock),
        None => Box::new(LockstepClock::at(run.sim.now())),
    };
    let interrupted = run_ticks(clock.as_mut(), &mut run, stop).interrupted;
    if let Some(error) = run.error {
        return Err(error);
    }
    let BuiltinTicks { sim, observer, controller, failure, controller_errors, .. } = run;
    if let Some(failure) = &failure {
        observer.note(sim.now(), LogLevel::Error, failure.message.clone());
    }
    let wall_s = started.elapsed().as_secs_f64();
    let sim_s = sim.now().as_secs_f64();
    let mut summary = observer.summary(scenario.capture.on_line_tolerance_m);
    summary.insert("realtime_factor".to_owned(), json!(sim_s / wall_s.max(1e-9)));
    if interrupted {
        summary.insert("interrupted_at_s".to_owned(), json!(sim_s));
    }
    if let Some(failure) = &failure {
        record_failure(&mut summary, failure);
    }
    summary.extend(fault_summary(sim.bus()));
    if !sim.bus().faults().is_empty() {
        summary.insert("faults.control_periods_skipped".to_owned(), json!(controller_errors));
    }
    if let Some(relocation) = controller.relocation() {
        summary.insert("relocation.replans".to_owned(), json!(relocation.replans()));
        if let Leg::Stuck { reason } = relocation.leg() {
            summary.insert("relocation.stuck".to_owned(), json!(reason));
        }
    }
    let (series, track) = observer.finish()?;
    Ok(RunOutcome { series, track, summary, settings: settings_json(scenario, robot), sim_s, wall_s })
}

/// The built-in controller's world in the tick loop: a control period (events, senses, the
/// controller's bus traffic, a captured row) starts at the first tick after the last one ended,
/// and the world advances one firmware tick at a time in between, so that an interruption and
/// the world watch act within a tick, not a period.
struct BuiltinTicks {
    sim: Lockstep,
    observer: Observer,
    controller: ReferenceController,
    watch: WorldWatch,
    /// Why the run failed, if it did: the world watch's verdict, or the controller's error.
    failure: Option<RunFailure>,
    /// The servos' firmware tick and the control period.
    tick: Duration,
    period: Duration,
    period_end: Duration,
    /// A control period is due before the next tick.
    control_due: bool,
    end: Duration,
    relocating: bool,
    wall_window_rad: f32,
    controller_errors: u64,
    last_sample: ControlSample,
    /// What ended the run early, if anything did.
    error: Option<RunError>,
}

impl BuiltinTicks {
    fn new(sim: Lockstep, observer: Observer, controller: ReferenceController, config: &ReferenceConfig, end: Duration) -> Self {
        let tick = sim.bus().servos().first().map_or(Duration::from_millis(1), Servo::control_period);
        Self {
            period_end: sim.now(),
            sim,
            observer,
            relocating: controller.relocation().is_some(),
            controller,
            watch: WorldWatch::new(),
            failure: None,
            tick,
            period: config.period(),
            control_due: true,
            end,
            wall_window_rad: config.wall_transition.as_ref().map_or(0.0, |t| t.square_window_deg.to_radians() as f32),
            controller_errors: 0,
            last_sample: ControlSample::default(),
            error: None,
        }
    }

    /// One control period's start at the world's time: events, senses, the controller's bus
    /// traffic, the captured row.
    fn control_period(&mut self) -> Result<(), RunError> {
        let (sim, observer) = (&mut self.sim, &mut self.observer);
        let now = sim.now();
        let t_s = now.as_secs_f64();
        observer.pre_update(t_s, sim.world_mut())?;
        self.controller.set_target_speed(observer.target_speed_m_s(t_s));
        let line = observer.update(sim.world(), now);
        let wall = observer.lidar_scan().map(|scan| WallSighting { ahead_m: f64::from(scan.ahead_m()), angle_rad: scan.wall_angle_rad(self.wall_window_rad).map(f64::from) });
        let returns = if self.relocating { observer.lidar_scan().map(LidarScan::returns_in_plan).unwrap_or_default() } else { Vec::new() };
        let pose = self.relocating.then(|| plan_pose(sim.world()));
        let senses = Senses { line, wall, pose, lidar_returns: &returns };
        let sample = match self.controller.tick(sim, now, &senses) {
            Ok(sample) => *sample,
            // With faults on the bus a lost or corrupted reply is expected: the controller skips
            // the period (its wheels keep the last command) and tries again next period, as a
            // real one that times out would. Without faults a failed read is still a bug.
            Err(error) if !sim.bus().faults().is_empty() => {
                self.controller_errors += 1;
                tracing::debug!(%error, t_s, "control period skipped");
                self.last_sample
            }
            // The controller under test failed: the run's verdict, not bad input. The run ends
            // here with its outputs, as for a world the watch gave up on.
            Err(error) => {
                self.failure = Some(RunFailure { at_s: t_s, message: format!("controller: {error} at t = {t_s:.2} s") });
                return Ok(());
            }
        };
        self.last_sample = sample;
        observer.post_update(t_s, sim.bus(), Some(&sample))?;
        self.period_end = sim.now() + self.period;
        Ok(())
    }
}

impl Ticked for BuiltinTicks {
    fn next_due(&mut self, _now: Duration) -> Option<Duration> {
        let now = self.sim.now();
        // A new period starts only before the scenario's end; a period under way runs out.
        if self.control_due && now >= self.end {
            return None;
        }
        let period_end = if self.control_due { now + self.period } else { self.period_end };
        Some(now + self.tick.min(period_end.saturating_sub(now)))
    }

    fn tick(&mut self, at: Duration) -> ControlFlow<()> {
        if self.control_due {
            if let Err(error) = self.control_period() {
                self.error = Some(error);
                return ControlFlow::Break(());
            }
            if self.failure.is_some() {
                return ControlFlow::Break(());
            }
            self.control_due = false;
        }
        self.sim.run(at.saturating_sub(self.sim.now()));
        self.failure = self.watch.check(self.sim.world(), self.sim.now().as_secs_f64()).cloned();
        if self.failure.is_some() {
            return ControlFlow::Break(());
        }
        self.control_due = self.sim.now() >= self.period_end;
        ControlFlow::Continue(())
    }
}
