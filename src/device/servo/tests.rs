//! The servo's instruction handling and firmware loop together, on the bench load.

use super::*;
use crate::device::profile::tests::xm540;
use crate::device::shaft::{BenchLoad, ShaftLoad};

fn servo() -> Servo {
    Servo::new(Arc::new(xm540()), 1, 1, 12.0)
}

fn write(servo: &mut Servo, now: Duration, address: u16, data: &[u8]) -> Result<Vec<u8>, DeviceError> {
    servo.handle(now, Request::Write { address, data }, Addressing::default()).reply
}

fn run(servo: &mut Servo, load: &mut BenchLoad, from: Duration, seconds: f64) -> Duration {
    let mut now = from;
    let ticks = (seconds / servo.control_period().as_secs_f64()) as usize;
    for _ in 0..ticks {
        now += servo.control_period();
        let drive = servo.drive();
        let state = load.step(&drive, servo.control_period().as_secs_f64());
        servo.sense(now, state);
    }
    now
}

fn read_i32(servo: &mut Servo, address: u16) -> i32 {
    let bytes = servo.handle(Duration::ZERO, Request::Read { address, length: 4 }, Addressing::default()).reply.unwrap();
    i32::from_le_bytes(bytes.try_into().unwrap())
}

#[test]
fn ping_reports_model_and_firmware() {
    let reply = servo().handle(Duration::ZERO, Request::Ping, Addressing::default()).reply.unwrap();
    assert_eq!(reply, [0x60, 0x04, 48]);
}

#[test]
fn position_mode_reaches_goal() {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 116, &1000i32.to_le_bytes()).unwrap();
    run(&mut s, &mut load, Duration::ZERO, 1.0);
    let present = read_i32(&mut s, 132);
    assert!((present - 1000).abs() <= 5, "present {present}");
}

#[test]
fn velocity_mode_tracks_goal() {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    write(&mut s, Duration::ZERO, 11, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 104, &50i32.to_le_bytes()).unwrap();
    run(&mut s, &mut load, Duration::ZERO, 2.0);
    let velocity = read_i32(&mut s, 128);
    assert!((velocity - 50).abs() <= 2, "velocity {velocity}");
}

#[test]
fn full_pwm_runs_at_datasheet_no_load_speed() {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    write(&mut s, Duration::ZERO, 11, &[16]).unwrap();
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 100, &885i16.to_le_bytes()).unwrap();
    run(&mut s, &mut load, Duration::ZERO, 0.5);
    let rpm = load.state().velocity_rad_s * 60.0 / TAU;
    assert!((rpm - 30.0).abs() / 30.0 < 0.02, "no-load speed {rpm} rev/min");
}

#[test]
fn watchdog_trips_and_refuses_goals_until_cleared() {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 98, &[5]).unwrap();
    let now = run(&mut s, &mut load, Duration::ZERO, 0.2);
    assert_eq!(s.table().read(98, 1).unwrap(), [0xFF]);
    assert_eq!(write(&mut s, now, 116, &0i32.to_le_bytes()), Err(DeviceError::DataRange));
    write(&mut s, now, 98, &[0]).unwrap();
    assert!(write(&mut s, now, 116, &0i32.to_le_bytes()).is_ok());
}

#[test]
fn shutdown_error_forces_torque_off_until_reboot() {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    write(&mut s, Duration::ZERO, 31, &[20]).unwrap(); // Temperature Limit below ambient
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    let now = run(&mut s, &mut load, Duration::ZERO, 0.01);
    assert_eq!(s.hardware_error_status() & 0x04, 0x04);
    assert!(!s.torque_on());
    write(&mut s, now, 64, &[1]).unwrap();
    assert!(!s.torque_on(), "torque stays off while the shutdown is latched");
    assert_eq!(s.status_error_byte(&Ok(vec![])), 0x80);
    write(&mut s, now, 31, &[80]).unwrap();
    s.finish(now, AfterReply::Reboot);
    assert_eq!(s.hardware_error_status(), 0);
}

