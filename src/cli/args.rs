//! What several subcommands share: flags (`--foxglove`, `--speed`, `--timing`, `--fault`), their
//! parsers, and loading the robot description.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Result, bail};
use clap::ValueEnum;

use climbsim::bus::Timing;
use climbsim::embedded;
use climbsim::fault::ScheduledFault;
use climbsim::robot::{RobotDescription, RobotOverrides};
use climbsim::runner::view::LiveAddress;
use climbsim::runner::{Pace, TimeBase};
use climbsim::virtual_time::VtSettings;

/// `--foxglove[=ADDR]`, shared by `run` and `serve`.
#[derive(Debug, Clone, clap::Args)]
pub struct FoxgloveArgs {
    /// Show the world live in Foxglove: serve Foxglove's WebSocket protocol at 127.0.0.1:8765,
    /// or at `--foxglove=ADDR` (PORT, HOST or HOST:PORT; only this machine can connect unless a
    /// host is given). In Foxglove: Open connection → Foxglove WebSocket. A built-in
    /// controller's run then keeps to real time (or --speed N times it) for the watcher.
    #[arg(long = "foxglove", requires = "scenario", value_name = "ADDR", num_args = 0..=1, require_equals = true, default_missing_value = "127.0.0.1:8765")]
    pub address: Option<LiveAddress>,
}

/// `--speed` and `--pace-tolerance-ms`, shared by `run`, `check`, `sweep` and `serve`.
#[derive(Debug, Clone, Copy, clap::Args)]
pub struct PaceArgs {
    /// Run the world, the bus's wire timing and an external controller's clocks (libfaketime)
    /// at N times the wall clock, so an unchanged controller runs faster than real time.
    #[arg(long, value_name = "N", default_value = "1", value_parser = parse_speed)]
    pub speed: f64,
    /// Fail a wall-clock run whose world ticks or replies come later than this (simulated
    /// milliseconds, 99th percentile): the machine could not keep the pace. The default is
    /// under a real USB adapter's own delivery delay (an FTDI chip's 16 ms latency timer,
    /// which the official SDK's timeouts allow for twice over).
    #[arg(long, value_name = "MS", default_value = "10", value_parser = parse_tolerance_ms)]
    pub pace_tolerance_ms: f64,
    /// Whose clock an external controller runs on. `wall`: the wall clock (or N times it with
    /// --speed N). `virtual`: the simulation's; the controller's clocks, sleeps and waits follow
    /// simulated time, so the run goes as fast as the CPU allows and repeats exactly
    /// (docs/virtual-time.md). The default: `virtual` for `check`, `wall` for the others (and
    /// for `check --speed N`).
    #[arg(long, value_enum)]
    pub clock: Option<ClockArg>,
    /// Under --clock virtual, also advance the clock by each controller thread's CPU time × F
    /// (1: this machine; 4: a target computer four times slower), so that a controller too slow
    /// for its period shows its overruns. The run is then no longer exactly repeatable.
    #[arg(long, value_name = "F", value_parser = parse_controller_cpu)]
    pub controller_cpu: Option<f64>,
    /// Under --clock virtual, how long (wall-clock seconds) a controller thread may compute
    /// without a call climbsim follows (loading a model at start, say) before the run fails: a
    /// loop that neither reads a clock nor waits would hold simulated time for ever. Default 60.
    #[arg(long, value_name = "S", value_parser = parse_compute_limit_s)]
    pub compute_limit_s: Option<f64>,
    /// Under --clock virtual, the CPU time (ms) a controller thread may compute without a call
    /// climbsim follows before it gives way to the other threads, as the kernel would preempt
    /// it (a spin on a flag another thread sets). 0: never; computation is then always free,
    /// but a thread that spins waiting for another keeps the turn until --compute-limit-s.
    /// Default 10 (docs/virtual-time.md).
    #[arg(long, value_name = "MS", value_parser = parse_preempt_after_ms)]
    pub preempt_after_ms: Option<f64>,
    /// Virtual time: simulated nanoseconds an intercepted call that does not block costs.
    #[arg(long, value_name = "NS", default_value = "1000", hide = true)]
    pub vt_syscall_ns: u64,
    /// Virtual time: the longest jump (µs) of a zero-timeout poll of a port with nothing due.
    #[arg(long, value_name = "US", default_value = "100", hide = true)]
    pub vt_spin_cap_us: u64,
}

