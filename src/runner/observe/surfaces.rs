//! What happens between the robot and the steel over a run: transitions from one surface to
//! another (floor to wall, wall to floor), how firmly the magnets held, and whether the robot
//! slid back along its line. Fed from the metric track's samples; pure arithmetic on what the
//! world reports (each wheel's contact normal and magnet pull) and the line's ground truth.
//!
//! # A transition
//! The surface the robot starts on is the mean of its four contact normals at the first sample
//! where all four magnets find steel. A transition **starts** at the first sample where some
//! wheel's contact normal has turned more than [`LEAVE_DEG`] from it, and is **complete** at the
//! first later sample where all four contact normals lie within [`ARRIVE_DEG`] of their mean and
//! that mean has turned at least [`NEW_SURFACE_DEG`] from the start's. Only the first transition
//! is measured.

use rapier3d::math::Vector;
use serde_json::{Value, json};

/// A wheel whose contact normal turned this far from the start surface's has left it (deg).
pub const LEAVE_DEG: f32 = 10.0;
/// All four contact normals within this of their mean: the robot stands on one surface (deg).
pub const ARRIVE_DEG: f32 = 10.0;
/// The surface arrived on differs from the start's by at least this (deg): a fillet's facet is
/// not a new surface, a wall is.
pub const NEW_SURFACE_DEG: f32 = 45.0;
/// A magnet "held" a pull when it kept at least that pull for this long (s): shorter dips are
/// bounces of a wheel over a bead, not a loss of grip.
pub const HOLD_S: f64 = 0.1;

pub use crate::scenario::DEFAULT_ADHESION_FLOOR_N;

/// One sample: time, each magnet's pull (N) and contact normal (None off the steel), the
/// line's ground truth (distance and arc length along it; NaN without a line).
#[derive(Debug, Clone, Copy)]
pub struct SurfaceSample {
    pub t_s: f64,
    pub pull_n: [f32; 4],
    pub normal: [Option<Vector>; 4],
    pub d_true_m: f64,
    pub arc_m: f64,
}

/// The metrics, accumulated sample by sample (so a run of days keeps no history).
#[derive(Debug, Clone)]
pub struct SurfaceTrack {
    /// The pull (N) a magnet may not stay under for long (`adhesion.longest_below_s`).
    floor_n: f32,
    start_normal: Option<Vector>,
    started_at_s: Option<f64>,
    completed_at_s: Option<f64>,
    max_abs_d_in_transition_m: f64,
    /// Per magnet: the time its pull last was at or above `floor_n`, and when it went under.
    under_since_s: [Option<f64>; 4],
    longest_below_s: f64,
    /// Per magnet: recent (t, pull) within [`HOLD_S`], for the weakest pull held.
    recent: [std::collections::VecDeque<(f64, f32)>; 4],
    min_held_n: Option<f32>,
    furthest_arc_m: f64,
    slid_back_m: f64,
}

impl SurfaceTrack {
    /// `floor_n`: the stated pull below which no magnet should stay for long.
    pub fn new(floor_n: f32) -> Self {
        Self {
            floor_n,
            start_normal: None,
            started_at_s: None,
            completed_at_s: None,
            max_abs_d_in_transition_m: 0.0,
            under_since_s: [None; 4],
            longest_below_s: 0.0,
            recent: Default::default(),
            min_held_n: None,
            furthest_arc_m: f64::NEG_INFINITY,
            slid_back_m: 0.0,
        }
    }

