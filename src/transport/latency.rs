//! The USB adapter's latency timer on the host. FTDI chips (the U2D2's FT232H included) hold
//! received bytes until 62 of them fill a USB packet or the latency timer expires, 16 ms by
//! default on Linux: a controller's reply waits up to that long in the adapter. Linux shows the
//! timer in `/sys/bus/usb-serial/devices/ttyUSBn/latency_timer`; `--low-latency` sets it to
//! 1 ms (and the tty's ASYNC_LOW_LATENCY flag) and puts both back on exit.

use std::io;
use std::os::fd::RawFd;
use std::path::{Path, PathBuf};

use thiserror::Error;
use tracing::{debug, info, warn};

/// Where to look for sysfs (`CLIMBSIM_SYSFS_ROOT` in tests stands a directory in for it).
pub const SYSFS_ROOT_ENV: &str = "CLIMBSIM_SYSFS_ROOT";

/// A udev rule that sets the timer at every plug-in, for users without write access.
pub const UDEV_RULE: &str = r#"ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTR{latency_timer}="1""#;

#[derive(Debug, Error)]
pub enum LatencyError {
    #[error(
        "--low-latency: cannot write {file}: permission denied. Run climbsim with write access to it, \
         or set it at every plug-in with a udev rule: put\n    {UDEV_RULE}\ninto /etc/udev/rules.d/99-usb-serial-latency.rules, \
         then `sudo udevadm control --reload` and replug the adapter"
    )]
    Permission { file: PathBuf },
    #[error("--low-latency: cannot write {file}: {source}")]
    Write { file: PathBuf, source: io::Error },
    #[error("--low-latency: {device} has no USB latency timer (no {file}); it is not a USB-serial adapter, or not one that has a timer")]
    NoTimer { device: PathBuf, file: PathBuf },
}

/// A device's latency timer file and its value when climbsim found it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LatencyTimer {
    pub file: PathBuf,
    pub ms: u32,
}

/// The sysfs root: `$CLIMBSIM_SYSFS_ROOT` or `/sys`.
pub fn sysfs_root() -> PathBuf {
    std::env::var_os(SYSFS_ROOT_ENV).map_or_else(|| PathBuf::from("/sys"), PathBuf::from)
}

/// The latency timer file of `device` (symlinks such as /dev/serial/by-id/... resolved).
pub fn timer_file(device: &Path, sysfs: &Path) -> PathBuf {
    let resolved = std::fs::canonicalize(device).unwrap_or_else(|_| device.to_owned());
    let name = resolved.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    sysfs.join("bus/usb-serial/devices").join(name).join("latency_timer")
}

/// Read `device`'s latency timer, if it has one.
pub fn read_timer(device: &Path, sysfs: &Path) -> Option<LatencyTimer> {
    read_timer_file(timer_file(device, sysfs))
}

fn read_timer_file(file: PathBuf) -> Option<LatencyTimer> {
    let ms = std::fs::read_to_string(&file).ok()?.trim().parse().ok()?;
    Some(LatencyTimer { file, ms })
}

/// What the timer means for the controller's loop, said once at start.
pub fn warn_if_slow(device: &Path, timer: &LatencyTimer) {
    if timer.ms > 1 {
        warn!(
            device = %device.display(),
            latency_timer_ms = timer.ms,
            "the adapter holds received bytes up to {} ms before handing them to climbsim (its USB latency timer, {}): \
             every request reaches the bus that much later. --low-latency sets it to 1 ms",
            timer.ms,
            timer.file.display()
        );
    } else {
        info!(device = %device.display(), latency_timer_ms = timer.ms, "adapter latency timer");
    }
}

/// Set the timer to 1 ms; the guard puts the old value back when dropped.
pub fn set_low(device: &Path, sysfs: &Path) -> Result<LowLatencyGuard, LatencyError> {
    let file = timer_file(device, sysfs);
    let Some(timer) = read_timer_file(file.clone()) else {
        return Err(LatencyError::NoTimer { device: device.to_owned(), file });
    };
    write_timer(&timer.file, 1)?;
    info!(file = %timer.file.display(), from_ms = timer.ms, "latency timer set to 1 ms");
    Ok(LowLatencyGuard { previous: timer })
}

fn write_timer(file: &Path, ms: u32) -> Result<(), LatencyError> {
    std::fs::write(file, format!("{ms}\n")).map_err(|source| match source.kind() {
        io::ErrorKind::PermissionDenied => LatencyError::Permission { file: file.to_owned() },
        _ => LatencyError::Write { file: file.to_owned(), source },
    })
}

/// Restores the latency timer on drop.
#[derive(Debug)]
pub struct LowLatencyGuard {
    previous: LatencyTimer,
}

