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
use std::sync::mpsc::{Receiver, Sender, SyncSender, channel, sync_channel};
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
    /// Serve the world live to Foxglove there (`--foxglove` with `--scenario`): the session's
    /// one connection, the real servos' replies beside the world's.
    pub live: Option<LiveAddress>,
}

impl TapWorld {
    /// Start the world's thread for the session recorded into `transcript`; the world (the
    /// scenario, the robot, the recording) is made there, and a failure to make it is returned
    /// here, before the session starts. (Not made here: `tap` runs inside a runtime that its
    /// thread never polls, and a live view started here would serve its viewers from that
    /// runtime, which never answers them: the connection was reset.)
    pub fn start(transcript: &Path, options: &TapWorldOptions) -> Result<Self> {
        let out = options.compare.out.clone();
        std::fs::create_dir_all(&out).map_err(|e| RunnerError::during(format!("tap --scenario: creating {}", out.display()), e))?;
        let (queue, records) = channel::<RealRecord>();
        let (started, start_result) = sync_channel::<std::result::Result<Option<String>, CompareError>>(1);
        let (transcript, world) = (transcript.to_owned(), options.clone());
        let thread = std::thread::Builder::new()
            .name("tap-world".to_owned())
            .spawn(move || reenact_live(&transcript, &world, &records, &started))
            .map_err(|e| RunnerError::during("cannot start the tap's world", e))?;
        match start_result.recv() {
            Ok(Ok(live_url)) => Ok(Self { queue, thread, out, live_url }),
            Ok(Err(error)) => Err(RunnerError::during("tap --scenario", error)),
            Err(_) => Err(RunnerError::during("tap --scenario", std::io::Error::other("the world's thread ended before it started"))),
        }
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

/// The world's thread: make the world, then re-enact each record until the queue closes. The
/// transcript's first line is its header, so the records are its lines from 2 on.
fn reenact_live(
    transcript: &Path,
    options: &TapWorldOptions,
    records: &Receiver<RealRecord>,
    started: &SyncSender<std::result::Result<Option<String>, CompareError>>,
) -> std::result::Result<CompareReport, CompareError> {
    let out = &options.compare.out;
    let mut world = match Reenactor::new(transcript, &options.compare, Some(&out.join(COMPARE_MCAP)), options.live.clone()) {
        Ok(world) => world,
        Err(error) => {
            let message = error.to_string();
            let _ = started.send(Err(error));
            return Err(CompareError::Write { path: out.clone(), source: std::io::Error::other(message) });
        }
    };
    let _ = started.send(Ok(world.live_url().map(str::to_owned)));
    for (index, record) in records.iter().enumerate() {
        world.instruction(index + 2, &record)?;
    }
    world.finish()
}
