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
