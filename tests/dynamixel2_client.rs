//! Client conformance with the `dynamixel2` crate (0.9.1), the Rust library a controller would use
//! unchanged on real hardware.
//!
//! Every test starts its own `climbsim serve` and talks to it only through `dynamixel2::Bus`:
//! over the pty (`--link <tmp>/ttyDXL`), or over TCP through a ser2net-style bridge built here (a
//! pty pair whose master is copied both ways to a `TcpStream`), since `dynamixel2` can only open
//! serial ports. Each test ends the emulator with SIGTERM and asserts exit status 0 and that the
//! link was removed; a guard kills it if the test fails first.
//!
//! Three quirks of dynamixel2 0.9.1 shape these tests (both are bugs of the crate, not of climbsim):
//! - `Bus::sync_read*` (the non-callback wrappers) drop every per-servo error and return the
//!   replies that did arrive, so each sync read here asserts the exact IDs it got back.
//! - `Bus::bulk_read` encodes entry `i` at parameter offset `i` instead of `5 * i`, so any bulk
//!   read of two or more servos is sent malformed. A single-entry `bulk_read` is correct; a
//!   multi-servo Bulk Read is sent with the crate's raw `write_instruction` /
//!   `read_status_response`, exactly the workaround a user of the crate would write.
//! - Its un-stuffing misses `FF FF FD FD` right after another `FF` (e.g. a negative Present
//!   Velocity followed by a Present Position with low byte 0xFD), so the stuffing test uses a
//!   payload without a leading `FF` and checks the exact stuffed bytes on the line separately.

mod support;

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpStream};
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use dynamixel2::instructions::{BulkReadData, BulkWriteData, SyncWriteData, instruction_id, packet_id};
use dynamixel2::{ReadError, TransferError};
use support::{Emulator, Options};

type Bus = dynamixel2::Bus<Vec<u8>, Vec<u8>>;

const BAUD: u32 = 57_600;
const IDS: [u8; 8] = [1, 2, 3, 4, 5, 6, 7, 8];
const XM540_W270_MODEL: u16 = 1120;

// Control-table addresses (XM540-W270, reference control table).
const A_MODEL: u16 = 0;
const A_FIRMWARE: u16 = 6;
const A_ID: u16 = 7;
const A_BAUD: u16 = 8;
const A_RETURN_DELAY: u16 = 9;
const A_OPERATING_MODE: u16 = 11;
const A_HOMING_OFFSET: u16 = 20;
const A_MOVING_THRESHOLD: u16 = 24;
const A_TORQUE: u16 = 64;
const A_LED: u16 = 65;
const A_REGISTERED: u16 = 69;
const A_POSITION_P_GAIN: u16 = 84;
const A_PROFILE_VELOCITY: u16 = 112;
const A_GOAL_POSITION: u16 = 116;
const A_MOVING: u16 = 122;
const A_PRESENT_VELOCITY: u16 = 128;
const A_PRESENT_POSITION: u16 = 132;

// Status error numbers (reference §5).
const ERR_INSTRUCTION: u8 = 0x02;
const ERR_DATA_RANGE: u8 = 0x04;
const ERR_DATA_LENGTH: u8 = 0x05;
const ERR_ACCESS: u8 = 0x07;

// ------------------------------------------------------------------------------------------------
// Emulator process guard
// ------------------------------------------------------------------------------------------------

/// Tests run one at a time: each one owns an emulator, and on a small machine parallel emulators
/// would only add scheduling noise to dynamixel2's ~36 ms reply timeout.
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// `climbsim serve --link <tmp>/ttyDXL --timing off <extra...>`, its stderr kept in a log in the
/// temporary directory and quoted if the test fails.
fn start_emulator(extra: &[&str]) -> Emulator {
    let args: Vec<&str> = ["--timing", "off"].iter().chain(extra).copied().collect();
    Options::default().temp_link().stderr_log().start(&args)
}

/// Opens the emulator's link with dynamixel2.
trait OpenBus {
    fn open(&self, baud: u32) -> Bus;
}

impl OpenBus for Emulator {
    fn open(&self, baud: u32) -> Bus {
        Bus::open(self.link(), baud).unwrap_or_else(|e| panic!("dynamixel2 cannot open {}: {e}", self.link().display()))
    }
}

// ------------------------------------------------------------------------------------------------
// ser2net-style TCP bridge
// ------------------------------------------------------------------------------------------------

/// A pty pair made here; dynamixel2 opens the slave, two threads copy bytes between the master
/// and a TCP connection to climbsim. The bridge holds its own slave descriptor (as a serial
/// device node would stay present) so the client may close and reopen the port.
struct Bridge {
    slave_path: PathBuf,
    master: Arc<OwnedFd>,
    _slave: OwnedFd,
    link: Option<Link>,
}

/// One TCP connection and its two copy threads.
struct Link {
    tcp: TcpStream,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

fn set_cloexec(fd: &OwnedFd) {
    // SAFETY: fcntl on a descriptor we own.
    let rc = unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_SETFD, libc::FD_CLOEXEC) };
    assert_eq!(rc, 0, "fcntl(FD_CLOEXEC)");
}

