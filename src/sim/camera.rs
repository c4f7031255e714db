//! The seed's machine-vision camera (§3.3): orthographic, at the robot's centre, looking straight
//! down, rendering the painted line into a small grayscale image.
//!
//! # Geometry
//! The camera looks along its pose's **−Y** axis (the middle body's down). Image row 0 is the
//! body's forward (+x) edge, column 0 its **left** (−z) edge, so the image is what one sees looking
//! down with the nose at the top. As in the seed, the image is a square of `image_px` = I pixels
//! (a power of two) and the camera has an orthographic size O (half the vertical viewing volume)
//! and an aspect ratio a: the view covers 2·O (along x, rows) × 2·O·a (along z, columns), so one
//! pixel is H = 2·O/I metres tall and W = H·a metres wide — the seed's HeightFactor and
//! WidthFactor. (A square texture with a non-square view gives non-square pixels when a ≠ 1;
//! this keeps both of the seed's factors exact.)
//!
//! # Rendering without ray casts
//! A rapier ray cast per pixel costs ~1 µs, 16 ms for a 128² frame. Instead the draped line's two
//! edge polylines are projected orthographically into the image plane (the view-axis component
//! dropped) and the stripe is rasterised as two triangles per pair of consecutive samples. Only
//! chunks of the line whose bounding sphere reaches the view are projected, only triangles whose
//! bounding box overlaps the image are scanned. Edges are anti-aliased by 4 × 4 supersampling:
//! each pixel keeps a 16-bit coverage mask, triangles OR their samples into it (so overlapping
//! triangles at bends do not darken twice and shared edges leave no cracks), and the gray level
//! is ground + (line − ground) · covered / 16. Pixels wholly inside or outside a triangle are
//! decided from the pixel centre without testing the 16 samples. Occlusion (terrain hiding the
//! line) and the near plane are ignored: the camera sits 0.1 m above a surface it cannot see
//! behind.
//!
//! Then, optionally: a separable box blur of `blur_px` radius (defocus), Gaussian noise of
//! `noise_std` gray levels from a SplitMix64 stream seeded by `seed` (deterministic), and
//! rounding to u8.
//!
//! # Timing
//! Frames are captured on the grid t = k / `frame_rate_hz`. A frame becomes visible
//! `latency_frames` captures later (the seed's AsyncGPUReadback delay), like a queue of
//! `latency_frames` frames in flight.

use std::collections::VecDeque;
use std::time::Duration;

use rapier3d::math::{Pose, Vector};
use serde::Deserialize;
use thiserror::Error;

use super::line::{CHUNK, WeldLine};
use crate::rng::SplitMix64;
use crate::robot::CameraMount;

/// Gray level of bare terrain (bright steel under the robot's light).
pub const GROUND_GRAY: f32 = 200.0;
/// Gray level of the painted line.
pub const LINE_GRAY: f32 = 30.0;
/// Largest accepted `image_px`: 4096² is already 16 M pixels per frame.
pub const MAX_IMAGE_PX: u32 = 4096;
/// Largest accepted `latency_frames` (frames kept in flight).
pub const MAX_LATENCY_FRAMES: u32 = 64;

/// Supersampling grid per pixel side (4 × 4 samples in a u16 mask).
const SS: usize = 4;

/// Camera settings, as written in a scenario's `[camera]` table.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct LineCameraSettings {
    /// Image size I in pixels per side, a power of two.
    pub image_px: u32,
    /// Orthographic size O: half the vertical (forward) viewing volume, metres.
    pub orthographic_size_m: f32,
    /// Aspect ratio a: view width / view height.
    #[serde(default = "one")]
    pub aspect: f32,
    #[serde(default = "thirty")]
    pub frame_rate_hz: f32,
    /// Standard deviation of Gaussian pixel noise, gray levels.
    #[serde(default)]
    pub noise_std: f32,
    /// Box blur radius in pixels (0 = sharp).
    #[serde(default)]
    pub blur_px: u32,
    /// Frames between capture and readback (AsyncGPUReadback latency).
    #[serde(default)]
    pub latency_frames: u32,
    /// Seed of the noise stream.
    #[serde(default)]
    pub seed: u64,
}

