//! Fault injection: every fault kind produces the register, status-packet and
//! physical effect it names. Servo and bus faults are tested on the bench (each servo on its own
//! rotor, or on a stalled shaft), world faults in the rapier world; all through real instruction
//! packets, the codec and the bus.

use std::path::Path;
use std::time::Duration;

use climbsim::bus::{Bus, BusFaults, Timing, Transaction};
use climbsim::device::{Plant, Servo, ShaftState};
use climbsim::fault::ScheduledFault;
use climbsim::protocol::{ALERT_BIT, Decoder, RawPacket, encode_instruction, opcode};
use climbsim::robot::WheelPosition;
use climbsim::scenario::Scenario;
use climbsim::sim::Lockstep;
use climbsim::sim::terrain::TerrainSpec;
use rapier3d::prelude::Vector;

mod support;
use support::physics::*;

const SHUTDOWN: u16 = 63;
const LED: u16 = 65;
const HARDWARE_ERROR_STATUS: u16 = 70;
const GOAL_PWM: u16 = 100;
const PRESENT_VELOCITY: u16 = 128;
const PRESENT_POSITION: u16 = 132;
const PRESENT_INPUT_VOLTAGE: u16 = 144;
const PRESENT_TEMPERATURE: u16 = 146;
const TEMPERATURE_LIMIT: u16 = 31;
const PWM_MODE: u8 = 16;
const OVERLOAD_BIT: u8 = 1 << 5;
const OVERHEATING_BIT: u8 = 1 << 2;
const VOLTAGE_BIT: u8 = 1 << 0;

fn faults(specs: &[&str], seed: u64) -> BusFaults {
    BusFaults::new(specs.iter().map(|s| ScheduledFault::parse(s).expect("fault spec")).collect(), seed)
}

/// A bus driven by hand: instructions through the codec, time advanced explicitly.
struct Rig {
    bus: Bus,
    now: Duration,
}

impl Rig {
    fn bench(timing: Timing, specs: &[&str]) -> Self {
        Self::with_plant(robot().bench_bus(timing, None).expect("bench bus"), specs)
    }

    fn with_plant(mut bus: Bus, specs: &[&str]) -> Self {
        bus.set_faults(faults(specs, 11));
        Self { bus, now: Duration::ZERO }
    }

    fn transactions(&mut self, id: u8, code: u8, params: &[u8]) -> Vec<Transaction> {
        let bytes = encode_instruction(id, code, params);
        let packets: Vec<RawPacket> = Decoder::default().push(self.now, &bytes).into_iter().map(|p| p.expect("valid instruction")).collect();
        packets.into_iter().map(|p| self.bus.handle(p, self.now, None)).collect()
    }

    /// The decoded replies of one instruction (a reply that fails its CRC is absent).
    fn replies(&mut self, id: u8, code: u8, params: &[u8]) -> Vec<RawPacket> {
        let mut out = Vec::new();
        for t in self.transactions(id, code, params) {
            for reply in t.replies {
                out.extend(Decoder::default().push(self.now, &reply.bytes).into_iter().filter_map(Result::ok));
            }
        }
        out
    }

    fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Option<RawPacket> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(data);
        self.replies(id, opcode::WRITE, &params).into_iter().next()
    }

    /// A Read's status packet: (error byte, data).
    fn read(&mut self, id: u8, address: u16, length: u16) -> Option<(u8, Vec<u8>)> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(&length.to_le_bytes());
        let reply = self.replies(id, opcode::READ, &params).into_iter().next()?;
        let (&error, data) = reply.params.split_first()?;
        Some((error, data.to_vec()))
    }

    fn read_value(&mut self, id: u8, address: u16, length: u16) -> (u8, i64) {
        let (error, data) = self.read(id, address, length).expect("a reply");
        (error, climbsim::device::decode_item(&data, true))
    }

    fn run(&mut self, duration: Duration) {
        self.now += duration;
        self.bus.advance(self.now);
    }

    fn servo(&self, id: u8) -> &Servo {
        self.bus.servos().iter().find(|s| s.id() == id).expect("servo on the bus")
    }
}

// ---------------------------------------------------------------------------------------------
// Bus faults