impl Bridge {
    fn connect(addr: SocketAddr) -> Self {
        let pty = nix::pty::openpty(None, None).expect("openpty");
        set_cloexec(&pty.master);
        set_cloexec(&pty.slave);
        let mut termios = nix::sys::termios::tcgetattr(&pty.slave).expect("tcgetattr");
        nix::sys::termios::cfmakeraw(&mut termios);
        nix::sys::termios::tcsetattr(&pty.slave, nix::sys::termios::SetArg::TCSANOW, &termios).expect("tcsetattr");
        let slave_path = std::fs::read_link(format!("/proc/self/fd/{}", pty.slave.as_raw_fd())).expect("pty slave path");
        assert!(slave_path.starts_with("/dev/pts"), "unexpected pty slave path {}", slave_path.display());
        let mut bridge = Self { slave_path, master: Arc::new(pty.master), _slave: pty.slave, link: None };
        bridge.reconnect(addr);
        bridge
    }

    fn open(&self, baud: u32) -> Bus {
        Bus::open(&self.slave_path, baud).unwrap_or_else(|e| panic!("dynamixel2 cannot open {}: {e}", self.slave_path.display()))
    }

    /// Drop the TCP connection (if any) and dial climbsim again, as ser2net does after a
    /// network hiccup. The pty, and any client on it, stays.
    fn reconnect(&mut self, addr: SocketAddr) {
        self.disconnect();
        let tcp = TcpStream::connect(addr).unwrap_or_else(|e| panic!("connect to climbsim at {addr}: {e}"));
        tcp.set_nodelay(true).expect("TCP_NODELAY");
        let stop = Arc::new(AtomicBool::new(false));

        let master = Arc::clone(&self.master);
        let mut to_tcp = tcp.try_clone().expect("clone TcpStream");
        let stop_a = Arc::clone(&stop);
        let pty_to_tcp = std::thread::spawn(move || {
            use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
            let mut buf = [0u8; 4096];
            while !stop_a.load(Ordering::Relaxed) {
                let mut fds = [PollFd::new(master.as_fd(), PollFlags::POLLIN)];
                match poll(&mut fds, PollTimeout::from(20u16)) {
                    Ok(0) | Err(nix::errno::Errno::EINTR) => continue,
                    Ok(_) => {}
                    Err(_) => return,
                }
                match nix::unistd::read(master.as_fd(), &mut buf) {
                    Ok(0) => std::thread::sleep(Duration::from_millis(1)),
                    Ok(n) => {
                        if to_tcp.write_all(&buf[..n]).is_err() {
                            return;
                        }
                    }
                    Err(nix::errno::Errno::EINTR | nix::errno::Errno::EAGAIN) => {}
                    // EIO: no slave open (cannot happen while the bridge holds one).
                    Err(nix::errno::Errno::EIO) => std::thread::sleep(Duration::from_millis(1)),
                    Err(_) => return,
                }
            }
        });

        let master = Arc::clone(&self.master);
        let mut from_tcp = tcp.try_clone().expect("clone TcpStream");
        from_tcp.set_read_timeout(Some(Duration::from_millis(20))).expect("read timeout");
        let stop_b = Arc::clone(&stop);
        let tcp_to_pty = std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while !stop_b.load(Ordering::Relaxed) {
                match from_tcp.read(&mut buf) {
                    Ok(0) => return,
                    Ok(n) => {
                        let mut data = &buf[..n];
                        while !data.is_empty() {
                            match nix::unistd::write(master.as_fd(), data) {
                                Ok(written) => data = &data[written..],
                                Err(nix::errno::Errno::EINTR | nix::errno::Errno::EAGAIN) => {}
                                Err(_) => return,
                            }
                        }
                    }
                    Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted) => {}
                    Err(_) => return,
                }
            }
        });
        self.link = Some(Link { tcp, stop, threads: vec![pty_to_tcp, tcp_to_pty] });
    }

    fn disconnect(&mut self) {
        if let Some(link) = self.link.take() {
            link.stop.store(true, Ordering::Relaxed);
            let _ = link.tcp.shutdown(Shutdown::Both);
            for thread in link.threads {
                let _ = thread.join();
            }
        }
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.disconnect();
    }
}

// ------------------------------------------------------------------------------------------------
// Helpers
// ------------------------------------------------------------------------------------------------

fn ok<T>(what: &str, result: Result<T, TransferError>) -> T {
    result.unwrap_or_else(|e| panic!("{what}: {e} ({e:?})"))
}

fn read_u8(bus: &mut Bus, id: u8, address: u16) -> u8 {
    let r = ok(&format!("read_u8(id {id}, addr {address})"), bus.read_u8(id, address));
    assert_eq!(r.motor_id, id, "reply to a Read of ID {id} came from ID {}", r.motor_id);
    r.data
}

fn read_u16(bus: &mut Bus, id: u8, address: u16) -> u16 {
    let r = ok(&format!("read_u16(id {id}, addr {address})"), bus.read_u16(id, address));
    assert_eq!(r.motor_id, id, "reply to a Read of ID {id} came from ID {}", r.motor_id);
    r.data
}

