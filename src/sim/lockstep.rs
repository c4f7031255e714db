//! An in-process controller's view of the simulated robot: instructions go through the real
//! codec and bus, and the world advances in lockstep, as fast as the CPU allows.

use std::time::Duration;

use thiserror::Error;

use crate::bus::{Bus, Timing};
use crate::protocol::{Decoder, RawPacket, encode_instruction, opcode};
use crate::robot::{RobotDescription, RobotError};

use super::world::{RobotWorld, WorldConfig, WorldError};

#[derive(Debug, Error)]
pub enum SimError {
    #[error(transparent)]
    Robot(#[from] RobotError),
    #[error(transparent)]
    World(#[from] WorldError),
}

/// A status reply's error byte was non-zero, or no reply came.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum ReplyError {
    #[error("no reply")]
    NoReply,
    #[error("status error 0x{0:02X}")]
    Status(u8),
}

pub struct Lockstep {
    bus: Bus,
    now: Duration,
}

impl Lockstep {
    pub fn new(robot: &RobotDescription, config: WorldConfig) -> Result<Self, SimError> {
        let servos = robot.servos(None)?;
        let world = RobotWorld::new(robot, config, &servos)?;
        let bus = robot.bus_of(servos, Box::new(world), Timing::Off, None)?;
        Ok(Self { bus, now: Duration::ZERO })
    }

    pub fn now(&self) -> Duration {
        self.now
    }

    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    pub fn bus_mut(&mut self) -> &mut Bus {
        &mut self.bus
    }

    pub fn world(&self) -> &RobotWorld {
        // ok: `new` always builds the bus around a RobotWorld.
        self.bus.plant::<RobotWorld>().expect("lockstep bus drives a RobotWorld")
    }

    pub fn world_mut(&mut self) -> &mut RobotWorld {
        self.bus.plant_mut::<RobotWorld>().expect("lockstep bus drives a RobotWorld")
    }

    /// Send instruction bytes; return the reply packets.
    pub fn transact(&mut self, bytes: &[u8]) -> Vec<RawPacket> {
        let mut replies = Vec::new();
        for packet in Decoder::default().push(self.now, bytes).into_iter().flatten() {
            let transaction = self.bus.handle(packet, self.now, None);
            for reply in transaction.replies {
                replies.extend(Decoder::default().push(self.now, &reply.bytes).into_iter().flatten());
            }
        }
        replies
    }

    fn single(&mut self, id: u8, code: u8, params: &[u8]) -> Result<Vec<u8>, ReplyError> {
        let replies = self.transact(&encode_instruction(id, code, params));
        let reply = replies.first().ok_or(ReplyError::NoReply)?;
        reply.status_data().map(<[u8]>::to_vec).map_err(|error| error.map_or(ReplyError::NoReply, ReplyError::Status))
    }

    pub fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<(), ReplyError> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(data);
        self.single(id, opcode::WRITE, &params).map(|_| ())
    }

    pub fn read(&mut self, id: u8, address: u16, length: u16) -> Result<Vec<u8>, ReplyError> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(&length.to_le_bytes());
        self.single(id, opcode::READ, &params)
    }

    /// Read a signed little-endian item of 1, 2 or 4 bytes.
    pub fn read_signed(&mut self, id: u8, address: u16, length: u16) -> Result<i64, ReplyError> {
        let bytes = self.read(id, address, length)?;
        Ok(crate::device::decode_item(&bytes, true))
    }

    /// Advance the world by `duration`.
    pub fn run(&mut self, duration: Duration) {
        self.now += duration;
        self.bus.advance(self.now);
    }
}
