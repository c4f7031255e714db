//! The seed's ImageProcessing (§3.3): find the left and right edges of the dark line on two image
//! rows, and from the two line centres the lateral offset `d` and heading `psi` of the line.
//!
//! # Outputs and signs
//! Robot frame as the camera's: image row 0 = forward (+x), column 0 = left (−z).
//! - `d_m`: lateral offset of the line from the image centre, measured along the image row
//!   through the centre (the seed's "distance from the middle of the image"), **positive when
//!   the line lies to the robot's left**.
//! - `psi_rad`: heading of the line relative to the robot's forward axis, **positive when the
//!   line turns left going forward** (counter-clockwise seen from above).
//!
//! Pixel → metre factors are the seed's: H = 2·O/I per row, W = H·a per column (taken from the
//! frame, which the camera stamps with them).
//!
//! # Per row
//! Threshold at the midpoint between the row's darkest and brightest pixel (or a fixed level),
//! so the detector does not care about exposure. A row is rejected when it has too little
//! contrast (no line in view), when its dark run touches the image border (one edge unseen, the
//! centre would be biased) or when the run is wider than `max_width_fraction` of the row (the
//! line is not a stripe there: e.g. crossing the row lengthwise). The longest dark run is taken
//! (noise speckles make short ones). Each edge is placed where linear interpolation between the
//! two pixel centres around it crosses the threshold, which gives sub-pixel precision on the
//! camera's anti-aliased edges.

use serde::Deserialize;
use thiserror::Error;

use super::camera::Frame;

/// Detector settings, as written in a scenario's `[detector]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorSettings {
    /// The two scan rows as fractions of the image height from the top (forward edge).
    pub rows: [f32; 2],
    /// Fixed threshold gray level; `None` = midpoint of each row's min and max.
    pub threshold: Option<u8>,
    /// Minimum max − min gray levels on a row for it to hold a line.
    pub min_contrast: u8,
    /// Widest accepted dark run, as a fraction of the row.
    pub max_width_fraction: f32,
}

impl Default for DetectorSettings {
    fn default() -> Self {
        DetectorSettings { rows: [0.25, 0.75], threshold: None, min_contrast: 40, max_width_fraction: 0.5 }
    }
}

#[derive(Debug, Error, PartialEq)]
pub enum DetectorError {
    #[error("detector rows must be distinct fractions in [0, 1), got {0:?}")]
    Rows([f32; 2]),
    #[error("detector max_width_fraction must be in (0, 1], got {0}")]
    MaxWidth(f32),
}

/// Why a row gave no line centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RowReject {
    LowContrast,
    NoRun,
    TouchesBorder,
    TooWide,
}

/// One measurement. When `valid` is false, `d_m` and `psi_rad` are 0 (a controller should hold
/// its last command rather than steer on them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineMeasurement {
    pub d_m: f32,
    pub psi_rad: f32,
    pub valid: bool,
    /// Line centre (continuous column, pixel c spans [c, c+1]) on each scan row, or why not.
    pub centres_px: [Result<f32, RowReject>; 2],
}

#[derive(Debug, Clone)]
pub struct LineDetector {
    settings: DetectorSettings,
}

impl LineDetector {
    pub fn new(settings: DetectorSettings) -> Result<Self, DetectorError> {
        let [a, b] = settings.rows;
        if !((0.0..1.0).contains(&a) && (0.0..1.0).contains(&b)) || a == b {
            return Err(DetectorError::Rows(settings.rows));
        }
        let m = settings.max_width_fraction;
        if !(m > 0.0 && m <= 1.0) {
            return Err(DetectorError::MaxWidth(m));
        }
        Ok(LineDetector { settings })
    }

    pub fn settings(&self) -> &DetectorSettings {
        &self.settings
    }

    /// The image row a fraction of the height falls on.
    pub fn row_index(&self, frame: &Frame, which: usize) -> u32 {
        ((self.settings.rows[which] * frame.height as f32).floor() as u32).min(frame.height.saturating_sub(1))
    }