fn read_u32(bus: &mut Bus, id: u8, address: u16) -> u32 {
    let r = ok(&format!("read_u32(id {id}, addr {address})"), bus.read_u32(id, address));
    assert_eq!(r.motor_id, id, "reply to a Read of ID {id} came from ID {}", r.motor_id);
    r.data
}

fn write_u8(bus: &mut Bus, id: u8, address: u16, value: u8) {
    let r = ok(&format!("write_u8(id {id}, addr {address}, {value})"), bus.write_u8(id, address, value));
    assert_eq!(r.motor_id, id);
}

fn write_u16(bus: &mut Bus, id: u8, address: u16, value: u16) {
    let r = ok(&format!("write_u16(id {id}, addr {address}, {value})"), bus.write_u16(id, address, value));
    assert_eq!(r.motor_id, id);
}

fn write_u32(bus: &mut Bus, id: u8, address: u16, value: u32) {
    let r = ok(&format!("write_u32(id {id}, addr {address}, {value})"), bus.write_u32(id, address, value));
    assert_eq!(r.motor_id, id);
}

/// The error number of a status reply the crate surfaced as `MotorError`.
fn motor_error<T: std::fmt::Debug>(what: &str, result: Result<T, TransferError>) -> u8 {
    match result {
        Err(TransferError::ReadError(ReadError::MotorError(e))) => {
            assert!(!e.alert(), "{what}: unexpected alert bit in {e:?}");
            e.error_number()
        }
        other => panic!("{what}: expected a status packet with an error, got {other:?}"),
    }
}

fn assert_timeout<T: std::fmt::Debug>(what: &str, result: Result<T, TransferError>) {
    match result {
        Err(TransferError::ReadError(ReadError::Io(e))) if e.kind() == std::io::ErrorKind::TimedOut => {}
        other => panic!("{what}: expected no reply (timeout), got {other:?}"),
    }
}

fn ping_all(bus: &mut Bus, what: &str) {
    for id in IDS {
        let r = ok(&format!("{what}: ping {id}"), bus.ping(id));
        assert_eq!(r.motor_id, id, "{what}: ping {id} answered by {}", r.motor_id);
        assert_eq!(r.data.model, XM540_W270_MODEL, "{what}: model of ID {id}");
        assert!(!r.alert, "{what}: alert bit in ping reply of ID {id}");
    }
}

fn scan_ids(bus: &mut Bus, what: &str) -> Vec<u8> {
    let found = bus.scan().unwrap_or_else(|e| panic!("{what}: scan: {e}"));
    found
        .into_iter()
        .map(|r| {
            let r = r.unwrap_or_else(|e| panic!("{what}: scan reported an error reply: {e} ({e:?})"));
            assert_eq!(r.data.model, XM540_W270_MODEL, "{what}: scan model of ID {}", r.motor_id);
            r.motor_id
        })
        .collect()
}

/// Sync Read of a u32 item; panics unless exactly `ids` answered, in that order.
fn sync_read_u32(bus: &mut Bus, ids: &[u8], address: u16) -> Vec<u32> {
    let mut values = Vec::new();
    let mut errors = Vec::new();
    bus.sync_read_u32_cb(ids, address, |r| match r {
        Ok(r) => values.push((r.motor_id, r.data)),
        Err(e) => errors.push(format!("{e} ({e:?})")),
    })
    .unwrap_or_else(|e| panic!("sync_read_u32 write: {e}"));
    assert!(errors.is_empty(), "sync read of {address} from {ids:?}: errors {errors:?}");
    let got: Vec<u8> = values.iter().map(|v| v.0).collect();
    assert_eq!(got, ids, "sync read of {address}: replies came from {got:?}");
    values.into_iter().map(|v| v.1).collect()
}

fn sync_read_u8(bus: &mut Bus, ids: &[u8], address: u16) -> Vec<u8> {
    let replies = ok("sync_read_u8", bus.sync_read_u8(ids, address));
    let got: Vec<u8> = replies.iter().map(|r| r.motor_id).collect();
    assert_eq!(got, ids, "sync read of {address}: replies came from {got:?}");
    replies.into_iter().map(|r| r.data).collect()
}

// ------------------------------------------------------------------------------------------------
// Over the pty
// ------------------------------------------------------------------------------------------------

#[test]
fn pty_ping_every_id_reports_xm540() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);
    let mut firmware = Vec::new();
    for id in IDS {
        let r = ok(&format!("ping {id}"), bus.ping(id));
        assert_eq!(r.motor_id, id);
        assert_eq!(r.data.model, XM540_W270_MODEL, "ping {id}: model number");
        assert!(!r.alert);
        firmware.push(r.data.firmware);
        // The ping reply carries the same numbers as the control table.
        assert_eq!(read_u16(&mut bus, id, A_MODEL), XM540_W270_MODEL, "Model Number (0) of ID {id}");
        assert_eq!(read_u8(&mut bus, id, A_FIRMWARE), r.data.firmware, "Firmware Version (6) of ID {id}");
        assert_eq!(read_u8(&mut bus, id, A_ID), id, "ID (7) item of ID {id}");
    }
    assert!(firmware.iter().all(|&f| f == firmware[0] && f > 0), "firmware versions {firmware:?}");
    // Nobody answers for an ID that is not on the bus.
    assert_timeout("ping 9", bus.ping(9));
    assert_timeout("ping 200", bus.ping(200));
    // And the bus is fine afterwards.
    assert_eq!(ok("ping 8 after timeouts", bus.ping(8)).motor_id, 8);
    drop(bus);
    emu.finish();
}