#[test]
fn operating_mode_change_resets_profile_and_goal_limits() {
    let mut s = servo();
    write(&mut s, Duration::ZERO, 112, &100i32.to_le_bytes()).unwrap();
    write(&mut s, Duration::ZERO, 100, &10i16.to_le_bytes()).unwrap();
    write(&mut s, Duration::ZERO, 11, &[1]).unwrap();
    assert_eq!(read_i32(&mut s, 112), 0);
    assert_eq!(s.table().read(100, 2).unwrap(), 885u16.to_le_bytes());
}

#[test]
fn reg_write_waits_for_action() {
    let mut s = servo();
    let reply = s.handle(Duration::ZERO, Request::RegWrite { address: 65, data: &[1] }, Addressing::default()).reply;
    assert!(reply.is_ok());
    assert_eq!(s.table().read(65, 1).unwrap(), [0]);
    assert_eq!(s.table().read(69, 1).unwrap(), [1]);
    assert!(s.handle(Duration::ZERO, Request::Action, Addressing::default()).reply.is_ok());
    assert_eq!(s.table().read(65, 1).unwrap(), [1]);
    assert_eq!(s.table().read(69, 1).unwrap(), [0]);
    assert_eq!(s.handle(Duration::ZERO, Request::Action, Addressing::default()).reply, Err(DeviceError::Instruction));
}

#[test]
fn reverse_drive_mode_flips_present_position() {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    write(&mut s, Duration::ZERO, 10, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 11, &[4]).unwrap();
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 116, &500i32.to_le_bytes()).unwrap();
    run(&mut s, &mut load, Duration::ZERO, 1.0);
    assert!((read_i32(&mut s, 132) - 500).abs() <= 5);
    assert!(load.state().position_rad < 0.0, "the shaft turned the other way");
}

/// Moves in position mode, sampling a register every 10 ms until the move has ended.
fn sample_move(s: &mut Servo, load: &mut BenchLoad, goal: i32, address: u16, length: u16, seconds: f64) -> Vec<i64> {
    let mut now = Duration::from_secs(1);
    write(s, now, 116, &goal.to_le_bytes()).unwrap();
    let mut samples = Vec::new();
    for _ in 0..(seconds / 0.01) as usize {
        now = run(s, load, now, 0.01);
        let bytes = s.handle(now, Request::Read { address, length }, Addressing::default()).reply.unwrap();
        samples.push(crate::device::decode_item(&bytes, true));
    }
    samples
}

/// A servo in position mode with torque on, at rest at its start.
fn positioned(extra: &[(u16, Vec<u8>)]) -> (Servo, BenchLoad) {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    for (address, data) in extra {
        write(&mut s, Duration::ZERO, *address, data).unwrap();
    }
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    run(&mut s, &mut load, Duration::ZERO, 1.0);
    (s, load)
}

/// e-manual, Goal PWM(100): outside PWM mode it limits the PWM output (it was ignored: 623-683
/// through such a move).
#[test]
fn goal_pwm_limits_the_output_in_position_mode() {
    let (mut s, mut load) = positioned(&[(112, 100i32.to_le_bytes().to_vec()), (100, 45i16.to_le_bytes().to_vec())]);
    let pwm = sample_move(&mut s, &mut load, 1500, 124, 2, 1.0);
    let largest = pwm.iter().map(|p| p.abs()).max().unwrap();
    assert!((40..=45).contains(&largest), "Present PWM up to {largest} with Goal PWM 45");
}

/// e-manual, Velocity Limit(44): it bounds Profile Velocity; the move cruises at the limit (it
/// ran at Profile Velocity 100 under a limit of 60).
#[test]
fn profile_velocity_is_bounded_by_velocity_limit() {
    let (mut s, mut load) = positioned(&[(44, 60i32.to_le_bytes().to_vec()), (112, 100i32.to_le_bytes().to_vec())]);
    let trajectory = sample_move(&mut s, &mut load, 1500, 136, 4, 2.0);
    let fastest = trajectory.iter().map(|v| v.abs()).max().unwrap();
    assert_eq!(fastest, 60, "the profile's velocity (Velocity Trajectory) peaks at {fastest}");
}

