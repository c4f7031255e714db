//! Hand-overs of the turn between the controller's own threads, as climbsim counts them: a
//! thread that parks hands the turn on itself (`Header::turns.hand_ons_begun` and `_ended`), and
//! climbsim decides nothing on a look that such a hand-over overlapped. A thread killed in the
//! middle of one leaves the counts apart for good; this writes such hand-overs off.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::abi;
use super::watchdog;

/// How long (wall time) the hand-over counts may stand unequal and unchanged before climbsim
/// looks for hand-overs whose threads were killed in them (a pool's worker ended by SIGTERM).
pub(super) const HAND_ON_STALL: Duration = Duration::from_millis(20);

/// Hand-overs of the turn between threads that never ended (see `Header::turns.hand_ons_begun`).
#[derive(Default)]
pub(super) struct HandOns {
    /// What the counts differ by with no hand-over under way (`begun == ended + written_off`):
    /// hand-overs whose threads died in them. A thread can die (a `multiprocessing` worker
    /// ended by SIGTERM, a thread the program's `exit` ends) between its mark and its count
    /// on either side, so this is not counted up per dead mark but taken from the counts once
    /// no live thread is marked.
    pub(super) written_off: u64,
    /// The counts (begun, ended) last seen unequal, and since when.
    stalled: Option<(u64, u64, Instant)>,
}

impl HandOns {
    /// The counts stand at `begun` and `ended` (read before this), further apart than what was
    /// written off: once they have stood so for a while, the marks of threads that are gone are
    /// cleared, and if no thread is marked then, whatever the counts differ by is written off.
    /// Whether no hand-over is under way.
    pub(super) fn write_off_dead(&mut self, shared: &abi::Shared, begun: u64, ended: u64) -> bool {
        match self.stalled {
            Some((b, e, since)) if (b, e) == (begun, ended) => {
                if since.elapsed() < HAND_ON_STALL {
                    return false;
                }
            }
            _ => {
                self.stalled = Some((begun, ended, Instant::now()));
                return false;
            }
        }
        self.stalled = None;
        let mut marked = false;
        for slot in shared.live_slots() {
            if slot.handing.load(Ordering::SeqCst) == 0 {
                continue;
            }
            let gone = || watchdog::stat_path(slot).is_none_or(|task| !watchdog::lives(&format!("{task}/stat")));
            if gone() {
                // Its mark kept the slot from being taken again.
                tracing::debug!(tid = slot.tid.load(Ordering::Relaxed), "a controller thread died handing its turn on");
                slot.handing.store(0, Ordering::SeqCst);
            } else {
                marked = true;
            }
        }
        // The counts were read before the marks: a hand-over that began since is not in them,
        // and one in them that has ended since ends up counted twice (the counts then differ
        // again, and are taken afresh after the next stall: climbsim waits, never decides early).
        if marked {
            return false;
        }
        self.written_off = begun.wrapping_sub(ended);
        true
    }
}