#[test]
fn pty_scan_finds_eight_servos_in_id_order() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);
    assert_eq!(scan_ids(&mut bus, "scan"), IDS, "broadcast ping replies");
    // A second scan sees the same (no leftovers from the first one).
    assert_eq!(scan_ids(&mut bus, "second scan"), IDS, "broadcast ping replies");
    assert_eq!(ok("ping after scan", bus.ping(5)).motor_id, 5);
    drop(bus);
    emu.finish();
}

#[test]
fn pty_read_write_u8_u16_u32_round_trip() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);

    // u8: LED.
    for id in IDS {
        assert_eq!(read_u8(&mut bus, id, A_LED), 0, "LED power-on value of ID {id}");
    }
    write_u8(&mut bus, 3, A_LED, 1);
    assert_eq!(read_u8(&mut bus, 3, A_LED), 1, "LED of ID 3 after writing 1");
    for id in IDS.into_iter().filter(|&id| id != 3) {
        assert_eq!(read_u8(&mut bus, id, A_LED), 0, "LED of ID {id} changed by a write to ID 3");
    }
    write_u8(&mut bus, 3, A_LED, 0);
    assert_eq!(read_u8(&mut bus, 3, A_LED), 0);

    // u16: Position P Gain (default 800).
    assert_eq!(read_u16(&mut bus, 2, A_POSITION_P_GAIN), 800, "Position P Gain default");
    write_u16(&mut bus, 2, A_POSITION_P_GAIN, 640);
    assert_eq!(read_u16(&mut bus, 2, A_POSITION_P_GAIN), 640);
    assert_eq!(read_u16(&mut bus, 1, A_POSITION_P_GAIN), 800, "ID 1 gain changed by a write to ID 2");

    // u32: Goal Position, a different value per servo, and Profile Velocity.
    for id in IDS {
        write_u32(&mut bus, id, A_GOAL_POSITION, 1000 + 100 * u32::from(id));
    }
    for id in IDS {
        assert_eq!(read_u32(&mut bus, id, A_GOAL_POSITION), 1000 + 100 * u32::from(id), "Goal Position of ID {id}");
    }
    write_u32(&mut bus, 6, A_PROFILE_VELOCITY, 77);
    assert_eq!(read_u32(&mut bus, 6, A_PROFILE_VELOCITY), 77);

    // A raw multi-byte read spanning several items: Goal Position + Realtime Tick ... from 116.
    let raw = ok("read 116..124", bus.read(4, A_GOAL_POSITION, 8));
    assert_eq!(raw.motor_id, 4);
    assert_eq!(raw.data.len(), 8);
    assert_eq!(u32::from_le_bytes(raw.data[0..4].try_into().unwrap()), 1400);
    drop(bus);
    emu.finish();
}

#[test]
fn pty_sync_read_present_position_of_all_eight() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);
    // Torque is off and nothing drives the shafts: positions are stable, so a unicast read and a
    // sync read must agree.
    let unicast: Vec<u32> = IDS.iter().map(|&id| read_u32(&mut bus, id, A_PRESENT_POSITION)).collect();
    let synced = sync_read_u32(&mut bus, &IDS, A_PRESENT_POSITION);
    for (i, id) in IDS.iter().enumerate() {
        let (a, b) = (unicast[i] as i32, synced[i] as i32);
        assert!((a - b).abs() <= 2, "Present Position of ID {id}: unicast {a}, sync read {b}");
    }

    // The crate's plain `sync_read` (bytes) of Present Velocity + Present Position.
    let replies = ok("sync_read 128/8", bus.sync_read(&IDS, A_PRESENT_VELOCITY, 8));
    let got: Vec<u8> = replies.iter().map(|r| r.motor_id).collect();
    assert_eq!(got, IDS, "sync read 128/8 replies from");
    for (i, r) in replies.iter().enumerate() {
        assert_eq!(r.data.len(), 8);
        let velocity = i32::from_le_bytes(r.data[0..4].try_into().unwrap());
        let position = i32::from_le_bytes(r.data[4..8].try_into().unwrap());
        assert_eq!(velocity, 0, "Present Velocity of idle ID {}", r.motor_id);
        assert!((position - unicast[i] as i32).abs() <= 2, "Present Position of ID {} in the 128/8 read", r.motor_id);
    }

    // The replies follow the order of the IDs in the instruction, not the ID order.
    let subset = [7u8, 2, 5];
    let values = sync_read_u32(&mut bus, &subset, A_PRESENT_POSITION);
    for (k, &id) in subset.iter().enumerate() {
        let i = usize::from(id - 1);
        assert!((values[k] as i32 - unicast[i] as i32).abs() <= 2, "ID {id} in a reordered sync read");
    }
    // A distinguishing item: the ID byte itself.
    assert_eq!(sync_read_u8(&mut bus, &[8, 1, 4], A_ID), vec![8, 1, 4]);
    drop(bus);
    emu.finish();
}

