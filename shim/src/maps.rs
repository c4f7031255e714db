//! Which file mapping an address lies in, from /proc/self/maps: a futex in a shared file
//! mapping is the same futex in every process that maps the file, at whatever address.

use core::ffi::c_long;

use crate::native;
use crate::sys::nr;

/// If `addr` lies in a shared mapping of a file: the file (device and inode, folded into 63
/// bits) and the offset in it.
pub(crate) fn shared_file_offset(addr: usize) -> Option<(u64, u64)> {
    const O_RDONLY_CLOEXEC: c_long = 0o2000000;
    let fd = native::call3(nr::OPENAT, crate::sys::AT_FDCWD, c"/proc/self/maps".as_ptr() as c_long, O_RDONLY_CLOEXEC);
    if fd < 0 {
        return None;
    }
    let mut chunk = [0u8; 4096];
    // The first bytes of the current line: the fields needed come before the path.
    let mut line = [0u8; 160];
    let mut used = 0;
    let mut found = None;
    'reading: loop {
        let got = native::call3(nr::READ, fd, chunk.as_mut_ptr() as c_long, chunk.len() as c_long);
        if got <= 0 {
            break;
        }
        for &byte in &chunk[..got as usize] {
            if byte != b'\n' {
                if used < line.len() {
                    line[used] = byte;
                    used += 1;
                }
                continue;
            }
            if let Some(hit) = parse_line(&line[..used], addr) {
                found = hit;
                break 'reading;
            }
            used = 0;
        }
    }
    native::call1(nr::CLOSE, fd);
    found
}

/// One line of maps (`start-end perms offset major:minor inode path`): None if `addr` is not in
/// it, Some(None) if it is but not in a shared file mapping.
fn parse_line(line: &[u8], addr: usize) -> Option<Option<(u64, u64)>> {
    let mut fields = line.split(|&b| b == b' ').filter(|f| !f.is_empty());
    let range = fields.next()?;
    let dash = range.iter().position(|&b| b == b'-')?;
    let start = hex(&range[..dash])?;
    let end = hex(&range[dash + 1..])?;
    if !(start..end).contains(&(addr as u64)) {
        return None;
    }
    let perms = fields.next().unwrap_or_default();
    let offset = fields.next().and_then(hex);
    let device = fields.next().unwrap_or_default();
    let inode = fields.next().and_then(decimal);
    let colon = device.iter().position(|&b| b == b':');
    let shared = perms.get(3) == Some(&b's');
    Some(match (shared, offset, colon, inode) {
        (true, Some(offset), Some(colon), Some(inode)) if inode != 0 => {
            let major = hex(&device[..colon]).unwrap_or(0);
            let minor = hex(&device[colon + 1..]).unwrap_or(0);
            let file = (inode ^ (major << 52) ^ (minor << 40)) & !(1 << 63);
            Some((file, offset + (addr as u64 - start)))
        }
        _ => None,
    })
}

fn hex(text: &[u8]) -> Option<u64> {
    number(text, 16)
}

fn decimal(text: &[u8]) -> Option<u64> {
    number(text, 10)
}

fn number(text: &[u8], radix: u32) -> Option<u64> {
    let mut value = 0u64;
    for &b in text {
        let digit = (b as char).to_digit(radix)?;
        value = value.checked_mul(u64::from(radix))?.checked_add(u64::from(digit))?;
    }
    (!text.is_empty()).then_some(value)
}