/// Pings to ID 1 under a bit error rate: (no reply at all, a reply that fails its CRC, good).
fn ping_outcomes(specs: &[&str], pings: usize) -> (usize, usize, usize) {
    let mut rig = Rig::bench(Timing::Off, specs);
    let (mut lost, mut corrupt, mut good) = (0, 0, 0);
    for _ in 0..pings {
        rig.run(Duration::from_millis(1));
        let replies: Vec<_> = rig.transactions(1, opcode::PING, &[]).into_iter().flat_map(|t| t.replies).collect();
        match replies.as_slice() {
            [] => lost += 1,
            [reply] => {
                let decoded = Decoder::default().push(rig.now, &reply.bytes);
                if decoded.iter().any(|p| p.as_ref().is_ok_and(|p| p.id == 1 && p.params.first() == Some(&0))) {
                    good += 1;
                } else {
                    corrupt += 1;
                }
            }
            more => panic!("{} replies to one ping", more.len()),
        }
    }
    (lost, corrupt, good)
}

#[test]
fn bit_errors_drop_instructions_and_corrupt_replies_at_the_rate() {
    let pings = 3000;
    assert_eq!(ping_outcomes(&[], pings), (0, 0, pings), "no faults: every ping answered intact");
    let rate = 1e-3;
    let spec = format!("bit_errors:rate={rate}");
    let (lost, corrupt, good) = ping_outcomes(&[&spec], pings);
    // A ping is 10 bytes (100 bits with start and stop bits); its reply 14 bytes (112 data bits).
    let p_lost = 1.0 - (1.0f64 - rate).powi(100);
    let p_corrupt = (1.0 - p_lost) * (1.0 - (1.0f64 - rate).powi(112));
    let expect = |p: f64| p * pings as f64;
    let within = |n: usize, p: f64| (n as f64 - expect(p)).abs() < 4.0 * (expect(p) * (1.0 - p)).sqrt() + 1.0;
    assert!(within(lost, p_lost), "{lost} unanswered pings, expected about {:.0}", expect(p_lost));
    assert!(within(corrupt, p_corrupt), "{corrupt} replies failed their CRC, expected about {:.0}", expect(p_corrupt));
    assert_eq!(lost + corrupt + good, pings);
    assert_eq!(ping_outcomes(&[&spec], pings), (lost, corrupt, good), "the same seed replays the same errors");
}

#[test]
fn dropped_replies_lose_the_status_packet_but_the_servo_still_executes() {
    let mut rig = Rig::bench(Timing::Off, &["drop_replies:id=2"]);
    assert!(rig.write(2, LED, &[1]).is_none(), "no status packet from ID 2");
    assert_eq!(rig.servo(2).table().read(LED, 1).unwrap(), [1], "the write took effect");
    assert!(rig.write(1, LED, &[1]).is_some(), "ID 1 answers as usual");
    assert_eq!(rig.bus.faults().counts().replies_dropped, 1);

    // With a probability, about that share of the replies is lost.
    let mut rig = Rig::bench(Timing::Off, &["drop_replies:id=3,probability=0.3"]);
    let answered = (0..1000).filter(|_| !rig.replies(3, opcode::PING, &[]).is_empty()).count();
    assert!((640..760).contains(&answered), "{answered} of 1000 pings answered at a 30 % drop rate");
}

#[test]
fn late_replies_arrive_later_and_push_back_the_replies_behind_them() {
    // Sync Read of Present Position from IDs 1-4; ID 3 is 4 ms late.
    let params = [PRESENT_POSITION.to_le_bytes().as_slice(), &4u16.to_le_bytes(), &[1, 2, 3, 4]].concat();
    let timing_of = |specs: &[&str]| {
        let mut rig = Rig::bench(Timing::Wire, specs);
        rig.run(Duration::from_millis(10));
        let t = rig.transactions(0xFE, opcode::SYNC_READ, &params).pop().expect("transaction");
        t.replies.iter().map(|r| (r.from[0], r.start, r.end)).collect::<Vec<_>>()
    };
    let clean = timing_of(&[]);
    let late = timing_of(&["late_replies:id=3,delay_ms=4"]);
    assert_eq!(clean.len(), 4);
    assert_eq!(late.len(), 4, "late, not lost");
    let delay = Duration::from_millis(4);
    for (c, l) in clean.iter().zip(&late) {
        let shift = if c.0 >= 3 { delay } else { Duration::ZERO };
        assert_eq!(l.1, c.1 + shift, "ID {} reply start", c.0);
        assert_eq!(l.2, c.2 + shift, "ID {} reply end", c.0);
    }
}