    pub fn push(&mut self, sample: &SurfaceSample) {
        let t = sample.t_s;
        for wheel in 0..4 {
            let pull = sample.pull_n[wheel];
            if pull < self.floor_n {
                let since = *self.under_since_s[wheel].get_or_insert(t);
                self.longest_below_s = self.longest_below_s.max(t - since);
            } else {
                self.under_since_s[wheel] = None;
            }
            let recent = &mut self.recent[wheel];
            recent.push_back((t, pull));
            while recent.front().is_some_and(|(t0, _)| t - t0 > HOLD_S) {
                recent.pop_front();
            }
            // Once the window spans HOLD_S, the pull stayed at or under its largest value in it
            // for that long: the least of those is the weakest pull held.
            if recent.front().is_some_and(|(t0, _)| t - t0 >= HOLD_S - 1e-9) {
                let held = recent.iter().map(|(_, p)| *p).fold(f32::NEG_INFINITY, f32::max);
                self.min_held_n = Some(self.min_held_n.map_or(held, |m| m.min(held)));
            }
        }
        if sample.arc_m.is_finite() {
            self.furthest_arc_m = self.furthest_arc_m.max(sample.arc_m);
            self.slid_back_m = self.slid_back_m.max(self.furthest_arc_m - sample.arc_m);
        }
        self.follow_transition(sample);
    }

    fn follow_transition(&mut self, sample: &SurfaceSample) {
        let all = sample.normal.iter().copied().collect::<Option<Vec<Vector>>>();
        let Some(start) = self.start_normal else {
            self.start_normal = all.as_deref().and_then(mean_direction);
            return;
        };
        if self.completed_at_s.is_some() {
            return;
        }
        if self.started_at_s.is_none() {
            if sample.normal.iter().flatten().any(|n| angle_deg(*n, start) > LEAVE_DEG) {
                self.started_at_s = Some(sample.t_s);
            } else {
                return;
            }
        }
        if sample.d_true_m.is_finite() {
            self.max_abs_d_in_transition_m = self.max_abs_d_in_transition_m.max(sample.d_true_m.abs());
        }
        if let Some(normals) = all
            && let Some(mean) = mean_direction(&normals)
            && normals.iter().all(|n| angle_deg(*n, mean) <= ARRIVE_DEG)
            && angle_deg(mean, start) >= NEW_SURFACE_DEG
        {
            self.completed_at_s = Some(sample.t_s);
        }
    }

    /// The metrics for `summary.json` (see `docs/scenarios-and-runs.md`): always the adhesion's
    /// and the slide's; the transition's once one started.
    pub fn summary(&self) -> Vec<(String, Value)> {
        let mut out = vec![("adhesion.longest_below_s".to_owned(), json!(self.longest_below_s)), ("adhesion.floor_n".to_owned(), json!(self.floor_n))];
        if let Some(held) = self.min_held_n {
            out.push(("adhesion.min_held_n".to_owned(), json!(held)));
        }
        if self.furthest_arc_m.is_finite() {
            out.push(("line.slid_back_m".to_owned(), json!(self.slid_back_m)));
        }
        if let Some(started) = self.started_at_s {
            out.push(("transition.started_at_s".to_owned(), json!(started)));
            out.push(("transition.completed".to_owned(), json!(u8::from(self.completed_at_s.is_some()))));
            out.push(("transition.max_abs_distance_m".to_owned(), json!(self.max_abs_d_in_transition_m)));
            if let Some(done) = self.completed_at_s {
                out.push(("transition.time_s".to_owned(), json!(done - started)));
            }
        }
        out
    }
}

fn angle_deg(a: Vector, b: Vector) -> f32 {
    a.angle_between(b).to_degrees()
}

fn mean_direction(normals: &[Vector]) -> Option<Vector> {
    normals.iter().sum::<Vector>().try_normalize()
}

/// As a metric of the run's track: each wheel's pull and contact normal, and the ground truth.
impl super::metrics::TrackMetric for SurfaceTrack {
    fn push(&mut self, sample: &super::metrics::TrackSample<'_>) {
        let adhesion = sample.world.adhesion();
        SurfaceTrack::push(
            self,
            &SurfaceSample {
                t_s: sample.t_s,
                pull_n: adhesion.each_ref().map(|a| a.force_n),
                normal: adhesion.each_ref().map(|a| a.contact.map(|(_, n)| n)),
                d_true_m: sample.truth.d_err_m,
                arc_m: sample.truth.arc_m,
            },
        );
    }

