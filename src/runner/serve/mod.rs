//! `climbsim serve`: the robot's servos on every transport asked for (pty always; TCP listener,
//! TCP client, SocketCAN, a real serial device), on the bench or in a scenario's world, which
//! then runs on its clock ([`crate::runner::ticks::Pacer`]) with its sensor server and
//! view, until SIGINT or SIGTERM. Each transport is started by its own module.

pub mod can;
pub mod device;
pub mod pty;
pub mod tcp;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use tracing::{info, warn};

use crate::bus::{BusFaults, Timing, TraceWriter};
use crate::fault::ScheduledFault;
use crate::overrides::Override;
use crate::robot::{RobotDescription, RobotOverrides};
use crate::runner::view::ViewOptions;
use crate::scenario::Scenario;
use crate::sensor_server::SensorFeed;
use crate::transport::{Adapter, BusHandle, PhysicsPace, VirtualPort};

use super::clock::{Pace, TimeBase};
use super::feed::{WorldFailed, observer_hook};
use super::observe::scenario_bus;
use super::outputs::finish_timing_report;
use super::process::faketime_env;
use super::recording::{RecordSpec, finish_recording, record_sensor_reads, start_recording};
use super::ticks::Pacer;
use super::time_base::Timekeeping;
use super::{Console, During as _, Result, RunnerError};

/// Every transport the bus is served on besides the pty, which is always there.
#[derive(Debug, Clone)]
pub struct Transports {
    /// A symlink to the pty (a stable name for the controller's configuration).
    pub link: Option<PathBuf>,
    /// The USB adapter the controller on the pty sits behind.
    pub adapter: Adapter,
    /// Listen for controllers on TCP.
    pub tcp: Option<SocketAddr>,
    /// Connect to a controller that is a TCP server, again whenever it goes away.
    pub tcp_connect: Option<SocketAddr>,
    pub can: Option<can::CanOptions>,
    pub device: Option<device::DeviceOptions>,
}

/// What `serve` serves, and how.
pub struct ServeOptions {
    /// A scenario's world; without one the servos sit on the bench.
    pub scenario: Option<PathBuf>,
    /// `--set`: the scenario's keys (the robot's and profile's are in the robot description
    /// given to [`serve`]); all of them recorded, for `replay`.
    pub overrides: Vec<Override>,
    pub transports: Transports,
    pub timing: Timing,
    /// Every bus transaction as JSON lines.
    pub trace_bus: Option<PathBuf>,
    /// Every servo's power-on baud, over the robot description's.
    pub baud: Option<u32>,
    /// The timing report written on exit.
    pub report: Option<PathBuf>,
    pub faults: Vec<ScheduledFault>,
    pub record: Option<PathBuf>,
    pub view: ViewOptions,
    pub pace: Pace,
}

/// How often the serving thread looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(20);