#[test]
fn pty_sync_write_then_read_back() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);

    let goals: Vec<SyncWriteData<u32>> = IDS.iter().map(|&id| SyncWriteData { motor_id: id, data: 2000 + 37 * u32::from(id) }).collect();
    bus.sync_write_u32(A_GOAL_POSITION, &goals).expect("sync_write_u32");
    let back = sync_read_u32(&mut bus, &IDS, A_GOAL_POSITION);
    let want: Vec<u32> = goals.iter().map(|g| g.data).collect();
    assert_eq!(back, want, "Goal Positions after sync write");
    assert_eq!(read_u32(&mut bus, 5, A_GOAL_POSITION), 2000 + 37 * 5);

    // Only the listed servos take a sync write.
    let leds: Vec<SyncWriteData<u8>> = [2u8, 4, 6, 8].iter().map(|&id| SyncWriteData { motor_id: id, data: 1 }).collect();
    bus.sync_write_u8(A_LED, &leds).expect("sync_write_u8");
    assert_eq!(sync_read_u8(&mut bus, &IDS, A_LED), vec![0, 1, 0, 1, 0, 1, 0, 1]);

    // The generic byte form, 2 bytes each.
    let gains: Vec<SyncWriteData<[u8; 2]>> = [1u8, 3].iter().map(|&id| SyncWriteData { motor_id: id, data: (600 + u16::from(id)).to_le_bytes() }).collect();
    bus.sync_write(A_POSITION_P_GAIN, 2, &gains).expect("sync_write");
    assert_eq!(read_u16(&mut bus, 1, A_POSITION_P_GAIN), 601);
    assert_eq!(read_u16(&mut bus, 2, A_POSITION_P_GAIN), 800, "unlisted ID 2 changed");
    assert_eq!(read_u16(&mut bus, 3, A_POSITION_P_GAIN), 603);
    drop(bus);
    emu.finish();
}

#[test]
fn pty_bulk_write_and_bulk_read() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);

    let writes = vec![
        BulkWriteData { motor_id: 1, address: A_LED, data: vec![1u8] },
        BulkWriteData { motor_id: 2, address: A_GOAL_POSITION, data: 1234u32.to_le_bytes().to_vec() },
        BulkWriteData { motor_id: 3, address: A_POSITION_P_GAIN, data: 700u16.to_le_bytes().to_vec() },
    ];
    bus.bulk_write(&writes).expect("bulk_write");
    assert_eq!(read_u8(&mut bus, 1, A_LED), 1);
    assert_eq!(read_u32(&mut bus, 2, A_GOAL_POSITION), 1234);
    assert_eq!(read_u16(&mut bus, 3, A_POSITION_P_GAIN), 700);
    assert_eq!(read_u8(&mut bus, 2, A_LED), 0, "ID 2 LED touched by a bulk write entry for ID 1");

    // The crate's bulk_read, one entry (see the module comment for why only one).
    let one = ok("bulk_read", bus.bulk_read(&[BulkReadData { motor_id: 2, address: A_GOAL_POSITION, count: 4 }]));
    assert_eq!(one.len(), 1);
    assert_eq!(one[0].motor_id, 2);
    assert_eq!(one[0].data, 1234u32.to_le_bytes());

    // A three-servo Bulk Read, different address and length each, through the crate's raw API.
    let reads = [(3u8, A_POSITION_P_GAIN, 2u16), (1, A_LED, 1), (2, A_GOAL_POSITION, 4)];
    bus.write_instruction(packet_id::BROADCAST, instruction_id::BULK_READ, 5 * reads.len(), |buf| {
        for (i, &(id, address, count)) in reads.iter().enumerate() {
            buf[5 * i] = id;
            buf[5 * i + 1..5 * i + 3].copy_from_slice(&address.to_le_bytes());
            buf[5 * i + 3..5 * i + 5].copy_from_slice(&count.to_le_bytes());
        }
    })
    .expect("write Bulk Read");
    let mut got = Vec::new();
    for &(id, _, count) in &reads {
        let status = bus.read_status_response(count).unwrap_or_else(|e| panic!("Bulk Read reply of ID {id}: {e} ({e:?})"));
        got.push((status.packet_id(), status.parameters().to_vec()));
    }
    assert_eq!(got, vec![(3, 700u16.to_le_bytes().to_vec()), (1, vec![1]), (2, 1234u32.to_le_bytes().to_vec())], "Bulk Read replies (order of the instruction, each its own address/length)");
    drop(bus);
    emu.finish();
}

