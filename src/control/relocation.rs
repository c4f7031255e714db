//! Relocation between welds (seed report §6), the built-in controller's option `[relocation]`:
//! after the last point of one weld the robot plans a path to just before the next weld's start
//! on its occupancy grid ([`super::planner`]), follows it (pure pursuit), turns on the spot to
//! the weld's heading, drives onto the weld until the camera sees it, and follows it. The grid
//! starts as the map the robot is given (terrain it cannot climb); every LIDAR return marks a
//! cell blocked, and a path that a new blocked cell comes too close to is planned again.
//!
//! The robot's pose comes from outside (see [`Pose2`]): climbsim hands the built-in controller
//! the simulator's own pose, a stand-in for whatever localisation a real robot has (the seed's
//! Unity robot had its transform). What this measures is planning and path following, not
//! localisation.

use serde::{Deserialize, Serialize};

use super::planner::{OccupancyGrid, PlannedPath};

fn default_speed_mm_min() -> f64 {
    3000.0
}
fn default_cell_m() -> f64 {
    0.05
}
fn default_clearance_m() -> f64 {
    0.25
}
fn default_approach_m() -> f64 {
    0.15
}
fn default_arrive_tolerance_m() -> f64 {
    0.02
}
fn default_lookahead_m() -> f64 {
    0.15
}
fn default_max_slope_deg() -> f64 {
    25.0
}
fn default_map_margin_m() -> f64 {
    1.0
}

/// A scenario's `[relocation]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RelocationConfig {
    /// Driving speed between welds (mm/min).
    #[serde(default = "default_speed_mm_min")]
    pub speed_mm_min: f64,
    /// The occupancy grid's cell (m).
    #[serde(default = "default_cell_m")]
    pub cell_m: f64,
    /// How far the robot's centre keeps from anything blocked (m): blocked cells are grown by
    /// this before planning. 0.25 m is this robot's half-diagonal (0.2 m to the wheels' fronts,
    /// 0.15 m to their outer faces) and a little more.
    #[serde(default = "default_clearance_m")]
    pub clearance_m: f64,
    /// The path ends this far before a weld's start, on its line, so that the robot drives onto
    /// it straight (m).
    #[serde(default = "default_approach_m")]
    pub approach_m: f64,
    /// Within this of the path's end the robot has arrived (m).
    #[serde(default = "default_arrive_tolerance_m")]
    pub arrive_tolerance_m: f64,
    /// Pure pursuit's look-ahead (m).
    #[serde(default = "default_lookahead_m")]
    pub lookahead_m: f64,
    /// Terrain steeper than this is not planned across (deg).
    #[serde(default = "default_max_slope_deg")]
    pub max_slope_deg: f64,
    /// The grid covers the welds and this much round them (m).
    #[serde(default = "default_map_margin_m")]
    pub map_margin_m: f64,
}

impl Default for RelocationConfig {
    fn default() -> Self {
        Self {
            speed_mm_min: default_speed_mm_min(),
            cell_m: default_cell_m(),
            clearance_m: default_clearance_m(),
            approach_m: default_approach_m(),
            arrive_tolerance_m: default_arrive_tolerance_m(),
            lookahead_m: default_lookahead_m(),
            max_slope_deg: default_max_slope_deg(),
            map_margin_m: default_map_margin_m(),
        }
    }
}

/// The robot in plan: (x, z) of its centre and its heading (yaw about +y, + = left; heading h
/// points along (cos h, −sin h) in (x, z)).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose2 {
    pub x: f64,
    pub z: f64,
    pub heading_rad: f64,
}

/// A weld as the controller knows it: its points in plan, start to end.
#[derive(Debug, Clone, PartialEq)]
pub struct WeldTask {
    pub points: Vec<[f32; 2]>,
}

impl WeldTask {
    fn start(&self) -> [f64; 2] {
        self.points.first().map_or([0.0; 2], |p| p.map(f64::from))
    }