#[test]
fn a_silent_servo_neither_executes_nor_answers_until_it_comes_back() {
    let mut rig = Rig::bench(Timing::Off, &["silent:id=5,at=1,until=2"]);
    assert!(rig.write(5, LED, &[1]).is_some(), "answers before the fault");
    rig.run(Duration::from_millis(1500));
    assert!(rig.replies(5, opcode::PING, &[]).is_empty(), "no reply to a ping");
    assert!(rig.write(5, LED, &[0]).is_none(), "no reply to a write");
    assert_eq!(rig.servo(5).table().read(LED, 1).unwrap(), [1], "and the write was not executed");
    assert!(rig.write(6, LED, &[1]).is_some(), "its neighbour is fine");
    rig.run(Duration::from_millis(1000));
    assert!(rig.write(5, LED, &[0]).is_some(), "answers again after until_s");
    assert_eq!(rig.servo(5).table().read(LED, 1).unwrap(), [0]);
}

// ---------------------------------------------------------------------------------------------
// Servo faults

fn spin_on_bench(rig: &mut Rig, id: u8, goal: i32) {
    rig.write(id, OPERATING_MODE, &[VELOCITY_MODE]).expect("mode");
    rig.write(id, TORQUE_ENABLE, &[1]).expect("torque on");
    rig.write(id, GOAL_VELOCITY, &goal.to_le_bytes()).expect("goal");
}

#[test]
fn overload_latches_turns_torque_off_sets_the_alert_bit_and_only_reboot_clears_it() {
    let mut rig = Rig::bench(Timing::Off, &["overload:id=2,at=1"]);
    spin_on_bench(&mut rig, 1, 50);
    spin_on_bench(&mut rig, 2, 50);
    rig.run(Duration::from_millis(900));
    let (error, velocity) = rig.read_value(2, PRESENT_VELOCITY, 4);
    assert_eq!(error, 0, "no alert before the fault");
    assert!((velocity - 50).abs() <= 2, "spinning before: {velocity}");

    rig.run(Duration::from_millis(1100));
    let (error, status) = rig.read_value(2, HARDWARE_ERROR_STATUS, 1);
    assert_eq!(status as u8, OVERLOAD_BIT, "Hardware Error Status");
    assert_eq!(error, ALERT_BIT, "alert bit in the status packet, no instruction error");
    assert_eq!(rig.read_value(2, TORQUE_ENABLE, 1).1, 0, "Shutdown turned torque off");
    assert_eq!(rig.read_value(2, PRESENT_VELOCITY, 4).1, 0, "the shaft coasted to a stop");
    assert!((rig.read_value(1, PRESENT_VELOCITY, 4).1 - 50).abs() <= 2, "ID 1 still spins");
    assert_eq!(rig.read_value(1, HARDWARE_ERROR_STATUS, 1), (0, 0));

    // Torque cannot come back, and the error stays, until a Reboot.
    rig.write(2, TORQUE_ENABLE, &[1]).expect("reply");
    rig.run(Duration::from_millis(100));
    assert_eq!(rig.read_value(2, TORQUE_ENABLE, 1), (ALERT_BIT, 0));
    rig.run(Duration::from_secs(5));
    assert_eq!(rig.read_value(2, HARDWARE_ERROR_STATUS, 1), (ALERT_BIT, i64::from(OVERLOAD_BIT)), "still latched 5 s later");
    assert!(!rig.replies(2, opcode::REBOOT, &[]).is_empty(), "reboot acknowledged");
    rig.run(Duration::from_secs(1));
    assert_eq!(rig.read_value(2, HARDWARE_ERROR_STATUS, 1), (0, 0), "reboot cleared it");
    spin_on_bench(&mut rig, 2, 50);
    rig.run(Duration::from_secs(1));
    assert!((rig.read_value(2, PRESENT_VELOCITY, 4).1 - 50).abs() <= 2, "spins again after the reboot");
}

/// Every shaft held still: a stalled motor draws the current its PWM sets.
struct Stalled;

