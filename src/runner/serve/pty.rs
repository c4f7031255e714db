//! The pty transport: the servos on a pseudo-terminal whose name the controller opens.

use std::sync::Arc;
use tokio::io::AsyncReadExt as _;

use crate::bus::{Bus, Timing};
use crate::device::StillPlant;
use crate::transport::{Adapter, AdapterModel, BusHandle, Clock, TransportError, VirtualPort, serve_stream_through};

use crate::runner::{During as _, Result};

/// Serve the pty on the wall clock until the process ends, the controller behind `adapter`.
/// The port outlives every controller connection. (Under virtual time the scheduler drives the
/// session: `runner::time_base`.)
pub async fn serve_pty(port: Arc<VirtualPort>, handle: Arc<BusHandle>, adapter: Adapter) -> Result<(), TransportError> {
    let line = port.line();
    let spin_for_requests = handle.with_bus(|bus| bus.timing()) == Timing::Off;
    serve_stream_through(port.stream(spin_for_requests)?, handle, &line, AdapterModel::new(adapter)).await
}

/// The servos as the run left them, on a bus of their own that answers at once and moves
/// nothing: what a controller's clean-up talks to after a run on virtual time (wheels stopped,
/// torque off), as a real robot's servos would answer it. The run's own bus (its world, faults,
/// statistics and recordings) stays as the run ended: nothing after the run is part of it.
pub fn after_the_run(handle: &BusHandle) -> Result<Arc<BusHandle>> {
    let (servos, baud) = handle.with_bus(|bus| (bus.servos().to_vec(), bus.default_baud()));
    let bus = Bus::new(servos, Box::new(StillPlant), Timing::Off, baud).during(|| "cannot set up the servos for the controller's clean-up".to_owned())?;
    Ok(BusHandle::with_clock(bus, None, None, Clock::wall_from(handle.clock().now())))
}

/// Serve `port` on the wall clock for as long as the caller lets it (it aborts the task), the
/// servos behind `handle` (see [`after_the_run`]).
pub async fn serve_after_the_run(port: Arc<VirtualPort>, handle: Arc<BusHandle>, written_before: Vec<u8>) -> Result<(), TransportError> {
    let line = port.line();
    // What the controller wrote through the block's ring that the run did not read (a request
    // sent at the run's last instant, which it still waits for) comes first, then the pty.
    let (read, write) = tokio::io::split(port.stream(false)?);
    let stream = tokio::io::join(std::io::Cursor::new(written_before).chain(read), write);
    serve_stream_through(stream, handle, &line, None).await
}

/// Serve `port` on a thread of its own: precise reply timing spins, and must not stall anything.
pub fn start_thread(port: Arc<VirtualPort>, handle: Arc<BusHandle>, adapter: Adapter) -> Result<std::thread::JoinHandle<Result<()>>> {
    std::thread::Builder::new()
        .name("pty".into())
        .spawn(move || -> Result<()> {
            let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().during(|| "cannot start the pty thread's runtime".to_owned())?;
            // Spawned, not run in `block_on`: a spawned task's I/O wake-ups stay in the
            // scheduler's local queue, while a `block_on` future is woken through the driver's
            // eventfd, which costs two extra syscalls and an extra epoll round per packet.
            runtime.block_on(async move { tokio::spawn(serve_pty(port, handle, adapter)).await }).during(|| "the pty session failed".to_owned())?.during(|| "the pty session ended".to_owned())
        })
        .during(|| "cannot start the pty thread".to_owned())
}