    fn end(&self) -> [f64; 2] {
        self.points.last().map_or([0.0; 2], |p| p.map(f64::from))
    }

    /// Unit direction of the first segment, and of the last.
    fn directions(&self) -> ([f64; 2], [f64; 2]) {
        let unit = |a: [f32; 2], b: [f32; 2]| {
            let (dx, dz) = (f64::from(b[0] - a[0]), f64::from(b[1] - a[1]));
            let length = dx.hypot(dz).max(f64::EPSILON);
            [dx / length, dz / length]
        };
        let n = self.points.len();
        if n < 2 {
            return ([1.0, 0.0], [1.0, 0.0]);
        }
        (unit(self.points[0], self.points[1]), unit(self.points[n - 2], self.points[n - 1]))
    }

    /// Where a path to this weld ends: `approach_m` before its start, on its line.
    fn approach(&self, approach_m: f64) -> [f64; 2] {
        let ([dx, dz], _) = self.directions();
        let [x, z] = self.start();
        [x - approach_m * dx, z - approach_m * dz]
    }

    fn heading_rad(&self) -> f64 {
        let ([dx, dz], _) = self.directions();
        (-dz).atan2(dx)
    }

    /// The robot's centre has passed the weld's last point.
    fn passed_end(&self, pose: Pose2) -> bool {
        let (_, [dx, dz]) = self.directions();
        let [x, z] = self.end();
        (pose.x - x) * dx + (pose.z - z) * dz >= 0.0
    }
}

/// What relocation is doing.
#[derive(Debug, Clone, PartialEq)]
pub enum Leg {
    /// Following weld `weld` on the camera.
    Welding { weld: usize },
    /// Driving the planned path to weld `weld`'s approach point.
    Driving { weld: usize, path: PlannedPath },
    /// At the approach point, turning on the spot to the weld's heading.
    Aligning { weld: usize },
    /// Driving straight onto the weld until the camera sees it.
    Joining { weld: usize },
    /// The last weld is done: standing still.
    Finished,
    /// No path: standing still (the planner's reason).
    Stuck { reason: String },
}

impl Leg {
    /// A number for the time series: the weld being worked on or driven to, + 0.5 between welds
    /// (driving, aligning, joining), −1 finished, −2 stuck.
    pub fn code(&self) -> f64 {
        match self {
            Leg::Welding { weld } => *weld as f64,
            Leg::Driving { weld, .. } | Leg::Aligning { weld } | Leg::Joining { weld } => *weld as f64 - 0.5,
            Leg::Finished => -1.0,
            Leg::Stuck { .. } => -2.0,
        }
    }
}

/// This period's commands; `None` leaves the line follower and the target speed in charge.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RelocationDecision {
    pub speed_m_s: Option<f64>,
    pub yaw_rate_rad_s: Option<f64>,
}

/// The relocation state machine.
#[derive(Debug, Clone)]
pub struct Relocation {
    config: RelocationConfig,
    welds: Vec<WeldTask>,
    /// What the robot knows: the given map plus every LIDAR return so far (not grown).
    map: OccupancyGrid,
    leg: Leg,
    replans: u32,
}

/// Turning on the spot faster than this (rad/s) is not asked for; the controller's own yaw
/// limit applies after it.
const TURN_RATE_RAD_S: f64 = 0.5;
/// Aligned with a weld within this (rad), 1°.
const ALIGNED_RAD: f64 = 0.0175;
/// A target more than this off the nose (rad), 40°, is turned to on the spot first.
const TURN_IN_PLACE_RAD: f64 = 0.7;

impl Relocation {
    pub fn new(config: RelocationConfig, welds: Vec<WeldTask>, map: OccupancyGrid) -> Self {
        Self { config, welds, map, leg: Leg::Welding { weld: 0 }, replans: 0 }
    }

    pub fn leg(&self) -> &Leg {
        &self.leg
    }

