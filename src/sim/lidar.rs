//! The front LIDAR the seed report proposes (§6): a scanning range sensor at the robot
//! description's `[lidar]` mount on the middle section, casting `beams` rays in the body's
//! plane (x forward, turning toward the left as the angle grows, as a ROS `LaserScan` does)
//! against the terrain and the obstacles, never the robot itself.
//!
//! A scan is taken `rate_hz` times a second. Each range gets Gaussian noise of `noise_std_m`
//! from a SplitMix64 stream seeded by `seed` (deterministic), and is kept within
//! [`min_range_m`, `range_m`]; a beam with no surface within `range_m` has no return
//! (infinity; `null` in JSON).

use std::time::Duration;

use rapier3d::math::{Pose, Rotation, Vector};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::RobotWorld;
use crate::rng::SplitMix64;

fn default_beams() -> u32 {
    61
}
fn default_fov_deg() -> f32 {
    180.0
}
fn default_range_m() -> f32 {
    4.0
}
fn default_min_range_m() -> f32 {
    0.02
}
fn default_rate_hz() -> f64 {
    10.0
}
fn default_noise_std_m() -> f32 {
    0.005
}

/// A scenario's `[lidar]`: its presence turns the LIDAR on.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LidarSettings {
    /// Rays per scan, spread evenly over the field of view (its edges included).
    #[serde(default = "default_beams")]
    pub beams: u32,
    #[serde(default = "default_fov_deg")]
    pub fov_deg: f32,
    /// No return beyond this (m).
    #[serde(default = "default_range_m")]
    pub range_m: f32,
    /// Returns closer than this read this (m).
    #[serde(default = "default_min_range_m")]
    pub min_range_m: f32,
    /// Scans per second.
    #[serde(default = "default_rate_hz")]
    pub rate_hz: f64,
    /// Standard deviation of the range noise (m).
    #[serde(default = "default_noise_std_m")]
    pub noise_std_m: f32,
    /// The scan plane pitched down by this much (deg) to see low steps.
    #[serde(default)]
    pub tilt_deg: f32,
    #[serde(default)]
    pub seed: u64,
}

impl Default for LidarSettings {
    fn default() -> Self {
        Self {
            beams: default_beams(),
            fov_deg: default_fov_deg(),
            range_m: default_range_m(),
            min_range_m: default_min_range_m(),
            rate_hz: default_rate_hz(),
            noise_std_m: default_noise_std_m(),
            tilt_deg: 0.0,
            seed: 0,
        }
    }
}

#[derive(Debug, Error, PartialEq)]
pub enum LidarError {
    #[error("[lidar] beams = {0}: needs 1 to {MAX_BEAMS}")]
    Beams(u32),
    #[error("[lidar] {field} = {value} is invalid: {reason}")]
    Invalid { field: &'static str, value: f64, reason: &'static str },
}

/// More rays than this would cost more than the physics step.
pub const MAX_BEAMS: u32 = 4096;

impl LidarSettings {
    pub fn validate(&self) -> Result<(), LidarError> {
        let check = |field: &'static str, value: f64, ok: bool, reason: &'static str| if ok { Ok(()) } else { Err(LidarError::Invalid { field, value, reason }) };
        if !(1..=MAX_BEAMS).contains(&self.beams) {
            return Err(LidarError::Beams(self.beams));
        }
        check("fov_deg", f64::from(self.fov_deg), self.fov_deg >= 0.0 && self.fov_deg <= 360.0, "must be in [0, 360] degrees")?;
        check("range_m", f64::from(self.range_m), self.range_m > 0.0 && self.range_m <= 1_000.0, "must be in (0, 1000] m")?;
        check("min_range_m", f64::from(self.min_range_m), self.min_range_m >= 0.0 && self.min_range_m < self.range_m, "must be at least 0 and below range_m")?;
        check("rate_hz", self.rate_hz, self.rate_hz > 0.0 && self.rate_hz <= 1_000.0, "must be in (0, 1000] Hz")?;
        check("noise_std_m", f64::from(self.noise_std_m), self.noise_std_m >= 0.0 && self.noise_std_m <= 1.0, "must be in [0, 1] m")?;
        check("tilt_deg", f64::from(self.tilt_deg), self.tilt_deg.abs() <= 90.0, "must be in [-90, 90] degrees")
    }
}

/// One scan.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarScan {
    /// When it was taken (simulated).
    pub t: Duration,
    /// The sensor in the world when it was taken (its x forward, y up).
    pub pose: Pose,
    /// The sensor in the middle section's frame (mount and tilt).
    pub mount: Pose,
    /// Angle of the first beam (rad, about the sensor's y axis, + to the left).
    pub start_angle_rad: f32,
    /// Angle between beams (rad).
    pub step_rad: f32,
    /// One range per beam (m); infinity where nothing is within range.
    pub ranges_m: Vec<f32>,
}

impl LidarScan {
    pub fn end_angle_rad(&self) -> f32 {
        self.start_angle_rad + self.step_rad * self.ranges_m.len().saturating_sub(1) as f32
    }