#[test]
fn pty_reg_write_then_action() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);

    write_u32(&mut bus, 1, A_GOAL_POSITION, 1000);
    assert_eq!(read_u8(&mut bus, 1, A_REGISTERED), 0);
    let r = ok("reg_write_u32", bus.reg_write_u32(1, A_GOAL_POSITION, 1500));
    assert_eq!(r.motor_id, 1);
    assert_eq!(read_u32(&mut bus, 1, A_GOAL_POSITION), 1000, "Reg Write applied before Action");
    assert_eq!(read_u8(&mut bus, 1, A_REGISTERED), 1, "Registered Instruction after Reg Write");
    let r = ok("action 1", bus.action(1));
    assert_eq!(r.motor_id, 1);
    assert_eq!(read_u32(&mut bus, 1, A_GOAL_POSITION), 1500, "Goal Position after Action");
    assert_eq!(read_u8(&mut bus, 1, A_REGISTERED), 0, "Registered Instruction after Action");

    // Action with nothing registered: Instruction Error.
    assert_eq!(motor_error("action 1 with nothing registered", bus.action(1)), ERR_INSTRUCTION);

    // Registered on two servos, released together by a broadcast Action (no reply).
    ok("reg_write_u8 2", bus.reg_write_u8(2, A_LED, 1));
    ok("reg_write (bytes) 3", bus.reg_write(3, A_LED, &[1]));
    assert_eq!(sync_read_u8(&mut bus, &[2, 3], A_LED), vec![0, 0], "LEDs lit before Action");
    bus.broadcast_action().expect("broadcast_action");
    assert_eq!(sync_read_u8(&mut bus, &[2, 3, 4], A_LED), vec![1, 1, 0], "LEDs after broadcast Action");
    assert_eq!(sync_read_u8(&mut bus, &[2, 3], A_REGISTERED), vec![0, 0]);
    drop(bus);
    emu.finish();
}

#[test]
fn pty_reboot_resets_ram_keeps_eeprom() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);

    write_u8(&mut bus, 4, A_LED, 1);
    write_u8(&mut bus, 5, A_LED, 1);
    write_u8(&mut bus, 4, A_RETURN_DELAY, 100); // EEPROM, torque is off
    write_u16(&mut bus, 4, A_POSITION_P_GAIN, 500); // RAM
    assert_eq!(read_u8(&mut bus, 4, A_RETURN_DELAY), 100);

    let r = ok("reboot 4", bus.reboot(4));
    assert_eq!(r.motor_id, 4, "reboot status reply");
    std::thread::sleep(Duration::from_millis(200));

    assert_eq!(ok("ping 4 after reboot", bus.ping(4)).data.model, XM540_W270_MODEL);
    assert_eq!(read_u8(&mut bus, 4, A_LED), 0, "LED (RAM) survived the reboot");
    assert_eq!(read_u16(&mut bus, 4, A_POSITION_P_GAIN), 800, "Position P Gain (RAM) survived the reboot");
    assert_eq!(read_u8(&mut bus, 4, A_RETURN_DELAY), 100, "Return Delay Time (EEPROM) lost in the reboot");
    assert_eq!(read_u8(&mut bus, 5, A_LED), 1, "rebooting ID 4 reset ID 5");
    drop(bus);
    emu.finish();
}

#[test]
fn pty_error_replies_surface_as_motor_errors() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);

    let before = read_u32(&mut bus, 1, A_PRESENT_POSITION);
    // Read-only item.
    assert_eq!(motor_error("write to Present Position (132)", bus.write_u32(1, A_PRESENT_POSITION, 0)), ERR_ACCESS);
    assert_eq!(motor_error("write_u8 to Present Position (132)", bus.write_u8(1, A_PRESENT_POSITION, 0)), ERR_ACCESS);
    assert!((read_u32(&mut bus, 1, A_PRESENT_POSITION) as i32 - before as i32).abs() <= 2);
    // Two bytes into a four-byte item.
    assert_eq!(motor_error("write_u16 to Goal Position (116)", bus.write_u16(1, A_GOAL_POSITION, 5)), ERR_DATA_LENGTH);
    // Outside the item's range (LED is 0..1).
    assert_eq!(motor_error("LED = 2", bus.write_u8(1, A_LED, 2)), ERR_DATA_RANGE);
    assert_eq!(read_u8(&mut bus, 1, A_LED), 0, "refused LED write was applied");
    // EEPROM is locked while torque is on.
    write_u8(&mut bus, 2, A_TORQUE, 1);
    assert_eq!(motor_error("EEPROM write with torque on", bus.write_u8(2, A_RETURN_DELAY, 0)), ERR_ACCESS);
    write_u8(&mut bus, 2, A_TORQUE, 0);
    write_u8(&mut bus, 2, A_RETURN_DELAY, 0);
    assert_eq!(read_u8(&mut bus, 2, A_RETURN_DELAY), 0);
    // The error reply is an ordinary reply of the addressed servo; the bus carries on.
    ping_all(&mut bus, "after errors");
    drop(bus);
    emu.finish();
}

