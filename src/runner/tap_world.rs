//! `climbsim tap --scenario`: the world re-enacting the real session live, beside the real
//! servos: each record of the transcript, as it is written, goes to the world's own thread,
//! which hands each instruction to the scenario's world at its recorded instant
//! ([`Reenactor`]) and sets the world's answers beside the real ones. When the tap ends, the
//! comparison is written as `compare` writes it (`compare.json`, the plots, `compare.mcap`),
//! and it is the one `compare` makes of the finished transcript: the same records, in order.
//!
//! The bridge never waits for the world: the queue into its thread has no bound (a world runs
//! many times faster than the real robot; one that falls behind catches up after the session,
//! before the comparison is written). Nothing is dropped, or the comparison would be wrong.

use std::path::Path;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::thread::JoinHandle;

use crate::real_bus::RealRecord;
use crate::runner::compare::{COMPARE_MCAP, CompareError, CompareOptions, CompareReport, Reenactor, write_report};
use crate::runner::view::LiveAddress;

use super::{Result, RunnerError};

/// The world's thread and the queue into it.
pub struct TapWorld {
    queue: Sender<RealRecord>,
    thread: JoinHandle<std::result::Result<CompareReport, CompareError>>,
    out: std::path::PathBuf,
    live_url: Option<String>,
}

/// What `tap --scenario` re-enacts the session in, and where it shows it.
#[derive(Debug, Clone)]
pub struct TapWorldOptions {
    /// The world, and where the comparison goes (`out`).
    pub compare: CompareOptions,
    /// Serve the world live to Foxglove there (`--foxglove` with `--scenario`), beside the
    /// tap's own view of the real servos.
    pub live: Option<LiveAddress>,
}

impl TapWorld {
    /// Make the world (the scenario, the robot, the recording) for the session recorded into
    /// `transcript`, before the session starts (a failure to make it is returned here), and
    /// start its thread.
    pub fn start(transcript: &Path, options: &TapWorldOptions) -> Result<Self> {
        let out = options.compare.out.clone();
        std::fs::create_dir_all(&out).map_err(|e| RunnerError::during(format!("tap --scenario: creating {}", out.display()), e))?;
        let world = Reenactor::new(transcript, &options.compare, Some(&out.join(COMPARE_MCAP)), options.live.clone()).map_err(|e| RunnerError::during("tap --scenario", e))?;
        let live_url = world.live_url().map(str::to_owned);
        let (queue, records) = channel::<RealRecord>();
        let thread = std::thread::Builder::new()
            .name("tap-world".to_owned())
            .spawn(move || reenact_live(world, &records))
            .map_err(|e| RunnerError::during("cannot start the tap's world", e))?;
        Ok(Self { queue, thread, out, live_url })
    }

    /// Where a live viewer sees the world (`ws://…`), when it is served live.
    pub fn live_url(&self) -> Option<&str> {
        self.live_url.as_deref()
    }

    /// Hand the next record of the transcript to the world, never waiting.
    pub fn send(&self, record: &RealRecord) {
        // A world that failed has ended its thread: what it says is reported at the end.
        let _ = self.queue.send(record.clone());
    }

    /// The session is over: the world re-enacts what is still queued, and the comparison is
    /// written into the output folder.
    pub fn finish(self) -> Result<CompareReport> {
        drop(self.queue);
        let report = match self.thread.join() {
            Ok(result) => result.map_err(|e| RunnerError::during("tap --scenario", e))?,
            Err(_) => return Err(RunnerError::during("tap --scenario", std::io::Error::other("the world's thread panicked"))),
        };
        write_report(&report, &self.out).map_err(|e| RunnerError::during("tap --scenario", e))?;
        Ok(report)
    }
}

/// The world's thread: re-enact each record until the queue closes. The transcript's first
/// line is its header, so the records are its lines from 2 on.
fn reenact_live(mut world: Reenactor, records: &Receiver<RealRecord>) -> std::result::Result<CompareReport, CompareError> {
    for (index, record) in records.iter().enumerate() {
        world.instruction(index + 2, &record)?;
    }
    world.finish()
}
