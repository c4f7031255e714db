//! Removing the device's echo of its own transmission. Half-duplex RS-485 adapters without
//! receiver gating, and one-wire TTL circuits that tie TX to RX, hand every byte climbsim sends
//! straight back to it. A controller never sends a status packet, so a reply's echo and the
//! controller's next instruction part at the instruction byte (0x55) at the latest: bytes that
//! match what was sent are held until the whole of it has come back (then dropped) or a byte
//! differs (then released, in order, as the controller's).

use std::collections::VecDeque;

/// Whether the device hears its own transmission, and what to do with it (`--echo`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Echo {
    /// Drop what comes back if it is exactly what was sent; anything else is the controller's.
    #[default]
    Auto,
    /// The device echoes: drop it, and count the sends whose echo did not come.
    On,
    /// Never drop anything.
    Off,
}

/// The echo filter of one device.
#[derive(Debug, Default)]
pub struct EchoFilter {
    mode: Echo,
    /// Sent bytes whose echo has not come back yet.
    pending: VecDeque<u8>,
    /// Received bytes matching the front of `pending`, not yet known to be echo.
    held: Vec<u8>,
    /// Echoes removed, whole sends whose echo was missing.
    echoes: u64,
    missing: u64,
}

impl EchoFilter {
    pub fn new(mode: Echo) -> Self {
        Self { mode, ..Self::default() }
    }

    /// Bytes were written to the device.
    pub fn sent(&mut self, bytes: &[u8]) {
        if self.mode != Echo::Off {
            self.pending.extend(bytes);
        }
    }

    /// Filter bytes received from the device; append the controller's to `out`.
    pub fn received(&mut self, bytes: &[u8], out: &mut Vec<u8>) {
        for &byte in bytes {
            if self.pending.is_empty() {
                out.push(byte);
            } else if self.pending.get(self.held.len()) == Some(&byte) {
                self.held.push(byte);
                if self.held.len() == self.pending.len() {
                    self.echoes += 1;
                    self.pending.clear();
                    self.held.clear();
                }
            } else {
                // Not our echo: what was held is the controller's, and no echo is coming.
                self.missing += 1;
                self.pending.clear();
                out.append(&mut self.held);
                out.push(byte);
            }
        }
    }

    /// Echoes dropped so far.
    pub fn echoes(&self) -> u64 {
        self.echoes
    }

    /// Sends whose echo did not come (with `--echo on`: the device does not echo after all).
    pub fn missing(&self) -> u64 {
        self.missing
    }

    pub fn mode(&self) -> Echo {
        self.mode
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const REPLY: [u8; 11] = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x04, 0x00, 0x55, 0x00, 0xA1, 0x0C];
    const PING: [u8; 10] = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E];

    fn feed(filter: &mut EchoFilter, chunks: &[&[u8]]) -> Vec<u8> {
        let mut out = Vec::new();
        for chunk in chunks {
            filter.received(chunk, &mut out);
        }
        out
    }

    #[test]
    fn an_echo_split_over_reads_is_dropped_and_what_follows_is_kept() {
        let mut filter = EchoFilter::new(Echo::Auto);
        filter.sent(&REPLY);
        assert_eq!(feed(&mut filter, &[&REPLY[..3], &REPLY[3..]]), Vec::<u8>::new());
        assert_eq!(feed(&mut filter, &[&PING]), PING);
        assert_eq!((filter.echoes(), filter.missing()), (1, 0));
    }

    #[test]
    fn without_an_echo_the_controllers_instruction_passes_whole_even_split_where_it_matches() {
        let mut filter = EchoFilter::new(Echo::Auto);
        filter.sent(&REPLY);
        // The ping's first five bytes (header, ID) equal the reply's: held, then released in
        // order at its length byte, which differs.
        assert_eq!(feed(&mut filter, &[&PING[..3], &PING[3..5]]), Vec::<u8>::new());
        assert_eq!(feed(&mut filter, &[&PING[5..]]), PING);
        assert_eq!((filter.echoes(), filter.missing()), (0, 1));
    }

    #[test]
    fn echoes_of_several_replies_in_one_read_are_all_dropped() {
        let mut filter = EchoFilter::new(Echo::On);
        filter.sent(&REPLY);
        filter.sent(&REPLY);
        let mut both = REPLY.to_vec();
        both.extend(REPLY);
        both.extend(PING);
        assert_eq!(feed(&mut filter, &[&both]), PING);
    }

    #[test]
    fn off_keeps_everything() {
        let mut filter = EchoFilter::new(Echo::Off);
        filter.sent(&REPLY);
        assert_eq!(feed(&mut filter, &[&REPLY]), REPLY);
    }
}