/// Moving Status bits 4-5 name the whole move's profile: a move long enough to reach Profile
/// Velocity is trapezoidal to its end (it turned triangular 358 pulses before the goal).
#[test]
fn moving_status_keeps_the_moves_profile_type() {
    let (mut s, mut load) = positioned(&[(108, 10i32.to_le_bytes().to_vec()), (112, 60i32.to_le_bytes().to_vec())]);
    let status = sample_move(&mut s, &mut load, 2000, 123, 1, 3.5);
    let during: Vec<i64> = status.iter().filter(|&&st| st & 0x02 != 0).map(|&st| (st >> 4) & 0x03).collect();
    assert!(during.len() > 100, "the profile ran {} samples", during.len());
    assert!(during.iter().all(|&kind| kind == 3), "profile types during the move: {during:?}");
    // A short move cannot reach it: triangular from its start.
    let status = sample_move(&mut s, &mut load, 2200, 123, 1, 1.0);
    let during: Vec<i64> = status.iter().filter(|&&st| st & 0x02 != 0).map(|&st| (st >> 4) & 0x03).collect();
    assert!(!during.is_empty() && during.iter().all(|&kind| kind == 2), "profile types of a short move: {during:?}");
}

fn read_i16(servo: &Servo, address: u16) -> i16 {
    let bytes = servo.table().read(address, 2).unwrap();
    i16::from_le_bytes(bytes.try_into().unwrap())
}

/// e-manual, Bus Watchdog(98): after expiry, writing 0 clears the error and new goals work. The
/// expiry had zeroed Goal PWM, a limit outside PWM mode, so a cleared servo never moved again.
#[test]
fn watchdog_cleared_velocity_servo_follows_new_goals() {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    write(&mut s, Duration::ZERO, 11, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 104, &50i32.to_le_bytes()).unwrap();
    write(&mut s, Duration::ZERO, 98, &[5]).unwrap();
    let now = run(&mut s, &mut load, Duration::ZERO, 0.4);
    assert_eq!(s.table().read(98, 1).unwrap(), [0xFF]);
    assert_eq!(read_i32(&mut s, 104), 0, "velocity mode stops with Goal Velocity 0");
    assert_eq!(write(&mut s, now, 104, &60i32.to_le_bytes()), Err(DeviceError::DataRange));
    write(&mut s, now, 98, &[0]).unwrap();
    write(&mut s, now, 104, &60i32.to_le_bytes()).unwrap();
    assert_eq!(read_i16(&s, 100), 885, "Goal PWM (a limit in velocity mode) kept its value");
    run(&mut s, &mut load, now, 1.5);
    let velocity = read_i32(&mut s, 128);
    assert!((velocity - 60).abs() <= 3, "Present Velocity {velocity} after clearing, goal 60");
}

/// In current-based position mode Goal Current is the limit and the profile shapes the move: the
/// expiry stops the servo where it is (the profile applied as 0) but changes neither, so after
/// clearing a new goal is followed as configured.
#[test]
fn watchdog_expiry_keeps_goal_current_limit_and_profile() {
    let (mut s, mut load) = positioned(&[(11, vec![5]), (112, 20i32.to_le_bytes().to_vec())]);
    let start = Duration::from_secs(1);
    write(&mut s, start, 98, &[5]).unwrap();
    write(&mut s, start, 116, &600i32.to_le_bytes()).unwrap();
    let now = run(&mut s, &mut load, start, 0.5);
    assert_eq!(s.table().read(98, 1).unwrap(), [0xFF]);
    let stopped_at = read_i32(&mut s, 132);
    assert!(stopped_at < 100, "the move (313 pulses/s) stopped at expiry, not at {stopped_at}");
    assert_eq!(read_i32(&mut s, 116), stopped_at, "Goal Position became Present Position");
    assert_eq!(read_i32(&mut s, 112), 20, "Profile Velocity is applied as 0, not written");
    assert_eq!(read_i16(&s, 102), 2047, "Goal Current (the limit in mode 5) kept its value");
    write(&mut s, now, 98, &[0]).unwrap();
    write(&mut s, now, 116, &600i32.to_le_bytes()).unwrap();
    run(&mut s, &mut load, now, 3.0);
    let present = read_i32(&mut s, 132);
    assert!((present - 600).abs() <= 5, "Present Position {present} after clearing, goal 600");
}

