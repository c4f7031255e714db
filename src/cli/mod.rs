//! Command-line interface: `climbsim serve`, `run`, `check`, `sweep`, `replay` and `diff`.

mod batch;
mod controller;
mod device;
mod interrupt;
mod pacer;
mod realtime;
mod replay;

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use tracing::{info, warn};

use climbsim::bus::{Timing, TraceWriter};
use climbsim::fault::ScheduledFault;
use climbsim::robot::RobotDescription;
use climbsim::scenario::Scenario;
use climbsim::scenario::run::LiveRun;
use climbsim::scenario::view::{LiveAddress, ViewOptions};
use climbsim::transport::can::CanIds;
use climbsim::transport::{Adapter, AdapterModel, BusHandle, Clock, PhysicsPace, TcpServer, TimingReport, VirtualPort, parse_tcp_addr, serve_stream_through};

use pacer::Pacer;

/// How a command failed, for its exit code: 1 for a failed run, 130 for an interruption; any
/// other error (bad input, an unusable path or program) exits 2. `docs/exit-codes.md`.
#[derive(Debug, thiserror::Error)]
pub enum Verdict {
    /// A run failed: its `[expect]` thresholds, its controller, its world or its pace.
    #[error("{0}")]
    Failed(String),
    /// A signal stopped the work; the outputs cover the part that ran and say so.
    #[error("{0}")]
    Interrupted(String),
}

impl Verdict {
    pub fn exit_code(&self) -> u8 {
        match self {
            Self::Failed(_) => 1,
            Self::Interrupted(_) => 130,
        }
    }
}

/// `--foxglove[=ADDR]`, shared by `run` and `serve`.
#[derive(Debug, Clone, clap::Args)]
pub struct FoxgloveArgs {
    /// Show the world live in Foxglove: serve Foxglove's WebSocket protocol at 127.0.0.1:8765,
    /// or at `--foxglove=ADDR` (PORT, HOST or HOST:PORT; only this machine can connect unless a
    /// host is given). In Foxglove: Open connection → Foxglove WebSocket. A built-in
    /// controller's run then keeps to real time (or --speed N times it) for the watcher.
    #[arg(long = "foxglove", requires = "scenario", value_name = "ADDR", num_args = 0..=1, require_equals = true, default_missing_value = "127.0.0.1:8765")]
    address: Option<LiveAddress>,
}

/// `--speed` and `--pace-tolerance-ms`, shared by `run`, `check`, `sweep` and `serve`.
#[derive(Debug, Clone, Copy, clap::Args)]
pub struct PaceArgs {
    /// Run the world, the bus's wire timing and an external controller's clocks (libfaketime)
    /// at N times the wall clock, so an unchanged controller runs faster than real time.
    #[arg(long, value_name = "N", default_value = "1", value_parser = parse_speed)]
    speed: f64,
    /// Fail a wall-clock run whose world ticks or replies come later than this (simulated
    /// milliseconds, 99th percentile): the machine could not keep the pace. The default is
    /// under a real USB adapter's own delivery delay (an FTDI chip's 16 ms latency timer,
    /// which the official SDK's timeouts allow for twice over).
    #[arg(long, value_name = "MS", default_value = "10", value_parser = parse_tolerance_ms)]
    pace_tolerance_ms: f64,
}

impl PaceArgs {
    fn pace(&self) -> realtime::Pace {
        realtime::Pace { speed: self.speed, tolerance: Duration::from_secs_f64(self.pace_tolerance_ms / 1e3) }
    }

    fn is_default(&self) -> bool {
        self.speed == 1.0
    }
}

/// The robot description `--robot` defaults to: the checkout's, from where climbsim is run (a
/// path compiled into the binary would point into the build machine); `CLIMBSIM_ROBOT` sets
/// another for every command.
const ROBOT_IN_CHECKOUT: &str = "hil/robot.toml";

/// Load the robot description at `path`, saying what to do when the default is not here.
fn load_robot(path: &Path) -> Result<RobotDescription> {
    if path == Path::new(ROBOT_IN_CHECKOUT) && !path.exists() {
        bail!("robot description {ROBOT_IN_CHECKOUT} not found from {}: run climbsim from its checkout, or pass --robot FILE or set CLIMBSIM_ROBOT", std::env::current_dir().map(|d| d.display().to_string()).unwrap_or_else(|_| "here".to_owned()));
    }
    Ok(RobotDescription::load(path)?)
}

/// The highest `--speed`: beyond it a firmware tick is shorter on the wall clock than a sleep.
const MAX_SPEED: f64 = 1000.0;

fn parse_speed(text: &str) -> Result<f64, String> {
    let speed: f64 = text.trim().parse().map_err(|_| format!("`{text}` is not a number (times real time)"))?;
    if !(speed.is_finite() && (0.01..=MAX_SPEED).contains(&speed)) {
        return Err(format!("{text} is outside 0.01-{MAX_SPEED} (times real time)"));
    }
    Ok(speed)
}

