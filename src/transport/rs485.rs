//! Linux's RS-485 mode for on-chip UARTs (`--rs485`): the driver drives the transceiver's
//! direction (DE on RTS) around each send, with optional delays before and after. USB–RS485
//! adapters switch direction themselves and need none of this. Thirty lines of ioctl rather
//! than a crate: the `rs485` crate wraps the same call and has not been maintained for years.

use std::io;
use std::os::fd::RawFd;

/// `struct serial_rs485` (include/uapi/linux/serial.h).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SerialRs485 {
    flags: u32,
    delay_rts_before_send: u32,
    delay_rts_after_send: u32,
    padding: [u32; 5],
}

const SER_RS485_ENABLED: u32 = 1 << 0;
const SER_RS485_RTS_ON_SEND: u32 = 1 << 1;

/// Delays around a send, in milliseconds (the kernel's unit).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Rs485Delays {
    pub before_send_ms: u32,
    pub after_send_ms: u32,
}

/// Put the UART behind `fd` into RS-485 mode (RTS high while sending); the settings it had, to
/// put back. An error where the driver has no RS-485 mode (ENOTTY, EINVAL) or refuses it.
pub fn enable(fd: RawFd, delays: Rs485Delays) -> io::Result<SerialRs485> {
    let mut previous = SerialRs485::default();
    // SAFETY: SerialRs485 matches the kernel's layout; the ioctls read and write one through a
    // pointer valid for the call.
    if unsafe { libc::ioctl(fd, libc::TIOCGRS485, &mut previous) } != 0 {
        return Err(io::Error::last_os_error());
    }
    let wanted = SerialRs485 { flags: SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND, delay_rts_before_send: delays.before_send_ms, delay_rts_after_send: delays.after_send_ms, padding: [0; 5] };
    // SAFETY: TIOCSRS485 reads `wanted`, laid out as the kernel's, through a pointer valid for the call.
    if unsafe { libc::ioctl(fd, libc::TIOCSRS485, &wanted) } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(previous)
}

/// Put back what [`enable`] found.
pub fn restore(fd: RawFd, previous: &SerialRs485) {
    // SAFETY: as in `enable`.
    if unsafe { libc::ioctl(fd, libc::TIOCSRS485, previous) } != 0 {
        tracing::warn!(error = %io::Error::last_os_error(), "could not restore the UART's RS-485 settings");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_struct_has_the_kernels_size() {
        assert_eq!(std::mem::size_of::<SerialRs485>(), 32);
    }

    #[test]
    fn a_pty_has_no_rs485_mode() {
        let pty = nix::pty::posix_openpt(nix::fcntl::OFlag::O_RDWR).expect("pty");
        let error = enable(std::os::fd::AsRawFd::as_raw_fd(&pty), Rs485Delays::default()).expect_err("a pty has no RS-485 mode");
        assert_eq!(error.raw_os_error(), Some(libc::ENOTTY), "{error}");
    }
}