/// `--clock`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ClockArg {
    Wall,
    Virtual,
}

impl PaceArgs {
    /// The pace asked for, on the wall clock unless `--clock virtual`.
    pub fn pace(&self) -> Result<Pace> {
        self.pace_defaulting_to(ClockArg::Wall)
    }

    /// The pace asked for; without `--clock`, on `default` (the wall clock if `--speed` is given).
    pub fn pace_defaulting_to(&self, default: ClockArg) -> Result<Pace> {
        let clock = self.clock.unwrap_or(if self.speed != 1.0 { ClockArg::Wall } else { default });
        if self.controller_cpu.is_some() && clock != ClockArg::Virtual {
            bail!("--controller-cpu applies to --clock virtual (on the wall clock the controller's computation takes its own time)");
        }
        if self.compute_limit_s.is_some() && clock != ClockArg::Virtual {
            bail!("--compute-limit-s applies to --clock virtual (on the wall clock a computing controller holds nothing up)");
        }
        if self.preempt_after_ms.is_some() && clock != ClockArg::Virtual {
            bail!("--preempt-after-ms applies to --clock virtual (on the wall clock the kernel preempts the controller's threads)");
        }
        let time = match clock {
            ClockArg::Wall => TimeBase::Wall,
            ClockArg::Virtual => {
                if self.speed != 1.0 {
                    bail!("--speed {} applies to --clock wall: under --clock virtual a run goes as fast as the CPU allows", self.speed);
                }
                let defaults = VtSettings::default();
                TimeBase::Virtual(VtSettings {
                    syscall_ns: self.vt_syscall_ns,
                    spin_cap_ns: self.vt_spin_cap_us.saturating_mul(1000),
                    controller_cpu: self.controller_cpu.unwrap_or(0.0),
                    compute_limit: self.compute_limit_s.map_or(defaults.compute_limit, Duration::from_secs_f64),
                    preempt_after: self.preempt_after_ms.map_or(defaults.preempt_after, |ms| Duration::from_secs_f64(ms / 1e3)),
                    ..defaults
                })
            }
        };
        Ok(Pace { speed: self.speed, tolerance: Duration::from_secs_f64(self.pace_tolerance_ms / 1e3), time })
    }

    pub fn is_default(&self) -> bool {
        self.speed == 1.0
    }
}

/// The robot description `--robot` defaults to: the checkout's, from where climbsim is run (a
/// path compiled into the binary would point into the build machine); `CLIMBSIM_ROBOT` sets
/// another for every command.
pub const ROBOT_IN_CHECKOUT: &str = "hil/robot.toml";

/// Load the robot description at `path`, saying what to do when the default is not here.
pub fn load_robot(path: &Path) -> Result<RobotDescription> {
    load_robot_with(path, &RobotOverrides::default())
}

/// [`load_robot`] with `--set robot.…` and `--set profile.…` keys.
pub fn load_robot_with(path: &Path, overrides: &RobotOverrides) -> Result<RobotDescription> {
    let resolved = robot_path(path);
    // A bare name that is neither a file here nor a built-in robot: say which names there are.
    if !resolved.is_file() && !embedded::is_embedded(&resolved) && path.extension().is_none() && path.components().count() == 1 {
        let names: Vec<&str> = embedded::ROBOTS.iter().map(|(name, _)| *name).collect();
        bail!("--robot {}: no such file, and no robot climbsim has built in is called that (it has {})", path.display(), names.join(", "));
    }
    Ok(RobotDescription::load_with(&resolved, overrides)?)
}

