//! `climbsim tap`: record an unchanged controller on the real servos, until SIGINT or SIGTERM
//! or until the device goes away.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Result;

use climbsim::embedded::COMPARE_LAYOUT;
use climbsim::real_bus::compare::Tolerances;
use climbsim::runner::Console as _;
use climbsim::runner::compare::CompareOptions;
use climbsim::runner::tap::{TapOptions, beside_transcript, default_report_path, tap};
use climbsim::runner::tap_view::TapViewOptions;
use climbsim::runner::tap_world::TapWorldOptions;
use climbsim::runner::view::LiveAddress;

use super::args::{ROBOT_IN_CHECKOUT, load_robot, robot_path};
use super::compare::{say_report, verdict};
use super::console::Terminal;
use super::interrupt;
use super::run::parse_overrides;

/// Sit between your controller and the real servos and record the bus: the controller opens
/// `--link` as it would the adapter, every byte is forwarded both ways as soon as it is read,
/// unaltered, and the session is written as a real bus's transcript (each instruction with its
/// replies and their times, missed replies, CRC errors) with a timing report of the servos at
/// the end. The robot moves: the controller's commands reach it as they are.
#[derive(Debug, clap::Args)]
pub struct TapArgs {
    /// The serial device the servos are on (a USB–RS485 adapter: /dev/serial/by-id/…): opened
    /// exclusively, 8N1, no flow control.
    #[arg(long, value_name = "PATH")]
    pub device: PathBuf,
    /// The port your controller opens: a symlink to climbsim's pseudo-terminal.
    #[arg(long, value_name = "PATH")]
    pub link: PathBuf,
    /// The transcript to write (JSON lines).
    #[arg(long, value_name = "FILE")]
    pub record: PathBuf,
    /// The timing report to write (default: beside the transcript, NAME.timing.json).
    #[arg(long, value_name = "FILE")]
    pub report: Option<PathBuf>,
    /// The rate the device starts at, and the port until the controller sets its own (the
    /// device then follows the controller's rate).
    #[arg(long, value_name = "BPS", default_value = "57600")]
    pub baud: u32,
    /// Set the USB adapter's latency timer to 1 ms (FTDI's default is 16) and the tty's
    /// ASYNC_LOW_LATENCY flag while tapping; both are put back on exit.
    #[arg(long)]
    pub low_latency: bool,
    /// Show the real servos live in Foxglove: their registers as their read replies say, on
    /// `/servos` (the shipped layout's plots), every record on `/bus/packets`, missed replies
    /// and errors on `/log`; at 127.0.0.1:8765 or `--foxglove=ADDR`. With `--scenario`, that
    /// one connection shows the world re-enacting the session beside the real servos instead:
    /// the world's scene and servos, the real replies on `/compare/robot` and the world's
    /// answers to the same reads on `/compare/world` (the compare layout plots both).
    #[arg(long = "foxglove", value_name = "ADDR", num_args = 0..=1, require_equals = true, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<LiveAddress>,
    /// Record what `--foxglove` shows into FILE (MCAP).
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Robot description: the servos' names and control table, for `--foxglove` and `--mcap`,
    /// and the world's robot for `--scenario`.
    #[arg(long, env = "CLIMBSIM_ROBOT", value_name = "FILE", default_value = ROBOT_IN_CHECKOUT)]
    pub robot: PathBuf,
    /// Re-enact the session live in this scenario's world as it is recorded (each instruction
    /// at its instant, open loop, as `compare` does), and compare the world's answers with the
    /// real ones: when the tap ends, compare.json, the plots and compare.mcap go into
    /// `--compare-out`, and tap exits 1 if a register is past its tolerance (the transcript and
    /// the timing report are complete either way; `compare` can set other tolerances after).
    #[arg(long, value_name = "FILE")]
    pub scenario: Option<PathBuf>,
    /// Override a key of the world (repeatable, with `--scenario`): the scenario's, the robot
    /// description's (`robot.…`) or the firmware profile's (`profile.…`).
    #[arg(long = "set", value_name = "KEY=VALUE", requires = "scenario")]
    pub set: Vec<String>,
    /// Where `--scenario`'s comparison goes (default: beside the transcript, NAME.compare).
    #[arg(long, value_name = "DIR", requires = "scenario")]
    pub compare_out: Option<PathBuf>,
}

/// `--scenario`'s comparison (the shipped tolerances, into `--compare-out`), and where the
/// world is served live with `--foxglove`: at its address, the one connection of the session.
fn world_options(args: &TapArgs) -> Result<Option<TapWorldOptions>> {
    let Some(scenario) = &args.scenario else { return Ok(None) };
    let robot = robot_path(&args.robot);
    let out = args.compare_out.clone().unwrap_or_else(|| beside_transcript(&args.record, "compare"));
    let compare = CompareOptions { scenario: scenario.clone(), overrides: parse_overrides(&args.set)?, robot, tolerances: Tolerances::default(), out };
    Ok(Some(TapWorldOptions { compare, live: args.foxglove.clone() }))
}

pub fn exec(args: TapArgs) -> Result<()> {
    interrupt::install()?;
    let world = world_options(&args)?;
    let report = args.report.unwrap_or_else(|| default_report_path(&args.record));
    // With a world, the live connection is the world's (which shows the real replies too);
    // the tap's own view of the real servos is then only recorded (`--mcap`).
    let live = if world.is_some() { None } else { args.foxglove };
    let view = if live.is_some() || args.mcap.is_some() {
        let robot = load_robot(&args.robot)?;
        let names = robot.servo.iter().map(|s| (s.id, s.name.clone())).collect();
        Some(TapViewOptions { live, mcap: args.mcap, names, profile: Arc::new(robot.profile()?) })
    } else {
        None
    };
    let options = TapOptions { device: args.device, link: args.link, record: args.record, report, baud: args.baud, low_latency: args.low_latency, view, world };
    let outcome = tap(&options, interrupt::flag(), |ready| {
        Terminal.say(&format!("port: {}", ready.port.display()));
        if let Some(url) = ready.servos_url {
            Terminal.say(&format!("foxglove: {url}"));
        }
        if let Some(url) = ready.world_url {
            Terminal.say(&format!("foxglove: {url} (the world re-enacting the session beside the real servos: layout {})", COMPARE_LAYOUT.file_name()));
        }
    })?;
    Terminal.note(&format!(
        "tap ended ({}): {} bytes from the controller, {} from the servos; transcript {}, timing report {}",
        outcome.ended,
        outcome.from_controller,
        outcome.from_servos,
        options.record.display(),
        options.report.display()
    ));
    Terminal.note(&outcome.report.table());
    match (&outcome.comparison, &options.world) {
        (Some(comparison), Some(world)) => {
            say_report(&options.record, &world.compare.scenario, comparison);
            Terminal.say(&format!("wrote {}: compare.json, compare.mcap, plots/", world.compare.out.display()));
            verdict(comparison)
        }
        _ => Ok(()),
    }
}