    pub fn detect(&self, frame: &Frame) -> LineMeasurement {
        let rows = [self.row_index(frame, 0), self.row_index(frame, 1)];
        let centres_px = rows.map(|r| self.row_centre(frame, r));
        let invalid = LineMeasurement { d_m: 0.0, psi_rad: 0.0, valid: false, centres_px };
        let ([Ok(c0), Ok(c1)], true) = (centres_px, rows[0] != rows[1]) else {
            return invalid;
        };
        let (w, h) = (frame.width_factor_m, frame.height_factor_m);
        // Robot-frame coordinates of the two centres: forward x from the centre row, lateral z
        // (right) from the centre column.
        let x = |r: u32| (frame.height as f32 / 2.0 - (r as f32 + 0.5)) * h;
        let z = |c: f32| (c - frame.width as f32 / 2.0) * w;
        let (x0, z0, x1, z1) = (x(rows[0]), z(c0), x(rows[1]), z(c1));
        // Lateral position where the line through both centres crosses the centre row (x = 0).
        let z_centre = z0 + (0.0 - x0) * (z1 - z0) / (x1 - x0);
        // Direction of the line going forward (towards +x); heading is positive towards −z.
        let (fx, fz) = if x0 > x1 { (x0 - x1, z0 - z1) } else { (x1 - x0, z1 - z0) };
        LineMeasurement { d_m: -z_centre, psi_rad: (-fz).atan2(fx), valid: true, centres_px }
    }

