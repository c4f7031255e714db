//! The weld lines painted on the terrain (`[line]`, then `[[welds]]`): built and draped once,
//! moved by line-offset events, and the ground truth of the robot measured against the nearest.

use std::path::Path;

use rapier3d::prelude::Vector;
use serde_json::{Value, json};

use crate::runner::RunError;
use crate::scenario::validate::{KeyPart, Problem};
use crate::scenario::{LineSection, MAX_WELDS, Scenario};
use crate::sim::line::{LineError as WeldLineError, LineSample};
use crate::sim::terrain::UnrolledProfile;
use crate::sim::{RobotWorld, Surface, WeldLine};

/// The robot's pose relative to the line: what a perfect sensor would say.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GroundTruth {
    /// Distance from the line (m), positive when the robot is left of it.
    pub d_err_m: f64,
    /// Heading relative to the line (rad), positive when the robot points left of it.
    pub psi_err_rad: f64,
    /// Ground speed along the body's forward axis (m/s).
    pub speed_m_s: f64,
    /// How far along the line the robot's nearest point is (m; NaN without a line).
    pub arc_m: f64,
    /// Which weld (0 = `[line]`, then `[[welds]]` in order) these are measured against: the
    /// nearest.
    pub weld: Option<usize>,
}

/// The robot seen from one weld, in plan (for the relocation metrics): how far, whether its
/// nearest point is inside the weld (not an end), and the signed distance and heading error
/// there (m, rad).
#[derive(Debug, Clone, Copy)]
pub struct WeldView {
    pub distance_m: f32,
    pub inside: bool,
    pub d_m: f32,
    pub psi_rad: f32,
}

/// The welds of a run (none: the world is still watched, the view and the robot's state).
pub struct Welds {
    lines: Vec<WeldLine>,
    /// Their control points as given, for line-offset events (the lines are rebuilt and draped
    /// again).
    points: Vec<Vec<[f32; 2]>>,
    /// The terrain laid flat when the line is painted on a wall terrain (see [`UnrolledProfile`]).
    sheet: Option<UnrolledProfile>,
}

impl Welds {
    pub fn new(scenario: &Scenario, world: &RobotWorld) -> Result<Self, RunError> {
        let sheet = UnrolledProfile::of(&scenario.terrain);
        let sections: Vec<&LineSection> = scenario.line.iter().chain(&scenario.welds).collect();
        let lines = sections
            .iter()
            .enumerate()
            .map(|(index, l)| build_line(&l.points, l.smoothness, l.width_m, 0.0, surface(&sheet, world)).map_err(|source| weld_error(&scenario.path, index, source)))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self { lines, points: sections.iter().map(|l| l.points.clone()).collect(), sheet })
    }

    pub fn is_empty(&self) -> bool {
        self.lines.is_empty()
    }

    /// The welds, `[line]` first.
    pub fn lines(&self) -> &[WeldLine] {
        &self.lines
    }

    /// The wall terrain laid flat, when the line is painted on one.
    pub fn sheet(&self) -> Option<&UnrolledProfile> {
        self.sheet.as_ref()
    }

    /// Every weld's draped samples (for the view's stripes).
    pub fn samples(&self) -> Vec<&[LineSample]> {
        self.lines.iter().map(WeldLine::samples).collect()
    }

    /// Move every weld `offset_m` to the left of its direction, draped again.
    pub fn offset(&mut self, offset_m: f64, world: &RobotWorld, scenario_path: &Path) -> Result<(), RunError> {
        let moved = self
            .lines
            .iter()
            .zip(&self.points)
            .enumerate()
            .map(|(index, (line, points))| build_line(points, line.smoothness(), line.width_m(), offset_m, surface(&self.sheet, world)).map_err(|source| weld_error(scenario_path, index, source)))
            .collect::<Result<Vec<_>, _>>()?;
        self.lines = moved;
        Ok(())
    }

    /// The robot's true pose relative to the nearest weld (d and ψ are NaN without a line).
    pub fn ground_truth(&self, world: &RobotWorld) -> GroundTruth {
        let pose = world.chassis_pose();
        let centre = pose.translation;
        let forward = pose.rotation * Vector::X;
        let speed_m_s = f64::from(world.chassis_velocity().dot(forward));
        // Against the weld nearest the robot (the one it follows, or is about to).
        let nearest = self.lines.iter().enumerate().map(|(k, line)| (k, line.nearest(centre))).min_by(|(_, a), (_, b)| (a.point - centre).length().total_cmp(&(b.point - centre).length()));
        let Some((weld, projection)) = nearest else { return GroundTruth { d_err_m: f64::NAN, psi_err_rad: f64::NAN, speed_m_s, arc_m: f64::NAN, weld: None } };
        let (d, psi) = projection.relative_pose(centre, forward);
        GroundTruth { d_err_m: f64::from(d), psi_err_rad: f64::from(psi), speed_m_s, arc_m: f64::from(projection.arc_length_m), weld: Some(weld) }
    }

    /// The robot seen from each weld, in plan (for the relocation metrics).
    pub fn views(&self, world: &RobotWorld) -> [Option<WeldView>; MAX_WELDS] {
        let pose = world.chassis_pose();
        let centre = pose.translation;
        let forward = pose.rotation * Vector::X;
        let mut views = [None; MAX_WELDS];
        for (view, line) in views.iter_mut().zip(&self.lines) {
            let p = line.nearest(centre);
            let (d_m, psi_rad) = p.relative_pose(centre, forward);
            *view = Some(WeldView { distance_m: (p.point.x - centre.x).hypot(p.point.z - centre.z), inside: p.arc_length_m > 1e-3 && p.arc_length_m < line.length_m() - 1e-3, d_m, psi_rad });
        }
        views
    }

    /// The weld list as the sensor server's `/welds` serves it.
    pub fn to_json(&self) -> Value {
        let welds: Vec<Value> = self
            .lines
            .iter()
            .zip(&self.points)
            .enumerate()
            .map(|(index, (line, points))| json!({ "index": index, "points": points, "smoothed": line.smoothed(), "length_m": line.length_m() }))
            .collect();
        json!({ "welds": welds })
    }
}

