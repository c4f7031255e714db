//! Criterion: decode + handle + encode of one Sync Read of 8 IDs × 4 bytes (Present Position),
//! the hot path of a controller's read cycle, without any I/O. Target (issue #2): < 5 µs.

use std::hint::black_box;
use std::time::Duration;

use climbsim::bus::Timing;
use climbsim::protocol::{Decoder, encode_instruction, opcode};
use climbsim::robot::RobotDescription;
use criterion::{Criterion, criterion_group, criterion_main};

fn sync_read_8x4(c: &mut Criterion) {
    let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot description");
    let mut bus = robot.bench_bus(Timing::Off, None).expect("bench bus");
    let request = encode_instruction(0xFE, opcode::SYNC_READ, &[132, 0, 4, 0, 1, 2, 3, 4, 5, 6, 7, 8]);
    let mut decoder = Decoder::default();
    let now = Duration::from_secs(1);
    bus.advance(now);
    c.bench_function("sync_read_8x4_decode_handle_encode", |b| {
        b.iter(|| {
            let mut reply_bytes = 0;
            for packet in decoder.push(now, black_box(&request)) {
                let transaction = bus.handle(packet.expect("valid packet"), now, None);
                reply_bytes += transaction.replies.iter().map(|r| r.bytes.len()).sum::<usize>();
            }
            assert_eq!(reply_bytes, 8 * 15);
            black_box(reply_bytes)
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    targets = sync_read_8x4
}
criterion_main!(benches);
