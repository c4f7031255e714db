//! Errors a servo reports in the status packet's error byte (reference §5).

use thiserror::Error;

/// Why an instruction failed. `code()` is the number the status packet carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum DeviceError {
    #[error("result fail (0x01): the instruction could not be carried out")]
    ResultFail,
    #[error("instruction error (0x02): unknown or out-of-order instruction")]
    Instruction,
    #[error("data range error (0x04): value outside the item's range")]
    DataRange,
    #[error("data length error (0x05): write covers only part of an item")]
    DataLength,
    #[error("data limit error (0x06): value outside a limit item")]
    DataLimit,
    #[error("access error (0x07): read-only, undefined or locked address")]
    Access,
}

impl DeviceError {
    pub fn code(self) -> u8 {
        match self {
            Self::ResultFail => 0x01,
            Self::Instruction => 0x02,
            Self::DataRange => 0x04,
            Self::DataLength => 0x05,
            Self::DataLimit => 0x06,
            Self::Access => 0x07,
        }
    }

    /// Which error wins when one write breaks several rules: access before length before value.
    fn rank(self) -> u8 {
        match self {
            Self::Access => 0,
            Self::DataLength => 1,
            Self::DataRange | Self::DataLimit => 2,
            Self::ResultFail | Self::Instruction => 3,
        }
    }

    /// The higher-priority of two errors.
    pub fn worst(self, other: Self) -> Self {
        if other.rank() < self.rank() { other } else { self }
    }
}
