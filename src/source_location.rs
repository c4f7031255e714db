//! Loading TOML data files (profiles, robot descriptions, scenarios) with errors that name the
//! file, line, column and key.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use thiserror::Error;

/// A data file that cannot be read or parsed.
#[derive(Debug, Error)]
pub enum DataFileError {
    #[error("cannot read {what} {path}: {source}")]
    Io { what: &'static str, path: PathBuf, source: std::io::Error },
    #[error("{what} {path}:{line}:{column}: {message}")]
    Parse { what: &'static str, path: PathBuf, line: usize, column: usize, message: String },
    /// The file with `--set` overrides applied does not make a valid one.
    #[error("{what} {path} with --set {sets}: {message}")]
    Override { what: &'static str, path: PathBuf, sets: String, message: String },
}

/// Line and column (1-based) of a byte offset in a text.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.rfind('\n').map_or(before.len(), |nl| before.len() - nl - 1) + 1;
    (line, column)
}

/// Parse TOML `text`; `what` and `path` name the file in errors.
pub fn parse_toml<T: DeserializeOwned>(what: &'static str, path: &Path, text: &str) -> Result<T, DataFileError> {
    toml::from_str(text).map_err(|e| {
        let (line, column) = e.span().map(|s| line_col(text, s.start)).unwrap_or((0, 0));
        DataFileError::Parse { what, path: path.to_owned(), line, column, message: e.message().to_owned() }
    })
}

/// Read and parse the TOML file at `path` (a file climbsim has built in if it says
/// `embedded:…`, see [`crate::embedded`]).
pub fn load_toml<T: DeserializeOwned>(what: &'static str, path: &Path) -> Result<T, DataFileError> {
    let text = crate::embedded::read_to_string(path).map_err(|source| DataFileError::Io { what, path: path.to_owned(), source })?;
    parse_toml(what, path, &text)
}

/// Read the TOML file at `path`, set `overrides` in it (see [`crate::overrides`]; their keys
/// start with `prefix`, which names the file: `robot.`), and parse the result; an override
/// that makes no valid file is named as it was given.
pub fn load_toml_with<T: DeserializeOwned>(what: &'static str, path: &Path, prefix: &str, overrides: &[crate::overrides::Override]) -> Result<T, DataFileError> {
    if overrides.is_empty() {
        return load_toml(what, path);
    }
    let mut table: toml::Table = load_toml(what, path)?;
    let sets = || overrides.iter().map(ToString::to_string).collect::<Vec<_>>().join(" ");
    for set in overrides {
        set.apply_under(prefix, &mut table).map_err(|e| DataFileError::Override { what, path: path.to_owned(), sets: sets(), message: e.to_string() })?;
    }
    table.try_into().map_err(|e: toml::de::Error| DataFileError::Override { what, path: path.to_owned(), sets: sets(), message: e.message().to_owned() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_and_column_are_one_based() {
        assert_eq!(line_col("ab\ncd", 0), (1, 1));
        assert_eq!(line_col("ab\ncd", 4), (2, 2));
    }
}
