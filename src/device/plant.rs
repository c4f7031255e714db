//! What the servos' shafts are attached to, advanced in firmware ticks up to a given time.

use std::time::Duration;

use super::servo::Servo;
use super::shaft::{BenchLoad, ShaftLoad};

/// Owns the shafts of a set of servos and advances them. The bus calls `advance` before it hands
/// a packet to the servos, so Present registers are current when they are read.
pub trait Plant: Send {
    fn advance(&mut self, servos: &mut [Servo], until: Duration);
    /// For callers that know the concrete plant (tests, sensors) to reach it through the bus.
    fn as_any(&self) -> &dyn std::any::Any;
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any;
    /// Start (`active`) or end a fault that acts on the plant (a magnet, the terrain); `key`
    /// tells apart faults of the same kind. False if this plant has nothing it could act on.
    fn inject_fault(&mut self, _key: usize, _fault: &crate::fault::Fault, _active: bool) -> bool {
        false
    }
}

/// A plant that no longer moves: the servos keep what they last sensed. For servos answering
/// after their world has stopped (a controller's clean-up after a run).
#[derive(Debug, Default)]
pub struct StillPlant;

impl Plant for StillPlant {
    fn advance(&mut self, _servos: &mut [Servo], _until: Duration) {}

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

/// Each servo on the bench, driving only its own rotor (and an optional extra inertia).
#[derive(Debug, Default)]
pub struct BenchPlant {
    loads: Vec<BenchLoad>,
}

/// An idle servo further behind than this is fast-forwarded instead of ticked.
const IDLE_FAST_FORWARD: Duration = Duration::from_millis(10);

impl BenchPlant {
    pub fn new(loads: Vec<BenchLoad>) -> Self {
        Self { loads }
    }
}

impl Plant for BenchPlant {
    fn advance(&mut self, servos: &mut [Servo], until: Duration) {
        if self.loads.len() < servos.len() {
            self.loads.resize_with(servos.len(), BenchLoad::default);
        }
        for (servo, load) in servos.iter_mut().zip(&mut self.loads) {
            if servo.is_idle() && until.saturating_sub(servo.next_tick()) > IDLE_FAST_FORWARD {
                servo.skip_idle_until(until);
                continue;
            }
            let dt = servo.control_period().as_secs_f64();
            while servo.next_tick() <= until {
                let tick = servo.next_tick();
                let drive = servo.drive();
                let state = load.step(&drive, dt);
                servo.sense(tick, state);
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