    /// How many times a path was planned again because the LIDAR found it blocked.
    pub fn replans(&self) -> u32 {
        self.replans
    }

    /// One control period: the robot's pose, the LIDAR's new returns in plan, whether the camera
    /// sees a line, and the welding speed.
    pub fn update(&mut self, pose: Pose2, returns: &[[f32; 2]], line_seen: bool) -> RelocationDecision {
        // Returns in cells not yet blocked (and inside the map: outside counts as blocked).
        let mut fresh = Vec::new();
        for &[x, z] in returns {
            if !self.map.is_blocked(x, z) {
                self.map.block_point(x, z);
                fresh.push([x, z]);
            }
        }
        let speed = self.config.speed_mm_min / 60_000.0;
        let stop = RelocationDecision { speed_m_s: Some(0.0), yaw_rate_rad_s: Some(0.0) };
        match self.leg.clone() {
            Leg::Welding { weld } => {
                if !self.welds.get(weld).is_some_and(|w| w.passed_end(pose)) {
                    return RelocationDecision::default();
                }
                if weld + 1 >= self.welds.len() {
                    tracing::info!(weld, "relocation: the last weld is done");
                    self.leg = Leg::Finished;
                    return stop;
                }
                self.plan_to(weld + 1, pose);
                stop
            }
            Leg::Driving { weld, path } => {
                let goal = path.points.last().copied().unwrap_or_default();
                let (dx, dz) = (f64::from(goal[0]) - pose.x, f64::from(goal[1]) - pose.z);
                // Arrived: within the tolerance, or close and already past it (a skid-steered
                // robot turning on the spot swings its centre round by a few centimetres, so it
                // may never land within a tight tolerance; the line follower takes up the rest).
                let behind = wrap((-dz).atan2(dx) - pose.heading_rad).abs() > std::f64::consts::FRAC_PI_2;
                let distance = dx.hypot(dz);
                if distance <= self.config.arrive_tolerance_m || (behind && distance <= self.config.lookahead_m) {
                    tracing::info!(weld, distance_m = distance, "relocation: arrived before the weld");
                    self.leg = Leg::Aligning { weld };
                    return stop;
                }
                if self.blocked_ahead(&path, pose, &fresh) {
                    self.replans += 1;
                    self.plan_to(weld, pose);
                    return stop;
                }
                self.pursue(&path, pose, speed)
            }
            Leg::Aligning { weld } => {
                let error = wrap(self.welds[weld].heading_rad() - pose.heading_rad);
                if error.abs() <= ALIGNED_RAD {
                    self.leg = Leg::Joining { weld };
                    return RelocationDecision { speed_m_s: None, yaw_rate_rad_s: Some(0.0) };
                }
                RelocationDecision { speed_m_s: Some(0.0), yaw_rate_rad_s: Some((2.0 * error).clamp(-TURN_RATE_RAD_S, TURN_RATE_RAD_S)) }
            }
            Leg::Joining { weld } => {
                if line_seen {
                    tracing::info!(weld, "relocation: on the weld");
                    self.leg = Leg::Welding { weld };
                    return RelocationDecision::default();
                }
                RelocationDecision { speed_m_s: None, yaw_rate_rad_s: Some(0.0) }
            }
            Leg::Finished | Leg::Stuck { .. } => stop,
        }
    }

    fn plan_to(&mut self, weld: usize, pose: Pose2) {
        let goal = self.welds[weld].approach(self.config.approach_m).map(|v| v as f32);
        let grown = self.map.inflated(self.config.clearance_m as f32);
        // A robot inside a grown cell (the end of a weld next to an obstacle) steps out to the
        // nearest free cell first instead of giving up.
        self.leg = match grown.plan_from_nearest_free([pose.x as f32, pose.z as f32], goal) {
            Ok(path) => {
                tracing::info!(weld, length_m = path.length_m, "relocation: path planned");
                Leg::Driving { weld, path }
            }
            Err(error) => {
                tracing::warn!(%error, weld, "relocation: no path");
                Leg::Stuck { reason: error.to_string() }
            }
        };
    }

