//! The world watch: what makes a run physically impossible, shared by the lockstep run and the
//! wall-clock observer ([`crate::runner::Observer::on_tick`]). A robot that left the terrain, or
//! that no wheel has touched for more than [`NO_CONTACT_LIMIT_S`], is no longer driving: the
//! metrics after that are about a falling body, so the run stops there and says why.

use crate::robot::WheelPosition;
use crate::sim::RobotWorld;

/// How long (s) the robot may go without any wheel on the terrain: longer than a bounce over a
/// bump or a weld bead (milliseconds), shorter than a fall that would leave the world (a second
/// of free fall is ~5 m).
pub const NO_CONTACT_LIMIT_S: f64 = 1.0;
/// A tread within this gap (m) of the terrain counts as touching it: a few times rapier's
/// allowed penetration, well under a bounce that would lose traction.
pub const CONTACT_GAP_M: f32 = 0.005;
/// Simulated time between checks (s): the rules act on the scale of a second, and the ray casts
/// need not cost every 1 ms physics step.
const CHECK_EVERY_S: f64 = 0.01;

/// Why a run stopped early: one line for `summary.json`'s `failures`, and when.
#[derive(Debug, Clone, PartialEq)]
pub struct RunFailure {
    pub at_s: f64,
    pub message: String,
}

/// The rules, checked over a run. The first failure sticks.
#[derive(Debug, Clone, Default)]
pub struct WorldWatch {
    last_contact_s: f64,
    next_check_s: f64,
    failure: Option<RunFailure>,
}

impl WorldWatch {
    pub fn new() -> Self {
        Self::default()
    }

    /// Check the world at `t_s` (at most every [`CHECK_EVERY_S`]); the failure, once there is one.
    pub fn check(&mut self, world: &RobotWorld, t_s: f64) -> Option<&RunFailure> {
        if self.failure.is_none() && t_s >= self.next_check_s {
            self.next_check_s = t_s + CHECK_EVERY_S;
            self.failure = judge(world, t_s, &mut self.last_contact_s);
        }
        self.failure.as_ref()
    }

    pub fn failure(&self) -> Option<&RunFailure> {
        self.failure.as_ref()
    }
}

fn judge(world: &RobotWorld, t_s: f64, last_contact_s: &mut f64) -> Option<RunFailure> {
    let y = world.chassis_pose().translation.y;
    if !over_terrain(world) {
        return Some(RunFailure { at_s: t_s, message: format!("world: the robot left the terrain at t = {t_s:.2} s (y = {y:.2} m)") });
    }
    if WheelPosition::ALL.iter().any(|&w| world.tread_gap_m(w).is_some_and(|gap| gap <= CONTACT_GAP_M)) {
        *last_contact_s = t_s;
        return None;
    }
    (t_s - *last_contact_s > NO_CONTACT_LIMIT_S)
        .then(|| RunFailure { at_s: t_s, message: format!("world: no wheel touched the terrain from t = {:.2} s to {t_s:.2} s (more than {NO_CONTACT_LIMIT_S} s; y = {y:.2} m)", *last_contact_s) })
}

/// Some wheel has terrain straight below (or above: the cast comes from high up) it.
fn over_terrain(world: &RobotWorld) -> bool {
    WheelPosition::ALL.iter().any(|&w| {
        let c = world.wheel_centre(w);
        world.surface_below(c.x, c.z).is_some()
    })
}

/// The start is possible: every wheel has terrain under it, and no obstacle. Checked once the world is built,
/// before the run, so that an impossible start is a load error rather than a fall.
pub fn check_start(world: &RobotWorld) -> Result<(), String> {
    let off: Vec<String> = WheelPosition::ALL
        .iter()
        .filter(|&&w| {
            let c = world.wheel_centre(w);
            world.surface_below(c.x, c.z).is_none()
        })
        .map(|w| {
            let c = world.wheel_centre(*w);
            format!("{w:?} wheel at (x = {:.2} m, z = {:.2} m)", c.x, c.z)
        })
        .collect();
    if !off.is_empty() {
        return Err(format!("the robot starts off the terrain: no terrain under the {} (see [start] and [terrain])", off.join(", ")));
    }
    // Placed on top of an obstacle, the robot would start wherever the obstacle's top is (a tall
    // box lifted it 100 m, to "follow" a weld below it).
    for wheel in WheelPosition::ALL {
        let c = world.wheel_centre(wheel);
        if let Some(index) = world.obstacle_at(c.x, c.z) {
            return Err(format!("obstacles[{index}] stands where the robot starts: under its {wheel:?} wheel at (x = {:.2} m, z = {:.2} m); move the obstacle or [start]", c.x, c.z));
        }
    }
    Ok(())
}
