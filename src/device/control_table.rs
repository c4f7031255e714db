//! The control table of one servo: memory laid out by the firmware profile, and the rules that
//! decide whether a read or write is allowed (reference §5, §8).

use std::sync::Arc;

use super::error::DeviceError;
use super::profile::{Access, Area, Bound, FirmwareProfile};

/// Who is writing: decides which rules apply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WriteContext {
    /// Torque Enable is 1: the EEPROM area is locked.
    pub torque_on: bool,
    /// The current Operating Mode, for limits that apply in some modes only.
    pub operating_mode: i64,
    /// The packet was addressed to the Secondary ID: only RAM items may change.
    pub via_secondary_id: bool,
}

/// A write that passed every check, ready to apply: `(item index, new value)` per touched item.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StagedWrite {
    pub items: Vec<(usize, i64)>,
}

impl StagedWrite {
    pub fn touches(&self, index: usize) -> bool {
        self.items.iter().any(|(i, _)| *i == index)
    }
    pub fn value_of(&self, index: usize) -> Option<i64> {
        self.items.iter().find(|(i, _)| *i == index).map(|(_, v)| *v)
    }
}

#[derive(Debug, Clone)]
pub struct ControlTable {
    profile: Arc<FirmwareProfile>,
    mem: Vec<u8>,
}

impl ControlTable {
    /// A table holding every item's default (items without a default read 0).
    pub fn new(profile: Arc<FirmwareProfile>) -> Self {
        let mut table = Self { mem: vec![0; profile.table_len()], profile };
        table.reset(|_| true);
        table
    }

    pub fn profile(&self) -> &Arc<FirmwareProfile> {
        &self.profile
    }

    /// Reset to defaults the items for which `which` is true.
    pub fn reset(&mut self, which: impl Fn(&super::profile::ItemSpec) -> bool) {
        let profile = Arc::clone(&self.profile);
        for (index, item) in profile.items.iter().enumerate() {
            if which(&item.spec) {
                self.set(index, item.spec.default.unwrap_or(0));
            }
        }
    }

    /// The value of item `index`, sign-extended if the item is signed.
    pub fn get(&self, index: usize) -> i64 {
        let item = &self.profile.items[index];
        decode(&self.mem[usize::from(item.address())..item.end()], item.spec.signed)
    }

    /// Store `value` in item `index` without any check (the servo's own updates).
    pub fn set(&mut self, index: usize, value: i64) {
        let item = &self.profile.items[index];
        let start = usize::from(item.address());
        let bytes = value.to_le_bytes();
        // Constant-length copies for the sizes items have: the Present registers are stored
        // every firmware tick, and a length-generic copy is a call into memcpy.
        let target = &mut self.mem[start..item.end()];
        match target.len() {
            1 => target[0] = bytes[0],
            2 => target.copy_from_slice(&bytes[..2]),
            4 => target.copy_from_slice(&bytes[..4]),
            n => target.copy_from_slice(&bytes[..n]),
        }
    }

    /// Raw bytes of the whole table (for backup).
    pub fn bytes(&self) -> &[u8] {
        &self.mem
    }

    /// Where a byte read or written at `address` really lands: Indirect Data bytes alias the byte
    /// their Indirect Address names.
    fn target_of(&self, address: usize) -> usize {
        for block in &self.profile.indirect_blocks {
            let first = usize::from(block.data_start);
            if (first..first + usize::from(block.count)).contains(&address) {
                let n = (address - first) as u16;
                if let Some(index) = self.profile.item_index_at(block.address_start + 2 * n) {
                    return self.get(index) as usize;
                }
            }
        }
        address
    }

    /// Bytes past the end of the table are undefined addresses: Access Error, whatever else the
    /// access covers. This also bounds every reply to a size a packet can carry.
    fn check_within_table(&self, address: u16, length: usize) -> Result<(), DeviceError> {
        if usize::from(address) + length > self.mem.len() { Err(DeviceError::Access) } else { Ok(()) }
    }

    fn item_at(&self, address: usize) -> Option<usize> {
        u16::try_from(address).ok().and_then(|a| self.profile.item_index_at(a))
    }

    /// Read `length` bytes at `address`. Reserved gaps between items read as 0; a read that covers
    /// no item at all is an Access Error (reference §5; gap behaviour unverified, §11.3).
    pub fn read(&self, address: u16, length: u16) -> Result<Vec<u8>, DeviceError> {
        self.check_within_table(address, usize::from(length))?;
        let mut out = Vec::with_capacity(usize::from(length));
        let mut any_item = false;
        for address in usize::from(address)..usize::from(address) + usize::from(length) {
            if self.item_at(address).is_none() {
                out.push(0);
                continue;
            }
            any_item = true;
            let target = self.target_of(address);
            out.push(self.mem.get(target).copied().unwrap_or(0));
        }
        if any_item { Ok(out) } else { Err(DeviceError::Access) }
    }