#[test]
fn pty_position_mode_with_torque_reaches_goal() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);
    let id = 5;
    assert_eq!(read_u8(&mut bus, id, A_OPERATING_MODE), 3, "factory Operating Mode is position");
    write_u8(&mut bus, id, A_TORQUE, 1);
    let start = read_u32(&mut bus, id, A_PRESENT_POSITION) as i32;
    assert!((0..=4095).contains(&start), "Present Position {start} after torque on in mode 3");
    let goal = if start + 400 <= 4095 { start + 400 } else { start - 400 };
    write_u32(&mut bus, id, A_GOAL_POSITION, goal as u32);

    let deadline = Instant::now() + Duration::from_secs(5);
    let mut saw_moving = false;
    let mut saw_between = false;
    let mut position = start;
    while Instant::now() < deadline {
        saw_moving |= read_u8(&mut bus, id, A_MOVING) == 1;
        position = read_u32(&mut bus, id, A_PRESENT_POSITION) as i32;
        saw_between |= (position - start).abs() > 20 && (position - goal).abs() > 20;
        if (position - goal).abs() <= 10 && saw_moving {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(saw_moving, "Moving (122) never read 1 during a 400-pulse move");
    assert!((position - goal).abs() <= 10, "Present Position {position} did not reach {goal} (from {start}) within 5 s");
    assert!(saw_between, "the servo jumped from {start} to {goal} without passing in between");
    // It holds the goal, and another servo never moved.
    std::thread::sleep(Duration::from_millis(300));
    let held = read_u32(&mut bus, id, A_PRESENT_POSITION) as i32;
    assert!((held - goal).abs() <= 10, "drifted to {held} from goal {goal}");
    assert_eq!(read_u8(&mut bus, id, A_MOVING), 0, "Moving still 1 after arrival");
    assert_eq!(read_u8(&mut bus, 6, A_TORQUE), 0);
    drop(bus);
    emu.finish();
}

#[test]
fn pty_close_and_reopen_same_link() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    for round in 0..3u32 {
        let mut bus = emu.open(BAUD);
        ping_all(&mut bus, &format!("round {round}"));
        if round > 0 {
            assert_eq!(read_u32(&mut bus, 7, A_GOAL_POSITION), 3000 + round - 1, "state lost across reopen (round {round})");
        }
        write_u32(&mut bus, 7, A_GOAL_POSITION, 3000 + round);
        // Leave an unread instruction reply behind when closing: the next open must not see it.
        bus.write_instruction(7, instruction_id::PING, 0, |_| ()).expect("write ping");
        std::thread::sleep(Duration::from_millis(20));
        drop(bus);
    }
    let mut bus = emu.open(BAUD);
    assert_eq!(scan_ids(&mut bus, "after reopen"), IDS);
    drop(bus);
    emu.finish();
}

#[test]
fn pty_servos_hear_only_their_baud() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    {
        let mut bus = emu.open(115_200);
        assert_timeout("ping 1 at 115200 while the servos are at 57600", bus.ping(1));
        assert!(scan_ids(&mut bus, "scan at 115200").is_empty(), "servos at 57600 answered a 115200 scan");
    }
    let mut bus = emu.open(BAUD);
    ping_all(&mut bus, "57600");
    // Switch every servo to 1 Mbps (code 3) with a broadcast write (no reply), then follow.
    ok("broadcast Baud Rate = 3", bus.write_u8(packet_id::BROADCAST, A_BAUD, 3));
    std::thread::sleep(Duration::from_millis(20));
    assert_timeout("ping 1 at 57600 after the switch", bus.ping(1));
    bus.set_baud_rate(1_000_000).expect("set_baud_rate");
    ping_all(&mut bus, "1 Mbps");
    assert_eq!(read_u8(&mut bus, 1, A_BAUD), 3);
    assert_eq!(scan_ids(&mut bus, "scan at 1 Mbps"), IDS);
    drop(bus);
    emu.finish();
}

#[test]
fn pty_power_on_baud_flag() {
    let _serial = serial();
    let emu = start_emulator(&["--baud", "1000000"]);
    let mut bus = emu.open(1_000_000);
    ping_all(&mut bus, "--baud 1000000");
    for id in IDS {
        assert_eq!(read_u8(&mut bus, id, A_BAUD), 3, "Baud Rate code of ID {id} with --baud 1000000");
    }
    drop(bus);
    let mut bus = emu.open(BAUD);
    assert_timeout("ping 1 at 57600 with servos at 1 Mbps", bus.ping(1));
    drop(bus);
    emu.finish();
}