/// The robot description `--robot` names. Its default, `hil/robot.toml`, is the checkout's
/// when climbsim runs in one (or a folder that has its own), else the one built into climbsim
/// (`embedded:hil/robot.toml`): an installed binary runs from any folder. A built-in robot's
/// name (`koch-follower`, `climber`) that is no file here names that robot.
pub fn robot_path(path: &Path) -> PathBuf {
    // A file wins over a name; a folder of that name does not. A named robot is the checkout's
    // description when it is here, else the one built in.
    if !path.is_file()
        && let Some(named) = path.to_str().and_then(embedded::robot_named)
    {
        let here = Path::new(named.path);
        return if here.is_file() { here.to_owned() } else { named.embedded_path() };
    }
    built_in_unless_here(path, ROBOT_IN_CHECKOUT, &embedded::ROBOT)
}

/// `path`, unless it is a flag's `default` and no such file is here: then the file climbsim
/// has built in for it.
pub fn built_in_unless_here(path: &Path, default: &str, built_in: &embedded::EmbeddedFile) -> PathBuf {
    if path == Path::new(default) && !path.exists() { built_in.embedded_path() } else { path.to_owned() }
}

/// The highest `--speed`: beyond it a firmware tick is shorter on the wall clock than a sleep.
const MAX_SPEED: f64 = 1000.0;

pub fn parse_speed(text: &str) -> Result<f64, String> {
    let speed: f64 = text.trim().parse().map_err(|_| format!("`{text}` is not a number (times real time)"))?;
    if !(speed.is_finite() && (0.01..=MAX_SPEED).contains(&speed)) {
        return Err(format!("{text} is outside 0.01-{MAX_SPEED} (times real time)"));
    }
    Ok(speed)
}

pub fn parse_controller_cpu(text: &str) -> Result<f64, String> {
    let factor: f64 = text.trim().parse().map_err(|_| format!("`{text}` is not a number (times this machine's CPU time)"))?;
    if !(factor.is_finite() && factor > 0.0 && factor <= 1000.0) {
        return Err(format!("{text} is outside (0, 1000] (times this machine's CPU time)"));
    }
    Ok(factor)
}

pub fn parse_compute_limit_s(text: &str) -> Result<f64, String> {
    let seconds: f64 = text.trim().parse().map_err(|_| format!("`{text}` is not a number of seconds (wall clock)"))?;
    if !(seconds.is_finite() && (1.0..=86_400.0).contains(&seconds)) {
        return Err(format!("{text} is outside 1-86400 (seconds of wall-clock time)"));
    }
    Ok(seconds)
}

pub fn parse_preempt_after_ms(text: &str) -> Result<f64, String> {
    let ms: f64 = text.trim().parse().map_err(|_| format!("`{text}` is not a number of milliseconds (CPU time)"))?;
    if !(ms.is_finite() && (ms == 0.0 || (1.0..=60_000.0).contains(&ms))) {
        return Err(format!("{text} ms is outside 1-60000 ms of CPU time (0: never preempt)"));
    }
    Ok(ms)
}

pub fn parse_tolerance_ms(text: &str) -> Result<f64, String> {
    let ms: f64 = text.trim().parse().map_err(|_| format!("`{text}` is not a number of milliseconds"))?;
    if !(ms.is_finite() && ms > 0.0 && ms <= 60_000.0) {
        return Err(format!("{text} ms is outside (0, 60000] ms"));
    }
    Ok(ms)
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum TimingArg {
    /// Replies arrive when a real bus would deliver them (Return Delay Time, bytes × 10 / baud).
    Wire,
    /// Replies as fast as possible.
    Off,
}

impl From<TimingArg> for Timing {
    fn from(timing: TimingArg) -> Self {
        match timing {
            TimingArg::Wire => Self::Wire,
            TimingArg::Off => Self::Off,
        }
    }
}

/// `--fault SPEC`, parsed by the code that reads a scenario's `fault` table.
pub fn parse_fault(spec: &str) -> Result<ScheduledFault, String> {
    ScheduledFault::parse(spec).map_err(|e| e.to_string())
}

/// A transcript replays the scenario's text; faults given on the command line are not in it.
pub fn refuse_recorded_cli_faults(faults: &[ScheduledFault], record: Option<&Path>) -> Result<()> {
    if !faults.is_empty() && record.is_some() {
        bail!("--fault and --record together: a replay rebuilds the scenario from its text, so put the faults in the scenario's [[events]] to record them");
    }
    Ok(())
}
