//! Relocation between a scenario's welds: the maps (what the built-in controller is given, and
//! the true one the metrics are judged on) and the metrics of each move from one weld to the
//! next.
//!
//! # Maps
//! Both cover the welds and `map_margin_m` round them in cells of `cell_m`. The **given** map
//! blocks where there is no terrain or it is steeper than `max_slope_deg` (a deck's drawing
//! shows that); obstacles are not on it, the LIDAR finds them. The **true** map also blocks
//! every cell under an obstacle (a ray straight down meets the obstacle before the terrain).
//!
//! # Metrics
//! The robot is **on** a weld while its centre is within [`ON_WELD_M`] of it and its nearest
//! point is not one of the weld's ends. A relocation runs from the last moment on weld k to the
//! moment the centre comes level with weld k + 1's start heading along it (its nearest point
//! leaves the start, within [`ARRIVAL_WINDOW_M`] of the weld and [`ARRIVAL_HEADING_RAD`] of its
//! direction). For each: its time, the length the centre drove,
//! that length over the shortest path on the true map's grid (grown by the clearance, as the
//! planner grows its own; 8-connected, so up to 8 % longer than the shortest curve, and a
//! smooth drive can come in under it) between the same two points, the least distance from the centre to an
//! obstacle cell of the true map, and how far off the weld (|d|) and how askew (|ψ|) the robot
//! was as it came level with the start: the weld it would miss, or weld crooked.

use serde_json::{Value, json};

use crate::control::RelocationConfig;
use crate::control::planner::{OccupancyGrid, PlanError};
use crate::sim::{RobotWorld, WeldLine};

pub use super::welds::WeldView;

/// Within this of a weld (m), the robot is on it.
pub const ON_WELD_M: f32 = 0.01;
/// A robot coming level with a weld's start within this of it (m) has arrived there (further
/// off, it is passing by).
pub const ARRIVAL_WINDOW_M: f32 = 0.1;
/// ... heading along it within this (rad, 60°): a robot crossing the weld, or driving over it
/// the wrong way on its way elsewhere, has not arrived.
pub const ARRIVAL_HEADING_RAD: f32 = std::f32::consts::FRAC_PI_3;
/// Obstacle clearance is looked for this far round the robot (m); further is reported as this.
const CLEARANCE_SEARCH_M: f32 = 2.0;
/// An obstacle stands more than this above the terrain under it (m) to block a cell.
const OBSTACLE_ABOVE_TERRAIN_M: f32 = 0.005;

/// The given map, and the true one, for `welds`.
pub fn maps(world: &RobotWorld, welds: &[WeldLine], config: &RelocationConfig) -> Result<(OccupancyGrid, OccupancyGrid), PlanError> {
    let margin = config.map_margin_m as f32;
    let (mut min, mut max) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for &[x, z] in welds.iter().flat_map(|w| w.smoothed()) {
        min = [min[0].min(x - margin), min[1].min(z - margin)];
        max = [max[0].max(x + margin), max[1].max(z + margin)];
    }
    let mut given = OccupancyGrid::new(min, max, config.cell_m as f32)?;
    let steepest_cos = config.max_slope_deg.to_radians().cos() as f32;
    given.block_where(|x, z| world.terrain_surface_below(x, z).is_none_or(|(_, normal)| normal.y < steepest_cos));
    let mut truth = given.clone();
    truth.block_where(|x, z| {
        let Some((ground, _)) = world.terrain_surface_below(x, z) else { return true };
        let from = rapier3d::math::Vector::new(x, ground.y + 100.0, z);
        world.cast_ray_at_surroundings(from, -rapier3d::math::Vector::Y, 200.0).is_some_and(|toi| from.y - toi > ground.y + OBSTACLE_ABOVE_TERRAIN_M)
    });
    Ok((given, truth))
}

/// One sample for the relocation metrics.
#[derive(Debug, Clone, Copy)]
pub struct RelocationSample {
    pub t_s: f64,
    /// The robot's centre in plan.
    pub position: [f32; 2],
    /// Per weld: distance to it (m), whether the nearest point is inside it (not an end), and
    /// the signed distance and heading error there (m, rad).
    pub nearest: [Option<WeldView>; MAX_WELDS],
}

/// The most welds a scenario may list: the relocation metrics keep a fixed array per sample.
pub use crate::scenario::MAX_WELDS;

#[derive(Debug, Clone, Default)]
struct Move {
    left_at_s: f64,
    from: [f32; 2],
    driven_m: f32,
    min_clearance_m: f32,
}

