//! Instruction codes and the parameter layouts of reference §4.

use thiserror::Error;

/// Instruction codes (reference §4).
pub mod opcode {
    pub const PING: u8 = 0x01;
    pub const READ: u8 = 0x02;
    pub const WRITE: u8 = 0x03;
    pub const REG_WRITE: u8 = 0x04;
    pub const ACTION: u8 = 0x05;
    pub const FACTORY_RESET: u8 = 0x06;
    pub const REBOOT: u8 = 0x08;
    pub const CLEAR: u8 = 0x10;
    pub const CONTROL_TABLE_BACKUP: u8 = 0x20;
    pub const STATUS: u8 = 0x55;
    pub const SYNC_READ: u8 = 0x82;
    pub const SYNC_WRITE: u8 = 0x83;
    pub const FAST_SYNC_READ: u8 = 0x8A;
    pub const BULK_READ: u8 = 0x92;
    pub const BULK_WRITE: u8 = 0x93;
    pub const FAST_BULK_READ: u8 = 0x9A;
}

/// One device's part of a Sync Write.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SyncWriteEntry {
    pub id: u8,
    pub data: Vec<u8>,
}

/// One device's part of a Bulk Read / Fast Bulk Read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BulkReadEntry {
    pub id: u8,
    pub address: u16,
    pub length: u16,
}

/// One device's part of a Bulk Write.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BulkWriteEntry {
    pub id: u8,
    pub address: u16,
    pub data: Vec<u8>,
}

/// A decoded instruction with its parameters interpreted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Instruction {
    Ping,
    Read {
        address: u16,
        length: u16,
    },
    Write {
        address: u16,
        data: Vec<u8>,
    },
    RegWrite {
        address: u16,
        data: Vec<u8>,
    },
    Action,
    FactoryReset {
        option: u8,
    },
    Reboot,
    /// Clear; the parameters are kept raw because their meaning (`01 44 58 4C 22` = reset the
    /// multi-turn count) is checked by the device.
    Clear {
        params: Vec<u8>,
    },
    ControlTableBackup {
        params: Vec<u8>,
    },
    SyncRead {
        address: u16,
        length: u16,
        ids: Vec<u8>,
    },
    FastSyncRead {
        address: u16,
        length: u16,
        ids: Vec<u8>,
    },
    SyncWrite {
        address: u16,
        length: u16,
        entries: Vec<SyncWriteEntry>,
    },
    BulkRead {
        entries: Vec<BulkReadEntry>,
    },
    FastBulkRead {
        entries: Vec<BulkReadEntry>,
    },
    BulkWrite {
        entries: Vec<BulkWriteEntry>,
    },
    /// A code this protocol does not define (the device answers Instruction Error).
    Unknown {
        code: u8,
    },
}

/// The parameters do not fit the instruction's layout.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ParamError {
    #[error("instruction 0x{code:02X} needs {expected} parameter bytes, got {got}")]
    WrongLength { code: u8, expected: &'static str, got: usize },
    #[error("instruction 0x{code:02X} lists ID {id} more than once")]
    DuplicateId { code: u8, id: u8 },
}

fn u16_at(params: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([params[at], params[at + 1]])
}