    /// Some point of the path still ahead lies within the clearance of a newly blocked cell (the
    /// rule the map's growing applies; the path was planned clear of the cells blocked before).
    fn blocked_ahead(&self, path: &PlannedPath, pose: Pose2, fresh: &[[f32; 2]]) -> bool {
        if fresh.is_empty() {
            return false;
        }
        let from = nearest_index(path, pose);
        let clearance = self.config.clearance_m as f32;
        path.points[from..].iter().any(|&p| fresh.iter().any(|&q| self.map.cells_within(p, q, clearance)))
    }

    /// Pure pursuit toward the point `lookahead_m` ahead on the path.
    fn pursue(&self, path: &PlannedPath, pose: Pose2, speed: f64) -> RelocationDecision {
        let from = nearest_index(path, pose);
        let lookahead = self.config.lookahead_m;
        let target = path.points[from..].iter().find(|p| (f64::from(p[0]) - pose.x).hypot(f64::from(p[1]) - pose.z) >= lookahead).or(path.points.last()).copied().unwrap_or_default();
        let (dx, dz) = (f64::from(target[0]) - pose.x, f64::from(target[1]) - pose.z);
        let alpha = wrap((-dz).atan2(dx) - pose.heading_rad);
        // Turning on the spot near the goal would only swing the centre round it.
        if alpha.abs() > TURN_IN_PLACE_RAD && dx.hypot(dz) >= lookahead {
            return RelocationDecision { speed_m_s: Some(0.0), yaw_rate_rad_s: Some(TURN_RATE_RAD_S.copysign(alpha)) };
        }
        let distance = dx.hypot(dz).max(1e-3);
        RelocationDecision { speed_m_s: Some(speed), yaw_rate_rad_s: Some(2.0 * speed * alpha.sin() / distance) }
    }
}

fn nearest_index(path: &PlannedPath, pose: Pose2) -> usize {
    path.points
        .iter()
        .enumerate()
        .min_by(|(_, a), (_, b)| {
            let da = (f64::from(a[0]) - pose.x).hypot(f64::from(a[1]) - pose.z);
            let db = (f64::from(b[0]) - pose.x).hypot(f64::from(b[1]) - pose.z);
            da.total_cmp(&db)
        })
        .map_or(0, |(k, _)| k)
}

