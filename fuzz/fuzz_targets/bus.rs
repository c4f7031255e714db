//! Any byte stream as a controller's instructions to the eight bench servos: decoding, routing,
//! every instruction's execution and reply scheduling must never panic.
#![no_main]

use std::sync::{Arc, OnceLock};
use std::time::Duration;

use climbsim::bus::{Bus, Timing, servos_from_profile};
use climbsim::device::{BenchPlant, FirmwareProfile};
use climbsim::protocol::{DEFAULT_MAX_LEN, Decoder};
use climbsim::robot::RobotDescription;
use libfuzzer_sys::fuzz_target;

/// The robot and its servos' profile, parsed once: a fresh bus per input is then cheap.
fn setup() -> &'static (RobotDescription, Arc<FirmwareProfile>) {
    static SETUP: OnceLock<(RobotDescription, Arc<FirmwareProfile>)> = OnceLock::new();
    SETUP.get_or_init(|| {
        let robot = RobotDescription::load(&RobotDescription::default_path()).expect("hil/robot.toml");
        let profile = Arc::new(FirmwareProfile::load(&robot.profile_path()).expect("firmware profile"));
        (robot, profile)
    })
}

fn fresh_bus() -> Option<Bus> {
    let (robot, profile) = setup();
    let servos = servos_from_profile(profile, &robot.ids(), robot.bus.baud_bps, robot.bus.supply_voltage_v).ok()?;
    robot.bus_of(servos, Box::new(BenchPlant::default()), Timing::Wire, None).ok()
}

fuzz_target!(|data: &[u8]| {
    let Some(mut bus) = fresh_bus() else { return };
    let mut decoder = Decoder::new(bus.inter_byte_timeout(), DEFAULT_MAX_LEN);
    let mut now = Duration::ZERO;
    let mut rest = data;
    // Each chunk: one byte of length (1–64) and one of gap (0–255 × 100 µs), then its bytes; the
    // line baud alternates between the servos' and another, like a controller changing rates.
    while let [len, gap, tail @ ..] = rest {
        let take = usize::from(*len % 64 + 1).min(tail.len());
        now += Duration::from_micros(u64::from(*gap) * 100);
        let baud = if gap % 7 == 0 { Some(1_000_000) } else { Some(57_600) };
        for packet in decoder.push(now, &tail[..take]).into_iter().flatten() {
            let transaction = bus.handle(packet, now, baud);
            for reply in &transaction.replies {
                assert!(reply.end >= reply.start, "a reply ends before it starts");
            }
        }
        rest = &tail[take..];
    }
});