impl Instruction {
    /// Interpret `params` (already unstuffed) for instruction `code`.
    pub fn parse(code: u8, params: &[u8]) -> Result<Self, ParamError> {
        let wrong = |expected: &'static str| ParamError::WrongLength { code, expected, got: params.len() };
        let exact = |n: usize, expected: &'static str| if params.len() == n { Ok(()) } else { Err(wrong(expected)) };
        Ok(match code {
            opcode::PING => {
                exact(0, "0")?;
                Self::Ping
            }
            opcode::READ => {
                exact(4, "4")?;
                Self::Read { address: u16_at(params, 0), length: u16_at(params, 2) }
            }
            opcode::WRITE | opcode::REG_WRITE => {
                if params.len() < 3 {
                    return Err(wrong("at least 3"));
                }
                let address = u16_at(params, 0);
                let data = params[2..].to_vec();
                if code == opcode::WRITE { Self::Write { address, data } } else { Self::RegWrite { address, data } }
            }
            opcode::ACTION => {
                exact(0, "0")?;
                Self::Action
            }
            opcode::FACTORY_RESET => {
                exact(1, "1")?;
                Self::FactoryReset { option: params[0] }
            }
            opcode::REBOOT => {
                exact(0, "0")?;
                Self::Reboot
            }
            opcode::CLEAR => Self::Clear { params: params.to_vec() },
            opcode::CONTROL_TABLE_BACKUP => Self::ControlTableBackup { params: params.to_vec() },
            opcode::SYNC_READ | opcode::FAST_SYNC_READ => {
                if params.len() < 5 {
                    return Err(wrong("4 + at least one ID"));
                }
                let address = u16_at(params, 0);
                let length = u16_at(params, 2);
                let ids = params[4..].to_vec();
                reject_duplicates(code, ids.iter().copied())?;
                if code == opcode::SYNC_READ { Self::SyncRead { address, length, ids } } else { Self::FastSyncRead { address, length, ids } }
            }
            opcode::SYNC_WRITE => {
                if params.len() < 4 {
                    return Err(wrong("4 + (1 + length) per ID"));
                }
                let address = u16_at(params, 0);
                let length = u16_at(params, 2);
                let stride = 1 + usize::from(length);
                let body = &params[4..];
                if length == 0 || body.is_empty() || !body.len().is_multiple_of(stride) {
                    return Err(wrong("4 + (1 + length) per ID"));
                }
                let entries = body.chunks_exact(stride).map(|chunk| SyncWriteEntry { id: chunk[0], data: chunk[1..].to_vec() }).collect::<Vec<_>>();
                Self::SyncWrite { address, length, entries }
            }
            opcode::BULK_READ | opcode::FAST_BULK_READ => {
                if params.is_empty() || !params.len().is_multiple_of(5) {
                    return Err(wrong("5 per ID"));
                }
                let entries = params.chunks_exact(5).map(|c| BulkReadEntry { id: c[0], address: u16_at(c, 1), length: u16_at(c, 3) }).collect::<Vec<_>>();
                reject_duplicates(code, entries.iter().map(|e| e.id))?;
                if code == opcode::BULK_READ { Self::BulkRead { entries } } else { Self::FastBulkRead { entries } }
            }
            opcode::BULK_WRITE => {
                let mut entries = Vec::new();
                let mut rest = params;
                while !rest.is_empty() {
                    if rest.len() < 5 {
                        return Err(wrong("5 + length per ID"));
                    }
                    let length = usize::from(u16_at(rest, 3));
                    if length == 0 || rest.len() < 5 + length {
                        return Err(wrong("5 + length per ID"));
                    }
                    entries.push(BulkWriteEntry { id: rest[0], address: u16_at(rest, 1), data: rest[5..5 + length].to_vec() });
                    rest = &rest[5 + length..];
                }
                if entries.is_empty() {
                    return Err(wrong("5 + length per ID"));
                }
                reject_duplicates(code, entries.iter().map(|e| e.id))?;
                Self::BulkWrite { entries }
            }
            code => Self::Unknown { code },
        })
    }

    /// The instruction code this variant is sent with.
    pub fn code(&self) -> u8 {
        match self {
            Self::Ping => opcode::PING,
            Self::Read { .. } => opcode::READ,
            Self::Write { .. } => opcode::WRITE,
            Self::RegWrite { .. } => opcode::REG_WRITE,
            Self::Action => opcode::ACTION,
            Self::FactoryReset { .. } => opcode::FACTORY_RESET,
            Self::Reboot => opcode::REBOOT,
            Self::Clear { .. } => opcode::CLEAR,
            Self::ControlTableBackup { .. } => opcode::CONTROL_TABLE_BACKUP,
            Self::SyncRead { .. } => opcode::SYNC_READ,
            Self::FastSyncRead { .. } => opcode::FAST_SYNC_READ,
            Self::SyncWrite { .. } => opcode::SYNC_WRITE,
            Self::BulkRead { .. } => opcode::BULK_READ,
            Self::FastBulkRead { .. } => opcode::FAST_BULK_READ,
            Self::BulkWrite { .. } => opcode::BULK_WRITE,
            Self::Unknown { code } => *code,
        }
    }