fn parse_tolerance_ms(text: &str) -> Result<f64, String> {
    let ms: f64 = text.trim().parse().map_err(|_| format!("`{text}` is not a number of milliseconds"))?;
    if !(ms.is_finite() && ms > 0.0 && ms <= 60_000.0) {
        return Err(format!("{text} ms is outside (0, 60000] ms"));
    }
    Ok(ms)
}

#[derive(Debug, Parser)]
#[command(name = "climbsim", version, about = "Hardware-in-the-loop simulator for a magnetic wall-climbing welding robot")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum TimingArg {
    /// Replies arrive when a real bus would deliver them (Return Delay Time, bytes × 10 / baud).
    Wire,
    /// Replies as fast as possible.
    Off,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum AdapterArg {
    /// Replies reach the controller as they arrive.
    Ideal,
    /// ROBOTIS U2D2 (FTDI FT232H): USB packets of 62 bytes, latency timer 16 ms unless
    /// --latency-timer-ms.
    U2d2,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum EchoArg {
    /// Drop what comes back if it is exactly what was sent.
    Auto,
    /// The device echoes every send: drop it (and count sends whose echo did not come).
    On,
    /// Never drop anything.
    Off,
}

impl From<EchoArg> for climbsim::transport::Echo {
    fn from(arg: EchoArg) -> Self {
        match arg {
            EchoArg::Auto => Self::Auto,
            EchoArg::On => Self::On,
            EchoArg::Off => Self::Off,
        }
    }
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Emulate the robot's eight servos on a virtual serial port (and optionally TCP).
    Serve {
        /// Scenario file: serve the robot in that world. Without one the servos sit on the bench
        /// (each drives only its own rotor).
        scenario: Option<PathBuf>,
        /// Also create this symlink to the port (a stable name for your controller's config).
        #[arg(long)]
        link: Option<PathBuf>,
        /// Also listen for controllers on TCP: PORT or HOST:PORT (a bare port binds 127.0.0.1).
        #[arg(long, value_parser = parse_tcp_addr)]
        tcp: Option<std::net::SocketAddr>,
        /// Also connect to a controller that is a TCP server, HOST:PORT (firmware in QEMU with
        /// `-serial tcp::PORT,server`, Renode's server socket terminal, ser2net), and reconnect
        /// whenever it goes away.
        #[arg(long, value_name = "HOST:PORT", value_parser = parse_tcp_addr)]
        tcp_connect: Option<std::net::SocketAddr>,
        /// Also serve the bus on this SocketCAN interface (e.g. can0, vcan0): each Dynamixel
        /// packet is one ISO-TP (ISO 15765-2) message. Linux, `can` feature.
        #[arg(long, value_name = "IFACE")]
        can: Option<String>,
        /// The bus's CAN ID pair: REQUEST,RESPONSE (controller to bus, bus to controller).
        /// Up to 0x7FF an 11-bit ID, above a 29-bit one.
        #[arg(long, value_name = "REQ,RESP", value_parser = parse_can_ids, default_value = "0x7E0,0x7E8")]
        can_ids: CanIds,
        /// Pad every CAN frame the bus sends to 8 bytes with this byte, or `off` for the shortest
        /// frames. Received frames are accepted padded or not.
        #[arg(long, value_name = "BYTE|off", value_parser = parse_can_padding, default_value = "0xCC")]
        can_padding: CanPadding,
        /// Also serve the bus on this serial device (a USB–RS485/TTL adapter, a UART, an
        /// emulator's pty), with a real controller on its far side: opened exclusively, 8N1, no
        /// flow control, at the servos' baud, following them when the controller changes it.
        #[arg(long, value_name = "PATH")]
        device: Option<PathBuf>,
        /// Whether the device hears its own sends (half-duplex adapters, one-wire TTL):
        /// `auto` drops what comes back if it is exactly what was sent.
        #[arg(long, value_enum, default_value = "auto", requires = "device")]
        echo: EchoArg,
        /// Set the USB adapter's latency timer to 1 ms (FTDI's default is 16) and the tty's
        /// ASYNC_LOW_LATENCY flag while serving; both are put back on exit.
        #[arg(long, requires = "device")]
        low_latency: bool,
        /// Put the device (an on-chip UART wired to an RS-485 transceiver) into Linux's RS-485
        /// mode: the driver raises RTS (the transceiver's DE) while sending. USB–RS485 adapters
        /// switch by themselves and need none.
        #[arg(long, requires = "device")]
        rs485: bool,
        /// RTS delays before and after each send in RS-485 mode, in milliseconds.
        #[arg(long, value_name = "BEFORE,AFTER", value_parser = parse_rs485_delays, requires = "rs485")]
        rs485_delay_ms: Option<climbsim::transport::rs485::Rs485Delays>,
        /// Reply timing.
        #[arg(long, value_enum, default_value = "wire")]
        timing: TimingArg,
        /// The USB adapter the controller on the pty sits behind: `ideal` hands it each reply
        /// as it arrives; `u2d2` (an FTDI FT232H) holds bytes until 62 fill a USB packet or its
        /// latency timer expires, as the real one does (docs/hardware.md).
        #[arg(long, value_enum, default_value = "ideal")]
        adapter: AdapterArg,
        /// The modelled adapter's latency timer (Linux's default for FTDI chips is 16 ms).
        #[arg(long, value_name = "MS", value_parser = clap::value_parser!(u32).range(1..=255))]
        latency_timer_ms: Option<u32>,
        /// Write every bus transaction to this file as JSON lines.
        #[arg(long)]
        trace_bus: Option<PathBuf>,
        /// Robot description (servo IDs, firmware profile, power-on baud).
        #[arg(long, env = "CLIMBSIM_ROBOT", default_value = ROBOT_IN_CHECKOUT)]
        robot: PathBuf,
        /// Power-on baud of every servo, overriding the robot description.
        #[arg(long)]
        baud: Option<u32>,
        /// On exit write the timing report here (JSON: loop period and jitter, request→reply
        /// latencies, bus utilisation, collisions, unread replies, inter-byte gaps, watchdog
        /// expiries, physics overruns) and its plot beside it (STEM-latency.png/.svg).
        #[arg(long)]
        report: Option<PathBuf>,
        /// Inject a fault: KIND[:key=value,...] with `at`/`until` in seconds, e.g.
        /// `overload:id=2,at=5` or `late_replies:id=3,delay_ms=4,until=10` (repeatable; the keys
        /// of a scenario's `fault` table, see scenarios/README.md).
        #[arg(long = "fault", value_name = "SPEC", value_parser = parse_fault)]
        faults: Vec<ScheduledFault>,
        /// Record the session (packets, world ticks, sensor reads) for `climbsim replay`. Needs
        /// a scenario.
        #[arg(long, value_name = "FILE", requires = "scenario")]
        record: Option<PathBuf>,
        /// Record the world for Foxglove into FILE (MCAP: the robot, terrain, camera, signals,
        /// servos' registers, events). Needs a scenario.
        #[arg(long, value_name = "FILE", requires = "scenario")]
        mcap: Option<PathBuf>,
        #[command(flatten)]
        foxglove: FoxgloveArgs,
        #[command(flatten)]
        pace: PaceArgs,
    },
    /// Run a scenario and write its time series, summary, workbook and plots. A built-in
    /// controller runs in lockstep, faster than real time; an external one (`command = [...]`)
    /// is started with `DXL_PORT` and `CLIMBSIM_SENSORS` and runs in real time.
    Run {
        /// Scenario file (default: scenarios/flat-line.toml).
        #[arg(default_value = "scenarios/flat-line.toml")]
        scenario: PathBuf,
        /// Output folder (default: results/<scenario name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Override a scenario key, e.g. `--set controller.zeta=0.5` (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Reply timing on the pty (external controllers only; default wire).
        #[arg(long, value_enum)]
        timing: Option<TimingArg>,
        /// Also create this symlink to the pty (external controllers only).
        #[arg(long)]
        link: Option<PathBuf>,
        #[arg(long, env = "CLIMBSIM_ROBOT", default_value = ROBOT_IN_CHECKOUT)]
        robot: PathBuf,
        /// Inject a fault, as `serve --fault` (added to the scenario's events; repeatable).
        #[arg(long = "fault", value_name = "SPEC", value_parser = parse_fault)]
        faults: Vec<ScheduledFault>,
        /// Record the session (packets, world ticks, sensor reads) for `climbsim replay`
        /// (external controllers only: a built-in one is deterministic already).
        #[arg(long, value_name = "FILE")]
        record: Option<PathBuf>,
        #[command(flatten)]
        foxglove: FoxgloveArgs,
        #[command(flatten)]
        pace: PaceArgs,
    },
    /// Run scenarios and test their `[expect]` thresholds; exit non-zero if any fails.
    Check {
        /// Scenario files, or folders (their `*.toml` files that have an `[expect]` section).
        #[arg(required = true)]
        paths: Vec<PathBuf>,
        /// Also write JUnit XML here.
        #[arg(long)]
        junit: Option<PathBuf>,
        /// Root of the runs' output folders.
        #[arg(long, default_value = "results/check")]
        out: PathBuf,
        #[arg(long, env = "CLIMBSIM_ROBOT", default_value = ROBOT_IN_CHECKOUT)]
        robot: PathBuf,
        /// `--speed` applies to scenarios with an external controller; built-in ones always run
        /// in lockstep, as fast as the CPU allows.
        #[command(flatten)]
        pace: PaceArgs,
    },
    /// Re-enact a `--record` transcript without its controller: the same scenario, world ticks
    /// and instruction packets in lockstep, deterministically; writes the same outputs as `run`.
    Replay {
        /// The transcript.
        transcript: PathBuf,
        /// Output folder (default: results/replay/<transcript name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Scenario file (default: the recorded path).
        #[arg(long)]
        scenario: Option<PathBuf>,
        /// Robot description (default: the recorded path).
        #[arg(long)]
        robot: Option<PathBuf>,
        /// Replay even if the scenario, robot description or firmware profile differs from the
        /// recording's.
        #[arg(long)]
        force: bool,
    },
    /// Compare two runs (output folders, or their timeseries.csv / summary.json): max |A-B| per
    /// time-series column (aligned on t_s) and per summary metric; exit non-zero if any exceeds
    /// its tolerance. Defaults by unit: _m 1e-4, _rad 1e-3, _m_s 1e-4, _rad_s 1e-2, _n 0.5,
    /// _s 0.02, _pct 0.5, _fraction 5e-3, line_valid 0, others 1e-9; t_s (the span) 1.5 capture
    /// periods; realtime_factor and physics_overruns are not compared.
    Diff {
        a: PathBuf,
        b: PathBuf,
        /// Absolute tolerance of a column or metric (repeatable); `inf` ignores it.
        #[arg(long = "tolerance", value_name = "KEY=ABS")]
        tolerance: Vec<String>,
        /// Relative tolerance for every key: |A-B| <= R * max |value| also passes.
        #[arg(long, value_name = "R")]
        rel: Option<f64>,
    },
    /// Run a scenario over a grid of parameters (in parallel), or merge sweeps' shards.
    Sweep {
        /// Scenario file (not with --merge).
        #[arg(required_unless_present = "merge")]
        scenario: Option<PathBuf>,
        /// A swept key and its values: `controller.zeta=0.3,0.5,0.7` (repeatable: a grid).
        #[arg(long = "set", value_name = "KEY=V1,V2,...")]
        set: Vec<String>,
        /// Runs at once (default: the number of CPUs).
        #[arg(long)]
        jobs: Option<usize>,
        /// Run only slice K of N of the grid (1-based), for CI matrices and job arrays; `auto/N`
        /// takes K from SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX (0-based).
        #[arg(long, value_name = "K/N")]
        shard: Option<String>,
        /// Print the grid points (of this shard) instead of running them.
        #[arg(long, conflicts_with = "merge")]
        list: bool,
        /// With --list: one JSON document (index, label, overrides, shard) for scripts.
        #[arg(long, requires = "list")]
        json: bool,
        /// Merge these sweeps' output folders (their sweep.json) instead of running.
        #[arg(long, num_args = 1.., conflicts_with_all = ["scenario", "set", "shard"])]
        merge: Vec<PathBuf>,
        /// With --merge: write the table even when grid points are missing or did not finish,
        /// and exit 0 (they are marked `not_run` / `interrupted` in it).
        #[arg(long, requires = "merge")]
        allow_incomplete: bool,
        /// Output folder (not needed with --list).
        #[arg(long, required_unless_present = "list")]
        out: Option<PathBuf>,
        /// Record `run.mcap` for every point too (off by default: a grid may have hundreds).
        #[arg(long)]
        mcap: bool,
        #[arg(long, env = "CLIMBSIM_ROBOT", default_value = ROBOT_IN_CHECKOUT)]
        robot: PathBuf,
        /// For an external controller: each point on its own port, at this speed.
        #[command(flatten)]
        pace: PaceArgs,
    },
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Serve { scenario, link, tcp, tcp_connect, can, can_ids, can_padding, device, echo, low_latency, rs485, rs485_delay_ms, timing, adapter, latency_timer_ms, trace_bus, robot, baud, report, faults, record, mcap, foxglove, pace } => {
            let adapter = match (adapter, latency_timer_ms) {
                (AdapterArg::Ideal, Some(_)) => bail!("--latency-timer-ms is a setting of a modelled adapter: give --adapter u2d2 with it"),
                (AdapterArg::Ideal, None) => Adapter::Ideal,
                (AdapterArg::U2d2, ms) => Adapter::u2d2(ms),
            };
            let can = can.map(|iface| CanOptions { iface, ids: can_ids, padding: can_padding.0 });
            let rs485 = rs485.then(|| rs485_delay_ms.unwrap_or_default());
            let device = device.map(|path| device::DeviceOptions { path, echo: echo.into(), low_latency, rs485 });
            let view = ViewOptions { mcap, live: foxglove.address, packets: false };
            let options = ServeOptions { scenario, link, tcp, tcp_connect, can, device, timing, adapter, trace_bus, baud, report, faults, record, view, pace };
            serve(options, &robot)
        }
        Command::Run { scenario, out, set, timing, link, robot, faults, record, foxglove: FoxgloveArgs { address: foxglove }, pace } => {
            interrupt::install()?;
            refuse_recorded_cli_faults(&faults, record.as_deref())?;
            let robot = load_robot(&robot)?;
            let overrides = batch::parse_overrides(&set)?;
            let mut loaded = Scenario::load_with(&scenario, &overrides)?;
            add_fault_events(&mut loaded, faults);
            let out_dir = out.unwrap_or_else(|| batch::default_out_dir(&scenario));
            // Every output path is checked before minutes of simulation, not after.
            batch::preflight_dir(&out_dir, "--out")?;
            if let Some(path) = &record {
                batch::preflight_file(path, "--record")?;
            }
            let outcome = match &loaded.controller {
                climbsim::scenario::ControllerSection::Builtin(_) => {
                    // Flags that only an external controller's wall-clock run uses are refused,
                    // not silently ignored.
                    let ignored = [(record.is_some(), "--record (a built-in controller's run is deterministic already: run it again)"), (link.is_some(), "--link (a built-in controller has no port)"), (timing.is_some(), "--timing (a built-in controller talks to the bus in lockstep)"), (!pace.is_default() && foxglove.is_none(), "--speed (a built-in controller runs in lockstep, as fast as the CPU allows; with --foxglove it keeps to --speed for the watcher)")];
                    if let Some((_, flag)) = ignored.iter().find(|(given, _)| *given) {
                        anyhow::bail!("{}: the scenario's controller is built in, so {flag}", scenario.display());
                    }
                    let live = foxglove.map(|address| LiveRun { address, speed: pace.speed, announce: announce_foxglove });
                    batch::run_builtin(&loaded, &robot, &out_dir, live.as_ref())?
                }
                climbsim::scenario::ControllerSection::External(external) => {
                    let record = record.map(|path| replay::RecordSpec { path, overrides: set.clone() });
                    let options = realtime::ExternalRun { timing: timing_of(timing.unwrap_or(TimingArg::Wire)), link: link.as_deref(), record: record.as_ref(), pace: pace.pace(), announce: true, live: foxglove };
                    realtime::run_external(&loaded, external, &robot, &options, &out_dir)?
                }
            };
            batch::print_summary(&outcome, &out_dir);
            let mut failures = climbsim::scenario::run::failures(&outcome.summary);
            failures.extend(loaded.failed_expectations(&outcome.summary));
            if !failures.is_empty() {
                return Err(Verdict::Failed(format!("the run failed ({} in {}):\n  {}", failures.len(), out_dir.display(), failures.join("\n  "))).into());
            }
            Ok(())
        }
        Command::Check { paths, junit, out, robot, pace } => {
            interrupt::install()?;
            let robot = load_robot(&robot)?;
            batch::preflight_dir(&out, "--out")?;
            if let Some(path) = &junit {
                batch::preflight_file(path, "--junit")?;
            }
            batch::check(&paths, &robot, &out, junit.as_deref(), pace.pace())
        }
        Command::Replay { transcript, out, scenario, robot, force } => replay::replay_command(&transcript, out, &climbsim::scenario::replay::ReplaySources { scenario, robot, force }),
        Command::Diff { a, b, tolerance, rel } => replay::diff_command(&a, &b, &tolerance, rel),
        Command::Sweep { scenario, set, jobs, shard, list, json, merge, allow_incomplete, out, mcap, robot, pace } => {
            let axes = climbsim::scenario::sweep::Axis::parse_all(&set)?;
            let shard = shard.as_deref().map(climbsim::scenario::sweep::Shard::parse).transpose()?.unwrap_or(climbsim::scenario::sweep::Shard::ALL);
            if list {
                return batch::list_sweep(&axes, shard, json);
            }
            let out = out.context("--out is needed")?;
            interrupt::install()?;
            batch::preflight_dir(&out, "--out")?;
            if !merge.is_empty() {
                return batch::merge(&merge, &out, allow_incomplete);
            }
            let robot = load_robot(&robot)?;
            let scenario = scenario.context("a scenario file is needed")?;
            let jobs = jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from));
            batch::sweep(&scenario, &batch::SweepPlan { axes: &axes, jobs, shard, pace: pace.pace(), record_mcap: mcap }, &robot, &out)
        }
    }
}

