//! The shared-memory block itself (layout: `shim/src/abi/layout.rs`): a 0600 file in `/dev/shm` (or the
//! temporary folder where there is none), mapped `MAP_SHARED`, removed when dropped.

use std::os::fd::AsRawFd as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::abi::{self, Shared};
use super::error::VtError;

/// Names of blocks made by this process: one per run (a sweep runs several at once).
static NEXT_BLOCK: AtomicU64 = AtomicU64::new(0);

/// What every block's file name starts with.
const NAME_PREFIX: &str = "climbsim-vt-";

/// Where blocks are made: `/dev/shm`, or the temporary folder where there is none.
fn block_dir() -> PathBuf {
    if Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() }
}

/// How many taken names [`Block::create`] passes over before it gives up.
const NAME_ATTEMPTS: u32 = 16;

pub struct Block {
    shared: *mut Shared,
    path: PathBuf,
    /// Open for as long as the block lives, with a shared `flock` on it: what tells a later
    /// climbsim that this block is not a dead one's ([`remove_blocks_of_dead_processes`]).
    _lock: std::fs::File,
}

// SAFETY: every field of the block is an atomic; the pointer stays valid until drop.
unsafe impl Send for Block {}
// SAFETY: as above.
unsafe impl Sync for Block {}

impl Block {
    pub fn create() -> Result<Self, VtError> {
        use std::os::unix::fs::OpenOptionsExt as _;
        let dir = block_dir();
        static SWEPT: std::sync::Once = std::sync::Once::new();
        SWEPT.call_once(|| remove_blocks_of_dead_processes(&dir));
        // A climbsim killed outright (SIGKILL, a power cut) leaves its block behind in /dev/shm,
        // and a later process can get its PID: the name carries the clock's nanoseconds too,
        // and a name that is taken all the same is passed over for the next one.
        let mut attempt = 0;
        let (file, path) = loop {
            let nonce = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
            let path = dir.join(format!("{NAME_PREFIX}{}-{}-{nonce:08x}", std::process::id(), NEXT_BLOCK.fetch_add(1, Ordering::Relaxed)));
            match std::fs::OpenOptions::new().read(true).write(true).create_new(true).mode(0o600).open(&path) {
                Ok(file) => break (file, path),
                Err(error) if error.kind() == std::io::ErrorKind::AlreadyExists && attempt < NAME_ATTEMPTS => attempt += 1,
                Err(source) => return Err(VtError::Block { path, what: "cannot create".to_owned(), source }),
            }
        };
        let io = |what: &str, source: std::io::Error| VtError::Block { path: path.clone(), what: what.to_owned(), source };
        // SAFETY: flock on the fd we just opened.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_SH | libc::LOCK_NB) } != 0 {
            let error = std::io::Error::last_os_error();
            let _ = std::fs::remove_file(&path);
            return Err(io("cannot lock", error));
        }
        file.set_len(abi::SHARED_BYTES as u64).map_err(|e| io("cannot size", e))?;
        // SAFETY: mapping the whole file, which is SHARED_BYTES long; the mapping outlives the fd.
        let mapped = unsafe { libc::mmap(std::ptr::null_mut(), abi::SHARED_BYTES, libc::PROT_READ | libc::PROT_WRITE, libc::MAP_SHARED, file.as_raw_fd(), 0) };
        if mapped == libc::MAP_FAILED {
            let error = std::io::Error::last_os_error();
            let _ = std::fs::remove_file(&path);
            return Err(io("cannot map", error));
        }
        Ok(Self { shared: mapped.cast(), path, _lock: file })
    }

    pub fn shared(&self) -> &Shared {
        // SAFETY: a live mapping of a whole, zero-initialised block (all atomics).
        unsafe { &*self.shared }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Remove the blocks that climbsims killed outright (SIGKILL, the OOM killer) left in `dir`:
/// each is 1 MiB of memory that /dev/shm keeps until the machine restarts. A live climbsim holds
/// a shared `flock` on its block for as long as the block lives, and the kernel drops the lock
/// when the process dies, however it dies: a block whose exclusive lock can be taken has no
/// climbsim behind it, in this PID namespace or another that shares the folder. Only this
/// user's blocks, and only those older than [`STALE_AFTER`] (a block is locked just after it
/// is made: a block this young may be between the two).
fn remove_blocks_of_dead_processes(dir: &Path) {
    use std::os::unix::fs::MetadataExt as _;
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    // SAFETY: getuid cannot fail.
    let me = unsafe { libc::getuid() };
    for entry in entries.flatten() {
        if !entry.file_name().to_str().is_some_and(|name| name.starts_with(NAME_PREFIX)) {
            continue;
        }
        let Ok(metadata) = entry.metadata() else { continue };
        let old = metadata.modified().ok().and_then(|t| t.elapsed().ok()).is_some_and(|age| age > STALE_AFTER);
        if !old || metadata.uid() != me || !metadata.is_file() {
            continue;
        }
        let Ok(file) = std::fs::File::open(entry.path()) else { continue };
        // SAFETY: flock on an fd we own; LOCK_NB: never waits.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
            tracing::debug!(path = %entry.path().display(), "removing a virtual-time block a dead climbsim left");
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// How old a dead process's block must be before it is removed.
const STALE_AFTER: std::time::Duration = std::time::Duration::from_secs(60);

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
        let dir = block_dir();
        let next = NEXT_BLOCK.load(Ordering::Relaxed);
        let leftovers: Vec<PathBuf> = (next..next + 4).map(|n| dir.join(format!("{NAME_PREFIX}{}-{n}", std::process::id()))).collect();
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

    /// An old block nobody holds goes; a held one (a live climbsim's), a fresh one and other
    /// files stay.
    #[test]
    fn blocks_no_climbsim_holds_are_removed_once_they_are_old() {
        let dir = std::env::temp_dir().join(format!("climbsim-vt-sweep-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("a folder");
        let dead = dir.join("climbsim-vt-1-0-00000000");
        let fresh = dir.join("climbsim-vt-1-1-00000000");
        let alive = dir.join("climbsim-vt-2-0-00000000");
        let other = dir.join("faketime_shm_1");
        for path in [&dead, &fresh, &alive, &other] {
            std::fs::write(path, b"a block").expect("written");
        }
        let long_ago = std::time::SystemTime::now() - 2 * STALE_AFTER;
        for path in [&dead, &alive, &other] {
            std::fs::File::options().write(true).open(path).and_then(|f| f.set_modified(long_ago)).expect("aged");
        }
        let held = std::fs::File::open(&alive).expect("opened");
        // SAFETY: flock on an fd we own.
        assert_eq!(unsafe { libc::flock(held.as_raw_fd(), libc::LOCK_SH | libc::LOCK_NB) }, 0);
        remove_blocks_of_dead_processes(&dir);
        assert!(!dead.exists(), "an old block nobody holds is removed");
        assert!(fresh.exists() && alive.exists() && other.exists(), "the others stay");
        drop(held);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
