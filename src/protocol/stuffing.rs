//! Byte stuffing: `FF FF FD` inside a packet body is sent as `FF FF FD FD`.

/// Insert an `FD` after every `FF FF FD` in `body` (the bytes from the instruction/error byte
/// through the last parameter). Returns the stuffed bytes.
pub fn stuff(body: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(body.len() + 2);
    for &byte in body {
        out.push(byte);
        // An inserted FD follows an FD, never two FFs, so it cannot start a new match.
        if out.ends_with(&[0xFF, 0xFF, 0xFD]) {
            out.push(0xFD);
        }
    }
    out
}

/// Turn every `FF FF FD FD` back into `FF FF FD`. Called only after the CRC has passed.
pub fn unstuff(body: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(body.len());
    let mut i = 0;
    while i < body.len() {
        out.push(body[i]);
        if body[i..].starts_with(&[0xFF, 0xFF, 0xFD, 0xFD]) {
            out.extend_from_slice(&[0xFF, 0xFD]);
            i += 4;
        } else {
            i += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stuffs_header_inside_body() {
        assert_eq!(stuff(&[0x55, 0x00, 0xFF, 0xFF, 0xFD, 0x00]), [0x55, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00]);
    }

    #[test]
    fn leaves_plain_body_alone() {
        let body = [0x03, 0x74, 0x00, 0xFF, 0xFD, 0xFF, 0x00];
        assert_eq!(stuff(&body), body);
    }

    #[test]
    fn unstuff_inverts_stuff() {
        let body = [0xFF, 0xFF, 0xFD, 0xFF, 0xFF, 0xFD, 0xFD, 0x01];
        assert_eq!(unstuff(&stuff(&body)), body);
    }

    #[test]
    fn unstuff_keeps_unstuffed_header_bytes() {
        // The Python SDK sends unstuffed params; after the CRC passes only FF FF FD FD is touched.
        let body = [0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00];
        assert_eq!(unstuff(&body), body);
    }
}