fn timing_of(timing: TimingArg) -> Timing {
    match timing {
        TimingArg::Wire => Timing::Wire,
        TimingArg::Off => Timing::Off,
    }
}

fn parse_can_ids(text: &str) -> Result<CanIds, String> {
    CanIds::parse(text).map_err(|e| e.to_string())
}

/// `--can-padding`: a byte, or `off`.
#[derive(Debug, Clone, Copy)]
pub struct CanPadding(Option<u8>);

fn parse_can_padding(text: &str) -> Result<CanPadding, String> {
    if text.eq_ignore_ascii_case("off") || text.eq_ignore_ascii_case("none") {
        return Ok(CanPadding(None));
    }
    let byte = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u8::from_str_radix(hex, 16),
        None => text.parse::<u8>(),
    };
    byte.map(|b| CanPadding(Some(b))).map_err(|_| format!("`{text}` is not a byte (0x00-0xFF) or `off`"))
}

#[derive(Debug, Clone)]
#[cfg_attr(not(all(feature = "can", target_os = "linux")), allow(dead_code))]
struct CanOptions {
    iface: String,
    ids: CanIds,
    padding: Option<u8>,
}

struct ServeOptions {
    scenario: Option<PathBuf>,
    link: Option<PathBuf>,
    tcp: Option<std::net::SocketAddr>,
    tcp_connect: Option<std::net::SocketAddr>,
    can: Option<CanOptions>,
    device: Option<device::DeviceOptions>,
    timing: TimingArg,
    adapter: Adapter,
    trace_bus: Option<PathBuf>,
    baud: Option<u32>,
    report: Option<PathBuf>,
    faults: Vec<ScheduledFault>,
    record: Option<PathBuf>,
    view: ViewOptions,
    pace: PaceArgs,
}

