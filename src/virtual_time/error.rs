//! What can go wrong under virtual time, for the run to report.

use thiserror::Error;

#[derive(Debug, Error)]
pub enum VtError {
    #[error("virtual time: the shim {path}: {what}: {source}")]
    Shim { path: std::path::PathBuf, what: String, source: std::io::Error },
    #[error("virtual time: the shared block {path}: {what}: {source}")]
    Block { path: std::path::PathBuf, what: String, source: std::io::Error },
    /// A controller that virtual time cannot follow (the watchdog's finding).
    #[error("{0}")]
    Stuck(String),
    #[error("interrupted")]
    Interrupted,
}