    /// Check a write of `data` at `address` against every rule, without changing anything.
    pub fn stage_write(&self, address: u16, data: &[u8], ctx: WriteContext) -> Result<StagedWrite, DeviceError> {
        self.check_within_table(address, data.len())?;
        // Per touched item: the staged bytes and which of them this write covers.
        let mut touched: Vec<(usize, [u8; 8], u8)> = Vec::new();
        let mut error: Option<DeviceError> = None;
        let fail = |error: &mut Option<DeviceError>, e: DeviceError| *error = Some(error.map_or(e, |old| old.worst(e)));
        for (offset, &byte) in data.iter().enumerate() {
            let address = usize::from(address) + offset;
            if self.item_at(address).is_none() {
                continue; // reserved gap: ignored (reference §11.3)
            }
            let target = self.target_of(address);
            let Some(index) = self.item_at(target) else {
                fail(&mut error, DeviceError::Access);
                continue;
            };
            let item = &self.profile.items[index];
            if item.spec.access == Access::R {
                fail(&mut error, DeviceError::Access);
            }
            if item.spec.area == Area::Eeprom && (ctx.torque_on || ctx.via_secondary_id) {
                fail(&mut error, DeviceError::Access);
            }
            let slot = match touched.iter().position(|(i, _, _)| *i == index) {
                Some(slot) => slot,
                None => {
                    let mut staged = [0u8; 8];
                    staged[..item.size()].copy_from_slice(&self.mem[usize::from(item.address())..item.end()]);
                    touched.push((index, staged, 0));
                    touched.len() - 1
                }
            };
            let within = target - usize::from(item.address());
            touched[slot].1[within] = byte;
            touched[slot].2 |= 1 << within;
        }
        if touched.is_empty() && error.is_none() {
            return Err(DeviceError::Access);
        }
        let mut items = Vec::with_capacity(touched.len());
        for (index, staged, covered) in touched {
            let item = &self.profile.items[index];
            if u32::from(covered) != (1u32 << item.size()) - 1 {
                fail(&mut error, DeviceError::DataLength);
                continue;
            }
            let value = decode(&staged[..item.size()], item.spec.signed);
            if let Err(e) = self.check_value(index, value, ctx.operating_mode) {
                fail(&mut error, e);
            }
            items.push((index, value));
        }
        match error {
            Some(e) => Err(e),
            None => Ok(StagedWrite { items }),
        }
    }

    fn bound_value(&self, bound: Bound) -> (i64, bool) {
        match bound {
            Bound::Const(c) => (c, false),
            Bound::Item { index, negate } => {
                let v = self.get(index);
                (if negate { -v } else { v }, true)
            }
        }
    }

    /// Range and limit rules for one item value.
    pub fn check_value(&self, index: usize, value: i64, operating_mode: i64) -> Result<(), DeviceError> {
        let item = &self.profile.items[index];
        if let Some(values) = &item.spec.values
            && !values.contains(&value)
        {
            return Err(DeviceError::DataRange);
        }
        let refs_apply = item.spec.refs_in_modes.as_ref().is_none_or(|modes| modes.contains(&operating_mode));
        // Constant ranges first (Data Range Error), then limit items (Data Limit Error).
        for (bound, is_min) in [(item.spec.min.map(Bound::Const), true), (item.spec.max.map(Bound::Const), false)] {
            if let Some(b) = bound {
                let (limit, _) = self.bound_value(b);
                if (is_min && value < limit) || (!is_min && value > limit) {
                    return Err(DeviceError::DataRange);
                }
            }
        }
        for (bound, is_min) in [(item.min, true), (item.max, false)] {
            if let Some(b @ Bound::Item { .. }) = bound {
                if !refs_apply {
                    continue;
                }
                let (limit, _) = self.bound_value(b);
                if (is_min && value < limit) || (!is_min && value > limit) {
                    return Err(DeviceError::DataLimit);
                }
            }
        }
        Ok(())
    }

    /// Apply a staged write.
    pub fn apply(&mut self, staged: &StagedWrite) {
        for &(index, value) in &staged.items {
            self.set(index, value);
        }
    }

