//! The run library's errors: [`RunError`] for what stops a run being built or run (a
//! scenario the world cannot hold, a controller error), [`RunnerError`] for the commands around
//! runs, with the verdicts (failed, interrupted) that become exit codes.

use std::path::PathBuf;

use thiserror::Error;

use crate::control::ControlError;
use crate::report;
use crate::scenario::ScenarioError;
use crate::sim::SimError;
use crate::sim::detector::DetectorError;
use crate::sim::line::LineError as WeldLineError;

#[derive(Debug, Error)]
pub enum RunError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error(transparent)]
    View(#[from] crate::runner::view::ViewError),
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error(transparent)]
    Robot(#[from] crate::robot::RobotError),
    /// A weld (`line`, or `welds[i]`) that cannot be drawn, at its line in the file.
    #[error("scenario {path}{}: {weld}: {source}", .line.map_or(String::new(), |l| format!(":{l}")))]
    Line { path: PathBuf, line: Option<usize>, weld: String, source: WeldLineError },
    #[error("scenario {path}: [camera]: {message}")]
    Camera { path: PathBuf, message: String },
    #[error("scenario {path}: {message}")]
    Lidar { path: PathBuf, message: String },
    #[error("scenario {path}: [relocation]: {message}")]
    Relocation { path: PathBuf, message: String },
    #[error("scenario {path} has no [line]: a run needs a weld line to follow")]
    NoLine { path: PathBuf },
    #[error("scenario {path}: [capture] signals: no signal `{name}` (known: {known})")]
    UnknownSignal { path: PathBuf, name: String, known: String },
    /// A capture faster than the run produces new states would repeat rows, or lag behind.
    #[error("scenario {path}: [capture] rate_hz = {rate_hz} Hz is more than this run can capture: {max_hz} Hz ({why})")]
    CaptureRate { path: PathBuf, rate_hz: f64, max_hz: f64, why: String },
    #[error("line detector: {0}")]
    Detector(#[from] DetectorError),
    #[error("controller: {0}")]
    Control(#[from] ControlError),
    #[error("scenario {path} has an external controller; run it with `climbsim run` (real time)")]
    NeedsRealTime { path: PathBuf },
    #[error(transparent)]
    Report(#[from] report::ReportError),
    #[error("scenario {path}: {message}")]
    Start { path: PathBuf, message: String },
    #[error("scenario {path}: {source}")]
    Fault { path: PathBuf, source: crate::fault::FaultError },
}

/// How a run, or the command around it, failed. [`RunnerError::Failed`] and
/// [`RunnerError::Interrupted`] are verdicts (exit 1 and 130); every other variant is bad input
/// or an unusable environment (exit 2). `docs/exit-codes.md`.
#[derive(Debug, Error)]
pub enum RunnerError {
    /// A run failed: its `[expect]` thresholds, its controller, its world or its pace.
    #[error("{0}")]
    Failed(String),
    /// A signal stopped the work; the outputs cover the part that ran and say so.
    #[error("{0}")]
    Interrupted(String),
    #[error(transparent)]
    Run(#[from] RunError),
    #[error(transparent)]
    Scenario(#[from] crate::scenario::ScenarioError),
    #[error(transparent)]
    Report(#[from] crate::report::ReportError),
    #[error(transparent)]
    Robot(#[from] crate::robot::RobotError),
    /// Virtual time could not be set up (its shared block, its shim file).
    #[error(transparent)]
    VirtualTime(#[from] crate::virtual_time::VtError),
    /// Bad input that is not a file's: a flag, a command, a combination.
    #[error("{0}")]
    Invalid(String),
    /// Something failed while doing `what`.
    #[error("{what}: {source}")]
    During {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

impl RunnerError {
    /// The process's exit code for this error: 1 a failed run, 130 interrupted, 2 anything else.
    pub fn exit_code(&self) -> u8 {
        match self {
            Self::Failed(_) => 1,
            Self::Interrupted(_) => 130,
            _ => 2,
        }
    }

    pub fn is_interrupted(&self) -> bool {
        matches!(self, Self::Interrupted(_))
    }

    /// `source` while doing `what` (the library's counterpart of anyhow's context).
    pub fn during(what: impl Into<String>, source: impl std::error::Error + Send + Sync + 'static) -> Self {
        Self::During { what: what.into(), source: Box::new(source) }
    }
}

pub type Result<T, E = RunnerError> = std::result::Result<T, E>;

/// `.during(|| "what")` on any result: its error, said as happening while doing that.
pub trait During<T> {
    fn during(self, what: impl FnOnce() -> String) -> Result<T>;
}

impl<T, E: std::error::Error + Send + Sync + 'static> During<T> for std::result::Result<T, E> {
    fn during(self, what: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|source| RunnerError::during(what(), source))
    }
}
