//! The shim climbsim carries inside itself (build.rs compiles `shim/` and this file embeds it),
//! written out once to a cache file that controllers can preload.
//!
//! Not beside the binary (`cargo install` installs binaries only, and a stale `.so` could sit
//! beside a newer climbsim); not `/tmp` or `/dev/shm` (often mounted `noexec`, which refuses the
//! mapping); not a memfd (`serve` prints a path that must outlive climbsim).

use std::io::Write as _;
use std::path::PathBuf;

use super::abi;
use super::error::VtError;

static SHIM: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/libclimbsim_shim.so"));

/// The embedded shim's bytes (an ELF shared object).
pub fn shim_bytes() -> &'static [u8] {
    SHIM
}

/// The shim to preload: `$CLIMBSIM_SHIM` if set (and not empty: an empty one preloaded
/// nothing, and the controller ran unfollowed), else the embedded one, written (once per
/// content) to `$XDG_CACHE_HOME/climbsim/` or `~/.cache/climbsim/`.
pub fn shim_path() -> Result<PathBuf, VtError> {
    if let Some(path) = std::env::var_os("CLIMBSIM_SHIM").filter(|p| !p.is_empty()) {
        return Ok(PathBuf::from(path));
    }
    let cache = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .filter(|p| p.is_absolute())
        .or_else(|| std::env::var_os("HOME").map(|home| PathBuf::from(home).join(".cache")))
        .unwrap_or_else(std::env::temp_dir)
        .join("climbsim");
    let path = cache.join(format!("shim-{}-{:016x}.so", abi::ABI, fnv1a(SHIM)));
    if std::fs::metadata(&path).is_ok_and(|m| m.len() == SHIM.len() as u64) {
        return Ok(path);
    }
    let io = |what: &str, source: std::io::Error| VtError::Shim { path: path.clone(), what: what.to_owned(), source };
    std::fs::create_dir_all(&cache).map_err(|e| io("cannot create its folder", e))?;
    // Written aside and renamed, so that a concurrent run never maps half a file.
    let mut staged = tempfile_in(&cache).map_err(|e| io("cannot write it", e))?;
    staged.1.write_all(SHIM).map_err(|e| io("cannot write it", e))?;
    drop(staged.1);
    std::fs::rename(&staged.0, &path).map_err(|e| io("cannot put it in place", e))?;
    Ok(path)
}

fn tempfile_in(dir: &std::path::Path) -> std::io::Result<(PathBuf, std::fs::File)> {
    use std::os::unix::fs::OpenOptionsExt as _;
    let path = dir.join(format!(".shim-{}-{}.tmp", std::process::id(), fnv1a(format!("{:?}", std::thread::current().id()).as_bytes())));
    let file = std::fs::OpenOptions::new().write(true).create(true).truncate(true).mode(0o755).open(&path)?;
    Ok((path, file))
}

/// FNV-1a, 64 bits: names the file by its content (not a security measure).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |hash, &b| (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_shim_is_a_shared_object_exporting_the_clock() {
        let bytes = shim_bytes();
        assert_eq!(&bytes[..4], b"\x7fELF");
        // ET_DYN at offset 16.
        assert_eq!(u16::from_le_bytes([bytes[16], bytes[17]]), 3);
        let has = |name: &[u8]| bytes.windows(name.len()).any(|w| w == name);
        for symbol in [&b"clock_gettime\0"[..], b"clock_nanosleep\0", b"select\0", b"poll\0"] {
            assert!(has(symbol), "{} not exported", String::from_utf8_lossy(symbol));
        }
    }
}
