//! `climbsim serve`: the servos on a pty (and TCP, CAN, a serial device), on the bench or in a
//! scenario's world, until SIGINT or SIGTERM.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::ValueEnum;

use climbsim::fault::ScheduledFault;
use climbsim::runner::serve::can::CanOptions;
use climbsim::runner::serve::device::DeviceOptions;
use climbsim::runner::serve::{ServeOptions, Transports, serve};
use climbsim::runner::view::ViewOptions;
use climbsim::transport::can::CanIds;
use climbsim::transport::{Adapter, parse_tcp_addr, parse_tcp_server_addr};

use super::args::{FoxgloveArgs, PaceArgs, ROBOT_IN_CHECKOUT, TimingArg, load_robot_with, parse_fault, refuse_recorded_cli_faults};
use super::console::Terminal;
use super::interrupt;

/// Emulate the robot's eight servos on a virtual serial port (and optionally TCP).
#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// Scenario file: serve the robot in that world. Without one the servos sit on the bench
    /// (each drives only its own rotor).
    pub scenario: Option<PathBuf>,
    /// Also create this symlink to the port (a stable name for your controller's config).
    #[arg(long)]
    pub link: Option<PathBuf>,
    /// Also listen for controllers on TCP: PORT or HOST:PORT (a bare port binds 127.0.0.1).
    #[arg(long, value_parser = parse_tcp_addr)]
    pub tcp: Option<std::net::SocketAddr>,
    /// Also connect to a controller that is a TCP server, HOST:PORT (firmware in QEMU with
    /// `-serial tcp::PORT,server`, Renode's server socket terminal, ser2net), and reconnect
    /// whenever it goes away.
    #[arg(long, value_name = "HOST:PORT", value_parser = parse_tcp_server_addr)]
    pub tcp_connect: Option<std::net::SocketAddr>,
    /// Also serve the bus on this SocketCAN interface (e.g. can0, vcan0): each Dynamixel
    /// packet is one ISO-TP (ISO 15765-2) message. Linux, `can` feature.
    #[arg(long, value_name = "IFACE")]
    pub can: Option<String>,
    /// The bus's CAN ID pair: REQUEST,RESPONSE (controller to bus, bus to controller).
    /// Up to 0x7FF an 11-bit ID, above a 29-bit one.
    #[arg(long, value_name = "REQ,RESP", value_parser = parse_can_ids, default_value = "0x7E0,0x7E8")]
    pub can_ids: CanIds,
    /// Pad every CAN frame the bus sends to 8 bytes with this byte, or `off` for the shortest
    /// frames. Received frames are accepted padded or not.
    #[arg(long, value_name = "BYTE|off", value_parser = parse_can_padding, default_value = "0xCC")]
    pub can_padding: CanPadding,
    /// Also serve the bus on this serial device (a USB–RS485/TTL adapter, a UART, an
    /// emulator's pty), with a real controller on its far side: opened exclusively, 8N1, no
    /// flow control, at the servos' baud, following them when the controller changes it.
    #[arg(long, value_name = "PATH")]
    pub device: Option<PathBuf>,
    /// Whether the device hears its own sends (half-duplex adapters, one-wire TTL):
    /// `auto` drops what comes back if it is exactly what was sent.
    #[arg(long, value_enum, default_value = "auto", requires = "device")]
    pub echo: EchoArg,
    /// Set the USB adapter's latency timer to 1 ms (FTDI's default is 16) and the tty's
    /// ASYNC_LOW_LATENCY flag while serving; both are put back on exit.
    #[arg(long, requires = "device")]
    pub low_latency: bool,
    /// Put the device (an on-chip UART wired to an RS-485 transceiver) into Linux's RS-485
    /// mode: the driver raises RTS (the transceiver's DE) while sending. USB–RS485 adapters
    /// switch by themselves and need none.
    #[arg(long, requires = "device")]
    pub rs485: bool,
    /// RTS delays before and after each send in RS-485 mode, in milliseconds.
    #[arg(long, value_name = "BEFORE,AFTER", value_parser = parse_rs485_delays, requires = "rs485")]
    pub rs485_delay_ms: Option<climbsim::transport::rs485::Rs485Delays>,
    /// Reply timing.
    #[arg(long, value_enum, default_value = "wire")]
    pub timing: TimingArg,
    /// The USB adapter the controller on the pty sits behind: `ideal` hands it each reply
    /// as it arrives; `u2d2` (an FTDI FT232H) holds bytes until 62 fill a USB packet or its
    /// latency timer expires, as the real one does (docs/hardware.md).
    #[arg(long, value_enum, default_value = "ideal")]
    pub adapter: AdapterArg,
    /// The modelled adapter's latency timer (Linux's default for FTDI chips is 16 ms).
    #[arg(long, value_name = "MS", value_parser = clap::value_parser!(u32).range(1..=255))]
    pub latency_timer_ms: Option<u32>,
    /// Write every bus transaction to this file as JSON lines.
    #[arg(long)]
    pub trace_bus: Option<PathBuf>,
    /// Robot description (servo IDs, firmware profiles, power-on baud), or a built-in robot by
    /// name: `climber` (the default), `koch-follower` or `koch-leader` (LeRobot's arms, their
    /// buses on the bench).
    #[arg(long, env = "CLIMBSIM_ROBOT", default_value = ROBOT_IN_CHECKOUT)]
    pub robot: PathBuf,
    /// Override a key (repeatable): the scenario's (`world.seed=2`), the robot description's
    /// (`robot.wheel.friction=0.35`) or the firmware profile's
    /// (`profile.motor.coulomb_friction_nm=0.04`). On the bench, only the last two.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Power-on baud of every servo, overriding the robot description.
    #[arg(long)]
    pub baud: Option<u32>,
    /// On exit write the timing report here (JSON: loop period and jitter, request→reply
    /// latencies, bus utilisation, collisions, unread replies, inter-byte gaps, watchdog
    /// expiries, physics overruns) and its plot beside it (STEM-latency.png/.svg).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Inject a fault: KIND[:key=value,...] with `at`/`until` in seconds, e.g.
    /// `overload:id=2,at=5` or `late_replies:id=3,delay_ms=4,until=10` (repeatable; the keys
    /// of a scenario's `fault` table, see scenarios/README.md).
    #[arg(long = "fault", value_name = "SPEC", value_parser = parse_fault)]
    pub faults: Vec<ScheduledFault>,
    /// Record the session (packets, world ticks, sensor reads) for `climbsim replay`. Needs
    /// a scenario.
    #[arg(long, value_name = "FILE", requires = "scenario")]
    pub record: Option<PathBuf>,
    /// Record the world for Foxglove into FILE (MCAP: the robot, terrain, camera, signals,
    /// servos' registers, events). Needs a scenario.
    #[arg(long, value_name = "FILE", requires = "scenario")]
    pub mcap: Option<PathBuf>,
    #[command(flatten)]
    pub foxglove: FoxgloveArgs,
    #[command(flatten)]
    pub pace: PaceArgs,
}