    /// The range of the beam closest to straight ahead.
    pub fn ahead_m(&self) -> f32 {
        let index = if self.step_rad > 0.0 { (-self.start_angle_rad / self.step_rad).round() } else { 0.0 };
        self.ranges_m.get(index.max(0.0) as usize).copied().unwrap_or(f32::INFINITY)
    }

    /// The surface ahead, fitted as a straight wall through the returns within `half_width_rad`
    /// of straight ahead (least squares, at least 3 of them): how far the robot should turn to
    /// face it square (rad, + = to the left), or None without enough returns.
    pub fn wall_angle_rad(&self, half_width_rad: f32) -> Option<f32> {
        let points: Vec<(f32, f32)> = self
            .ranges_m
            .iter()
            .enumerate()
            .map(|(k, r)| (self.start_angle_rad + self.step_rad * k as f32, *r))
            .filter(|(angle, r)| angle.abs() <= half_width_rad && r.is_finite())
            .map(|(angle, r)| (r * angle.cos(), r * angle.sin()))
            .collect();
        if points.len() < 3 {
            return None;
        }
        let n = points.len() as f32;
        let (mx, my) = points.iter().fold((0.0, 0.0), |(sx, sy), (x, y)| (sx + x / n, sy + y / n));
        let (sxx, syy, sxy) = points.iter().fold((0.0, 0.0, 0.0), |(a, b, c), (x, y)| {
            let (dx, dy) = (x - mx, y - my);
            (a + dx * dx, b + dy * dy, c + dx * dy)
        });
        // The wall runs along the points' principal direction; its normal is the other one.
        let along = 0.5 * (2.0 * sxy).atan2(sxx - syy);
        let (nx, ny) = (along.sin(), -along.cos());
        // The normal that points away from the sensor, into the wall.
        let (nx, ny) = if nx * mx + ny * my >= 0.0 { (nx, ny) } else { (-nx, -ny) };
        Some(ny.atan2(nx))
    }

    /// Every return as a point in the world, seen from above: (x, z).
    pub fn returns_in_plan(&self) -> Vec<[f32; 2]> {
        self.ranges_m
            .iter()
            .enumerate()
            .filter(|(_, r)| r.is_finite())
            .map(|(k, r)| {
                let angle = self.start_angle_rad + self.step_rad * k as f32;
                // Sensor frame: x ahead, z to the right, so a beam turned left goes toward −z.
                let p = self.pose.transform_point(Vector::new(r * angle.cos(), 0.0, -r * angle.sin()));
                [p.x, p.z]
            })
            .collect()
    }

    /// The nearest return of the scan (infinity without any).
    pub fn nearest_m(&self) -> f32 {
        self.ranges_m.iter().copied().fold(f32::INFINITY, f32::min)
    }

    /// The scan as the sensor server's `/lidar` serves it.
    pub fn to_json(&self) -> serde_json::Value {
        let ranges: Vec<Option<f32>> = self.ranges_m.iter().map(|r| r.is_finite().then_some(*r)).collect();
        let [x, y, z] = [self.pose.translation.x, self.pose.translation.y, self.pose.translation.z];
        let [qx, qy, qz, qw] = [self.pose.rotation.x, self.pose.rotation.y, self.pose.rotation.z, self.pose.rotation.w];
        serde_json::json!({
            "t": self.t.as_secs_f64(),
            "pose": { "position": [x, y, z], "orientation_xyzw": [qx, qy, qz, qw] },
            "start_angle_rad": self.start_angle_rad,
            "end_angle_rad": self.end_angle_rad(),
            "step_rad": self.step_rad,
            "ranges_m": ranges,
        })
    }
}

/// The LIDAR on its mount.
#[derive(Debug, Clone)]
pub struct Lidar {
    settings: LidarSettings,
    mount: Pose,
    next_due: Duration,
    rng: SplitMix64,
    latest: Option<LidarScan>,
}

impl Lidar {
    /// A LIDAR at `position_m` on the middle section.
    pub fn new(settings: LidarSettings, position_m: [f32; 3]) -> Result<Self, LidarError> {
        settings.validate()?;
        let [x, y, z] = position_m;
        // Pitched down about the body's z axis (right): a negative turn about +z tips +x down.
        let mount = Pose::from_parts(Vector::new(x, y, z), Rotation::from_rotation_z(-settings.tilt_deg.to_radians()));
        let rng = SplitMix64::new(settings.seed ^ 0x11DA_2000);
        Ok(Self { settings, mount, next_due: Duration::ZERO, rng, latest: None })
    }

    pub fn settings(&self) -> &LidarSettings {
        &self.settings
    }

    pub fn latest(&self) -> Option<&LidarScan> {
        self.latest.as_ref()
    }