fn one() -> f32 {
    1.0
}

fn thirty() -> f32 {
    30.0
}

impl LineCameraSettings {
    /// The robot description's camera with the defaults for everything else.
    pub fn from_mount(mount: &CameraMount) -> Self {
        Self::with_size(mount.image_px, mount.orthographic_size_m)
    }

    /// An `image_px` camera seeing 2·`orthographic_size_m`, every other setting at its default.
    pub fn with_size(image_px: u32, orthographic_size_m: f32) -> Self {
        LineCameraSettings { image_px, orthographic_size_m, aspect: 1.0, frame_rate_hz: 30.0, noise_std: 0.0, blur_px: 0, latency_frames: 0, seed: 0 }
    }

    /// H: metres per pixel along the image's vertical (robot forward).
    pub fn height_factor(&self) -> f32 {
        2.0 * self.orthographic_size_m / self.image_px as f32
    }

    /// W = H · a: metres per pixel along the image's horizontal (robot right).
    pub fn width_factor(&self) -> f32 {
        self.height_factor() * self.aspect
    }
}

/// Why camera settings are invalid.
#[derive(Debug, Error, PartialEq)]
pub enum CameraError {
    #[error("camera image_px {0} is not a power of two (use e.g. 64, 128, 256)")]
    ImageNotPowerOfTwo(u32),
    #[error("camera image_px {0} is outside 2..={MAX_IMAGE_PX}")]
    ImageSize(u32),
    #[error("camera {field} must be positive and finite, got {value}")]
    NotPositive { field: &'static str, value: f32 },
    #[error("camera noise_std must be ≥ 0 and finite, got {0}")]
    Noise(f32),
    #[error("camera blur_px {0} must be less than half the image")]
    Blur(u32),
    #[error("camera latency_frames {0} is larger than {MAX_LATENCY_FRAMES}")]
    Latency(u32),
}

/// One captured image.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Simulation time of the capture (the pose's time), not of its readback.
    pub t: Duration,
    pub width: u32,
    pub height: u32,
    /// Row-major gray levels, row 0 = forward edge, column 0 = left edge.
    pub pixels: Vec<u8>,
    /// Camera pose at capture.
    pub pose: Pose,
    /// H: metres per pixel along a column (forward).
    pub height_factor_m: f32,
    /// W: metres per pixel along a row (right).
    pub width_factor_m: f32,
}

impl Frame {
    /// Gray level at (column, row).
    pub fn pixel(&self, col: u32, row: u32) -> u8 {
        self.pixels[(row * self.width + col) as usize]
    }

    /// The frame as an 8-bit grayscale PNG (for the HTTP sensor endpoint and debugging).
    pub fn to_png(&self) -> Result<Vec<u8>, png::EncodingError> {
        self.to_png_with(png::Compression::Balanced)
    }

    /// [`Frame::to_png`] at a chosen compression (a recording of every frame takes `Fastest`).
    pub fn to_png_with(&self, compression: png::Compression) -> Result<Vec<u8>, png::EncodingError> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, self.width, self.height);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(compression);
        let mut writer = encoder.write_header()?;
        writer.write_image_data(&self.pixels)?;
        writer.finish()?;
        Ok(out)
    }
}

/// The pose of a camera mounted at `mount_position` (in the chassis frame) on a chassis at
/// `chassis`: same orientation, so it looks along the chassis' −Y.
pub fn camera_pose(chassis: Pose, mount_position: Vector) -> Pose {
    chassis * Pose::from_translation(mount_position)
}