pub fn exec(args: ServeArgs) -> Result<()> {
    let ServeArgs {
        scenario,
        link,
        tcp,
        tcp_connect,
        can,
        can_ids,
        can_padding,
        device,
        echo,
        low_latency,
        rs485,
        rs485_delay_ms,
        timing,
        adapter,
        latency_timer_ms,
        trace_bus,
        robot,
        set,
        baud,
        report,
        faults,
        record,
        mcap,
        foxglove,
        pace,
    } = args;
    interrupt::install()?;
    let adapter = match (adapter, latency_timer_ms) {
        (AdapterArg::Ideal, Some(_)) => bail!("--latency-timer-ms is a setting of a modelled adapter: give --adapter u2d2 with it"),
        (AdapterArg::Ideal, None) => Adapter::Ideal,
        (AdapterArg::U2d2, ms) => Adapter::u2d2(ms),
    };
    refuse_recorded_cli_faults(&faults, record.as_deref())?;
    for (path, flag) in [(&report, "--report"), (&trace_bus, "--trace-bus"), (&record, "--record")] {
        if let Some(path) = path {
            climbsim::runner::preflight_file(path, flag)?;
        }
    }
    let transports = Transports {
        link,
        adapter,
        tcp,
        tcp_connect,
        can: can.map(|iface| CanOptions { iface, ids: can_ids, padding: can_padding.0 }),
        device: device.map(|path| DeviceOptions { path, echo: echo.into(), low_latency, rs485: rs485.then(|| rs485_delay_ms.unwrap_or_default()) }),
    };
    let view = ViewOptions { mcap, live: foxglove.address, packets: false, compare: false };
    let overrides = super::run::parse_overrides(&set)?;
    let (_, robot_sets) = climbsim::robot::RobotOverrides::split(&overrides);
    let options = ServeOptions { scenario, overrides, transports, timing: timing.into(), trace_bus, baud, report, faults, record, view, pace: pace.pace()? };
    let robot = load_robot_with(&robot, &robot_sets)?;
    Ok(serve(options, &robot, interrupt::flag(), &Terminal)?)
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

/// `--rs485-delay-ms BEFORE,AFTER` (milliseconds, whole numbers up to 1000).
fn parse_rs485_delays(text: &str) -> Result<climbsim::transport::rs485::Rs485Delays, String> {
    let (before, after) = text.split_once(',').ok_or_else(|| format!("`{text}` is not BEFORE,AFTER (milliseconds, e.g. 0,1)"))?;
    let ms = |part: &str| part.trim().parse::<u32>().ok().filter(|&ms| ms <= 1000).ok_or_else(|| format!("`{part}` is not a whole number of milliseconds in 0..=1000"));
    Ok(climbsim::transport::rs485::Rs485Delays { before_send_ms: ms(before)?, after_send_ms: ms(after)? })
}
