//! CRC-16/UMTS (poly 0x8005, init 0, no reflection, no final XOR), as DynamixelSDK's `updateCRC`.

use crc::{CRC_16_UMTS, Crc};

const UMTS: Crc<u16> = Crc::<u16>::new(&CRC_16_UMTS);

/// CRC of `bytes`, header included, as the protocol transmits it (low byte first on the wire).
pub fn crc16(bytes: &[u8]) -> u16 {
    UMTS.checksum(bytes)
}

/// A running CRC, for the Fast Sync/Bulk Read reply whose per-device CRCs are prefixes of one stream.
pub(crate) struct RunningCrc(crc::Digest<'static, u16>);

impl RunningCrc {
    pub(crate) fn new() -> Self {
        Self(UMTS.digest())
    }
    pub(crate) fn update(&mut self, bytes: &[u8]) {
        self.0.update(bytes);
    }
    /// The CRC of everything fed so far; the digest keeps running.
    pub(crate) fn value(&self) -> u16 {
        self.0.clone().finalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value_matches_crc16_umts() {
        assert_eq!(crc16(b"123456789"), 0xFEE8);
    }

    #[test]
    fn ping_id1_crc_from_emanual() {
        // FF FF FD 00 01 03 00 01 | 19 4E
        assert_eq!(crc16(&[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01]), 0x4E19);
    }

    #[test]
    fn running_crc_equals_one_shot() {
        let data = [1u8, 2, 3, 4, 5, 6, 7];
        let mut running = RunningCrc::new();
        running.update(&data[..3]);
        assert_eq!(running.value(), crc16(&data[..3]));
        running.update(&data[3..]);
        assert_eq!(running.value(), crc16(&data));
    }
}