/// Weld `index` (0: `[line]`, then `[[welds]]` in order) could not be drawn: named as its key,
/// at its line in the scenario file.
fn weld_error(scenario_path: &Path, index: usize, source: WeldLineError) -> RunError {
    let key = match index {
        0 => vec![KeyPart::Key("line".to_owned())],
        n => vec![KeyPart::Key("welds".to_owned()), KeyPart::Index(n - 1)],
    };
    let problem = Problem { key, message: source.to_string() };
    let line = std::fs::read_to_string(scenario_path).ok().and_then(|text| problem.line_in(&text));
    RunError::Line { path: scenario_path.to_owned(), line, weld: problem.key_text(), source }
}

fn build_line(points: &[[f32; 2]], smoothness: u32, width_m: f32, offset_m: f64, surface: &dyn Surface) -> Result<WeldLine, WeldLineError> {
    let shifted = offset_points(points, offset_m as f32);
    let mut line = WeldLine::new(&shifted, smoothness, width_m)?;
    line.drape(surface)?;
    Ok(line)
}

/// What a line is painted on: a wall terrain's unrolled sheet (so it can go up the wall), or
/// whatever is below its points.
fn surface<'a>(sheet: &'a Option<UnrolledProfile>, world: &'a RobotWorld) -> &'a dyn Surface {
    match sheet {
        Some(sheet) => sheet,
        None => world,
    }
}

/// The control points moved `offset` to the left of the line's direction (per segment, joined
/// at each corner along the mean of its segments' left normals).
fn offset_points(points: &[[f32; 2]], offset: f32) -> Vec<[f32; 2]> {
    if offset == 0.0 || points.len() < 2 {
        return points.to_vec();
    }
    let left = |a: [f32; 2], b: [f32; 2]| {
        let (dx, dz) = (b[0] - a[0], b[1] - a[1]);
        let length = dx.hypot(dz).max(f32::EPSILON);
        // Up × along, with z to the right: (dz, −dx) / length.
        [dz / length, -dx / length]
    };
    (0..points.len())
        .map(|i| {
            let before = (i > 0).then(|| left(points[i - 1], points[i]));
            let after = (i + 1 < points.len()).then(|| left(points[i], points[i + 1]));
            let n = match (before, after) {
                (Some(a), Some(b)) => {
                    let (x, z) = (a[0] + b[0], a[1] + b[1]);
                    let length = x.hypot(z).max(f32::EPSILON);
                    [x / length, z / length]
                }
                (Some(n), None) | (None, Some(n)) => n,
                (None, None) => [0.0, 0.0],
            };
            [points[i][0] + offset * n[0], points[i][1] + offset * n[1]]
        })
        .collect()
}