    /// Copy the bytes of the items for which `which` is true from `source`.
    pub fn copy_items_from(&mut self, source: &[u8], which: impl Fn(&super::profile::ItemSpec) -> bool) {
        for item in &self.profile.items {
            if which(&item.spec) {
                let range = usize::from(item.address())..item.end();
                self.mem[range.clone()].copy_from_slice(&source[range]);
            }
        }
    }
}

/// Little-endian item bytes (1..=4) as a value, sign-extended for signed items.
pub fn decode(bytes: &[u8], signed: bool) -> i64 {
    let unsigned = match *bytes {
        [b0] => u64::from(b0),
        [b0, b1] => u64::from(u16::from_le_bytes([b0, b1])),
        [b0, b1, b2, b3] => u64::from(u32::from_le_bytes([b0, b1, b2, b3])),
        _ => {
            let mut raw = [0u8; 8];
            raw[..bytes.len()].copy_from_slice(bytes);
            u64::from_le_bytes(raw)
        }
    };
    if signed {
        let shift = 64 - 8 * bytes.len() as u32;
        ((unsigned << shift) as i64) >> shift
    } else {
        unsigned as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::profile::tests::xm540;

    const FREE: WriteContext = WriteContext { torque_on: false, operating_mode: 3, via_secondary_id: false };

    fn table() -> ControlTable {
        ControlTable::new(Arc::new(xm540()))
    }

    #[test]
    fn defaults_read_back_little_endian() {
        let t = table();
        assert_eq!(t.read(0, 2).unwrap(), [0x60, 0x04]);
        assert_eq!(t.read(9, 1).unwrap(), [250]);
    }

    #[test]
    fn read_of_only_reserved_bytes_is_access_error() {
        assert_eq!(table().read(40, 4), Err(DeviceError::Access));
        assert_eq!(table().read(700, 1), Err(DeviceError::Access));
        assert_eq!(table().read(0, 0xFFFF), Err(DeviceError::Access), "runs past the table");
    }

    #[test]
    fn read_across_gap_reads_zeros_there() {
        let got = table().read(64, 6).unwrap(); // 64,65 defined; 66,67 reserved; 68,69 defined
        assert_eq!(got, [0, 0, 0, 0, 2, 0]);
    }

    #[test]
    fn partial_item_write_is_length_error() {
        assert_eq!(table().stage_write(116, &[0, 2], FREE), Err(DeviceError::DataLength));
    }

    #[test]
    fn eeprom_locked_while_torque_on() {
        let ctx = WriteContext { torque_on: true, ..FREE };
        assert_eq!(table().stage_write(9, &[0], ctx), Err(DeviceError::Access));
    }

    #[test]
    fn read_only_write_is_access_error() {
        assert_eq!(table().stage_write(132, &[0; 4], FREE), Err(DeviceError::Access));
    }

    #[test]
    fn goal_position_limits_apply_only_in_position_mode() {
        let t = table();
        let above = 5000i32.to_le_bytes();
        assert_eq!(t.stage_write(116, &above, FREE), Err(DeviceError::DataLimit));
        let extended = WriteContext { operating_mode: 4, ..FREE };
        assert!(t.stage_write(116, &above, extended).is_ok());
        let beyond = 2_000_000i32.to_le_bytes();
        assert_eq!(t.stage_write(116, &beyond, extended), Err(DeviceError::DataRange));
    }

    #[test]
    fn operating_mode_accepts_only_listed_values() {
        assert_eq!(table().stage_write(11, &[2], FREE), Err(DeviceError::DataRange));
        assert!(table().stage_write(11, &[16], FREE).is_ok());
    }

    #[test]
    fn indirect_data_aliases_target_byte() {
        let mut t = table();
        // Indirect Address 1..4 -> Goal Position 116..119.
        for n in 0..4u16 {
            let staged = t.stage_write(168 + 2 * n, &(116 + n).to_le_bytes(), FREE).unwrap();
            t.apply(&staged);
        }
        let staged = t.stage_write(224, &[0x00, 0x02, 0x00, 0x00], FREE).unwrap();
        t.apply(&staged);
        assert_eq!(t.read(116, 4).unwrap(), [0x00, 0x02, 0x00, 0x00]);
        assert_eq!(t.read(224, 4).unwrap(), [0x00, 0x02, 0x00, 0x00]);
    }

    #[test]
    fn signed_items_sign_extend() {
        let mut t = table();
        let goal = t.profile().index("goal_velocity");
        t.set(goal, -5);
        assert_eq!(t.get(goal), -5);
        assert_eq!(t.read(104, 4).unwrap(), [0xFB, 0xFF, 0xFF, 0xFF]);
    }
}