impl Plant for Stalled {
    fn advance(&mut self, servos: &mut [Servo], until: Duration) {
        for servo in servos {
            if servo.is_idle() {
                servo.skip_idle_until(until);
                continue;
            }
            while servo.next_tick() <= until {
                let tick = servo.next_tick();
                servo.drive();
                servo.sense(tick, ShaftState::default());
            }
        }
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

#[test]
fn overheating_follows_the_current_through_the_thermal_model() {
    // Both servos sit in 75 °C air; ID 1 is stalled at 60 % PWM (2.6 A, below the overload
    // threshold), ID 2 is idle. Only the loaded one passes the 80 °C Temperature Limit.
    let bus = robot().bus_with_plant(Box::new(Stalled), Timing::Off, None).expect("bus");
    let mut rig = Rig::with_plant(bus, &["overheating:id=1,ambient_c=75", "overheating:id=2,ambient_c=75"]);
    assert_eq!(rig.read_value(1, TEMPERATURE_LIMIT, 1).1, 80);
    rig.write(1, OPERATING_MODE, &[PWM_MODE]).expect("mode");
    rig.write(1, TORQUE_ENABLE, &[1]).expect("torque");
    rig.write(1, GOAL_PWM, &531i16.to_le_bytes()).expect("goal PWM");
    let mut tripped_at = None;
    for second in 1..=900 {
        rig.run(Duration::from_secs(1));
        if tripped_at.is_none() && rig.servo(1).hardware_error_status() != 0 {
            tripped_at = Some(second);
            break;
        }
    }
    let tripped_at = tripped_at.expect("the loaded servo overheated within 900 s");
    // T(t) = T_ss − (T_ss − 25)·e^(−t/τ) with T_ss = 75 + I²R·R_th: the crossing of 80.5 °C is
    // minutes, not seconds (τ = 600 s), and not immediate (it starts at 25 °C).
    assert!((120..700).contains(&tripped_at), "overheated after {tripped_at} s");
    let (error, status) = rig.read_value(1, HARDWARE_ERROR_STATUS, 1);
    assert_eq!((error, status as u8), (ALERT_BIT, OVERHEATING_BIT));
    // It tripped as the winding passed 80.5 °C (Present Temperature 81) and has cooled a little
    // since, with torque off, for up to a second.
    assert!(rig.read_value(1, PRESENT_TEMPERATURE, 1).1 >= 80, "Present Temperature at the limit");
    assert_eq!(rig.read_value(1, TORQUE_ENABLE, 1).1, 0, "Shutdown (bit 2 by default) turned torque off");
    let (error, temperature) = rig.read_value(2, PRESENT_TEMPERATURE, 1);
    assert_eq!(error, 0, "the idle servo has no error");
    // The idle one only warms toward the air: 75 − 50·e^(−t/600 s), well short of the limit.
    let expected = 75.0 - 50.0 * (-f64::from(tripped_at) / 600.0).exp();
    assert!((temperature as f64 - expected).abs() <= 1.5, "the idle servo is at {temperature} °C, expected {expected:.1} °C");
}

/// Full PWM on the bench: the no-load speed (Present Velocity units) after `seconds`.
fn full_pwm_speed(rig: &mut Rig, id: u8) -> i64 {
    rig.write(id, OPERATING_MODE, &[PWM_MODE]).expect("mode");
    rig.write(id, TORQUE_ENABLE, &[1]).expect("torque");
    rig.write(id, GOAL_PWM, &885i16.to_le_bytes()).expect("goal PWM");
    rig.run(Duration::from_millis(500));
    rig.read_value(id, PRESENT_VELOCITY, 4).1
}

#[test]
fn voltage_sag_scales_the_no_load_speed_and_sets_the_voltage_bit_outside_the_limits() {
    let mut rig = Rig::bench(Timing::Off, &["voltage_sag:volts=10,at=1,until=2", "voltage_sag:id=1,volts=8,at=2,until=3"]);
    let nominal = full_pwm_speed(&mut rig, 1);
    assert_eq!(rig.read_value(1, PRESENT_INPUT_VOLTAGE, 2), (0, 120));
    rig.run(Duration::from_millis(1000)); // t = 1.5: the whole supply at 10 V
    let (error, volts) = rig.read_value(1, PRESENT_INPUT_VOLTAGE, 2);
    assert_eq!((error, volts), (0, 100), "10 V is inside [9.5, 16] V: no error");
    assert_eq!(rig.read_value(5, PRESENT_INPUT_VOLTAGE, 2).1, 100, "every servo sags without an id");
    let at_10 = rig.read_value(1, PRESENT_VELOCITY, 4).1;
    let ratio = at_10 as f64 / nominal as f64;
    assert!((ratio - 10.0 / 12.0).abs() < 0.03, "no-load speed {at_10} vs {nominal} at 12 V: ratio {ratio:.3}");

    rig.run(Duration::from_millis(1000)); // t = 2.5: ID 1 at 8 V
    let (error, status) = rig.read_value(1, HARDWARE_ERROR_STATUS, 1);
    assert_eq!((error, status as u8), (ALERT_BIT, VOLTAGE_BIT), "below Min Voltage Limit");
    assert_eq!(rig.read_value(1, PRESENT_INPUT_VOLTAGE, 2).1, 80);
    assert_eq!(rig.read_value(5, PRESENT_INPUT_VOLTAGE, 2), (0, 120), "only ID 1 sags");
    // Bit 0 is not in the default Shutdown mask (0x34): the motor keeps running, slower.
    assert_eq!(rig.read_value(1, SHUTDOWN, 1).1 & 1, 0);
    let at_8 = rig.read_value(1, PRESENT_VELOCITY, 4).1;
    let ratio = at_8 as f64 / nominal as f64;
    assert!((ratio - 8.0 / 12.0).abs() < 0.03, "no-load speed {at_8} at 8 V: ratio {ratio:.3}");

    rig.run(Duration::from_millis(1000)); // t = 3.5: supply restored, error latched
    assert_eq!(rig.read_value(1, PRESENT_INPUT_VOLTAGE, 2).1, 120);
    assert_eq!(rig.read_value(1, HARDWARE_ERROR_STATUS, 1), (ALERT_BIT, i64::from(VOLTAGE_BIT)), "latched until reboot");
    assert!((rig.read_value(1, PRESENT_VELOCITY, 4).1 - nominal).abs() <= 2, "full speed again");
}

fn std_dev(values: &[f64]) -> f64 {
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt()
}

/// Present Position and Present Velocity of a servo at rest, read every 10 ms.
fn readings_at_rest(specs: &[&str]) -> (Vec<f64>, Vec<f64>) {
    let mut rig = Rig::bench(Timing::Off, specs);
    // Torque on at zero velocity: the servo keeps ticking (an idle one is fast-forwarded).
    spin_on_bench(&mut rig, 4, 0);
    let (mut positions, mut velocities) = (Vec::new(), Vec::new());
    for _ in 0..400 {
        rig.run(Duration::from_millis(10));
        positions.push(rig.read_value(4, PRESENT_POSITION, 4).1 as f64);
        velocities.push(rig.read_value(4, PRESENT_VELOCITY, 4).1 as f64);
    }
    (positions, velocities)
}

#[test]
fn encoder_noise_shows_in_present_position_and_velocity_and_replays_with_the_seed() {
    let (clean_p, clean_v) = readings_at_rest(&[]);
    assert_eq!(std_dev(&clean_p), 0.0);
    assert_eq!(std_dev(&clean_v), 0.0);
    let spec = "encoder_noise:id=4,position_std_pulses=20,velocity_std=5";
    let (noisy_p, noisy_v) = readings_at_rest(&[spec]);
    let (sp, sv) = (std_dev(&noisy_p), std_dev(&noisy_v));
    // The velocity loop closes on the noisy speed and nudges the shaft, so the position spread
    // is the noise plus a little real motion.
    assert!((16.0..30.0).contains(&sp), "Present Position spread {sp:.1} pulses for σ = 20");
    assert!((4.0..6.5).contains(&sv), "Present Velocity spread {sv:.2} units for σ = 5");
    assert_eq!(readings_at_rest(&[spec]), (noisy_p, noisy_v), "the same seed replays the same noise");
}

// ---------------------------------------------------------------------------------------------
// World faults

fn world(terrain: TerrainSpec, gravity: Vector, specs: &[&str]) -> Lockstep {
    let mut sim = world_with_payload(terrain, gravity, true, 0.0);
    sim.bus_mut().set_faults(faults(specs, 7));
    sim
}

/// Hold at zero speed on a vertical wall for 10 s after the fault at 0.5 s; the drift (m, + up).
fn wall_drift(specs: &[&str]) -> (f32, [f32; 4]) {
    let (drift, pulls, _) = wall_drift_and_pulls(specs);
    (drift, pulls)
}

/// [`wall_drift`] and the magnets' pulls (N) at the end as well.
fn wall_drift_and_pulls(specs: &[&str]) -> (f32, [f32; 4], [f32; 4]) {
    let mut sim = world(flat(), tilted_gravity(90.0), specs);
    drive_wheels(&mut sim, 0);
    sim.run(Duration::from_millis(1000));
    let x0 = sim.world().chassis_pose().translation.x;
    let pulls = sim.world().adhesion().map(|a| a.force_n);
    sim.run(Duration::from_secs(10));
    let end = sim.world().adhesion().map(|a| a.force_n);
    (sim.world().chassis_pose().translation.x - x0, pulls, end)
}

#[test]
fn a_failed_magnet_pulls_nothing_and_the_others_hold_the_robot_on_a_wall_unless_both_front_ones_fail() {
    let (healthy_drift, healthy) = wall_drift(&[]);
    let (drift, pulls) = wall_drift(&["magnet_failure:wheel=fl,at=0.5"]);
    assert!(healthy.iter().all(|&f| f > 10.0), "all magnets pull: {healthy:?}");
    assert_eq!(pulls[0], 0.0, "the failed magnet pulls nothing");
    assert!(pulls[1..].iter().all(|&f| f > 10.0), "the others still pull: {pulls:?}");
    assert!(healthy_drift.abs() < 0.001, "healthy drift {:.2} mm", healthy_drift * 1000.0);
    // Measured: three magnets still carry the robot on a vertical wall.
    assert!(drift.abs() < 0.005, "one magnet failed: drift {:.2} mm in 10 s", drift * 1000.0);

    // Measured: both left magnets failed, the right pair still holds (1.5 mm in 10 s)...
    let (drift, _) = wall_drift(&["magnet_failure:wheel=fl,at=0.5", "magnet_failure:wheel=rl,at=0.5"]);
    assert!(drift.abs() < 0.005, "left pair failed: drift {:.2} mm", drift * 1000.0);
    // ...but with both front magnets failed the front section peels off and the robot falls.
    // The pulls are checked at the end: with the front section locked in pitch to the middle one
    // (a multibody rocker) the frame turns away from the wall as one body, and 0.5 s after the
    // failure the rear magnets still reach the steel (37 N each) before the robot falls.
    let (drift, _, pulls) = wall_drift_and_pulls(&["magnet_failure:wheel=fl,at=0.5", "magnet_failure:wheel=fr,at=0.5"]);
    assert!(drift < -1.0, "front pair failed: fell only {:.3} m", -drift);
    assert!(pulls.iter().all(|&f| f == 0.0), "off the wall, no magnet reaches the steel: {pulls:?}");
}

/// Climb a 30° slope at goal 50 for `seconds`; (chassis advance (m), mean slip of the wheels
/// over the last second (m/s), tread speed v·R (m/s)).
fn climb(specs: &[&str], seconds: u64) -> (f32, f32, f32) {
    let mut sim = world(flat(), tilted_gravity(30.0), specs);
    drive_wheels(&mut sim, 50);
    let x0 = sim.world().chassis_pose().translation.x;
    sim.run(Duration::from_secs(seconds - 1));
    let mut slip = 0.0;
    for _ in 0..100 {
        sim.run(Duration::from_millis(10));
        slip += WheelPosition::ALL.iter().map(|&w| sim.world().wheel_slip(w)).sum::<f32>() / 4.0 / 100.0;
    }
    let tread = 50.0 * 0.229 / 60.0 * std::f32::consts::TAU * climber().wheel.outer_radius_m;
    (sim.world().chassis_pose().translation.x - x0, slip, tread)
}

#[test]
fn wheels_slip_on_a_low_friction_patch_and_grip_outside_it() {
    let (advance, slip, tread) = climb(&[], 4);
    assert!(slip.abs() < 0.1 * tread, "rolling: slip {slip:.4} m/s vs tread {tread:.4} m/s");
    assert!(advance > 2.5 * tread, "climbed {advance:.3} m");
    // A patch far from the robot changes nothing.
    let (far_advance, far_slip, _) = climb(&["slip_patch:x_m=[5,6],friction=0.0"], 4);
    assert!((far_advance - advance).abs() < 1e-4 && (far_slip - slip).abs() < 1e-4, "a distant patch acts: {far_advance} vs {advance}");
    // Under the robot: the wheels spin and the robot slides back down.
    let (advance, slip, tread) = climb(&["slip_patch:x_m=[-2,2],z_m=[-2,2],friction=0.05"], 4);
    assert!(slip > 0.5 * tread, "spinning: slip {slip:.4} m/s vs tread {tread:.4} m/s");
    assert!(advance < 0.0, "slid {advance:.3} m instead of climbing");
}

// ---------------------------------------------------------------------------------------------
// Scenarios

fn scenario_with(events: &str) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().expect("temp dir");
    let base = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/flat-line.toml")).expect("flat-line");
    let base = base.replace("duration_s = 120.0", "duration_s = 4.0");
    let base = base.split("[expect]").next().unwrap_or_default().to_owned();
    let path = dir.path().join("faults.toml");
    std::fs::write(&path, format!("{base}\n{events}")).expect("write scenario");
    (dir, path)
}

#[test]
fn scenario_fault_events_are_checked_and_show_in_the_time_series_and_summary() {
    let (_dir, path) = scenario_with("[[events]]\nat_s = 1.0\nfault = { kind = \"overlaod\", id = 2 }\n");
    let error = Scenario::load(&path).unwrap_err().to_string();
    assert!(error.contains("faults.toml:") && error.contains("overlaod"), "{error}");
    let (_dir, path) = scenario_with("[[events]]\nat_s = 1.0\nuntil_s = 2.0\nfault = { kind = \"overload\", id = 2 }\n");
    assert!(Scenario::load(&path).unwrap_err().to_string().contains("Reboot"));

    let (_dir, path) = scenario_with(
        "[[events]]\nat_s = 1.0\nfault = { kind = \"overload\", id = 2 }\n\n\
         [[events]]\nat_s = 2.0\nuntil_s = 3.0\nfault = { kind = \"voltage_sag\", volts = 10.0 }\n\n\
         [[events]]\nat_s = 0.5\nfault = { kind = \"drop_replies\", id = 8, probability = 0.5 }\n",
    );
    let scenario = Scenario::load(&path).expect("scenario with faults");
    let outcome = climbsim::runner::lockstep::run_lockstep(&scenario, &robot()).expect("run");
    let series = outcome.series.as_ref().expect("run_lockstep keeps the captured rows");
    let column = |name: &str| series.column(name).expect(name);
    let (t, hw2, torque2, volts) = (column("t_s"), column("hw_error_2"), column("torque_on_2"), column("input_voltage_1_v"));
    let at = |values: &[f64], time: f64| values[t.iter().position(|&s| s >= time).expect("time in series")];
    assert_eq!((at(&hw2, 0.9), at(&torque2, 0.9)), (0.0, 1.0));
    assert_eq!((at(&hw2, 1.1), at(&torque2, 1.1)), (f64::from(OVERLOAD_BIT), 0.0));
    assert_eq!((at(&volts, 1.9), at(&volts, 2.5), at(&volts, 3.5)), (12.0, 10.0, 12.0));
    assert_eq!(at(&column("faults_active"), 2.5), 3.0);
    assert!(*column("bus_faults").last().unwrap() > 10.0, "dropped replies counted");
    assert_eq!(outcome.summary["faults.scheduled"], 3);
    assert_eq!(outcome.summary["faults.hw_error_2"], u64::from(OVERLOAD_BIT));
    assert!(outcome.summary["faults.replies_dropped"].as_u64().unwrap() > 10);
    assert!(outcome.summary["faults.control_periods_skipped"].as_u64().unwrap() > 10, "the controller lived through lost replies");
    assert_eq!(outcome.settings["faults"].as_array().map(Vec::len), Some(3));
}
