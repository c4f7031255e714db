//! The painted weld line (seed report §3.2): a polyline of control points, optionally smoothed,
//! draped onto the terrain so that it follows the bumps, with ground-truth queries for metrics.
//!
//! # Frame
//! World frame as everywhere in `sim`: x = robot forward at start, y = up, **z = robot's right**
//! (right-handed). A heading is a yaw about +Y: positive turns the nose left (counter-clockwise
//! seen from above), so heading `h` points along `(cos h, 0, −sin h)`, and "left" is −z.
//!
//! # Smoothing: Chaikin corner cutting
//! The seed's Line Renderer draws straight segments at smoothness 1 and a rounded curve at 10.
//! We cut corners with Chaikin's algorithm, `smoothness − 1` iterations, keeping both endpoints:
//! - smoothness 1 is exactly the polyline, so a sharp corner stays sharp at its control point;
//! - each iteration replaces every segment by its points at 1/4 and 3/4 (the endpoints are kept),
//!   so corners get rounded while straight stretches stay straight; the curve converges to the
//!   quadratic B-spline of the control points: it passes through both endpoints and through the
//!   midpoint of every segment (tangent to it there), a corner is rounded only between the
//!   midpoints of its two segments, and the curve stays inside the control polygon's hull (no
//!   overshoot). Catmull-Rom would instead pass through the corner vertex itself and so not round
//!   it off the way the seed's figure 10 does; an interpolating spline can also overshoot.
//! - so smoothness 2 already chamfers a corner from a quarter of each segment before it (the
//!   curve's distance to the corner vertex is then final: the chamfer's midpoint stays on the
//!   curve); higher values halve the remaining kinks each step (45°, 22.5°, ... for a 90° corner).
//!
//! Iterations beyond [`MAX_CHAIKIN_ITERATIONS`] are not run: each one moves the curve by a
//! quarter of the previous one, so after 10 the change is < 1e-6 of a segment, far below the
//! 5 mm resampling, while the point count would keep doubling.
//!
//! # Draping
//! The smoothed polyline is resampled to at most [`DRAPE_SPACING_M`] between samples (every
//! vertex of the smoothed polyline is kept, so sharp corners survive resampling), then each
//! sample is projected straight down onto a [`Surface`]. The painted stripe's two edges are
//! offset by ± width/2 **along the surface** (perpendicular to the tangent and the surface
//! normal), mitred at kinks so the stripe keeps its width through a sharp corner.

use rapier3d::math::Vector;
use thiserror::Error;

use super::terrain::{TerrainGeometry, UnrolledProfile};

/// Largest spacing between draped samples: short enough to follow terrain bumps of a few cm
/// and to make the stripe's edges look straight in a camera pixel (~1 mm).
pub const DRAPE_SPACING_M: f32 = 0.005;

/// Chaikin iterations are capped here (see the module docs).
pub const MAX_CHAIKIN_ITERATIONS: u32 = 10;

/// Mitre factor cap: the edge offset at a kink grows as 1/cos(half the turn) to keep the
/// stripe's width, up to 2× (a 120° turn); sharper turns get a shorter, bevel-like corner
/// instead of a spike.
const MAX_MITRE: f32 = 2.0;

/// Samples per culling chunk (see [`WeldLine::chunks`]).
pub(crate) const CHUNK: usize = 32;

/// Something a line can be draped on.
pub trait Surface {
    /// The surface point straight below/above (x, z) (the highest one for a heightfield there is
    /// only one) and its unit normal pointing to the side the robot drives on; `None` off the
    /// surface. A surface laid out flat ([`UnrolledProfile`]) takes (x, z) as its own sheet
    /// coordinates instead.
    fn project_down(&self, x: f32, z: f32) -> Option<(Vector, Vector)>;
}