/// The orthographic line camera with its in-flight frame queue.
#[derive(Debug)]
pub struct LineCamera {
    settings: LineCameraSettings,
    size: usize,
    /// Index of the next capture on the t = k / rate grid.
    next_capture: u64,
    in_flight: VecDeque<Frame>,
    visible: Option<Frame>,
    /// Recycled pixel buffer (the frame that stopped being visible).
    spare: Vec<u8>,
    masks: Vec<u16>,
    gray: Vec<f32>,
    projected: Vec<[f32; 4]>,
    rng: SplitMix64,
}

impl LineCamera {
    pub fn new(settings: LineCameraSettings) -> Result<Self, CameraError> {
        let i = settings.image_px;
        if !i.is_power_of_two() {
            return Err(CameraError::ImageNotPowerOfTwo(i));
        }
        if !(2..=MAX_IMAGE_PX).contains(&i) {
            return Err(CameraError::ImageSize(i));
        }
        for (field, value) in [("orthographic_size_m", settings.orthographic_size_m), ("aspect", settings.aspect), ("frame_rate_hz", settings.frame_rate_hz)] {
            if !(value > 0.0 && value.is_finite()) {
                return Err(CameraError::NotPositive { field, value });
            }
        }
        if !(settings.noise_std >= 0.0 && settings.noise_std.is_finite()) {
            return Err(CameraError::Noise(settings.noise_std));
        }
        if settings.blur_px >= i / 2 {
            return Err(CameraError::Blur(settings.blur_px));
        }
        if settings.latency_frames > MAX_LATENCY_FRAMES {
            return Err(CameraError::Latency(settings.latency_frames));
        }
        let size = i as usize;
        Ok(LineCamera {
            rng: SplitMix64::new(settings.seed),
            settings,
            size,
            next_capture: 0,
            in_flight: VecDeque::new(),
            visible: None,
            spare: Vec::new(),
            masks: vec![0; size * size],
            gray: Vec::new(),
            projected: Vec::new(),
        })
    }

    pub fn settings(&self) -> &LineCameraSettings {
        &self.settings
    }

    /// Advance the camera to time `t` with the camera at `camera_pose` (see [`camera_pose`]).
    /// If a capture is due (t has reached the next k / rate) the line is rendered now; missed
    /// captures (t jumped several periods) are skipped, not rendered late. Returns the frame that
    /// becomes visible at this call (the capture `latency_frames` captures ago), or `None` if
    /// none does; [`LineCamera::latest`] keeps returning the last visible frame. Every line of
    /// `lines` is painted (a scenario's welds).
    pub fn render(&mut self, camera_pose: Pose, lines: &[WeldLine], t: Duration) -> Option<&Frame> {
        // Position on the capture grid in frames; the 1e-6 frame tolerance absorbs rounding of
        // callers that compute k / rate in floating point.
        let frames = t.as_secs_f64() * f64::from(self.settings.frame_rate_hz) + 1e-6;
        if frames < self.next_capture as f64 {
            return None;
        }
        self.next_capture = (frames.floor() as u64).max(self.next_capture) + 1;
        let frame = self.capture(camera_pose, lines, t);
        self.in_flight.push_back(frame);
        if self.in_flight.len() > self.settings.latency_frames as usize {
            let shown = self.in_flight.pop_front();
            if let Some(old) = std::mem::replace(&mut self.visible, shown) {
                self.spare = old.pixels;
            }
            return self.visible.as_ref();
        }
        None
    }

    /// The last frame that became visible.
    pub fn latest(&self) -> Option<&Frame> {
        self.visible.as_ref()
    }