    /// Scan if one is due at `t`; the new scan, if taken.
    pub fn scan(&mut self, world: &RobotWorld, t: Duration) -> Option<&LidarScan> {
        if t < self.next_due {
            return None;
        }
        let period = Duration::from_secs_f64(1.0 / self.settings.rate_hz);
        // The next scan on the rate's grid, never two for one instant.
        while self.next_due <= t {
            self.next_due += period;
        }
        let s = &self.settings;
        let pose = world.chassis_pose() * self.mount;
        let beams = s.beams as usize;
        let fov = s.fov_deg.to_radians();
        let step = if beams > 1 { fov / (beams - 1) as f32 } else { 0.0 };
        let start = -fov / 2.0;
        let mut ranges = Vec::with_capacity(beams);
        for beam in 0..beams {
            let angle = start + step * beam as f32;
            let direction = pose.rotation * Vector::new(angle.cos(), 0.0, -angle.sin());
            let range = match world.cast_ray_at_surroundings(pose.translation, direction, s.range_m) {
                Some(hit) => {
                    let noisy = hit + s.noise_std_m * self.rng.next_gaussian() as f32;
                    noisy.clamp(s.min_range_m, s.range_m)
                }
                None => f32::INFINITY,
            };
            ranges.push(range);
        }
        self.latest = Some(LidarScan { t, pose, mount: self.mount, start_angle_rad: start, step_rad: step, ranges_m: ranges });
        self.latest.as_ref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(ranges: Vec<f32>) -> LidarScan {
        let step = std::f32::consts::PI / (ranges.len() - 1) as f32;
        LidarScan { t: Duration::ZERO, pose: Pose::IDENTITY, mount: Pose::IDENTITY, start_angle_rad: -std::f32::consts::FRAC_PI_2, step_rad: step, ranges_m: ranges }
    }

    #[test]
    fn ahead_is_the_middle_beam_and_nearest_the_smallest_return() {
        let s = scan(vec![3.0, f32::INFINITY, 1.5, 2.0, f32::INFINITY]);
        assert_eq!(s.ahead_m(), 1.5);
        assert_eq!(s.nearest_m(), 1.5);
        assert!((s.end_angle_rad() - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        let json = s.to_json();
        assert!(json["ranges_m"][1].is_null() && json["ranges_m"][0] == 3.0, "{json}");
    }

    /// A straight wall whose into-wall normal points `normal_deg` left of ahead, `distance` away,
    /// seen by 61 beams over 180°.
    fn wall_scan(normal_deg: f32, distance: f32) -> LidarScan {
        let normal = normal_deg.to_radians();
        let ranges = (0..61)
            .map(|k| {
                let angle = -std::f32::consts::FRAC_PI_2 + std::f32::consts::PI * k as f32 / 60.0;
                // r · cos(angle − normal) = distance along the normal.
                let c = (angle - normal).cos();
                if c > 0.05 { distance / c } else { f32::INFINITY }
            })
            .collect();
        scan(ranges)
    }

    #[test]
    fn the_wall_angle_is_the_turn_that_faces_the_wall_square() {
        for normal_deg in [-25.0f32, -5.0, 0.0, 10.0, 30.0] {
            let angle = wall_scan(normal_deg, 0.4).wall_angle_rad(20f32.to_radians()).unwrap();
            assert!((angle.to_degrees() - normal_deg).abs() < 1e-3, "{normal_deg}° → {}°", angle.to_degrees());
        }
        // Too few returns within the window: no answer.
        assert_eq!(scan(vec![f32::INFINITY; 61]).wall_angle_rad(0.3), None);
        assert_eq!(wall_scan(0.0, 0.4).wall_angle_rad(0.01), None);
    }

    #[test]
    fn returns_land_where_the_beams_point() {
        // The sensor at (1, 0.1, 2) turned 90° left (facing −z): ahead is −z, its left is −x.
        let mut s = scan(vec![1.0, f32::INFINITY, 2.0]);
        s.pose = Pose::from_parts(Vector::new(1.0, 0.1, 2.0), Rotation::from_rotation_y(std::f32::consts::FRAC_PI_2));
        let points = s.returns_in_plan();
        assert_eq!(points.len(), 2);
        // Beam 0 is 90° right of ahead (+x here), beam 2 90° left (−x).
        assert!((points[0][0] - 2.0).abs() < 1e-5 && (points[0][1] - 2.0).abs() < 1e-5, "{points:?}");
        assert!((points[1][0] + 1.0).abs() < 1e-5 && (points[1][1] - 2.0).abs() < 1e-5, "{points:?}");
    }

    #[test]
    fn settings_out_of_range_are_named() {
        assert_eq!(LidarSettings { beams: 0, ..LidarSettings::default() }.validate(), Err(LidarError::Beams(0)));
        let error = LidarSettings { min_range_m: 5.0, ..LidarSettings::default() }.validate();
        assert!(matches!(error, Err(LidarError::Invalid { field: "min_range_m", .. })), "{error:?}");
        assert!(LidarSettings { rate_hz: f64::NAN, ..LidarSettings::default() }.validate().is_err());
        assert!(toml::from_str::<LidarSettings>("beam = 3").is_err(), "unknown keys are refused");
    }
}