/// Serve until `stop` is set (the command line sets it on SIGINT and SIGTERM, whose handlers
/// are in place before the port is announced: a supervisor that stops climbsim as soon as it has
/// printed its port still gets a clean shutdown).
pub fn serve(options: ServeOptions, robot: &RobotDescription, stop: &AtomicBool, console: &dyn Console) -> Result<()> {
    let ServeOptions { scenario, overrides, transports, timing, trace_bus, baud, report, faults, record, view, pace } = options;
    let (scenario_sets, _) = RobotOverrides::split(&overrides);
    if scenario.is_none()
        && let Some(set) = scenario_sets.first()
    {
        return Err(RunnerError::Invalid(format!("--set {set}: a scenario key, and serve has no scenario (on the bench only robot.… and profile.… keys apply)")));
    }
    let speed_scaled = pace.speed != 1.0;
    if speed_scaled && transports.can.is_some() {
        return Err(RunnerError::Invalid("--speed with --can: a CAN bus is a real bus whose other nodes keep real time; serve it at --speed 1".to_owned()));
    }
    if speed_scaled && transports.device.is_some() {
        return Err(RunnerError::Invalid("--speed with --device: the controller on a serial device keeps real time; serve it at --speed 1".to_owned()));
    }
    if matches!(pace.time, TimeBase::Virtual(_)) {
        if scenario.is_none() {
            return Err(RunnerError::Invalid("serve --clock virtual needs a scenario: on the bench there is no world whose time could wait for the controller".to_owned()));
        }
        if transports.tcp.is_some() || transports.tcp_connect.is_some() || transports.can.is_some() || transports.device.is_some() {
            return Err(RunnerError::Invalid("serve --clock virtual serves the pty only: a controller on TCP, CAN or a serial device keeps real time".to_owned()));
        }
    }
    let time = Timekeeping::assemble(&pace)?;
    time.wait_for_controllers();
    // Said before anything starts: a controller must be started with these to keep the pace.
    let faketime = if speed_scaled { Some(faketime_env(pace.speed).during(|| format!("--speed {}", pace.speed))?) } else { None };
    if let Some(bps) = baud {
        robot.servos(Some(bps)).during(|| format!("--baud {bps}"))?;
    }
    // A world gets its observer (the camera and line detector when it has a weld line), the
    // sensor server and, if asked, the Foxglove view.
    let (bus, observer, recorder) = match &scenario {
        Some(path) => {
            let mut loaded = Scenario::load_with(path, &scenario_sets)?;
            loaded.add_faults(faults);
            let (mut bus, mut observer) = scenario_bus(&loaded, robot, timing, baud)?;
            let spec = record.map(|path| RecordSpec { path, overrides: overrides.iter().map(ToString::to_string).collect() });
            let recorder = spec.map(|spec| start_recording(&spec, "serve", &loaded, robot, &bus, baud)).transpose()?;
            // `serve` writes no time series: a session may last for days.
            observer.discard_rows();
            let view = ViewOptions { packets: loaded.capture.bus_packets, ..view };
            if let Some(url) = observer.start_view(&view, &mut bus)? {
                console.say(&format!("foxglove: {url}"));
            }
            (bus, Some(Arc::new(Mutex::new(observer))), recorder)
        }
        None => {
            let mut bus = robot.bench_bus(timing, baud)?;
            // The bench has no scenario seed: its faults draw from seed 0.
            bus.set_faults(BusFaults::new(faults, 0));
            (bus, None, None)
        }
    };
    let trace = match &trace_bus {
        Some(path) => {
            let file = std::fs::File::create(path).during(|| format!("cannot create bus trace {}", path.display()))?;
            Some(TraceWriter::new(Box::new(std::io::BufWriter::new(file))))
        }
        None => None,
    };
    let handle = BusHandle::with_clock(bus, trace, recorder, time.bus_clock());
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().during(|| "cannot start the runtime".to_owned())?;
    let port = runtime.block_on(async {
        let port = Arc::new(VirtualPort::open(transports.link.as_deref()).during(|| "cannot open the pty".to_owned())?);
        let tcp_bound = match transports.tcp {
            Some(addr) => Some(tcp::listen(addr, Arc::clone(&handle)).await?),
            None => None,
        };
        // The CAN socket is open (and hears requests) before the port is announced.
        let can_thread = match &transports.can {
            Some(options) => Some(can::start(options.clone(), Arc::clone(&handle)).await?),
            None => None,
        };
        let device_service = match &transports.device {
            Some(options) => Some(device::start_device(options.clone(), Arc::clone(&handle)).await?),
            None => None,
        };
        console.say(&format!("port: {}", port.path().display()));
        if let Some(bound) = tcp_bound {
            console.say(&format!("tcp: {bound}"));
        }
        if let Some(addr) = transports.tcp_connect {
            tcp::connect(addr, Arc::clone(&handle))?;
            console.say(&format!("tcp-connect: {addr}"));
        }
        if let Some(options) = &transports.can {
            console.say(&format!("can: {} request {} response {}", options.iface, options.ids.request, options.ids.response));
        }
        if let (Some(options), Some(service)) = (&transports.device, &device_service) {
            console.say(&format!("device: {} at {} bps", options.path.display(), service.baud));
        }
        if let Some(env) = &faketime {
            let assignments: Vec<String> = env.iter().map(|(k, v)| format!("{k}='{v}'")).collect();
            console.say(&format!("speed: {}x; start your controller with its clocks scaled alike: {} <command>", pace.speed, assignments.join(" ")));
        }
        // Under virtual time the session runs inside the scheduler, at exact simulated instants.
        let pty_thread = time.serve_pty(Arc::clone(&port), Arc::clone(&handle), transports.adapter, pty::start_thread)?;
        // A world runs on the wall clock: the pacer advances it every firmware tick against
        // absolute deadlines, so it moves between packets too (packets advance it as well). The
        // bench needs none: its servos are brought up to date exactly when a packet arrives.
        let pacer = match observer.clone() {
            Some(observer) => {
                let feed = Arc::new(SensorFeed::default());
                record_sensor_reads(&handle, &feed);
                let url = time.start_sensor_server(Arc::clone(&feed)).await?;
                console.say(&format!("sensors: {url}"));
                if time.is_virtual() {
                    let mut env = time.controller_env()?;
                    env.push(("DXL_PORT".to_owned(), port.path().display().to_string()));
                    env.push(("CLIMBSIM_SENSORS".to_owned(), url.clone()));
                    let assignments: Vec<String> = env.iter().map(|(k, v)| format!("{k}='{v}'")).collect();
                    console.say(&format!(
                        "virtual time: the world waits for your controller; start it with: {} <command>\n  (under gdb: `set environment` for each, so that gdb itself is not preloaded; the world waits while it is stopped)",
                        assignments.join(" ")
                    ));
                }
                let errors = Arc::new(Mutex::new(None));
                Some(Pacer::start(Arc::clone(&handle), observer_hook(observer, feed, errors, WorldFailed::GoesOn), time.tick_source()))
            }
            None => None,
        };
        while !stop.load(Ordering::Relaxed) {
            tokio::time::sleep(STOP_POLL).await;
        }
        info!("stop requested: shutting down");
        if pty_thread.as_ref().is_some_and(std::thread::JoinHandle::is_finished) {
            warn!("the pty session had stopped before shutdown");
        }
        // The controller's clean-up runs on the wall clock from here.
        time.end();
        if can_thread.as_ref().is_some_and(std::thread::JoinHandle::is_finished) {
            warn!("the CAN session had stopped before shutdown");
        }
        if let Some(service) = device_service {
            if service.is_finished() {
                warn!("the device session had stopped before shutdown");
            }
            service.stop();
        }
        // Let the controller read the last reply before the master closes.
        port.drain(Duration::from_secs(1)).await;
        let mut pace_kept = PhysicsPace::default();
        if let Some(pacer) = pacer {
            pace_kept = pacer.stop();
            info!(ticks = pace_kept.ticks, overruns = pace_kept.overruns, "world pacing: firmware ticks run on the wall clock, deadlines missed");
            if pace_kept.overruns > 0 {
                console.note(&format!("climbsim: the world missed {} of {} wall-clock deadlines (it ran slower than {}x real time)", pace_kept.overruns, pace_kept.ticks, pace.speed));
            }
        }
        let timing_report = finish_timing_report(&handle, &pace_kept, report.as_deref(), console)?;
        for problem in timing_report.pace_problems(pace.tolerance) {
            console.note(&format!("climbsim: {problem}"));
        }
        finish_recording(&handle, &pace_kept, console)?;
        if let Some(observer) = observer {
            observer.lock().unwrap_or_else(PoisonError::into_inner).finish_view()?;
        }
        Ok::<_, RunnerError>(port)
    })?;
    port.remove_link();
    Ok(())
}