    /// Render one frame now, ignoring the frame rate and the latency queue (for tools and tests;
    /// it does advance the noise stream).
    pub fn capture(&mut self, camera_pose: Pose, lines: &[WeldLine], t: Duration) -> Frame {
        let n = self.size;
        let (h, w) = (self.settings.height_factor(), self.settings.width_factor());
        self.masks.fill(0);
        self.projected.clear();
        for line in lines {
            self.project(camera_pose, line, h, w);
        }
        // Each pair is two consecutive samples k, k+1 as [left col, left row, right col, right
        // row]; their quad L_k R_k R_k+1 L_k+1 is two triangles.
        for pair in self.projected.chunks_exact(2) {
            let ([lc0, lr0, rc0, rr0], [lc1, lr1, rc1, rr1]) = (pair[0], pair[1]);
            raster_triangle(&mut self.masks, n, [lc0, lr0], [rc0, rr0], [rc1, rr1]);
            raster_triangle(&mut self.masks, n, [lc0, lr0], [rc1, rr1], [lc1, lr1]);
        }
        let mut pixels = std::mem::take(&mut self.spare);
        pixels.clear();
        let s = &self.settings;
        if s.blur_px == 0 && s.noise_std == 0.0 {
            let lut: [u8; SS * SS + 1] = std::array::from_fn(|c| shade(c as u32).round() as u8);
            pixels.extend(self.masks.iter().map(|m| lut[m.count_ones() as usize]));
        } else {
            self.gray.clear();
            self.gray.extend(self.masks.iter().map(|m| shade(m.count_ones())));
            if s.blur_px > 0 {
                box_blur(&mut self.gray, n, s.blur_px as usize);
            }
            let std = s.noise_std;
            if std > 0.0 {
                for pair in self.gray.chunks_mut(2) {
                    let (z0, z1) = self.rng.normal_pair();
                    let (z0, z1) = (z0 as f32, z1 as f32);
                    pair[0] += std * z0;
                    if let Some(v) = pair.get_mut(1) {
                        *v += std * z1;
                    }
                }
            }
            pixels.extend(self.gray.iter().map(|v| v.round().clamp(0.0, 255.0) as u8));
        }
        Frame { t, width: n as u32, height: n as u32, pixels, pose: camera_pose, height_factor_m: h, width_factor_m: w }
    }

    /// Project the stripe edges of the chunks that can reach the view into continuous pixel
    /// coordinates (pixel (c, r) spans [c, c+1] × [r, r+1]), as pairs of consecutive samples
    /// `[left col, left row, right col, right row]` in `self.projected`.
    fn project(&mut self, pose: Pose, line: &WeldLine, h: f32, w: f32) {
        let n = self.size as f32;
        let (half_rows_m, half_cols_m) = (h * n / 2.0, w * n / 2.0);
        let to_px = |q: Vector| {
            let l = pose.inverse_transform_point(q);
            [(l.z + half_cols_m) / w, (half_rows_m - l.x) / h]
        };
        let samples = line.samples();
        for (c, &(centre, radius)) in line.chunks().iter().enumerate() {
            let l = pose.inverse_transform_point(centre);
            if l.x.abs() > half_rows_m + radius || l.z.abs() > half_cols_m + radius {
                continue;
            }
            let range = c * CHUNK..(c * CHUNK + CHUNK + 1).min(samples.len());
            let mut previous: Option<[f32; 4]> = None;
            for s in &samples[range] {
                let ([lc, lr], [rc, rr]) = (to_px(s.left_edge), to_px(s.right_edge));
                let current = [lc, lr, rc, rr];
                if let Some(p) = previous {
                    self.projected.push(p);
                    self.projected.push(current);
                }
                previous = Some(current);
            }
        }
    }
}

/// Gray level for `covered` of the 16 samples.
fn shade(covered: u32) -> f32 {
    GROUND_GRAY + (LINE_GRAY - GROUND_GRAY) * covered as f32 / (SS * SS) as f32
}