/// `--rs485-delay-ms BEFORE,AFTER` (milliseconds, whole numbers up to 1000).
fn parse_rs485_delays(text: &str) -> Result<climbsim::transport::rs485::Rs485Delays, String> {
    let (before, after) = text.split_once(',').ok_or_else(|| format!("`{text}` is not BEFORE,AFTER (milliseconds, e.g. 0,1)"))?;
    let ms = |part: &str| part.trim().parse::<u32>().ok().filter(|&ms| ms <= 1000).ok_or_else(|| format!("`{part}` is not a whole number of milliseconds in 0..=1000"));
    Ok(climbsim::transport::rs485::Rs485Delays { before_send_ms: ms(before)?, after_send_ms: ms(after)? })
}

/// `--fault SPEC`, parsed by the code that reads a scenario's `fault` table.
fn parse_fault(spec: &str) -> Result<ScheduledFault, String> {
    ScheduledFault::parse(spec).map_err(|e| e.to_string())
}

/// Append `--fault` faults to a scenario as events.
fn add_fault_events(scenario: &mut Scenario, faults: Vec<ScheduledFault>) {
    scenario.events.extend(faults.into_iter().map(|f| climbsim::scenario::Event {
        at_s: f.at_s,
        set_speed_mm_min: None,
        line_offset_m: None,
        magnets: None,
        fault: Some(f.fault),
        until_s: f.until_s,
    }));
}

