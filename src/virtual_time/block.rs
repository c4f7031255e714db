//! The shared-memory block itself (layout: `shim/src/abi.rs`): a 0600 file in `/dev/shm` (or the
//! temporary folder where there is none), mapped `MAP_SHARED`, removed when dropped.

use std::os::fd::AsRawFd as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::VtError;
use super::abi::{self, Shared};

/// Names of blocks made by this process: one per run (a sweep runs several at once).
static NEXT_BLOCK: AtomicU64 = AtomicU64::new(0);

/// How many taken names [`Block::create`] passes over before it gives up.
const NAME_ATTEMPTS: u32 = 16;

pub struct Block {
    shared: *mut Shared,
    path: PathBuf,
}

// SAFETY: every field of the block is an atomic; the pointer stays valid until drop.
unsafe impl Send for Block {}
// SAFETY: as above.
unsafe impl Sync for Block {}

impl Block {
    pub fn create() -> Result<Self, VtError> {
        use std::os::unix::fs::OpenOptionsExt as _;
        let dir = if Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        // A climbsim killed outright (SIGKILL, a power cut) leaves its block behind in /dev/shm,
        // and a later process can get its PID: the name carries the clock's nanoseconds too,
        // and a name that is taken all the same is passed over for the next one.
        let mut attempt = 0;
        let (file, path) = loop {
            let nonce = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
            let path = dir.join(format!("climbsim-vt-{}-{}-{nonce:08x}", std::process::id(), NEXT_BLOCK.fetch_add(1, Ordering::Relaxed)));
            match std::fs::OpenOptions::new().read(true).write(true).create_new(true).mode(0o600).open(&path) {
                Ok(file) => break (file, path),
                Err(error) if error.kind() == std::io::ErrorKind::AlreadyExists && attempt < NAME_ATTEMPTS => attempt += 1,
                Err(source) => return Err(VtError::Block { path, what: "cannot create".to_owned(), source }),
            }
        };
        let io = |what: &str, source: std::io::Error| VtError::Block { path: path.clone(), what: what.to_owned(), source };
        file.set_len(abi::SHARED_BYTES as u64).map_err(|e| io("cannot size", e))?;
        // SAFETY: mapping the whole file, which is SHARED_BYTES long; the mapping outlives the fd.
        let mapped = unsafe { libc::mmap(std::ptr::null_mut(), abi::SHARED_BYTES, libc::PROT_READ | libc::PROT_WRITE, libc::MAP_SHARED, file.as_raw_fd(), 0) };
        if mapped == libc::MAP_FAILED {
            let error = std::io::Error::last_os_error();
            let _ = std::fs::remove_file(&path);
            return Err(io("cannot map", error));
        }
        Ok(Self { shared: mapped.cast(), path })
    }

    pub fn shared(&self) -> &Shared {
        // SAFETY: a live mapping of a whole, zero-initialised block (all atomics).
        unsafe { &*self.shared }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for Block {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
        // SAFETY: unmapping our own mapping; nothing refers to it after drop.
        unsafe { libc::munmap(self.shared.cast(), abi::SHARED_BYTES) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A block left behind by a killed climbsim whose PID this process now has, under the name
    /// the next block would have had without the nonce: it is passed over, not an error.
    #[test]
    fn a_leftover_block_under_this_processs_pid_does_not_stop_a_run() {
        let dir = if Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        let next = NEXT_BLOCK.load(Ordering::Relaxed);
        let leftovers: Vec<PathBuf> = (next..next + 4).map(|n| dir.join(format!("climbsim-vt-{}-{n}", std::process::id()))).collect();
        for leftover in &leftovers {
            std::fs::write(leftover, b"left behind").expect("a leftover");
        }
        let block = Block::create().expect("a block beside the leftovers");
        assert!(block.path().exists() && !leftovers.contains(&block.path().to_path_buf()), "{}", block.path().display());
        let path = block.path().to_path_buf();
        drop(block);
        assert!(!path.exists(), "removed when dropped");
        for leftover in &leftovers {
            let _ = std::fs::remove_file(leftover);
        }
    }
}