/// OR the 4 × 4 sample coverage of triangle (a, b, c) (pixel coordinates, any winding) into
/// `masks` (an n × n image).
fn raster_triangle(masks: &mut [u16], n: usize, a: [f32; 2], b: [f32; 2], c: [f32; 2]) {
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if area.is_nan() || area.abs() <= 1e-9 {
        return; // degenerate
    }
    let (b, c) = if area > 0.0 { (b, c) } else { (c, b) };
    let (min_x, max_x) = (a[0].min(b[0]).min(c[0]), a[0].max(b[0]).max(c[0]));
    let (min_y, max_y) = (a[1].min(b[1]).min(c[1]), a[1].max(b[1]).max(c[1]));
    let nf = n as f32;
    if max_x < 0.0 || max_y < 0.0 || min_x > nf || min_y > nf {
        return;
    }
    let (x0, x1) = (min_x.floor().max(0.0) as usize, (max_x.ceil().min(nf) as usize).min(n));
    let (y0, y1) = (min_y.floor().max(0.0) as usize, (max_y.ceil().min(nf) as usize).min(n));
    // Edge functions e(p) = A·x + B·y + C, ≥ 0 inside for a counter-clockwise (area > 0) triangle
    // in (x right, y down) pixel coordinates.
    let edge = |p: [f32; 2], q: [f32; 2]| {
        let (ea, eb) = (-(q[1] - p[1]), q[0] - p[0]);
        (ea, eb, -(ea * p[0] + eb * p[1]))
    };
    let edges = [edge(a, b), edge(b, c), edge(c, a)];
    let bounds = edges.map(|(ea, eb, _)| 0.5 * (ea.abs() + eb.abs()));
    let offsets: [f32; SS] = std::array::from_fn(|i| (i as f32 + 0.5) / SS as f32 - 0.5);
    for py in y0..y1 {
        let cy = py as f32 + 0.5;
        let row = &mut masks[py * n..py * n + n];
        for (px, mask) in row.iter_mut().enumerate().take(x1).skip(x0) {
            if *mask == u16::MAX {
                continue;
            }
            let cx = px as f32 + 0.5;
            let mut all_in = true;
            let mut e_centre = [0.0f32; 3];
            let mut outside = false;
            for (i, &(ea, eb, ec)) in edges.iter().enumerate() {
                let e = ea * cx + eb * cy + ec;
                e_centre[i] = e;
                if e < -bounds[i] {
                    outside = true;
                    break;
                }
                all_in &= e >= bounds[i];
            }
            if outside {
                continue;
            }
            if all_in {
                *mask = u16::MAX;
                continue;
            }
            let mut m = 0u16;
            for (sy, dy) in offsets.iter().enumerate() {
                for (sx, dx) in offsets.iter().enumerate() {
                    let inside = edges.iter().zip(e_centre).all(|(&(ea, eb, _), e)| e + ea * dx + eb * dy >= 0.0);
                    m |= u16::from(inside) << (sy * SS + sx);
                }
            }
            *mask |= m;
        }
    }
}

/// Separable box blur of radius `r` with clamped borders, in place on an n × n image.
fn box_blur(image: &mut [f32], n: usize, r: usize) {
    let mut line = vec![0.0f32; n];
    let norm = 1.0 / (2 * r + 1) as f32;
    let mut pass = |get: &dyn Fn(usize) -> usize, image: &mut [f32]| {
        for (i, v) in line.iter_mut().enumerate() {
            *v = image[get(i)];
        }
        // Running sum over the clamped window [i − r, i + r].
        let at = |i: isize| line[i.clamp(0, n as isize - 1) as usize];
        let mut sum: f32 = (-(r as isize)..=r as isize).map(at).sum();
        for i in 0..n {
            image[get(i)] = sum * norm;
            sum += at(i as isize + r as isize + 1) - at(i as isize - r as isize);
        }
    };
    for row in 0..n {
        pass(&|i| row * n + i, image);
    }
    for col in 0..n {
        pass(&|i| i * n + col, image);
    }
}

#[cfg(test)]
mod tests {
    use rapier3d::math::{Pose, Vector};

    use super::*;