/// Heightfields answer from [`TerrainGeometry::height_at`]; trimesh terrains return `None`
/// (the world implements [`Surface`] with ray casts for those).
impl Surface for TerrainGeometry {
    fn project_down(&self, x: f32, z: f32) -> Option<(Vector, Vector)> {
        let y = self.height_at(x, z)?;
        // Central differences over ±1 mm (one-sided at the border): smooth across triangle
        // edges, and exact on each heightfield triangle larger than 2 mm.
        const E: f32 = 1.0e-3;
        let slope = |a: Option<f32>, b: Option<f32>| match (a, b) {
            (Some(a), Some(b)) => (b - a) / (2.0 * E),
            (None, Some(b)) => (b - y) / E,
            (Some(a), None) => (y - a) / E,
            (None, None) => 0.0,
        };
        let dx = slope(self.height_at(x - E, z), self.height_at(x + E, z));
        let dz = slope(self.height_at(x, z - E), self.height_at(x, z + E));
        Some((Vector::new(x, y, z), Vector::new(-dx, 1.0, -dz).normalize()))
    }
}

/// A wall terrain's unrolled sheet: (x, z) are the sheet's (u, z), see [`UnrolledProfile`].
impl Surface for UnrolledProfile {
    fn project_down(&self, u: f32, z: f32) -> Option<(Vector, Vector)> {
        self.point(u, z)
    }
}

/// Why a weld line could not be built or draped.
#[derive(Debug, Error, PartialEq)]
pub enum LineError {
    #[error("a weld line needs at least 2 distinct points, got {count}")]
    TooFewPoints { count: usize },
    #[error("weld line point {index} is not finite: ({x}, {z})")]
    NonFinite { index: usize, x: f32, z: f32 },
    #[error("weld line width must be positive and finite, got {width_m} m")]
    Width { width_m: f32 },
    #[error("weld line smoothness must be at least 1 (1 = straight segments), got 0")]
    Smoothness,
    #[error("weld line point ({x}, {z}) is not above the terrain")]
    OffSurface { x: f32, z: f32 },
}

/// One draped sample of the line's centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineSample {
    /// Point on the surface.
    pub point: Vector,
    /// Unit surface normal there.
    pub normal: Vector,
    /// Arc length from the first point, measured along the draped (3D) line.
    pub arc_length_m: f32,
    /// Left edge of the painted stripe (on the robot's left when driving along the line).
    pub left_edge: Vector,
    /// Right edge of the painted stripe.
    pub right_edge: Vector,
}

/// The nearest point of the line to a query point: the ground truth for metrics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineProjection {
    /// Nearest point on the line's centre.
    pub point: Vector,
    /// Unit tangent there, pointing along increasing arc length.
    pub tangent: Vector,
    /// Unit surface normal there.
    pub normal: Vector,
    /// Signed distance of the query point from the line, measured along the surface's "left"
    /// (`normal × tangent`): **positive when the line lies to the left of the query point**
    /// for someone at the query point facing along the tangent (the query point is right of the
    /// line). So for a robot heading along the line this equals the detector's `d`.
    pub signed_lateral_m: f32,
    /// Arc length of `point` from the start of the line.
    pub arc_length_m: f32,
    /// Heading of the tangent (yaw about +Y, positive = towards −z = left), radians in (−π, π].
    pub heading_rad: f32,
}

impl LineProjection {
    /// Where a body at `centre` facing `forward` stands relative to the line here, in the run's
    /// convention: its distance (m, + when it is left of the line) and its heading error in the
    /// surface's plane, from the line's tangent to its forward (rad, + when it points left).
    pub fn relative_pose(&self, centre: Vector, forward: Vector) -> (f32, f32) {
        let left = self.normal.cross(self.tangent);
        let forward_in_plane = forward - self.normal * forward.dot(self.normal);
        let psi = self.tangent.cross(forward_in_plane).dot(self.normal).atan2(self.tangent.dot(forward_in_plane));
        ((centre - self.point).dot(left), psi)
    }
}