    fn summary(&self) -> Vec<(String, Value)> {
        SurfaceTrack::summary(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const UP: Vector = Vector::Y;
    const WALL: Vector = Vector::NEG_X;

    fn sample(t_s: f64, normal: [Option<Vector>; 4], pull_n: [f32; 4], arc_m: f64) -> SurfaceSample {
        SurfaceSample { t_s, pull_n, normal, d_true_m: 0.001 * t_s, arc_m }
    }

    fn metrics(track: &SurfaceTrack) -> std::collections::BTreeMap<String, f64> {
        track.summary().into_iter().map(|(k, v)| (k, v.as_f64().unwrap_or(f64::NAN))).collect()
    }

    #[test]
    fn a_floor_to_wall_transition_starts_when_a_wheel_turns_and_ends_when_all_four_stand_on_the_wall() {
        let mut track = SurfaceTrack::new(20.0);
        let tilted = Vector::new(-0.5, 0.866, 0.0); // 30° up the fillet
        let frames: [(f64, [Option<Vector>; 4]); 6] = [
            (0.0, [Some(UP); 4]),
            (1.0, [Some(UP); 4]),
            (2.0, [Some(tilted), Some(tilted), Some(UP), Some(UP)]),
            (3.0, [Some(WALL), Some(WALL), None, Some(tilted)]),
            (4.0, [Some(WALL), Some(WALL), Some(WALL), Some(tilted)]),
            (5.0, [Some(WALL); 4]),
        ];
        for (t, normal) in frames {
            track.push(&sample(t, normal, [80.0; 4], t));
        }
        let m = metrics(&track);
        assert_eq!(m["transition.started_at_s"], 2.0);
        assert_eq!(m["transition.completed"], 1.0);
        assert_eq!(m["transition.time_s"], 3.0);
        // The distance error's largest from 2 s to 5 s: 5 mm.
        assert!((m["transition.max_abs_distance_m"] - 0.005).abs() < 1e-12);
        assert_eq!(m["line.slid_back_m"], 0.0);
    }

    #[test]
    fn no_transition_no_transition_metrics_and_one_that_never_arrives_is_not_completed() {
        let mut flat = SurfaceTrack::new(20.0);
        for k in 0..10 {
            flat.push(&sample(f64::from(k), [Some(UP); 4], [80.0; 4], 0.0));
        }
        assert!(!metrics(&flat).contains_key("transition.started_at_s"));
        let mut stuck = SurfaceTrack::new(20.0);
        let tilted = Vector::new(-0.5, 0.866, 0.0);
        for k in 0..10 {
            let n = if k < 3 { UP } else { tilted };
            stuck.push(&sample(f64::from(k), [Some(n), Some(n), Some(UP), Some(UP)], [80.0; 4], 0.0));
        }
        let m = metrics(&stuck);
        assert_eq!(m["transition.completed"], 0.0);
        assert!(!m.contains_key("transition.time_s"));
    }

    #[test]
    fn adhesion_longest_below_the_floor_and_the_least_pull_held_for_a_tenth_of_a_second() {
        let mut track = SurfaceTrack::new(20.0);
        // 100 Hz: the front-left magnet dips to 5 N for 30 ms (a bounce), then to 15 N for 0.5 s.
        for k in 0..=200 {
            let t = f64::from(k) * 0.01;
            let fl = match k {
                50..=52 => 5.0,
                100..=150 => 15.0,
                _ => 80.0,
            };
            track.push(&sample(t, [Some(UP); 4], [fl, 80.0, 80.0, 80.0], 0.0));
        }
        let m = metrics(&track);
        assert!((m["adhesion.longest_below_s"] - 0.5).abs() < 1e-9, "{m:?}");
        // The bounce to 5 N is shorter than 0.1 s; 15 N was held.
        assert_eq!(m["adhesion.min_held_n"], 15.0);
    }

    #[test]
    fn sliding_back_along_the_line_is_measured_from_the_furthest_point_reached() {
        let mut track = SurfaceTrack::new(20.0);
        for (t, arc) in [(0.0, 0.0), (1.0, 0.3), (2.0, 0.5), (3.0, 0.42), (4.0, 0.6), (5.0, 0.58)] {
            track.push(&sample(t, [Some(WALL); 4], [80.0; 4], arc));
        }
        assert!((metrics(&track)["line.slid_back_m"] - 0.08).abs() < 1e-9);
    }
}