impl Drop for LowLatencyGuard {
    fn drop(&mut self) {
        match write_timer(&self.previous.file, self.previous.ms) {
            Ok(()) => info!(file = %self.previous.file.display(), ms = self.previous.ms, "latency timer restored"),
            Err(error) => warn!(%error, "could not restore the latency timer"),
        }
    }
}

/// Linux's `struct serial_struct` (include/uapi/linux/serial.h), for TIOCGSERIAL/TIOCSSERIAL.
#[repr(C)]
#[derive(Clone, Copy)]
struct SerialStruct {
    kind: libc::c_int,
    line: libc::c_int,
    port: libc::c_uint,
    irq: libc::c_int,
    flags: libc::c_int,
    xmit_fifo_size: libc::c_int,
    custom_divisor: libc::c_int,
    baud_base: libc::c_int,
    close_delay: libc::c_ushort,
    io_type: libc::c_char,
    reserved_char: [libc::c_char; 1],
    hub6: libc::c_int,
    closing_wait: libc::c_ushort,
    closing_wait2: libc::c_ushort,
    iomem_base: *mut libc::c_uchar,
    iomem_reg_shift: libc::c_ushort,
    port_high: libc::c_uint,
    iomap_base: libc::c_ulong,
}

const ASYNC_LOW_LATENCY: libc::c_int = 1 << 13;

/// Set or clear the tty's ASYNC_LOW_LATENCY flag; its previous state, or None where the driver
/// keeps no serial info (a pty, most on-chip UARTs' drivers accept it).
pub fn set_async_low_latency(fd: RawFd, on: bool) -> Option<bool> {
    // SAFETY: SerialStruct is plain data matching the kernel's layout; the ioctls read and write
    // one through a pointer valid for the call.
    let mut serial: SerialStruct = unsafe { std::mem::zeroed() };
    // SAFETY: TIOCGSERIAL fills the SerialStruct above through a pointer valid for the call.
    if unsafe { libc::ioctl(fd, libc::TIOCGSERIAL, &mut serial) } != 0 {
        debug!(error = %io::Error::last_os_error(), "no serial info (TIOCGSERIAL): ASYNC_LOW_LATENCY not set");
        return None;
    }
    let was = serial.flags & ASYNC_LOW_LATENCY != 0;
    if was != on {
        serial.flags = if on { serial.flags | ASYNC_LOW_LATENCY } else { serial.flags & !ASYNC_LOW_LATENCY };
        // SAFETY: TIOCSSERIAL reads the SerialStruct above through a pointer valid for the call.
        if unsafe { libc::ioctl(fd, libc::TIOCSSERIAL, &serial) } != 0 {
            warn!(error = %io::Error::last_os_error(), "cannot set ASYNC_LOW_LATENCY (TIOCSSERIAL)");
            return None;
        }
    }
    Some(was)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_timer_is_found_behind_a_symlink_set_low_and_restored() {
        let root = std::env::temp_dir().join(format!("climbsim-sysfs-{}", std::process::id()));
        let devices = root.join("bus/usb-serial/devices/ttyUSB7");
        std::fs::create_dir_all(&devices).expect("dirs");
        std::fs::write(devices.join("latency_timer"), "16\n").expect("timer");
        let dev = root.join("dev");
        std::fs::create_dir_all(&dev).expect("dev");
        std::fs::write(dev.join("ttyUSB7"), "").expect("node");
        let by_id = root.join("usb-FTDI_FT232H-if00-port0");
        let _ = std::fs::remove_file(&by_id);
        std::os::unix::fs::symlink(dev.join("ttyUSB7"), &by_id).expect("link");

        assert_eq!(read_timer(&by_id, &root).map(|t| t.ms), Some(16));
        {
            let _guard = set_low(&by_id, &root).expect("set");
            assert_eq!(read_timer(&by_id, &root).map(|t| t.ms), Some(1));
        }
        assert_eq!(read_timer(&by_id, &root).map(|t| t.ms), Some(16), "restored on drop");
        let missing = set_low(&dev, &root).expect_err("no timer for a directory");
        assert!(missing.to_string().contains("no USB latency timer"), "{missing}");
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn a_permission_error_names_the_udev_rule() {
        let error = LatencyError::Permission { file: PathBuf::from("/sys/bus/usb-serial/devices/ttyUSB0/latency_timer") };
        let text = error.to_string();
        assert!(text.contains("ATTR{latency_timer}=\"1\"") && text.contains("/etc/udev/rules.d/"), "{text}");
    }

    #[test]
    fn a_pty_has_no_serial_info() {
        let pty = nix::pty::posix_openpt(nix::fcntl::OFlag::O_RDWR).expect("pty");
        assert_eq!(set_async_low_latency(std::os::fd::AsRawFd::as_raw_fd(&pty), true), None);
    }
}