    /// The parameter bytes of this instruction (unstuffed), the inverse of [`Instruction::parse`].
    pub fn params(&self) -> Vec<u8> {
        let mut p = Vec::new();
        match self {
            Self::Ping | Self::Action | Self::Reboot | Self::Unknown { .. } => {}
            Self::Read { address, length } => {
                p.extend_from_slice(&address.to_le_bytes());
                p.extend_from_slice(&length.to_le_bytes());
            }
            Self::Write { address, data } | Self::RegWrite { address, data } => {
                p.extend_from_slice(&address.to_le_bytes());
                p.extend_from_slice(data);
            }
            Self::FactoryReset { option } => p.push(*option),
            Self::Clear { params } | Self::ControlTableBackup { params } => p.extend_from_slice(params),
            Self::SyncRead { address, length, ids } | Self::FastSyncRead { address, length, ids } => {
                p.extend_from_slice(&address.to_le_bytes());
                p.extend_from_slice(&length.to_le_bytes());
                p.extend_from_slice(ids);
            }
            Self::SyncWrite { address, length, entries } => {
                p.extend_from_slice(&address.to_le_bytes());
                p.extend_from_slice(&length.to_le_bytes());
                for entry in entries {
                    p.push(entry.id);
                    p.extend_from_slice(&entry.data);
                }
            }
            Self::BulkRead { entries } | Self::FastBulkRead { entries } => {
                for entry in entries {
                    p.push(entry.id);
                    p.extend_from_slice(&entry.address.to_le_bytes());
                    p.extend_from_slice(&entry.length.to_le_bytes());
                }
            }
            Self::BulkWrite { entries } => {
                for entry in entries {
                    p.push(entry.id);
                    p.extend_from_slice(&entry.address.to_le_bytes());
                    p.extend_from_slice(&(entry.data.len() as u16).to_le_bytes());
                    p.extend_from_slice(&entry.data);
                }
            }
        }
        p
    }

    /// Human-readable name, for traces.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Ping => "Ping",
            Self::Read { .. } => "Read",
            Self::Write { .. } => "Write",
            Self::RegWrite { .. } => "RegWrite",
            Self::Action => "Action",
            Self::FactoryReset { .. } => "FactoryReset",
            Self::Reboot => "Reboot",
            Self::Clear { .. } => "Clear",
            Self::ControlTableBackup { .. } => "ControlTableBackup",
            Self::SyncRead { .. } => "SyncRead",
            Self::FastSyncRead { .. } => "FastSyncRead",
            Self::SyncWrite { .. } => "SyncWrite",
            Self::BulkRead { .. } => "BulkRead",
            Self::FastBulkRead { .. } => "FastBulkRead",
            Self::BulkWrite { .. } => "BulkWrite",
            Self::Unknown { .. } => "Unknown",
        }
    }
}

fn reject_duplicates(code: u8, ids: impl Iterator<Item = u8>) -> Result<(), ParamError> {
    let mut seen = [false; 256];
    for id in ids {
        if std::mem::replace(&mut seen[usize::from(id)], true) {
            return Err(ParamError::DuplicateId { code, id });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_sync_read_and_round_trips() {
        let params = [0x84, 0x00, 0x04, 0x00, 0x01, 0x02];
        let parsed = Instruction::parse(opcode::SYNC_READ, &params).unwrap();
        assert_eq!(parsed, Instruction::SyncRead { address: 132, length: 4, ids: vec![1, 2] });
        assert_eq!(parsed.params(), params);
    }

    #[test]
    fn parses_bulk_write_with_different_lengths() {
        let params = [1, 116, 0, 4, 0, 0, 2, 0, 0, 2, 64, 0, 1, 0, 1];
        let parsed = Instruction::parse(opcode::BULK_WRITE, &params).unwrap();
        assert_eq!(parsed, Instruction::BulkWrite { entries: vec![BulkWriteEntry { id: 1, address: 116, data: vec![0, 2, 0, 0] }, BulkWriteEntry { id: 2, address: 64, data: vec![1] },] });
        assert_eq!(parsed.params(), params);
    }

    #[test]
    fn rejects_truncated_read() {
        assert!(matches!(Instruction::parse(opcode::READ, &[0x84, 0x00, 0x04]), Err(ParamError::WrongLength { .. })));
    }

    #[test]
    fn rejects_bulk_read_with_repeated_id() {
        let params = [1, 132, 0, 4, 0, 1, 128, 0, 4, 0];
        assert_eq!(Instruction::parse(opcode::BULK_READ, &params), Err(ParamError::DuplicateId { code: opcode::BULK_READ, id: 1 }));
    }

    #[test]
    fn rejects_sync_write_with_ragged_body() {
        let params = [116, 0, 4, 0, 1, 0, 0, 0];
        assert!(Instruction::parse(opcode::SYNC_WRITE, &params).is_err());
    }

    #[test]
    fn unknown_code_is_kept() {
        assert_eq!(Instruction::parse(0x77, &[1, 2]), Ok(Instruction::Unknown { code: 0x77 }));
    }
}