    fn settings() -> LineCameraSettings {
        LineCameraSettings::with_size(64, 0.1)
    }

    fn line() -> WeldLine {
        WeldLine::new(&[[-1.0, 0.0], [1.0, 0.0]], 1, 0.02).unwrap()
    }

    fn at(x: f32) -> Pose {
        Pose::from_translation(Vector::new(x, 0.1, 0.0))
    }

    /// Time of capture k at 30 Hz, as a caller stepping at 1 kHz would see it.
    fn frame_time(k: u32) -> Duration {
        Duration::from_millis((u64::from(k) * 1000).div_ceil(30))
    }

    #[test]
    fn renders_a_dark_stripe_on_bright_ground() {
        let mut camera = LineCamera::new(settings()).unwrap();
        let frame = camera.capture(at(0.0), &[line()], Duration::ZERO);
        assert_eq!((frame.width, frame.height, frame.pixels.len()), (64, 64, 64 * 64));
        // 20 mm = 6.4 px centred on column 32: columns 29..=34 fully dark, 28 and 35 partly.
        for row in [0, 31, 63] {
            assert_eq!(frame.pixel(0, row), GROUND_GRAY as u8);
            for col in 30..34 {
                assert_eq!(frame.pixel(col, row), LINE_GRAY as u8, "({col}, {row})");
            }
            let partial = frame.pixel(28, row);
            assert!(partial > LINE_GRAY as u8 && partial < GROUND_GRAY as u8, "{partial}");
        }
        // The line turning left of the robot appears towards column 0 at the top (row 0 = +x).
        let left = WeldLine::new(&[[-0.05, 0.0], [0.05, -0.05]], 1, 0.01).unwrap();
        let frame = camera.capture(at(0.0), std::slice::from_ref(&left), Duration::ZERO);
        let darkest = |row| (0..64).min_by_key(|&c| frame.pixel(c, row)).unwrap();
        assert!(darkest(16) < darkest(48), "top {} bottom {}", darkest(16), darkest(48));
    }

    #[test]
    fn frame_rate_and_latency() {
        let mut camera = LineCamera::new(LineCameraSettings { latency_frames: 2, ..settings() }).unwrap();
        let line = line();
        let mut shown = Vec::new();
        for ms in 0..=200u32 {
            let t = Duration::from_millis(u64::from(ms));
            // The pose encodes the time it was captured at.
            if let Some(frame) = camera.render(at(ms as f32 * 1e-3), std::slice::from_ref(&line), t) {
                shown.push((ms, frame.t, frame.pose.translation.x));
            }
        }
        // Captures at 0, 34, 67, 100, 134, 167, 200 ms; each one shows the capture 2 earlier.
        let expected: Vec<_> = (2..7).map(|k| (frame_time(k).as_millis() as u32, frame_time(k - 2))).collect();
        let got: Vec<_> = shown.iter().map(|(ms, t, _)| (*ms, *t)).collect();
        assert_eq!(got, expected);
        for (_, t, x) in &shown {
            assert!((x - t.as_secs_f32()).abs() < 1e-6, "pose of the capture time");
        }
        assert_eq!(camera.latest().map(|f| f.t), Some(frame_time(4)));
    }

    #[test]
    fn no_latency_shows_each_capture_and_skips_missed_ones() {
        let mut camera = LineCamera::new(settings()).unwrap();
        let line = line();
        assert!(camera.render(at(0.0), std::slice::from_ref(&line), Duration::ZERO).is_some());
        assert!(camera.render(at(0.0), std::slice::from_ref(&line), Duration::from_millis(20)).is_none());
        assert!(camera.render(at(0.0), std::slice::from_ref(&line), Duration::from_millis(34)).is_some());
        // A jump over several periods renders once, then waits for the next grid point.
        assert!(camera.render(at(0.0), std::slice::from_ref(&line), Duration::from_millis(500)).is_some());
        assert!(camera.render(at(0.0), std::slice::from_ref(&line), Duration::from_millis(510)).is_none());
        assert!(camera.render(at(0.0), std::slice::from_ref(&line), Duration::from_millis(534)).is_some());
    }