/// A transcript replays the scenario's text; faults given on the command line are not in it.
fn refuse_recorded_cli_faults(faults: &[ScheduledFault], record: Option<&std::path::Path>) -> Result<()> {
    if !faults.is_empty() && record.is_some() {
        anyhow::bail!("--fault and --record together: a replay rebuilds the scenario from its text, so put the faults in the scenario's [[events]] to record them");
    }
    Ok(())
}

fn serve(options: ServeOptions, robot_path: &std::path::Path) -> Result<()> {
    let ServeOptions { scenario, link, tcp, tcp_connect, can, device, timing, adapter, trace_bus, baud, report, faults, record, view, pace } = options;
    refuse_recorded_cli_faults(&faults, record.as_deref())?;
    if !pace.is_default() && can.is_some() {
        anyhow::bail!("--speed with --can: a CAN bus is a real bus whose other nodes keep real time; serve it at --speed 1");
    }
    if !pace.is_default() && device.is_some() {
        anyhow::bail!("--speed with --device: the controller on a serial device keeps real time; serve it at --speed 1");
    }
    for (path, flag) in [(&report, "--report"), (&trace_bus, "--trace-bus"), (&record, "--record")] {
        if let Some(path) = path {
            batch::preflight_file(path, flag)?;
        }
    }
    // Said before anything starts: a controller must be started with these to keep the pace.
    let faketime = if pace.is_default() { None } else { Some(controller::faketime_env(pace.speed).with_context(|| format!("--speed {}", pace.speed))?) };
    let robot = load_robot(robot_path)?;
    if let Some(bps) = baud {
        robot.servos(Some(bps)).with_context(|| format!("--baud {bps}"))?;
    }
    let timing = timing_of(timing);
    let world_on_wall_clock = scenario.is_some();
    // A world gets its observer (the camera and line detector when it has a weld line), the
    // sensor server and, if asked, the Foxglove view.
    let (bus, observer, recorder) = match &scenario {
        Some(path) => {
            let mut loaded = Scenario::load(path)?;
            add_fault_events(&mut loaded, faults);
            let (bus, observer) = realtime::scenario_bus(&loaded, &robot, timing, baud)?;
            let spec = record.map(|path| replay::RecordSpec { path, overrides: Vec::new() });
            let recorder = spec.map(|spec| replay::start_recording(&spec, "serve", &loaded, &robot, &bus, baud)).transpose()?;
            // `serve` writes no time series: a session may last for days.
            let (mut bus, mut observer) = (bus, observer);
            observer.discard_rows();
            let view = ViewOptions { packets: loaded.capture.bus_packets, ..view };
            if let Some(url) = observer.start_view(&view, &mut bus)? {
                announce_foxglove(&url);
            }
            let observer = Some(Arc::new(std::sync::Mutex::new(observer)));
            (bus, observer, recorder)
        }
        None => {
            let mut bus = robot.bench_bus(timing, baud)?;
            // The bench has no scenario seed: its faults draw from seed 0.
            bus.set_faults(climbsim::bus::BusFaults::new(faults, 0));
            (bus, None, None)
        }
    };
    let trace = match &trace_bus {
        Some(path) => {
            let file = std::fs::File::create(path).with_context(|| format!("cannot create bus trace {}", path.display()))?;
            Some(TraceWriter::new(Box::new(std::io::BufWriter::new(file))))
        }
        None => None,
    };
    let handle = BusHandle::with_clock(bus, trace, recorder, Clock::scaled(pace.speed));
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    runtime.block_on(async move {
        let port = Arc::new(VirtualPort::open(link.as_deref())?);
        let tcp_server = match tcp {
            Some(addr) => Some(TcpServer::bind(addr).await.with_context(|| format!("cannot listen on {addr}"))?),
            None => None,
        };
        // The CAN socket is open (and hears requests) before the port is announced.
        let can_thread = match &can {
            Some(options) => Some(start_can(options.clone(), Arc::clone(&handle)).await?),
            None => None,
        };
        let device_thread = match &device {
            Some(options) => Some(device::start_device(options.clone(), Arc::clone(&handle)).await?),
            None => None,
        };
        // The handlers are in place before the port is announced: a supervisor that stops
        // climbsim as soon as it has printed its port must still get a clean shutdown.
        use tokio::signal::unix::{SignalKind, signal};
        let (mut interrupt, mut terminate) = (signal(SignalKind::interrupt())?, signal(SignalKind::terminate())?);
        let mut stdout = std::io::stdout().lock();
        writeln!(stdout, "port: {}", port.path().display())?;
        if let Some(server) = &tcp_server {
            writeln!(stdout, "tcp: {}", server.local_addr()?)?;
        }
        if let Some(addr) = tcp_connect {
            climbsim::transport::connect_forever(addr, Arc::clone(&handle))?;
            writeln!(stdout, "tcp-connect: {addr}")?;
        }
        if let Some(options) = &can {
            writeln!(stdout, "can: {} request {} response {}", options.iface, options.ids.request, options.ids.response)?;
        }
        if let (Some(options), Some(service)) = (&device, &device_thread) {
            writeln!(stdout, "device: {} at {} bps", options.path.display(), service.baud)?;
        }
        if let Some(env) = &faketime {
            let assignments: Vec<String> = env.iter().map(|(k, v)| format!("{k}='{v}'")).collect();
            writeln!(stdout, "speed: {}x; start your controller with its clocks scaled alike: {} <command>", pace.speed, assignments.join(" "))?;
        }
        stdout.flush()?;
        drop(stdout);

        // The pty gets its own thread: precise reply timing spins, and must not stall anything.
        let pty_handle = Arc::clone(&handle);
        let pty_port = Arc::clone(&port);
        let pty_thread = std::thread::Builder::new().name("pty".into()).spawn(move || -> Result<()> {
            let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
            // Spawned, not run in `block_on`: a spawned task's I/O wake-ups stay in the scheduler's
            // local queue, while a `block_on` future is woken through the driver's eventfd, which
            // costs two extra syscalls and an extra epoll round per packet.
            runtime.block_on(async move { tokio::spawn(serve_pty(pty_port, pty_handle, adapter)).await? })
        })?;
        // A world runs on the wall clock: a pacer advances it every firmware tick against
        // absolute deadlines, so it moves between packets too (packets advance it as well). The
        // bench needs none: its servos are brought up to date exactly when a packet arrives.
        let pacer = match observer.clone() {
            Some(observer) => {
                let feed = Arc::new(climbsim::sensor_server::SensorFeed::default());
                replay::record_sensor_reads(&handle, &feed);
                let url = realtime::start_sensor_server(Arc::clone(&feed)).await?;
                println!("sensors: {url}");
                std::io::stdout().flush()?;
                let errors = Arc::new(std::sync::Mutex::new(None));
                Some(Pacer::start_with(Arc::clone(&handle), realtime::observer_hook(observer, feed, errors)))
            }
            None => world_on_wall_clock.then(|| Pacer::start(Arc::clone(&handle))),
        };
        if let Some(server) = tcp_server {
            let tcp_handle = Arc::clone(&handle);
            tokio::spawn(async move {
                if let Err(error) = server.run(tcp_handle).await {
                    warn!(%error, "TCP listener stopped");
                }
            });
        }
        tokio::select! {
            _ = interrupt.recv() => info!("SIGINT: shutting down"),
            _ = terminate.recv() => info!("SIGTERM: shutting down"),
        }
        if pty_thread.is_finished() {
            warn!("the pty session had stopped before shutdown");
        }
        if can_thread.as_ref().is_some_and(|thread| thread.is_finished()) {
            warn!("the CAN session had stopped before shutdown");
        }
        if device_thread.as_ref().is_some_and(device::DeviceService::is_finished) {
            warn!("the device session had stopped before shutdown");
        }
        if let Some(service) = device_thread {
            service.stop();
        }
        // Let the controller read the last reply before the master closes.
        port.drain(Duration::from_secs(1)).await;
        let mut pace_kept = PhysicsPace::default();
        if let Some(pacer) = pacer {
            pace_kept = pacer.stop();
            info!(ticks = pace_kept.ticks, overruns = pace_kept.overruns, "world pacing: firmware ticks run on the wall clock, deadlines missed");
            if pace_kept.overruns > 0 {
                eprintln!("climbsim: the world missed {} of {} wall-clock deadlines (it ran slower than {}x real time)", pace_kept.overruns, pace_kept.ticks, pace.speed);
            }
        }
        let timing_report = finish_timing_report(&handle, &pace_kept, report.as_deref())?;
        for problem in timing_report.pace_problems(pace.pace().tolerance) {
            eprintln!("climbsim: {problem}");
        }
        replay::finish_recording(&handle, &pace_kept)?;
        if let Some(observer) = observer {
            observer.lock().unwrap_or_else(std::sync::PoisonError::into_inner).finish_view()?;
        }
        Ok::<_, anyhow::Error>(port)
    })
    .map(|port| port.remove_link())
}