/// An angle in (−π, π].
fn wrap(angle: f64) -> f64 {
    let wrapped = angle.rem_euclid(std::f64::consts::TAU);
    if wrapped > std::f64::consts::PI { wrapped - std::f64::consts::TAU } else { wrapped }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn welds() -> Vec<WeldTask> {
        vec![WeldTask { points: vec![[0.0, 0.0], [1.0, 0.0]] }, WeldTask { points: vec![[1.0, 1.0], [2.0, 1.0]] }]
    }

    fn open_map() -> OccupancyGrid {
        OccupancyGrid::new([-1.0, -1.0], [3.0, 2.0], 0.05).unwrap()
    }

    #[test]
    fn a_weld_then_a_path_then_turning_onto_the_next_weld_then_finished() {
        let mut r = Relocation::new(RelocationConfig::default(), welds(), open_map());
        // On the first weld: the line follower is in charge.
        assert_eq!(r.update(Pose2 { x: 0.5, z: 0.0, heading_rad: 0.0 }, &[], true), RelocationDecision::default());
        // Past its end: a path to 0.15 m before (1, 1) is planned; the robot stops this period.
        let d = r.update(Pose2 { x: 1.001, z: 0.0, heading_rad: 0.0 }, &[], true);
        assert_eq!(d.speed_m_s, Some(0.0));
        let Leg::Driving { weld: 1, path } = r.leg().clone() else { panic!("{:?}", r.leg()) };
        let end = path.points.last().copied().unwrap();
        assert!((end[0] - 0.85).abs() < 1e-6 && (end[1] - 1.0).abs() < 1e-6, "{end:?}");
        // The goal is to the robot's right (+z) and behind-ish: it turns right on the spot first.
        let d = r.update(Pose2 { x: 1.001, z: 0.0, heading_rad: 0.0 }, &[], false);
        assert_eq!(d.speed_m_s, Some(0.0));
        assert!(d.yaw_rate_rad_s.unwrap() < 0.0, "{d:?}");
        // Facing the path, it drives at 3000 mm/min.
        let facing = Pose2 { x: 1.0, z: 0.05, heading_rad: -std::f64::consts::FRAC_PI_2 - 0.4 };
        let d = r.update(facing, &[], false);
        assert_eq!(d.speed_m_s, Some(0.05));
        // At the approach point: align to the weld's heading (0), turning left.
        let d = r.update(Pose2 { x: 0.855, z: 1.0, heading_rad: -1.0 }, &[], false);
        assert_eq!(r.leg(), &Leg::Aligning { weld: 1 });
        assert_eq!(d.speed_m_s, Some(0.0));
        assert!(r.update(Pose2 { x: 0.855, z: 1.0, heading_rad: -1.0 }, &[], false).yaw_rate_rad_s.unwrap() > 0.0);
        // Aligned: straight on at the welding speed until the camera sees the line.
        assert_eq!(r.update(Pose2 { x: 0.855, z: 1.0, heading_rad: 0.001 }, &[], false).yaw_rate_rad_s, Some(0.0));
        assert_eq!(r.leg(), &Leg::Joining { weld: 1 });
        assert_eq!(r.update(Pose2 { x: 0.9, z: 1.0, heading_rad: 0.0 }, &[], true), RelocationDecision::default());
        assert_eq!(r.leg(), &Leg::Welding { weld: 1 });
        // Past the last weld's end: finished, standing still.
        assert_eq!(r.update(Pose2 { x: 2.01, z: 1.0, heading_rad: 0.0 }, &[], true).speed_m_s, Some(0.0));
        assert_eq!(r.leg(), &Leg::Finished);
        assert_eq!(r.leg().code(), -1.0);
    }

    #[test]
    fn a_lidar_return_on_the_path_makes_it_plan_again_around_it() {
        let mut r = Relocation::new(RelocationConfig::default(), welds(), open_map());
        r.update(Pose2 { x: 1.001, z: 0.0, heading_rad: 0.0 }, &[], true);
        let Leg::Driving { path: before, .. } = r.leg().clone() else { panic!("{:?}", r.leg()) };
        // A post right on the path's middle.
        let middle = before.points[before.points.len() / 2];
        r.update(Pose2 { x: 1.001, z: 0.0, heading_rad: -1.5 }, &[middle], false);
        assert_eq!(r.replans(), 1);
        let Leg::Driving { path: after, .. } = r.leg().clone() else { panic!("{:?}", r.leg()) };
        let clearance = |p: &[f32; 2]| (p[0] - middle[0]).hypot(p[1] - middle[1]);
        assert!(after.points.iter().all(|p| clearance(p) >= 0.25 - 0.05), "the new path keeps off the post");
        assert!(after.length_m > before.length_m);
    }

    #[test]
    fn no_way_through_is_stuck_and_standing_still() {
        let mut map = open_map();
        // A wall across the whole map between the welds.
        map.block_where(|_, z| (z - 0.5).abs() < 0.05);
        let mut r = Relocation::new(RelocationConfig::default(), welds(), map);
        let d = r.update(Pose2 { x: 1.001, z: 0.0, heading_rad: 0.0 }, &[], true);
        assert_eq!(d.speed_m_s, Some(0.0));
        assert!(matches!(r.leg(), Leg::Stuck { .. }), "{:?}", r.leg());
        assert_eq!(r.leg().code(), -2.0);
    }
}
