//! `--record FILE` (on `run` and `serve`): the session's transcript for `climbsim replay`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use crate::bus::{Bus, Timing};
use crate::robot::RobotDescription;
use crate::scenario::Scenario;
use crate::sensor_server::SensorFeed;
use crate::transcript::{BusSettings, Header, Recorder, RobotCopy, ScenarioCopy, crc64_hex, nanos};
use crate::transport::{BusHandle, PhysicsPace};

use super::{Console, During as _, Result};

/// What `--record` needs besides the loaded scenario: the file, and the `--set` overrides as
/// given (the replay applies them to the scenario file again).
#[derive(Debug, Clone)]
pub struct RecordSpec {
    pub path: PathBuf,
    pub overrides: Vec<String>,
}

/// Create the transcript for a session of `scenario` on `bus` and write its header.
pub fn start_recording(spec: &RecordSpec, mode: &str, scenario: &Scenario, robot: &RobotDescription, bus: &Bus, baud_override: Option<u32>) -> Result<Arc<Recorder>> {
    let read = |path: &Path| std::fs::read_to_string(path).during(|| format!("--record: cannot read {}", path.display()));
    let profile_path = robot.profile_path();
    let tick = bus.servos().first().map_or(Duration::from_millis(1), |s| s.control_period());
    let header = Header::new(
        mode,
        ScenarioCopy { path: scenario.path.clone(), overrides: spec.overrides.clone(), text: read(&scenario.path)? },
        RobotCopy { path: robot.path.clone(), text: read(&robot.path)?, profile_crc64: crc64_hex(read(&profile_path)?.as_bytes()), profile_path },
        scenario.world.seed,
        BusSettings {
            baud: baud_override.unwrap_or(robot.bus.baud_bps),
            baud_override,
            timing: match bus.timing() {
                Timing::Wire => "wire",
                Timing::Off => "off",
            }
            .to_owned(),
            tick_ns: nanos(tick),
        },
    );
    let recorder = Recorder::create(&spec.path, &header).during(|| format!("--record {}", spec.path.display()))?;
    Ok(Arc::new(recorder))
}

/// Record what the sensor server serves into the handle's transcript, if it has one.
pub fn record_sensor_reads(handle: &Arc<BusHandle>, feed: &SensorFeed) {
    let Some(recorder) = handle.recorder().cloned() else { return };
    let clock = handle.clock();
    feed.on_read(Box::new(move |path, status, content_type, body| recorder.sensor_read(clock.now(), path, status, content_type, body)));
}

/// Write the transcript's `end` line; say where it is.
pub fn finish_recording(handle: &BusHandle, pace: &PhysicsPace, console: &dyn Console) -> Result<()> {
    let Some(recorder) = handle.recorder() else { return Ok(()) };
    recorder.finish(handle.clock().now(), pace.ticks, pace.overruns).during(|| format!("--record {}", recorder.path().display()))?;
    console.note(&format!("climbsim: recorded the session in {}", recorder.path().display()));
    Ok(())
}