/// A painted line: control points, smoothing and the draped samples.
#[derive(Debug, Clone, PartialEq)]
pub struct WeldLine {
    control: Vec<[f32; 2]>,
    smoothness: u32,
    width_m: f32,
    /// The smoothed polyline in plan (x, z), before resampling.
    smoothed: Vec<[f32; 2]>,
    samples: Vec<LineSample>,
    /// Bounding spheres (centre, radius) of the stripe over samples
    /// `[CHUNK·i, CHUNK·(i+1)]` (the last sample of a chunk is the first of the next), so the
    /// camera can skip the parts of a long line it cannot see without projecting them.
    chunks: Vec<(Vector, f32)>,
}

impl WeldLine {
    /// A line through the control points `(x, z)` in metres, with `smoothness` as in the seed
    /// (1 = straight segments, higher = rounder corners, see the module docs) and a painted
    /// width. Consecutive duplicate points are dropped. The line lies flat at y = 0 until
    /// [`WeldLine::drape`] puts it on a terrain.
    pub fn new(points: &[[f32; 2]], smoothness: u32, width_m: f32) -> Result<Self, LineError> {
        if let Some((index, &[x, z])) = points.iter().enumerate().find(|(_, p)| !(p[0].is_finite() && p[1].is_finite())) {
            return Err(LineError::NonFinite { index, x, z });
        }
        if !(width_m > 0.0 && width_m.is_finite()) {
            return Err(LineError::Width { width_m });
        }
        if smoothness == 0 {
            return Err(LineError::Smoothness);
        }
        let mut control: Vec<[f32; 2]> = Vec::with_capacity(points.len());
        for p in points {
            if control.last() != Some(p) {
                control.push(*p);
            }
        }
        if control.len() < 2 {
            return Err(LineError::TooFewPoints { count: control.len() });
        }
        let smoothed = chaikin(&control, (smoothness - 1).min(MAX_CHAIKIN_ITERATIONS));
        let mut line = WeldLine { control, smoothness, width_m, smoothed, samples: Vec::new(), chunks: Vec::new() };
        let flat = resample(&line.smoothed).into_iter().map(|[x, z]| (Vector::new(x, 0.0, z), Vector::Y)).collect();
        line.set_samples(flat);
        Ok(line)
    }

    /// Project every sample straight down onto `surface` (normals too) and rebuild the stripe
    /// edges and arc lengths. Fails, leaving the line unchanged, if any sample is off the surface.
    pub fn drape(&mut self, surface: &dyn Surface) -> Result<(), LineError> {
        let draped = resample(&self.smoothed).into_iter().map(|[x, z]| surface.project_down(x, z).ok_or(LineError::OffSurface { x, z })).collect::<Result<Vec<_>, _>>()?;
        self.set_samples(draped);
        Ok(())
    }

    pub fn smoothness(&self) -> u32 {
        self.smoothness
    }

    pub fn width_m(&self) -> f32 {
        self.width_m
    }

    /// The smoothed polyline in plan (x, z), before resampling and draping.
    pub fn smoothed(&self) -> &[[f32; 2]] {
        &self.smoothed
    }

    /// The draped samples, at most [`DRAPE_SPACING_M`] apart in plan.
    pub fn samples(&self) -> &[LineSample] {
        &self.samples
    }

    /// Total draped length.
    pub fn length_m(&self) -> f32 {
        self.samples.last().map_or(0.0, |s| s.arc_length_m)
    }

    pub(crate) fn chunks(&self) -> &[(Vector, f32)] {
        &self.chunks
    }

