//! All-or-nothing file writes.

use std::ffi::OsString;
use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use super::{ReportError, io_error};

/// Writes `path` atomically: `write` fills `NAME.tmp` in the same directory, which is flushed
/// and fsynced and then renamed over `path`; the directory is fsynced so the rename survives a
/// crash. If anything fails, the temporary file is removed and `path` is left as it was.
pub fn write_atomically(path: &Path, write: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>) -> Result<(), ReportError> {
    let temporary = temporary_path(path);
    let written = (|| {
        let mut writer = BufWriter::new(File::create(&temporary)?);
        write(&mut writer)?;
        let file = writer.into_inner().map_err(io::IntoInnerError::into_error)?;
        file.sync_all()
    })();
    if let Err(source) = written {
        // Best effort: the error that matters is the write's, not the clean-up's.
        let _ = fs::remove_file(&temporary);
        return Err(ReportError::Io { path: temporary, source });
    }
    commit(&temporary, path)
}

/// Writes `path` atomically through a writer that wants a path rather than a stream (e.g. the
/// workbook's, which saves a file itself): `write` fills `NAME.tmp`, which is then fsynced and
/// renamed over `path` as in [`write_atomically`]; on failure it is removed.
pub(crate) fn write_atomically_at(path: &Path, write: impl FnOnce(&Path) -> Result<(), ReportError>) -> Result<(), ReportError> {
    let temporary = temporary_path(path);
    let written = write(&temporary).and_then(|()| File::open(&temporary).and_then(|file| file.sync_all()).map_err(io_error(&temporary)));
    if let Err(error) = written {
        // Best effort: the error that matters is the write's, not the clean-up's.
        let _ = fs::remove_file(&temporary);
        return Err(error);
    }
    commit(&temporary, path)
}

/// The second half of an atomic write: rename the finished (and fsynced) `temporary` over
/// `path`, then fsync the directory so the rename survives a crash. A failed rename removes the
/// temporary.
pub(crate) fn commit(temporary: &Path, path: &Path) -> Result<(), ReportError> {
    if let Err(source) = fs::rename(temporary, path) {
        let _ = fs::remove_file(temporary);
        return Err(ReportError::Io { path: path.to_path_buf(), source });
    }
    let directory = directory_of(path);
    File::open(directory).and_then(|dir| dir.sync_all()).map_err(io_error(directory))
}

/// Writes `bytes` to `path` atomically (see [`write_atomically`]).
pub(crate) fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<(), ReportError> {
    write_atomically(path, |writer| writer.write_all(bytes))
}

/// `NAME.tmp` beside `NAME`: the same directory, hence the same file system, so the rename is
/// atomic.
pub(crate) fn temporary_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().map(OsString::from).unwrap_or_default();
    name.push(".tmp");
    path.with_file_name(name)
}

fn directory_of(path: &Path) -> &Path {
    match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent,
        _ => Path::new("."),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_completed_write_leaves_only_the_file() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("out.txt");
        write_bytes_atomically(&path, b"hello").expect("written");
        assert_eq!(fs::read(&path).expect("readable"), b"hello");
        assert!(!dir.path().join("out.txt.tmp").exists());
    }

    #[test]
    fn a_failed_write_keeps_the_old_file_and_removes_the_temporary() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("out.txt");
        write_bytes_atomically(&path, b"old").expect("written");
        let result = write_atomically(&path, |writer| {
            writer.write_all(b"half a ")?;
            Err(io::Error::other("killed"))
        });
        match result {
            Err(ReportError::Io { path: failed, .. }) => {
                assert_eq!(failed, dir.path().join("out.txt.tmp"))
            }
            other => panic!("expected an I/O error, got {other:?}"),
        }
        assert_eq!(fs::read(&path).expect("readable"), b"old");
        assert!(!dir.path().join("out.txt.tmp").exists());
    }

    #[test]
    fn a_missing_directory_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("missing").join("out.txt");
        let error = write_bytes_atomically(&path, b"x").expect_err("no directory");
        assert!(error.to_string().contains("out.txt.tmp"), "{error}");
    }
}
