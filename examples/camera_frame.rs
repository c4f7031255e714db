//! Cost of one camera frame: 1000 renders of a 128 × 128 image of a 3-segment line (smoothness
//! 5) draped on flat ground, the robot driving along it. Prints the median and the 99th
//! percentile in µs per frame. Run with `cargo run --release --example camera_frame`.

use std::path::Path;
use std::time::{Duration, Instant};

use climbsim::sim::camera::{LineCamera, LineCameraSettings};
use climbsim::sim::detector::{DetectorSettings, LineDetector};
use climbsim::sim::line::WeldLine;
use climbsim::sim::terrain::{self, TerrainSpec};
use rapier3d::math::{Pose, Rotation, Vector};

fn main() -> anyhow::Result<()> {
    let terrain = terrain::generate(&TerrainSpec::Flat { size_m: 4.0 }, 0, Path::new("."))?;
    let mut line = WeldLine::new(&[[-1.0, 0.0], [0.0, 0.0], [0.6, -0.4], [1.2, -0.4]], 5, 0.02)?;
    line.drape(&terrain)?;
    let settings = LineCameraSettings { image_px: 128, orthographic_size_m: 0.1, aspect: 1.0, frame_rate_hz: 1000.0, noise_std: 0.0, blur_px: 0, latency_frames: 0, seed: 1 };
    let mut camera = LineCamera::new(settings)?;
    let detector = LineDetector::new(DetectorSettings::default())?;
    let frames = 1000;
    let mut micros = Vec::with_capacity(frames);
    let mut valid = 0;
    for k in 0..frames {
        // Drive along the line, 2 mm per frame, slightly off it and yawing.
        let p = line.nearest(Vector::new(-0.9 + 0.002 * k as f32, 0.0, 0.0));
        let yaw = p.heading_rad + 0.1 * (k as f32 * 0.05).sin();
        let pose = Pose::from_parts(p.point + Vector::new(0.0, 0.1, 0.01), Rotation::from_rotation_y(yaw));
        let t = Duration::from_millis(k as u64);
        let start = Instant::now();
        let frame = camera.render(pose, std::slice::from_ref(&line), t);
        micros.push(start.elapsed().as_secs_f64() * 1e6);
        if let Some(frame) = frame {
            valid += usize::from(detector.detect(frame).valid);
        }
    }
    micros.sort_by(f64::total_cmp);
    println!(
        "camera_frame: 128x128, {} line samples: median {:.1} µs/frame, p99 {:.1} µs ({valid}/{frames} frames with a valid line)",
        line.samples().len(),
        micros[frames / 2],
        micros[frames * 99 / 100],
    );
    Ok(())
}