#[derive(Debug, Clone)]
struct Done {
    time_s: f64,
    path_ratio: Option<f64>,
    min_clearance_m: f32,
    arrival_offset_m: f32,
    arrival_heading_rad: f32,
}

/// The metrics over a run.
#[derive(Debug, Clone)]
pub struct RelocationTrack {
    truth: OccupancyGrid,
    clearance_m: f32,
    welds: usize,
    /// The weld the robot is on or last left.
    last_weld: Option<usize>,
    moving: Option<Move>,
    last_position: Option<[f32; 2]>,
    /// The last moment and place on a weld.
    last_on: (f64, [f32; 2]),
    done: Vec<Done>,
    /// The furthest weld reached (its index), for `welds.reached`.
    furthest: Option<usize>,
}

impl RelocationTrack {
    pub fn new(truth: OccupancyGrid, clearance_m: f32, welds: usize) -> Self {
        Self { truth, clearance_m, welds, last_weld: None, moving: None, last_position: None, last_on: (0.0, [0.0; 2]), done: Vec::new(), furthest: None }
    }

    pub fn push(&mut self, sample: &RelocationSample) {
        let on = sample.nearest.iter().enumerate().find_map(|(k, v)| v.filter(|v| v.inside && v.distance_m <= ON_WELD_M).map(|v| (k, v)));
        let next = self.last_weld.map(|last| last + 1);
        let arrived = next.and_then(|k| sample.nearest.get(k).copied().flatten().filter(|v| v.inside && v.distance_m <= ARRIVAL_WINDOW_M && v.psi_rad.abs() <= ARRIVAL_HEADING_RAD).map(|v| (k, v)));
        let step = self.last_position.map_or(0.0, |p| (p[0] - sample.position[0]).hypot(p[1] - sample.position[1]));
        self.last_position = Some(sample.position);
        match (arrived.or(on), self.last_weld) {
            (Some((k, view)), Some(last)) if k == last + 1 => {
                if let Some(moved) = self.moving.take() {
                    let optimum = self.truth.inflated(self.clearance_m).plan_from_nearest_free(moved.from, sample.position).ok().map(|p| p.length_m);
                    let driven = moved.driven_m + step;
                    self.done.push(Done {
                        time_s: sample.t_s - moved.left_at_s,
                        path_ratio: optimum.filter(|o| *o > 0.0).map(|o| f64::from(driven / o)),
                        min_clearance_m: moved.min_clearance_m,
                        arrival_offset_m: view.d_m.abs(),
                        arrival_heading_rad: view.psi_rad.abs(),
                    });
                }
                self.last_weld = Some(k);
                self.last_on = (sample.t_s, sample.position);
            }
            (Some((k, _)), _) => {
                self.moving = None;
                self.last_weld = Some(k);
                self.last_on = (sample.t_s, sample.position);
            }
            (None, Some(_)) => {
                let clearance = self.truth.clearance_m(sample.position[0], sample.position[1], CLEARANCE_SEARCH_M);
                let (left_at_s, from) = self.last_on;
                let moving = self.moving.get_or_insert(Move { left_at_s, from, driven_m: 0.0, min_clearance_m: CLEARANCE_SEARCH_M });
                moving.driven_m += step;
                moving.min_clearance_m = moving.min_clearance_m.min(clearance);
            }
            (None, None) => {}
        }
        if let Some(k) = on.map(|(k, _)| k) {
            self.furthest = Some(self.furthest.map_or(k, |f| f.max(k)));
        }
    }

    /// `relocation.*` for `summary.json` (see `docs/scenarios-and-runs.md`).
    pub fn summary(&self) -> Vec<(String, Value)> {
        let max = |f: &dyn Fn(&Done) -> f64| self.done.iter().map(f).fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))));
        let mut out = vec![
            ("relocation.expected".to_owned(), json!(self.welds.saturating_sub(1))),
            ("relocation.completed".to_owned(), json!(self.done.len())),
            ("welds.reached".to_owned(), json!(self.furthest.map_or(0, |f| f + 1))),
        ];
        if self.done.is_empty() {
            return out;
        }
        out.push(("relocation.max_time_s".to_owned(), json!(max(&|d| d.time_s))));
        if let Some(ratio) = max(&|d| d.path_ratio.unwrap_or(f64::NAN)).filter(|r| r.is_finite()) {
            out.push(("relocation.max_path_ratio".to_owned(), json!(ratio)));
        }
        out.push(("relocation.min_clearance_m".to_owned(), json!(self.done.iter().map(|d| d.min_clearance_m).fold(f32::INFINITY, f32::min))));
        out.push(("relocation.max_arrival_offset_m".to_owned(), json!(max(&|d| f64::from(d.arrival_offset_m)))));
        out.push(("relocation.max_arrival_heading_deg".to_owned(), json!(max(&|d| f64::from(d.arrival_heading_rad).to_degrees()))));
        out
    }
}