    /// Sub-pixel centre of the dark run on `row`.
    fn row_centre(&self, frame: &Frame, row: u32) -> Result<f32, RowReject> {
        let width = frame.width as usize;
        let start = row as usize * width;
        let Some(px) = frame.pixels.get(start..start + width) else {
            return Err(RowReject::NoRun);
        };
        let (lo, hi) = px.iter().fold((u8::MAX, u8::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        if hi.saturating_sub(lo) < self.settings.min_contrast {
            return Err(RowReject::LowContrast);
        }
        let threshold = self.settings.threshold.map_or((f32::from(lo) + f32::from(hi)) / 2.0, f32::from);
        // Longest run of pixels darker than the threshold.
        let mut best: Option<(usize, usize)> = None;
        let mut run_start = None;
        // A bright sentinel after the row closes a run that reaches the right border.
        let darkness = px.iter().map(|&v| f32::from(v) < threshold).chain(std::iter::once(false));
        for (i, dark) in darkness.enumerate() {
            match (dark, run_start) {
                (true, None) => run_start = Some(i),
                (false, Some(s)) => {
                    if best.is_none_or(|(bs, be)| i - s > be - bs) {
                        best = Some((s, i));
                    }
                    run_start = None;
                }
                _ => {}
            }
        }
        let (first, end) = best.ok_or(RowReject::NoRun)?;
        if first == 0 || end == width {
            return Err(RowReject::TouchesBorder);
        }
        if (end - first) as f32 > self.settings.max_width_fraction * width as f32 {
            return Err(RowReject::TooWide);
        }
        let last = end - 1;
        // Threshold crossings between pixel centres (i + 0.5): bright first − 1 → dark first,
        // dark last → bright last + 1.
        let crossing = |bright: u8, dark: u8| (f32::from(bright) - threshold) / (f32::from(bright) - f32::from(dark));
        let left = first as f32 - 0.5 + crossing(px[first - 1], px[first]);
        let right = last as f32 + 1.5 - crossing(px[last + 1], px[last]);
        Ok((left + right) / 2.0)
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;
    use std::time::Duration;

    use rapier3d::math::{Pose, Rotation, Vector};

    use super::*;
    use crate::sim::camera::{LineCamera, LineCameraSettings};
    use crate::sim::line::WeldLine;
    use crate::sim::terrain::{self, TerrainSpec};

    fn settings(image_px: u32, aspect: f32) -> LineCameraSettings {
        LineCameraSettings { image_px, orthographic_size_m: 0.1, aspect, frame_rate_hz: 30.0, noise_std: 0.0, blur_px: 0, latency_frames: 0, seed: 0 }
    }

    fn flat() -> terrain::TerrainGeometry {
        terrain::generate(&TerrainSpec::Flat { size_m: 3.0 }, 0, Path::new(".")).unwrap()
    }

    /// A straight line through (cx, cz) with world heading `heading` (positive = towards −z).
    fn straight(cx: f32, cz: f32, heading: f32) -> WeldLine {
        let (ux, uz) = (heading.cos(), -heading.sin());
        let mut line = WeldLine::new(&[[cx - 0.6 * ux, cz - 0.6 * uz], [cx + 0.6 * ux, cz + 0.6 * uz]], 1, 0.02).unwrap();
        line.drape(&flat()).unwrap();
        line
    }

    fn robot(x: f32, z: f32, yaw: f32) -> Pose {
        Pose::from_parts(Vector::new(x, 0.1, z), Rotation::from_rotation_y(yaw))
    }

    /// Ground truth from geometry alone: the line's (d, psi) in the camera frame.
    fn truth(pose: Pose, line: &WeldLine) -> (f32, f32) {
        let s = line.samples();
        let (a, b) = (pose.inverse_transform_point(s[0].point), pose.inverse_transform_point(s[s.len() - 1].point));
        let u = if b.x > a.x { b - a } else { a - b };
        let z_at_centre = a.z + (0.0 - a.x) * u.z / u.x;
        (-z_at_centre, (-u.z).atan2(u.x))
    }

    fn measure(settings: LineCameraSettings, pose: Pose, line: &WeldLine) -> LineMeasurement {
        let mut camera = LineCamera::new(settings).unwrap();
        let frame = camera.capture(pose, std::slice::from_ref(line), Duration::ZERO);
        LineDetector::new(DetectorSettings::default()).unwrap().detect(&frame)
    }

    fn check(settings: LineCameraSettings, pose: Pose, line: &WeldLine) -> LineMeasurement {
        let (w, h) = (settings.width_factor(), settings.height_factor());
        let spacing = 0.5 * settings.image_px as f32 * h;
        let m = measure(settings, pose, line);
        let (d, psi) = truth(pose, line);
        assert!(m.valid, "no line found: {m:?}");
        assert!((m.d_m - d).abs() <= w, "d = {} m, truth {d} m (W = {w})", m.d_m);
        assert!((m.psi_rad - psi).abs() <= (w / spacing).atan(), "psi = {}, truth {psi}", m.psi_rad);
        m
    }

    #[test]
    fn offsets_and_headings_within_a_pixel() {
        for offset in [0.0, 0.02, -0.02, 0.05, -0.05] {
            for deg in [0.0f32, 10.0, -10.0, 20.0, -20.0] {
                // Line through (0, offset) in z: a positive offset is on the robot's right.
                check(settings(128, 1.0), robot(0.0, 0.0, 0.0), &straight(0.0, offset, deg.to_radians()));
            }
        }
    }

    #[test]
    fn line_to_the_left_gives_positive_d_and_left_turn_positive_psi() {
        // 30 mm towards −z = left of a robot heading +x.
        let m = check(settings(128, 1.0), robot(0.0, 0.0, 0.0), &straight(0.0, -0.03, 0.0));
        assert!((m.d_m - 0.03).abs() < 0.0016 && m.psi_rad.abs() < 0.016, "{m:?}");
        // A line heading 15° left of the robot's nose.
        let m = check(settings(128, 1.0), robot(0.0, 0.0, 0.0), &straight(0.0, 0.0, 15f32.to_radians()));
        assert!((m.psi_rad - 15f32.to_radians()).abs() < 0.016, "{m:?}");
        // The robot yawed 10° left over a line along +x: the line heads 10° right of the nose,
        // and ahead of the robot it drifts right, but through the centre it is at d = 0.
        let m = check(settings(128, 1.0), robot(0.0, 0.0, 10f32.to_radians()), &straight(0.0, 0.0, 0.0));
        assert!((m.psi_rad + 10f32.to_radians()).abs() < 0.016 && m.d_m.abs() < 0.0016, "{m:?}");
    }

    #[test]
    fn yawed_and_displaced_robot() {
        for (x, z, yaw, offset, heading) in [(0.3, -0.2, 25.0f32, 0.03, 15.0f32), (-0.2, 0.1, -30.0, -0.04, -20.0), (0.0, 0.0, 90.0, 0.0, 100.0)] {
            let pose = robot(x, z, yaw.to_radians());
            // The line passes `offset` metres to the robot's right of its centre.
            let right = pose.transform_vector(Vector::Z) * offset;
            let line = straight(x + right.x, z + right.z, heading.to_radians());
            check(settings(128, 1.0), pose, &line);
        }
    }

    #[test]
    fn aspect_two_uses_w_equals_h_times_a() {
        // W = 2H: the same line over twice the lateral range.
        check(settings(128, 2.0), robot(0.0, 0.0, 0.0), &straight(0.0, 0.09, 10f32.to_radians()));
        check(settings(256, 1.0), robot(0.0, 0.0, 0.0), &straight(0.0, -0.04, -20f32.to_radians()));
    }

    #[test]
    fn no_line_and_half_seen_line_are_invalid() {
        let m = measure(settings(128, 1.0), robot(0.0, 0.0, 0.0), &straight(0.0, 0.5, 0.0));
        assert!(!m.valid);
        assert_eq!(m.centres_px, [Err(RowReject::LowContrast); 2]);
        // A line on the image's left border: one edge out of view.
        let m = measure(settings(128, 1.0), robot(0.0, 0.0, 0.0), &straight(0.0, -0.1, 0.0));
        assert_eq!(m.centres_px, [Err(RowReject::TouchesBorder); 2]);
        // A line crossing the image sideways fills the scan rows.
        let m = measure(settings(128, 1.0), robot(0.0, 0.0, 0.0), &straight(0.05, 0.0, 90f32.to_radians()));
        assert!(!m.valid, "{m:?}");
    }

    #[test]
    fn detects_through_noise_and_blur() {
        let noisy = LineCameraSettings { noise_std: 8.0, blur_px: 1, seed: 7, ..settings(128, 1.0) };
        check(noisy, robot(0.0, 0.0, 0.0), &straight(0.0, 0.02, 10f32.to_radians()));
    }

    #[test]
    fn draped_line_on_a_bump_is_still_measured() {
        let terrain = crate::sim::line::tests::bumpy_terrain();
        let mut line = WeldLine::new(&[[-0.4, 0.05], [0.4, 0.05]], 1, 0.02).unwrap();
        line.drape(&terrain).unwrap();
        let m = measure(settings(128, 1.0), robot(0.1, 0.0, 0.0), &line);
        // The stripe's edges tilt with the bump's flanks, so allow two pixels here.
        assert!(m.valid && (m.d_m + 0.05).abs() < 0.0032 && m.psi_rad.abs() < 0.03, "{m:?}");
    }

    #[test]
    fn settings_are_validated() {
        assert!(LineDetector::new(DetectorSettings { rows: [0.5, 0.5], ..Default::default() }).is_err());
        assert!(LineDetector::new(DetectorSettings { rows: [0.2, 1.0], ..Default::default() }).is_err());
        assert!(LineDetector::new(DetectorSettings { max_width_fraction: 0.0, ..Default::default() }).is_err());
        let parsed: DetectorSettings = toml::from_str("rows = [0.1, 0.9]").unwrap();
        assert_eq!(parsed.rows, [0.1, 0.9]);
        assert!(toml::from_str::<DetectorSettings>("row = [0.1, 0.9]").is_err());
    }
}