    #[test]
    fn noise_is_deterministic_for_a_seed() {
        let noisy = |seed| LineCameraSettings { noise_std: 6.0, seed, ..settings() };
        let frames = |seed| {
            let mut camera = LineCamera::new(noisy(seed)).unwrap();
            (0..3).map(|k| camera.capture(at(0.0), &[line()], frame_time(k)).pixels).collect::<Vec<_>>()
        };
        let (a, b, c) = (frames(1), frames(1), frames(2));
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_ne!(a[0], a[1], "the stream advances from frame to frame");
        let clean = LineCamera::new(settings()).unwrap().capture(at(0.0), &[line()], Duration::ZERO).pixels;
        let mean_abs = a[0].iter().zip(&clean).map(|(x, y)| f32::from(x.abs_diff(*y))).sum::<f32>() / clean.len() as f32;
        // E|N(0, 6)| = 6·√(2/π) ≈ 4.8
        assert!((3.5..6.0).contains(&mean_abs), "mean |noise| {mean_abs}");
    }

    #[test]
    fn blur_softens_the_edges() {
        let mut sharp = LineCamera::new(settings()).unwrap();
        let mut soft = LineCamera::new(LineCameraSettings { blur_px: 2, ..settings() }).unwrap();
        let (a, b) = (sharp.capture(at(0.0), &[line()], Duration::ZERO), soft.capture(at(0.0), &[line()], Duration::ZERO));
        assert!(b.pixel(27, 10) < a.pixel(27, 10) && b.pixel(30, 10) > a.pixel(30, 10));
        // Far from the line nothing changes.
        assert_eq!(a.pixel(5, 5), b.pixel(5, 5));
    }

    #[test]
    fn png_round_trip() {
        let frame = LineCamera::new(settings()).unwrap().capture(at(0.0), &[line()], Duration::ZERO);
        let bytes = frame.to_png().unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().unwrap();
        let mut buffer = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buffer).unwrap();
        assert_eq!((info.width, info.height, info.color_type), (64, 64, png::ColorType::Grayscale));
        assert_eq!(&buffer[..64 * 64], &frame.pixels[..]);
    }

    #[test]
    fn settings_are_validated_and_parsed() {
        let bad = |s: LineCameraSettings| LineCamera::new(s).err();
        assert_eq!(bad(LineCameraSettings { image_px: 100, ..settings() }), Some(CameraError::ImageNotPowerOfTwo(100)));
        assert_eq!(bad(LineCameraSettings { image_px: 8192, ..settings() }), Some(CameraError::ImageSize(8192)));
        assert!(matches!(bad(LineCameraSettings { aspect: 0.0, ..settings() }), Some(CameraError::NotPositive { field: "aspect", .. })));
        assert_eq!(bad(LineCameraSettings { noise_std: -1.0, ..settings() }), Some(CameraError::Noise(-1.0)));
        assert_eq!(bad(LineCameraSettings { blur_px: 32, ..settings() }), Some(CameraError::Blur(32)));
        let parsed: LineCameraSettings = toml::from_str("image_px = 128\northographic_size_m = 0.1\nlatency_frames = 1").unwrap();
        assert_eq!(parsed, LineCameraSettings { image_px: 128, latency_frames: 1, ..settings() });
        assert!(toml::from_str::<LineCameraSettings>("image_px = 128\northographic_size_m = 0.1\nfps = 1").is_err());
        // H and W as in the seed.
        let s = LineCameraSettings { aspect: 1.5, ..parsed };
        assert!((s.height_factor() - 0.2 / 128.0).abs() < 1e-9 && (s.width_factor() - 1.5 * 0.2 / 128.0).abs() < 1e-9);
    }
}
