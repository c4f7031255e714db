//! `run.mcap`: a run recorded for Foxglove (MCAP is also the ROS 2 bag format; Rerun opens it
//! too), written with the Foxglove SDK, which brings the well-known schemas and the writer.
//!
//! Topics (log time = simulated time since the run began):
//! - `/tf` (`foxglove.FrameTransforms`): `map` (z up) → `world` (rapier's y up) → each rigid
//!   part of the robot (`middle`, `front`, `wheel_front_left`, …), at the capture rate;
//! - `/camera/image` (`foxglove.CompressedImage`, PNG): every frame of the downward camera;
//! - `/signals` (JSON): every column of `timeseries.csv` at the capture rate, for plots.
//!
//! The file is written as `run.mcap.tmp` and renamed when the run ends, interrupted or not, so a
//! `run.mcap` is always complete.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use foxglove::messages::{CompressedImage, FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3};
use foxglove::{Channel, ChannelBuilder, Context, McapWriter, McapWriterHandle, PartialMetadata, RawChannel, Schema};
use rapier3d::prelude::Pose;
use thiserror::Error;

/// The recording's file name in a run's output folder.
pub const MCAP_FILE: &str = "run.mcap";

#[derive(Debug, Error)]
pub enum McapError {
    #[error("cannot write {path}: {message}")]
    Write { path: PathBuf, message: String },
}

/// One run's recording.
pub struct McapRecording {
    /// Channels and writer belong to a context of their own: runs of a sweep record side by side.
    _context: Arc<Context>,
    writer: Option<McapWriterHandle<BufWriter<File>>>,
    transforms: Channel<FrameTransforms>,
    image: Channel<CompressedImage>,
    signals: Arc<RawChannel>,
    columns: Vec<&'static str>,
    /// The signals' JSON, reused row after row.
    json: String,
    temporary: PathBuf,
    path: PathBuf,
}

fn nanos(t: Duration) -> u64 {
    u64::try_from(t.as_nanos()).unwrap_or(u64::MAX)
}

fn timestamp(t: Duration) -> Timestamp {
    Timestamp::new(u32::try_from(t.as_secs()).unwrap_or(u32::MAX), t.subsec_nanos())
}

/// A JSON schema for the signals: one number per column.
fn signals_schema(columns: &[&str]) -> Vec<u8> {
    let properties: serde_json::Map<String, serde_json::Value> = columns.iter().map(|&name| (name.to_owned(), serde_json::json!({ "type": "number" }))).collect();
    serde_json::json!({ "type": "object", "properties": properties }).to_string().into_bytes()
}

impl McapRecording {
    /// Start `out_dir/run.mcap` (as `run.mcap.tmp` until [`McapRecording::finish`]); `columns`
    /// name the values of each [`McapRecording::signals`] row.
    pub fn create(out_dir: &Path, columns: &[&'static str]) -> Result<Self, McapError> {
        let path = out_dir.join(MCAP_FILE);
        let temporary = out_dir.join(format!("{MCAP_FILE}.tmp"));
        let error = |message: String| McapError::Write { path: path.clone(), message };
        // A leftover of a killed run would make `create_new` fail.
        let _ = std::fs::remove_file(&temporary);
        let context = Context::new();
        let writer = McapWriter::new().context(&context).create_new_buffered_file(&temporary).map_err(|e| error(e.to_string()))?;
        let transforms = ChannelBuilder::new("/tf").context(&context).build::<FrameTransforms>();
        let image = ChannelBuilder::new("/camera/image").context(&context).build::<CompressedImage>();
        let signals = ChannelBuilder::new("/signals")
            .context(&context)
            .message_encoding("json")
            .schema(Schema::new("climbsim.Signals", "jsonschema", signals_schema(columns)))
            .build_raw()
            .map_err(|e| error(e.to_string()))?;
        Ok(Self { _context: context, writer: Some(writer), transforms, image, signals, columns: columns.to_vec(), json: String::new(), temporary, path })
    }

    /// The robot's parts at `t`, as transforms from `world`.
    pub fn transforms(&self, t: Duration, parts: &[(&str, Pose)]) {
        // Foxglove's 3D panel has z up; rapier's world has y up: +90° about x turns one into the other.
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let mut transforms = vec![FrameTransform {
            timestamp: Some(timestamp(t)),
            parent_frame_id: "map".to_owned(),
            child_frame_id: "world".to_owned(),
            translation: Some(Vector3 { x: 0.0, y: 0.0, z: 0.0 }),
            rotation: Some(Quaternion { x: half, y: 0.0, z: 0.0, w: half }),
        }];
        transforms.extend(parts.iter().map(|(name, pose)| FrameTransform {
            timestamp: Some(timestamp(t)),
            parent_frame_id: "world".to_owned(),
            child_frame_id: (*name).to_owned(),
            translation: Some(Vector3 { x: f64::from(pose.translation.x), y: f64::from(pose.translation.y), z: f64::from(pose.translation.z) }),
            rotation: Some(Quaternion { x: f64::from(pose.rotation.x), y: f64::from(pose.rotation.y), z: f64::from(pose.rotation.z), w: f64::from(pose.rotation.w) }),
        }));
        self.transforms.log_with_time(&FrameTransforms { transforms }, nanos(t));
    }

    /// A camera frame taken at `t`, PNG-encoded.
    pub fn image(&self, t: Duration, png: Vec<u8>) {
        let message = CompressedImage { timestamp: Some(timestamp(t)), frame_id: "camera".to_owned(), data: png.into(), format: "png".to_owned() };
        self.image.log_with_time(&message, nanos(t));
    }

    /// One row of signals (the values of the columns given to [`McapRecording::create`]); NaN
    /// and infinite values are left out (JSON has no number for them).
    pub fn signals(&mut self, t: Duration, row: &[f64]) {
        // Written by hand into a reused buffer: the column names are plain identifiers, and a
        // finite f64's Display is a valid JSON number (no exponent, no NaN).
        use std::fmt::Write as _;
        let json = &mut self.json;
        json.clear();
        json.push('{');
        for (&name, &value) in self.columns.iter().zip(row).filter(|(_, v)| v.is_finite()) {
            if json.len() > 1 {
                json.push(',');
            }
            let _ = write!(json, "\"{name}\":{value}");
        }
        json.push('}');
        self.signals.log_with_meta(json.as_bytes(), PartialMetadata { log_time: Some(nanos(t)) });
    }

    /// Close the file and give it its final name.
    pub fn finish(mut self) -> Result<(), McapError> {
        let error = |message: String| McapError::Write { path: self.path.clone(), message };
        if let Some(writer) = self.writer.take() {
            writer.close().map_err(|e| error(e.to_string()))?;
        }
        std::fs::rename(&self.temporary, &self.path).map_err(|e| error(e.to_string()))
    }
}