    /// The nearest point of the line's centre to `p` (a linear search over the samples:
    /// ~1 µs per metre of line, fine for per-step metrics).
    pub fn nearest(&self, p: Vector) -> LineProjection {
        let mut best = (f32::INFINITY, 0usize, 0.0f32);
        for (k, w) in self.samples.windows(2).enumerate() {
            let (a, b) = (w[0].point, w[1].point);
            let ab = b - a;
            let len2 = ab.length_squared();
            let s = if len2 > 0.0 { ((p - a).dot(ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
            let d2 = (a + ab * s - p).length_squared();
            if d2 < best.0 {
                best = (d2, k, s);
            }
        }
        let (_, k, s) = best;
        let (a, b) = (self.samples[k], self.samples[k + 1]);
        let point = a.point.lerp(b.point, s);
        let tangent = (b.point - a.point).normalize_or(Vector::X);
        let normal = a.normal.lerp(b.normal, s).normalize_or(Vector::Y);
        let left = normal.cross(tangent).normalize_or(Vector::NEG_Z);
        LineProjection {
            point,
            tangent,
            normal,
            signed_lateral_m: (point - p).dot(left),
            arc_length_m: a.arc_length_m + s * (b.arc_length_m - a.arc_length_m),
            heading_rad: (-tangent.z).atan2(tangent.x),
        }
    }

    /// Fill samples from (point, normal) pairs: arc lengths, mitred stripe edges, chunks.
    fn set_samples(&mut self, draped: Vec<(Vector, Vector)>) {
        let n = draped.len();
        let half = self.width_m / 2.0;
        let dir = |k: usize| (draped[k + 1].0 - draped[k].0).normalize_or(Vector::X);
        let mut arc = 0.0;
        self.samples = (0..n)
            .map(|k| {
                let (point, normal) = draped[k];
                if k > 0 {
                    arc += (point - draped[k - 1].0).length();
                }
                let before = if k > 0 { dir(k - 1) } else { dir(k) };
                let after = if k + 1 < n { dir(k) } else { before };
                let tangent = (before + after).normalize_or(before);
                let left = normal.cross(tangent).normalize_or(Vector::NEG_Z);
                let segment_left = normal.cross(before).normalize_or(left);
                let mitre = 1.0 / left.dot(segment_left).max(1.0 / MAX_MITRE);
                let offset = left * (half * mitre);
                LineSample { point, normal, arc_length_m: arc, left_edge: point + offset, right_edge: point - offset }
            })
            .collect();
        self.chunks = (0..n.saturating_sub(1).div_ceil(CHUNK).max(1))
            .map(|c| {
                let range = &self.samples[c * CHUNK..(c * CHUNK + CHUNK + 1).min(n)];
                let (lo, hi) = range.iter().fold((Vector::INFINITY, Vector::NEG_INFINITY), |(lo, hi), s| (lo.min(s.left_edge).min(s.right_edge), hi.max(s.left_edge).max(s.right_edge)));
                let centre = (lo + hi) / 2.0;
                (centre, (hi - centre).length())
            })
            .collect();
    }
}

/// Chaikin corner cutting with fixed endpoints: every segment is replaced by its points at 1/4
/// and 3/4, and the two endpoints are kept, so the end segments stay straight from the endpoint
/// to their midpoint.
fn chaikin(points: &[[f32; 2]], iterations: u32) -> Vec<[f32; 2]> {
    let mut current = points.to_vec();
    for _ in 0..iterations {
        if current.len() < 3 {
            break; // a single segment has no corner to cut
        }
        let last = current[current.len() - 1];
        let mut next = Vec::with_capacity(2 * current.len());
        next.push(current[0]);
        for w in current.windows(2) {
            let ([ax, az], [bx, bz]) = (w[0], w[1]);
            next.push([0.75 * ax + 0.25 * bx, 0.75 * az + 0.25 * bz]);
            next.push([0.25 * ax + 0.75 * bx, 0.25 * az + 0.75 * bz]);
        }
        next.push(last);
        current = next;
    }
    current
}

/// Split every segment into equal pieces no longer than [`DRAPE_SPACING_M`], keeping vertices.
fn resample(points: &[[f32; 2]]) -> Vec<[f32; 2]> {
    let mut out = vec![points[0]];
    for w in points.windows(2) {
        let ([ax, az], [bx, bz]) = (w[0], w[1]);
        let len = (bx - ax).hypot(bz - az);
        let pieces = (len / DRAPE_SPACING_M).ceil().max(1.0) as usize;
        for i in 1..=pieces {
            let s = i as f32 / pieces as f32;
            out.push([ax + s * (bx - ax), az + s * (bz - az)]);
        }
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A 1 m × 1 m heightfield (64 cells) with a raised-cosine bump of 30 mm at (0.1, 0.05)
    /// and a gentle Perlin-like ripple, built by hand.
    pub(crate) fn bumpy_terrain() -> TerrainGeometry {
        let n = 65;
        let size = 1.0f32;
        let mut heights = Vec::with_capacity(n * n);
        for i in 0..n {
            let z = (-0.5 + i as f32 / (n - 1) as f32) * size;
            for j in 0..n {
                let x = (-0.5 + j as f32 / (n - 1) as f32) * size;
                let d = ((x - 0.1).powi(2) + (z - 0.05).powi(2)).sqrt();
                let bump = if d < 0.1 { 0.015 * (1.0 + (std::f32::consts::PI * d / 0.1).cos()) } else { 0.0 };
                let ripple = 0.004 * (7.0 * x).sin() * (5.0 * z + 0.3).cos();
                heights.push(bump + ripple);
            }
        }
        TerrainGeometry::HeightField { heights, rows: n, cols: n, scale: Vector::new(size, 1.0, size) }
    }

    fn distance_to(points: &[[f32; 2]], c: [f32; 2]) -> f32 {
        points.iter().map(|p| (p[0] - c[0]).hypot(p[1] - c[1])).fold(f32::INFINITY, f32::min)
    }

    #[test]
    fn drape_follows_the_heightfield() {
        let terrain = bumpy_terrain();
        let mut line = WeldLine::new(&[[-0.3, 0.05], [0.3, 0.05], [0.3, -0.2]], 3, 0.02).unwrap();
        line.drape(&terrain).unwrap();
        let top = line.samples().iter().map(|s| s.point.y).fold(f32::MIN, f32::max);
        assert!(top > 0.025, "the line crosses the 30 mm bump, highest sample {top}");
        for s in line.samples() {
            let h = terrain.height_at(s.point.x, s.point.z).unwrap();
            assert!((s.point.y - h).abs() < 1e-3, "sample {:?} vs height {h}", s.point);
            assert!((s.normal.length() - 1.0).abs() < 1e-4);
            // Edges lie in the tangent plane, half a width (or a mitre) from the centre.
            let half = (s.left_edge - s.point).length();
            assert!((0.01 - 1e-4..=0.02 + 1e-4).contains(&half), "half width {half}");
            assert!((s.left_edge - s.point).dot(s.normal).abs() < 1e-5);
        }
        // Samples are dense enough to follow the bump (spacing in plan ≤ 5 mm).
        for w in line.samples().windows(2) {
            let d = (w[1].point.x - w[0].point.x).hypot(w[1].point.z - w[0].point.z);
            assert!(d <= DRAPE_SPACING_M + 1e-6);
        }
        // The normal leans away from the bump's top on its flank: at x = 0.05 (left of the
        // centre x = 0.1) the surface rises towards +x, so the normal points towards −x.
        let flank = line.samples().iter().find(|s| (s.point.x - 0.05).abs() < 0.003).unwrap();
        assert!(flank.normal.x < -0.2, "normal on the flank {:?}", flank.normal);
    }

    #[test]
    fn drape_off_the_terrain_is_an_error_and_keeps_the_line() {
        let mut line = WeldLine::new(&[[0.0, 0.0], [0.8, 0.0]], 1, 0.02).unwrap();
        let before = line.clone();
        assert!(matches!(line.drape(&bumpy_terrain()), Err(LineError::OffSurface { .. })));
        assert_eq!(line, before);
    }

    #[test]
    fn smoothness_1_keeps_the_corner_and_10_cuts_it() {
        let corner = [0.3, 0.0];
        let points = [[-0.2, 0.0], corner, [0.3, -0.5]];
        let sharp = WeldLine::new(&points, 1, 0.02).unwrap();
        let smooth = WeldLine::new(&points, 10, 0.02).unwrap();
        let plan = |l: &WeldLine| l.samples().iter().map(|s| [s.point.x, s.point.z]).collect::<Vec<_>>();
        assert!(distance_to(&plan(&sharp), corner) < 1e-6);
        // The first Chaikin step chamfers the corner from 1/4 of the way along each leg; the
        // chamfer's midpoint, 88 mm from a 90° corner with 0.5 m legs, stays on the curve.
        let cut = distance_to(&plan(&smooth), corner);
        assert!(cut > 0.080, "smoothness 10 passes {cut} m from the corner");
        // Both keep their endpoints and pass near the segment midpoints.
        for l in [&sharp, &smooth] {
            let s = l.samples();
            assert_eq!([s[0].point.x, s[0].point.z], points[0]);
            assert_eq!([s[s.len() - 1].point.x, s[s.len() - 1].point.z], points[2]);
            assert!(distance_to(&plan(l), [0.3, -0.25]) < 0.003);
        }
        // Higher smoothness = gentler kinks: the sharpest turn between smoothed segments is
        // 90° at 1, 45° at 2 (one chamfer), and halves with each further step.
        let two = WeldLine::new(&points, 2, 0.02).unwrap();
        let turns = [&sharp, &two, &smooth].map(|l| max_turn_deg(l.smoothed()));
        assert!((turns[0] - 90.0).abs() < 1e-3 && (turns[1] - 45.0).abs() < 1e-3, "{turns:?}");
        assert!(turns[2] < 0.5, "{turns:?}");
    }

    fn max_turn_deg(points: &[[f32; 2]]) -> f32 {
        points
            .windows(3)
            .map(|w| {
                let a = (w[1][1] - w[0][1]).atan2(w[1][0] - w[0][0]);
                let b = (w[2][1] - w[1][1]).atan2(w[2][0] - w[1][0]);
                let d = (b - a).to_degrees();
                (d + 180.0).rem_euclid(360.0) - 180.0
            })
            .fold(0.0, |m: f32, d| m.max(d.abs()))
    }

    #[test]
    fn invalid_lines_are_rejected() {
        assert_eq!(WeldLine::new(&[[0.0, 0.0]], 1, 0.02), Err(LineError::TooFewPoints { count: 1 }));
        assert_eq!(WeldLine::new(&[[0.0, 0.0], [0.0, 0.0]], 1, 0.02), Err(LineError::TooFewPoints { count: 1 }));
        assert!(matches!(WeldLine::new(&[[0.0, 0.0], [f32::NAN, 0.0]], 1, 0.02), Err(LineError::NonFinite { index: 1, .. })));
        assert_eq!(WeldLine::new(&[[0.0, 0.0], [1.0, 0.0]], 1, 0.0), Err(LineError::Width { width_m: 0.0 }));
        assert_eq!(WeldLine::new(&[[0.0, 0.0], [1.0, 0.0]], 0, 0.02), Err(LineError::Smoothness));
    }

    #[test]
    fn nearest_signs_and_heading() {
        // Along +x, then turning left (towards −z).
        let line = WeldLine::new(&[[-1.0, 0.0], [0.0, 0.0], [0.0, -1.0]], 1, 0.02).unwrap();
        // A point to the right of the first leg (z > 0): the line is to its left → positive.
        let p = line.nearest(Vector::new(-0.5, 0.0, 0.03));
        assert!((p.signed_lateral_m - 0.03).abs() < 1e-5, "{p:?}");
        assert!(p.heading_rad.abs() < 1e-5);
        assert!((p.arc_length_m - 0.5).abs() < 1e-4);
        let q = line.nearest(Vector::new(-0.5, 0.0, -0.03));
        assert!((q.signed_lateral_m + 0.03).abs() < 1e-5);
        // On the second leg the line heads left: +90°.
        let r = line.nearest(Vector::new(0.02, 0.0, -0.5));
        assert!((r.heading_rad - std::f32::consts::FRAC_PI_2).abs() < 1e-4, "{r:?}");
        // Facing −z, left is −x: the point at x = +0.02 is right of the line → positive.
        assert!((r.signed_lateral_m - 0.02).abs() < 1e-5, "{r:?}");
        assert!((r.arc_length_m - 1.5).abs() < 1e-3);
    }
}
