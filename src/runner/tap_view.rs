//! What `climbsim tap --foxglove` (and `--mcap`) shows: the *real* servos, as their read
//! replies say, in the shipped layout's topics — `/servos` (each servo's registers by name, raw
//! values, as a run's view has them), `/bus/packets` (each record of the transcript as it is
//! written) and `/log` (missed replies, CRC and framing errors, late replies).
//!
//! The bridge never waits for the view: events go to the view's own thread through a bounded
//! queue, and when the view falls behind (a slow viewer, a full disk), events are dropped from
//! the view, never from the bridge or the transcript; the count is logged at the end.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::Duration;

use foxglove::messages::log::Level as LogLevel;
use tracing::warn;

use crate::device::FirmwareProfile;
use crate::protocol::RawPacket;
use crate::real_bus::compare::{fast_blocks, is_fast_read, read_spans, registers_in};
use crate::real_bus::{Event, RealRecord};
use crate::runner::compare::real_bus_note;
use crate::runner::view::{LiveAddress, ReadingsTopic, ServoReadings, Setup, View, ViewError, ViewOptions};
use crate::transcript::packet_from_bytes;

use super::{Result, RunnerError};

/// How many events may wait for the view (a 1 Mbps bus at a 1 kHz loop: about 1 s).
const QUEUE: usize = 1024;

/// Where the tap shows the real servos, and what it needs to know of them.
#[derive(Debug, Clone)]
pub struct TapViewOptions {
    pub live: Option<LiveAddress>,
    pub mcap: Option<PathBuf>,
    /// (ID, name) from the robot description.
    pub names: Vec<(u8, String)>,
    /// The control table their replies are decoded with.
    pub profile: Arc<FirmwareProfile>,
}

/// The view's thread and the queue into it.
pub struct TapView {
    queue: SyncSender<Event>,
    dropped: u64,
    thread: JoinHandle<std::result::Result<(), ViewError>>,
    url: Option<String>,
}

impl TapView {
    /// Start the view's thread; the view itself (its recording, its server) starts there, and
    /// a failure to start is returned here.
    pub fn start(options: &TapViewOptions) -> Result<Self> {
        let (queue, events) = sync_channel::<Event>(QUEUE);
        let (started, start_result) = sync_channel::<std::result::Result<Option<String>, ViewError>>(1);
        let view_options = ViewOptions { mcap: options.mcap.clone(), live: options.live.clone(), packets: true, compare: false };
        let servos = options.clone();
        let thread = std::thread::Builder::new()
            .name("tap-view".to_owned())
            .spawn(move || show(&view_options, &servos, &events, &started))
            .map_err(|e| RunnerError::during("cannot start the tap's view", e))?;
        match start_result.recv() {
            Ok(Ok(url)) => Ok(Self { queue, dropped: 0, thread, url }),
            Ok(Err(error)) => Err(RunnerError::during("tap's view", error)),
            Err(_) => Err(RunnerError::during("tap's view", std::io::Error::other("its thread ended before it started"))),
        }
    }

    /// Where a live viewer connects (`ws://…`), when the view is live.
    pub fn live_url(&self) -> Option<&str> {
        self.url.as_deref()
    }

    /// Hand an event to the view, never waiting.
    pub fn send(&mut self, event: &Event) {
        match self.queue.try_send(event.clone()) {
            Ok(()) => {}
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => self.dropped += 1,
        }
    }

    /// Close the view: the recording gets its final name, the live server stops.
    pub fn finish(self) -> Result<()> {
        drop(self.queue);
        if self.dropped > 0 {
            warn!(dropped = self.dropped, "the tap's view fell behind; these events were not shown (the transcript has them all)");
        }
        match self.thread.join() {
            Ok(result) => result.map_err(|e| RunnerError::during("tap's view", e)),
            Err(_) => Err(RunnerError::during("tap's view", std::io::Error::other("its thread panicked"))),
        }
    }
}

/// The view's thread: start the view, then show each event until the queue closes.
fn show(options: &ViewOptions, servos: &TapViewOptions, events: &Receiver<Event>, started: &SyncSender<std::result::Result<Option<String>, ViewError>>) -> std::result::Result<(), ViewError> {
    let names: Vec<String> = servos.names.iter().map(|(_, name)| name.clone()).collect();
    let setup = Setup { columns: &[], servo_names: &names, has_lidar: false, tyre_radius_m: 0.0, camera_distance_m: 0.0 };
    let view = match View::start(options, &setup) {
        Ok(view) => view,
        Err(error) => {
            let _ = started.send(Err(error));
            return Ok(());
        }
    };
    let _ = started.send(Ok(view.live_url()));
    view.log(Duration::ZERO, LogLevel::Info, "climbsim tap: the real servos, as their read replies say".to_owned());
    for event in events {
        show_event(&view, servos, &event);
    }
    view.finish()
}

fn show_event(view: &View, servos: &TapViewOptions, event: &Event) {
    let record = RealRecord::from_event(event);
    let at = Duration::from_nanos(record.t());
    if let Ok(line) = serde_json::to_string(&record) {
        view.packet_line(at, &line);
    }
    let name = |id: u8| servos.names.iter().find(|(of, _)| *of == id).map_or_else(|| format!("id{id}"), |(_, name)| name.clone());
    if let Event::Transaction(seen) = event {
        let spans = read_spans(&seen.instruction);
        let packets: Vec<RawPacket> = seen.replies.iter().filter_map(|reply| packet_from_bytes(&reply.bytes).ok()).collect();
        // (ID, first address, data) of each servo's answer: a Fast read's one reply split.
        let blocks: Vec<(u8, u16, &[u8])> = if is_fast_read(&seen.instruction) {
            packets.first().map(|packet| fast_blocks(packet, &spans)).unwrap_or_default()
        } else {
            packets.iter().filter_map(|packet| Some((packet.id, spans.iter().find(|(of, _, _)| *of == packet.id)?.1, packet.status_data().ok()?))).collect()
        };
        let names: Vec<String> = blocks.iter().map(|(id, _, _)| name(*id)).collect();
        let readings: Vec<ServoReadings<'_>> =
            blocks.iter().zip(&names).map(|(&(id, address, data), name)| ServoReadings { name, id, registers: registers_in(&servos.profile, address, data) }).collect();
        view.readings(ReadingsTopic::Servos, seen.t, &readings);
    }
    if let Some((level, note)) = real_bus_note(&record, |id| format!("{} ({id})", name(id))) {
        view.log(at, level, note);
    }
    view.time(at);
}