#[test]
fn pty_stuffed_reply_reaches_the_client_intact() {
    let _serial = serial();
    let emu = start_emulator(&[]);
    let mut bus = emu.open(BAUD);
    // Homing Offset (20) = -65536 is `00 00 FF FF`, Moving Threshold (24) = 253 is `FD 00 00 00`:
    // a Read of 20..28 carries `FF FF FD`, which the servo must stuff (reference §3).
    write_u32(&mut bus, 1, A_HOMING_OFFSET, (-65536i32) as u32);
    write_u32(&mut bus, 1, A_MOVING_THRESHOLD, 253);
    let data = [0x00, 0x00, 0xFF, 0xFF, 0xFD, 0x00, 0x00, 0x00];

    // The bytes on the line, read straight from the crate's serial port (its read timeout is
    // whatever the crate last set; the loop runs to its own deadline either way).
    bus.write_instruction(1, instruction_id::READ, 4, |buf| {
        buf[0..2].copy_from_slice(&A_HOMING_OFFSET.to_le_bytes());
        buf[2..4].copy_from_slice(&8u16.to_le_bytes());
    })
    .expect("write Read");
    let mut wire = Vec::new();
    let deadline = Instant::now() + Duration::from_millis(500);
    let mut chunk = [0u8; 64];
    while wire.len() < 20 && Instant::now() < deadline {
        match bus.serial_port().read(&mut chunk) {
            Ok(n) => wire.extend_from_slice(&chunk[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("raw read: {e}"),
        }
    }
    let mut want = vec![0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x0D, 0x00, 0x55, 0x00, 0x00, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00, 0x00, 0x00];
    let crc = dynamixel2::checksum::calculate_checksum(0, &want);
    want.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(wire, want, "stuffed Read reply on the wire: got {wire:02X?}, want {want:02X?}");

    // And through the crate's own decoding.
    let r = ok("read 20..28", bus.read(1, A_HOMING_OFFSET, 8));
    assert_eq!(r.data, data, "unstuffed data");
    assert_eq!(read_u32(&mut bus, 1, A_HOMING_OFFSET) as i32, -65536);
    assert_eq!(read_u32(&mut bus, 1, A_MOVING_THRESHOLD), 253);
    drop(bus);
    emu.finish();
}

// ------------------------------------------------------------------------------------------------
// Over TCP, through a ser2net-style bridge
// ------------------------------------------------------------------------------------------------

#[test]
fn tcp_bridge_ping_scan_sync_read_write() {
    let _serial = serial();
    let emu = start_emulator(&["--tcp", "127.0.0.1:0"]);
    let bridge = Bridge::connect(emu.tcp());
    let mut bus = bridge.open(BAUD);

    ping_all(&mut bus, "tcp");
    assert_eq!(scan_ids(&mut bus, "tcp scan"), IDS);
    let positions = sync_read_u32(&mut bus, &IDS, A_PRESENT_POSITION);
    for (i, &id) in IDS.iter().enumerate() {
        let p = read_u32(&mut bus, id, A_PRESENT_POSITION) as i32;
        assert!((p - positions[i] as i32).abs() <= 2, "ID {id}: sync read {} vs read {p}", positions[i]);
    }

    write_u32(&mut bus, 3, A_GOAL_POSITION, 2222);
    assert_eq!(read_u32(&mut bus, 3, A_GOAL_POSITION), 2222);
    let goals: Vec<SyncWriteData<u32>> = IDS.iter().map(|&id| SyncWriteData { motor_id: id, data: 500 + u32::from(id) }).collect();
    bus.sync_write_u32(A_GOAL_POSITION, &goals).expect("sync_write_u32 over tcp");
    assert_eq!(sync_read_u32(&mut bus, &IDS, A_GOAL_POSITION), goals.iter().map(|g| g.data).collect::<Vec<_>>());
    assert_eq!(motor_error("tcp: write to Present Position", bus.write_u32(1, A_PRESENT_POSITION, 0)), ERR_ACCESS);

    // TCP has no baud: whatever the client's port is set to, every servo hears.
    drop(bus);
    let mut bus = bridge.open(1_000_000);
    ping_all(&mut bus, "tcp, client port at 1 Mbps");
    drop(bus);
    drop(bridge);
    emu.finish();
}

#[test]
fn tcp_reconnect_and_client_reopen() {
    let _serial = serial();
    let emu = start_emulator(&["--tcp", "127.0.0.1:0"]);
    let mut bridge = Bridge::connect(emu.tcp());
    {
        let mut bus = bridge.open(BAUD);
        ping_all(&mut bus, "first connection");
        write_u32(&mut bus, 2, A_GOAL_POSITION, 1111);
        write_u8(&mut bus, 8, A_LED, 1);
    }
    // The network drops and comes back; the client's port stays open across it.
    let mut bus = bridge.open(BAUD);
    bridge.reconnect(emu.tcp());
    assert_eq!(read_u32(&mut bus, 2, A_GOAL_POSITION), 1111, "state lost across the TCP reconnect");
    assert_eq!(read_u8(&mut bus, 8, A_LED), 1);
    assert_eq!(scan_ids(&mut bus, "after TCP reconnect"), IDS);
    drop(bus);
    // The client closes and reopens its port on the same bridge.
    let mut bus = bridge.open(BAUD);
    ping_all(&mut bus, "client reopened");
    assert_eq!(sync_read_u32(&mut bus, &[2], A_GOAL_POSITION), vec![1111]);
    drop(bus);
    // A brand-new bridge (new pty, new connection).
    drop(bridge);
    let bridge = Bridge::connect(emu.tcp());
    let mut bus = bridge.open(BAUD);
    ping_all(&mut bus, "second bridge");
    assert_eq!(read_u32(&mut bus, 2, A_GOAL_POSITION), 1111);
    drop(bus);
    drop(bridge);
    emu.finish();
}

#[test]
fn tcp_and_pty_clients_share_one_bus() {
    let _serial = serial();
    let emu = start_emulator(&["--tcp", "127.0.0.1:0"]);
    let bridge = Bridge::connect(emu.tcp());
    let mut over_tcp = bridge.open(BAUD);
    let mut over_pty = emu.open(BAUD);
    write_u32(&mut over_tcp, 6, A_GOAL_POSITION, 2468);
    assert_eq!(read_u32(&mut over_pty, 6, A_GOAL_POSITION), 2468, "pty client does not see the TCP client's write");
    write_u8(&mut over_pty, 6, A_LED, 1);
    assert_eq!(read_u8(&mut over_tcp, 6, A_LED), 1, "TCP client does not see the pty client's write");
    drop(over_tcp);
    drop(over_pty);
    drop(bridge);
    emu.finish();
}