/// In PWM mode Goal PWM is the output itself: the expiry's stop is Goal PWM 0.
#[test]
fn watchdog_expiry_in_pwm_mode_zeroes_goal_pwm() {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    write(&mut s, Duration::ZERO, 11, &[16]).unwrap();
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 100, &400i16.to_le_bytes()).unwrap();
    write(&mut s, Duration::ZERO, 98, &[5]).unwrap();
    run(&mut s, &mut load, Duration::ZERO, 0.4);
    assert_eq!(s.table().read(98, 1).unwrap(), [0xFF]);
    assert_eq!(read_i16(&s, 100), 0);
    assert_eq!(read_i16(&s, 124), 0, "Present PWM after the stop");
}

/// Current-based position (mode 5): the position loop drives the voltage and Goal Current caps
/// the current (e-manual, Goal Current(102)). The shaft settles on its goal instead of ringing
/// round it, and against a heavy load the current stays within the cap.
#[test]
fn current_based_position_settles_and_caps_its_current() {
    let mut s = servo();
    let mut load = BenchLoad::new(0.0);
    write(&mut s, Duration::ZERO, 11, &[5]).unwrap();
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 116, &600i32.to_le_bytes()).unwrap();
    let mut now = run(&mut s, &mut load, Duration::ZERO, 1.0);
    let mut spread = (i32::MAX, i32::MIN);
    for _ in 0..50 {
        now = run(&mut s, &mut load, now, 0.01);
        let present = read_i32(&mut s, 132);
        spread = (spread.0.min(present), spread.1.max(present));
    }
    assert!((spread.0 - 600).abs() <= 5 && (spread.1 - 600).abs() <= 5, "Present Position over the last half second: {spread:?}");

    let mut s = servo();
    let mut heavy = BenchLoad::new(50.0);
    write(&mut s, Duration::ZERO, 11, &[5]).unwrap();
    write(&mut s, Duration::ZERO, 102, &200i16.to_le_bytes()).unwrap();
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 116, &4000i32.to_le_bytes()).unwrap();
    run(&mut s, &mut heavy, Duration::ZERO, 0.2);
    let current = i16::from_le_bytes(s.table().read(126, 2).unwrap().try_into().unwrap());
    assert!(current > 150 && current <= 201, "Present Current {current} under a Goal Current of 200 while it pushes the load");

    // Reversed (Drive Mode bit 0), a light load, a low cap that holds while the shaft runs (where
    // the back-EMF matters), towards a negative goal: the current keeps the move's sign and its
    // cap all the way, and the goal is reached.
    let mut s = servo();
    let mut light = BenchLoad::new(0.05);
    write(&mut s, Duration::ZERO, 10, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 11, &[5]).unwrap();
    write(&mut s, Duration::ZERO, 102, &100i16.to_le_bytes()).unwrap();
    write(&mut s, Duration::ZERO, 64, &[1]).unwrap();
    write(&mut s, Duration::ZERO, 116, &(-2000i32).to_le_bytes()).unwrap();
    let mut now = Duration::ZERO;
    let mut currents = Vec::new();
    for _ in 0..40 {
        now = run(&mut s, &mut light, now, 0.01);
        currents.push(i16::from_le_bytes(s.table().read(126, 2).unwrap().try_into().unwrap()));
    }
    assert!(currents.iter().all(|&c| c.abs() <= 101), "the cap of 100 held: {currents:?}");
    assert!(currents[..5].iter().all(|&c| c < -50), "pushing towards the negative goal at the cap: {currents:?}");
    run(&mut s, &mut light, now, 3.0);
    let present = read_i32(&mut s, 132);
    assert!((present + 2000).abs() <= 10, "reached -2000 under the cap: {present}");
}
