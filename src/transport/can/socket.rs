//! A SocketCAN raw socket (Linux, `can` feature) as a [`CanFrameIo`], through the `socketcan`
//! crate's tokio socket. The kernel filter passes only the one ID the owner listens to.

use socketcan::{EmbeddedFrame, ExtendedId, Id, SocketOptions, StandardId};

use super::{CanError, CanFrame, CanFrameIo, CanId};

/// A raw CAN socket bound to one interface, e.g. `can0` or `vcan0`.
pub struct SocketCanPort {
    socket: socketcan::tokio::CanSocket,
}

impl std::fmt::Debug for SocketCanPort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SocketCanPort").finish_non_exhaustive()
    }
}

impl SocketCanPort {
    /// Open `iface` and receive only data frames with the ID `listen`. Needs a tokio runtime.
    pub fn open(iface: &str, listen: CanId) -> Result<Self, CanError> {
        let open_error = |source| CanError::Open { iface: iface.to_owned(), source };
        let socket = socketcan::tokio::CanSocket::open(iface).map_err(open_error)?;
        let (id, mask) = match listen {
            CanId::Standard(id) => (u32::from(id), libc::CAN_SFF_MASK),
            CanId::Extended(id) => (id | libc::CAN_EFF_FLAG, libc::CAN_EFF_MASK),
        };
        // Match the frame format (EFF) and exclude remote frames (RTR) as well as the ID.
        let filter = socketcan::CanFilter::new(id, mask | libc::CAN_EFF_FLAG | libc::CAN_RTR_FLAG);
        socket.set_filters(&[filter]).map_err(open_error)?;
        Ok(Self { socket })
    }
}

fn to_socketcan(frame: &CanFrame) -> Option<socketcan::CanFrame> {
    let id = match frame.id {
        CanId::Standard(id) => Id::Standard(StandardId::new(id)?),
        CanId::Extended(id) => Id::Extended(ExtendedId::new(id)?),
    };
    socketcan::CanFrame::new(id, frame.data.as_slice())
}

fn from_socketcan(frame: &socketcan::CanFrame) -> Option<CanFrame> {
    let socketcan::CanFrame::Data(data) = frame else {
        return None;
    };
    let id = match data.id() {
        Id::Standard(id) => CanId::Standard(id.as_raw()),
        Id::Extended(id) => CanId::Extended(id.as_raw()),
    };
    CanFrame::new(id, data.data())
}

impl CanFrameIo for SocketCanPort {
    async fn send(&mut self, frame: CanFrame) -> std::io::Result<()> {
        let frame = to_socketcan(&frame).ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "CAN frame out of range"))?;
        self.socket.write_frame(frame).await
    }

    async fn recv(&mut self) -> std::io::Result<Option<CanFrame>> {
        loop {
            let frame = self.socket.read_frame().await?;
            // Remote and error frames carry no ISO-TP data.
            if let Some(frame) = from_socketcan(&frame) {
                return Ok(Some(frame));
            }
        }
    }
}