/// Print the session's timing summary and, if asked, write the report and its plot.
fn finish_timing_report(handle: &BusHandle, pace: &PhysicsPace, path: Option<&std::path::Path>) -> Result<TimingReport> {
    let report = handle.timing_report(pace);
    eprintln!("{}", report.human_summary());
    if let Some(path) = path {
        let files = climbsim::report::write_timing_report(path, &report).with_context(|| format!("cannot write the timing report {}", path.display()))?;
        for file in files {
            eprintln!("  wrote {}", file.display());
        }
    }
    Ok(report)
}

/// Open the CAN interface on a thread of its own (precise reply timing spins, like the pty's) and
/// serve the bus there; returns once the socket is open.
#[cfg(all(feature = "can", target_os = "linux"))]
async fn start_can(options: CanOptions, handle: Arc<BusHandle>) -> Result<std::thread::JoinHandle<()>> {
    use climbsim::transport::can::{SocketCanPort, isotp, serve_can};
    let (opened_tx, opened_rx) = tokio::sync::oneshot::channel();
    let thread = std::thread::Builder::new().name("can".into()).spawn(move || {
        let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
            Ok(runtime) => runtime,
            Err(error) => return drop(opened_tx.send(Err(anyhow::Error::from(error)))),
        };
        runtime.block_on(async move {
            // The socket registers with this thread's runtime, so it is opened here.
            let port = match SocketCanPort::open(&options.iface, options.ids.request) {
                Ok(port) => port,
                Err(error) => return drop(opened_tx.send(Err(error.into()))),
            };
            let _ = opened_tx.send(Ok(()));
            let config = isotp::Config { padding: options.padding, ..isotp::Config::default() };
            let session = tokio::spawn(serve_can(port, options.ids, config, handle));
            match session.await {
                Ok(Ok(())) => info!(iface = options.iface, "CAN session ended"),
                Ok(Err(error)) => warn!(iface = options.iface, %error, "CAN session ended"),
                Err(error) => warn!(iface = options.iface, %error, "CAN session failed"),
            }
        });
    })?;
    opened_rx.await.context("the CAN thread ended before opening its socket")??;
    Ok(thread)
}

#[cfg(not(all(feature = "can", target_os = "linux")))]
async fn start_can(_options: CanOptions, _handle: Arc<BusHandle>) -> Result<std::thread::JoinHandle<()>> {
    anyhow::bail!("--can needs SocketCAN: this climbsim was built without the `can` feature or not for Linux")
}

/// Serve the pty until the process ends, the controller behind `adapter`. The port outlives
/// every controller connection.
async fn serve_pty(port: Arc<VirtualPort>, handle: Arc<BusHandle>, adapter: Adapter) -> Result<()> {
    let line = port.line();
    let spin_for_requests = handle.with_bus(|bus| bus.timing()) == Timing::Off;
    serve_stream_through(port.stream(spin_for_requests)?, handle, &line, AdapterModel::new(adapter)).await?;
    Ok(())
}

/// Where a built-in controller's live run is watched (printed before the run starts).
fn announce_foxglove(url: &str) {
    println!("foxglove: {url}");
    let _ = std::io::Write::flush(&mut std::io::stdout());
}
