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

/// The guard of `mutex`, poisoned or not: a panic elsewhere (a driven future's) must not take
/// the scheduler's bookkeeping down with it, and every value behind these locks stays whole
/// between statements.
pub(super) fn lock<T>(mutex: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}