/// As a metric of the run's track: the robot's centre in plan, seen from every weld.
impl super::metrics::TrackMetric for RelocationTrack {
    fn push(&mut self, sample: &super::metrics::TrackSample<'_>) {
        let position = sample.world.chassis_pose().translation;
        RelocationTrack::push(self, &RelocationSample { t_s: sample.t_s, position: [position.x, position.z], nearest: sample.welds.views(sample.world) });
    }

    fn summary(&self) -> Vec<(String, Value)> {
        RelocationTrack::summary(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(distance_m: f32, inside: bool, d_m: f32) -> Option<WeldView> {
        Some(WeldView { distance_m, inside, d_m, psi_rad: 0.02 })
    }

    fn sample(t_s: f64, position: [f32; 2], on: Option<(usize, f32)>) -> RelocationSample {
        let mut nearest = [None; MAX_WELDS];
        nearest[0] = view(1.0, false, 0.0);
        nearest[1] = view(1.0, false, 0.0);
        if let Some((k, d)) = on {
            nearest[k] = view(d.abs(), true, d);
        }
        RelocationSample { t_s, position, nearest }
    }

    #[test]
    fn a_move_from_one_weld_to_the_next_is_timed_measured_against_the_optimum_and_its_arrival() {
        let mut truth = OccupancyGrid::new([-1.0, -1.0], [3.0, 2.0], 0.05).unwrap();
        // An obstacle cell at (1.025, 0.525): the straight way from (1, 0) to (1, 1) passes it.
        truth.block_point(1.01, 0.51);
        let mut track = RelocationTrack::new(truth, 0.1, 2);
        track.push(&sample(0.0, [0.5, 0.0], Some((0, 0.0))));
        track.push(&sample(1.0, [1.0, 0.0], Some((0, 0.001))));
        // Off the weld: round the obstacle by 0.2 m to the left of it.
        for (k, p) in [[1.0, 0.1], [0.8, 0.3], [0.8, 0.7], [1.0, 0.9]].into_iter().enumerate() {
            track.push(&sample(2.0 + k as f64, p, None));
        }
        track.push(&sample(6.0, [1.0, 1.0], Some((1, 0.004))));
        let m: std::collections::BTreeMap<String, f64> = track.summary().into_iter().map(|(k, v)| (k, v.as_f64().unwrap_or(f64::NAN))).collect();
        assert_eq!(m["relocation.completed"], 1.0);
        assert_eq!(m["relocation.expected"], 1.0);
        assert_eq!(m["welds.reached"], 2.0);
        // Left at 1 s (the last sample on weld 0), arrived at 6 s.
        assert_eq!(m["relocation.max_time_s"], 5.0);
        assert!((m["relocation.max_arrival_offset_m"] - 0.004).abs() < 1e-9);
        // The nearest the centre came to the obstacle cell's centre (1.025, 0.525): at
        // (0.8, 0.7), 0.285 m away.
        assert!((m["relocation.min_clearance_m"] - 0.2850).abs() < 1e-3, "{m:?}");
        // Driven 0.1 + 0.283 + 0.4 + 0.283 + 0.1 = 1.166 m, against the grid's shortest path
        // that keeps 0.1 m off the cell: 8-connected, it is itself a little longer than the
        // shortest curve, so the ratio of a near-optimal drive can dip under 1.
        let ratio = m["relocation.max_path_ratio"];
        assert!(ratio > 0.95 && ratio < 1.1, "{ratio}");
    }

    #[test]
    fn a_robot_that_never_reaches_the_next_weld_has_no_completed_move() {
        let truth = OccupancyGrid::new([-1.0, -1.0], [3.0, 2.0], 0.05).unwrap();
        let mut track = RelocationTrack::new(truth, 0.1, 3);
        track.push(&sample(0.0, [0.5, 0.0], Some((0, 0.0))));
        track.push(&sample(1.0, [1.2, 0.0], None));
        let m: std::collections::BTreeMap<String, f64> = track.summary().into_iter().map(|(k, v)| (k, v.as_f64().unwrap_or(f64::NAN))).collect();
        assert_eq!((m["relocation.completed"], m["relocation.expected"], m["welds.reached"]), (0.0, 2.0, 1.0));
        assert!(!m.contains_key("relocation.max_time_s"));
    }
}
