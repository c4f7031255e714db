//! Frame-vector tests of the ISO-TP endpoint: every frame written out in bytes.

use super::*;

const T0: Duration = Duration::ZERO;

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// Every frame the endpoint has due at `now`, as byte vectors.
fn frames(endpoint: &mut Endpoint, now: Duration) -> Vec<Vec<u8>> {
    std::iter::from_fn(|| endpoint.poll_frame(now)).map(|f| f.as_slice().to_vec()).collect()
}

fn events(endpoint: &mut Endpoint) -> Vec<Event> {
    std::iter::from_fn(|| endpoint.poll_event()).collect()
}

fn errors(endpoint: &mut Endpoint) -> Vec<IsoTpError> {
    events(endpoint)
        .into_iter()
        .filter_map(|e| match e {
            Event::Error(error) => Some(error),
            _ => None,
        })
        .collect()
}

fn received(endpoint: &mut Endpoint) -> Vec<Vec<u8>> {
    events(endpoint)
        .into_iter()
        .filter_map(|e| match e {
            Event::Received(message) => Some(message),
            _ => None,
        })
        .collect()
}

fn unpadded() -> Config {
    Config { padding: None, ..Config::default() }
}

fn message(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i * 7 + 3) as u8).collect()
}

/// Move frames both ways between two endpoints until neither has anything due at `now`.
fn exchange(a: &mut Endpoint, b: &mut Endpoint, now: Duration) {
    loop {
        let from_a = frames(a, now);
        let from_b = frames(b, now);
        if from_a.is_empty() && from_b.is_empty() {
            return;
        }
        from_a.iter().for_each(|f| b.on_frame(now, f));
        from_b.iter().for_each(|f| a.on_frame(now, f));
    }
}

#[test]
fn single_frame_is_padded_with_cc_by_default() {
    let mut tx = Endpoint::new(Config::default());
    tx.send(vec![0xFF, 0xFF, 0xFD]).unwrap();
    assert_eq!(frames(&mut tx, T0), [vec![0x03, 0xFF, 0xFF, 0xFD, 0xCC, 0xCC, 0xCC, 0xCC]]);
    assert_eq!(events(&mut tx), [Event::Sent(3)]);
    assert!(tx.tx_idle());
}

#[test]
fn single_frame_without_padding_is_as_short_as_it_can_be() {
    let mut tx = Endpoint::new(unpadded());
    tx.send(message(7)).unwrap();
    let sent = frames(&mut tx, T0);
    assert_eq!(sent.len(), 1);
    assert_eq!(sent[0][0], 0x07);
    assert_eq!(&sent[0][1..], &message(7)[..]);
}

#[test]
fn single_frame_received_padded_or_not() {
    let mut rx = Endpoint::new(Config::default());
    rx.on_frame(T0, &[0x02, 0xAA, 0xBB, 0x55, 0x55, 0x55, 0x55, 0x55]);
    rx.on_frame(T0, &[0x01, 0x42]);
    assert_eq!(received(&mut rx), [vec![0xAA, 0xBB], vec![0x42]]);
}

#[test]
fn first_and_consecutive_frames_with_sequence_number_wrap() {
    // 6 bytes in the first frame + 17 consecutive frames of 7: SN 1..=15, then 0 and 1.
    let body = message(6 + 17 * 7);
    let mut tx = Endpoint::new(Config::default());
    tx.send(body.clone()).unwrap();
    let first = frames(&mut tx, T0);
    assert_eq!(first, [vec![0x10, 125, body[0], body[1], body[2], body[3], body[4], body[5]]]);
    assert!(frames(&mut tx, ms(5)).is_empty(), "nothing before the flow control");

    tx.on_frame(ms(1), &[0x30, 0x00, 0x00, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]);
    let consecutive = frames(&mut tx, ms(1));
    assert_eq!(consecutive.len(), 17);
    let sns: Vec<u8> = consecutive.iter().map(|f| f[0]).collect();
    let mut expected: Vec<u8> = (0x21..=0x2F).collect();
    expected.extend([0x20, 0x21]);
    assert_eq!(sns, expected);
    assert!(consecutive.iter().all(|f| f.len() == 8));
    let reassembled: Vec<u8> = first[0][2..].iter().chain(consecutive.iter().flat_map(|f| &f[1..])).copied().collect();
    assert_eq!(reassembled, body);
    assert_eq!(events(&mut tx), [Event::Sent(125)]);

    // And the receiving side puts it back together, answering the first frame with CTS.
    let mut rx = Endpoint::new(Config::default());
    rx.on_frame(T0, &first[0]);
    assert_eq!(frames(&mut rx, T0), [vec![0x30, 0x00, 0x00, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]]);
    consecutive.iter().for_each(|f| rx.on_frame(ms(1), f));
    assert_eq!(received(&mut rx), [body]);
}

#[test]
fn last_consecutive_frame_padded_only_when_configured() {
    let body = message(10); // FF with 6, one CF with 4
    for (config, len) in [(Config::default(), 8), (unpadded(), 5)] {
        let mut tx = Endpoint::new(config.clone());
        tx.send(body.clone()).unwrap();
        frames(&mut tx, T0);
        tx.on_frame(T0, &[0x30, 0, 0]);
        let last = frames(&mut tx, T0);
        assert_eq!(last.len(), 1);
        assert_eq!(last[0].len(), len, "{config:?}");
        assert_eq!(&last[0][..5], &[0x21, body[6], body[7], body[8], body[9]]);
    }
    // Unpadded flow control: three bytes.
    let mut rx = Endpoint::new(unpadded());
    rx.on_frame(T0, &[0x10, 10, 1, 2, 3, 4, 5, 6]);
    assert_eq!(frames(&mut rx, T0), [vec![0x30, 0, 0]]);
}

#[test]
fn largest_message_round_trips_and_one_byte_more_is_refused() {
    let mut a = Endpoint::new(Config::default());
    let mut b = Endpoint::new(Config { block_size: 8, ..Config::default() });
    let body = message(MAX_MESSAGE_LEN);
    a.send(body.clone()).unwrap();
    exchange(&mut a, &mut b, T0);
    assert_eq!(received(&mut b), [body]);
    assert_eq!(a.send(message(MAX_MESSAGE_LEN + 1)), Err(IsoTpError::TxMessageLen(4096)));
    assert_eq!(a.send(Vec::new()), Err(IsoTpError::TxMessageLen(0)));
}

#[test]
fn receiver_block_size_asks_for_flow_control_after_each_block() {
    let mut rx = Endpoint::new(Config { block_size: 2, st_min: StMin::from_raw(0xF5), ..unpadded() });
    // 6 + 7 * 4 = 34 bytes: FF, then CF 1..=4.
    let body = message(34);
    let mut first = vec![0x10, 34];
    first.extend_from_slice(&body[..6]);
    rx.on_frame(T0, &first);
    assert_eq!(frames(&mut rx, T0), [vec![0x30, 2, 0xF5]]);
    let cf = |sn: u8, at: usize| -> Vec<u8> { std::iter::once(0x20 | sn).chain(body[at..at + 7].iter().copied()).collect() };
    rx.on_frame(T0, &cf(1, 6));
    assert!(frames(&mut rx, T0).is_empty());
    rx.on_frame(T0, &cf(2, 13));
    assert_eq!(frames(&mut rx, T0), [vec![0x30, 2, 0xF5]], "block of 2 done: next CTS");
    rx.on_frame(T0, &cf(3, 20));
    rx.on_frame(T0, &cf(4, 27));
    assert!(frames(&mut rx, T0).is_empty(), "the message is complete: no flow control");
    assert_eq!(received(&mut rx), [body]);
}

#[test]
fn sender_waits_for_flow_control_after_each_block() {
    let mut tx = Endpoint::new(unpadded());
    tx.send(message(6 + 5 * 7)).unwrap();
    frames(&mut tx, T0);
    tx.on_frame(ms(1), &[0x30, 2, 0]);
    assert_eq!(frames(&mut tx, ms(1)).len(), 2);
    assert_eq!(tx.poll_deadline(), Some(ms(1) + Config::default().n_bs), "N_Bs runs again");
    assert!(frames(&mut tx, ms(2)).is_empty());
    tx.on_frame(ms(3), &[0x30, 2, 0]);
    let next: Vec<u8> = frames(&mut tx, ms(3)).iter().map(|f| f[0]).collect();
    assert_eq!(next, [0x23, 0x24]);
    tx.on_frame(ms(4), &[0x30, 0, 0]);
    let last: Vec<u8> = frames(&mut tx, ms(4)).iter().map(|f| f[0]).collect();
    assert_eq!(last, [0x25]);
    assert!(tx.tx_idle());
}

#[test]
fn st_min_encoding() {
    assert_eq!(StMin::from_raw(0x00).duration(), Duration::ZERO);
    assert_eq!(StMin::from_raw(0x7F).duration(), ms(127));
    assert_eq!(StMin::from_raw(0xF1).duration(), Duration::from_micros(100));
    assert_eq!(StMin::from_raw(0xF9).duration(), Duration::from_micros(900));
    for reserved in [0x80, 0xF0, 0xFA, 0xFF] {
        assert_eq!(StMin::from_raw(reserved).duration(), ms(127), "{reserved:#X} is reserved: 127 ms");
    }
    assert_eq!(StMin::from_duration(Duration::from_micros(300)), Some(StMin::from_raw(0xF3)));
    assert_eq!(StMin::from_duration(ms(5)), Some(StMin::from_raw(0x05)));
    assert_eq!(StMin::from_duration(Duration::from_micros(150)), None);
    assert_eq!(StMin::from_duration(ms(128)), None);
}

#[test]
fn sender_keeps_the_receivers_st_min_between_consecutive_frames() {
    for (raw, gap) in [(0x0A, ms(10)), (0xF3, Duration::from_micros(300))] {
        let mut tx = Endpoint::new(Config::default());
        tx.send(message(6 + 3 * 7)).unwrap();
        frames(&mut tx, T0);
        tx.on_frame(ms(1), &[0x30, 0, raw]);
        assert_eq!(frames(&mut tx, ms(1)).len(), 1, "the first CF goes at once");
        assert_eq!(tx.poll_deadline(), Some(ms(1) + gap));
        assert!(frames(&mut tx, ms(1) + gap - Duration::from_micros(1)).is_empty(), "{raw:#X}: not before STmin");
        assert_eq!(frames(&mut tx, ms(1) + gap).len(), 1);
        assert!(frames(&mut tx, ms(1) + gap * 2 - Duration::from_micros(1)).is_empty());
        assert_eq!(frames(&mut tx, ms(1) + gap * 2).len(), 1);
        assert!(tx.tx_idle());
    }
}

#[test]
fn flow_control_wait_extends_n_bs_until_too_many() {
    let config = Config { max_wait_frames: 2, ..Config::default() };
    let n_bs = config.n_bs;
    let mut tx = Endpoint::new(config);
    tx.send(message(20)).unwrap();
    frames(&mut tx, T0);
    tx.on_frame(ms(500), &[0x31, 0, 0]);
    assert_eq!(tx.poll_deadline(), Some(ms(500) + n_bs));
    tx.handle_timeout(n_bs);
    assert!(errors(&mut tx).is_empty(), "WAIT restarted N_Bs");
    tx.on_frame(ms(600), &[0x31, 0, 0]);
    tx.on_frame(ms(700), &[0x31, 0, 0]);
    assert_eq!(errors(&mut tx), [IsoTpError::TxTooManyWaits(2)]);
    assert!(tx.tx_idle());
}

#[test]
fn overflow_from_the_receiver_drops_the_message_and_the_next_one_goes() {
    let mut tx = Endpoint::new(Config::default());
    tx.send(message(100)).unwrap();
    tx.send(vec![1, 2]).unwrap();
    frames(&mut tx, T0);
    tx.on_frame(T0, &[0x32, 0, 0]);
    assert_eq!(errors(&mut tx), [IsoTpError::TxOverflow(100)]);
    assert_eq!(frames(&mut tx, T0), [vec![0x02, 1, 2, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]]);
}

#[test]
fn first_frame_longer_than_accepted_gets_overflow() {
    let mut rx = Endpoint::new(Config { max_rx_len: 100, ..Config::default() });
    rx.on_frame(T0, &[0x10, 200, 0, 0, 0, 0, 0, 0]);
    assert_eq!(frames(&mut rx, T0), [vec![0x32, 0, 0, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]]);
    assert_eq!(errors(&mut rx), [IsoTpError::RxOverflow { len: 200, max: 100 }]);
    rx.on_frame(T0, &[0x21, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(errors(&mut rx), [IsoTpError::UnexpectedConsecutive]);
    // The 32-bit escape is for messages beyond 4095 bytes: overflow as well.
    let mut rx = Endpoint::new(Config::default());
    rx.on_frame(T0, &[0x10, 0x00, 0x00, 0x01, 0x00, 0x00, 0, 0]);
    assert_eq!(errors(&mut rx), [IsoTpError::RxOverflow { len: 65536, max: 4095 }]);
    assert_eq!(frames(&mut rx, T0).len(), 1);
}

#[test]
fn malformed_frames_are_reported_and_ignored() {
    let mut rx = Endpoint::new(Config::default());
    rx.on_frame(T0, &[]);
    rx.on_frame(T0, &[0x40, 1, 2]);
    rx.on_frame(T0, &[0x00, 1, 2]);
    rx.on_frame(T0, &[0x05, 1, 2]);
    rx.on_frame(T0, &[0x08, 1, 2, 3, 4, 5, 6, 7]);
    rx.on_frame(T0, &[0x10, 20, 1, 2, 3]);
    rx.on_frame(T0, &[0x10, 7, 1, 2, 3, 4, 5, 6]);
    rx.on_frame(T0, &[0x10, 0x00, 0x00, 0x00, 0x00, 0x10, 0, 0]);
    rx.on_frame(T0, &[0x30, 0, 0]);
    rx.on_frame(T0, &[0x30]);
    assert_eq!(
        errors(&mut rx),
        [
            IsoTpError::EmptyFrame,
            IsoTpError::UnknownPci(4),
            IsoTpError::BadSingleFrameLen { len: 0, dlc: 3 },
            IsoTpError::BadSingleFrameLen { len: 5, dlc: 3 },
            IsoTpError::BadSingleFrameLen { len: 8, dlc: 8 },
            IsoTpError::Truncated { kind: "first", dlc: 5 },
            IsoTpError::FirstFrameTooShort(7),
            IsoTpError::NeedlessEscape(16),
            IsoTpError::UnexpectedFlowControl,
            IsoTpError::Truncated { kind: "flow control", dlc: 1 },
        ]
    );
    assert!(frames(&mut rx, T0).is_empty(), "no flow control for any of them");
    rx.on_frame(T0, &[0x01, 0x99]);
    assert_eq!(received(&mut rx), [vec![0x99]]);
}

#[test]
fn invalid_flow_status_aborts_the_message() {
    let mut tx = Endpoint::new(Config::default());
    tx.send(message(30)).unwrap();
    frames(&mut tx, T0);
    tx.on_frame(T0, &[0x37, 0, 0]);
    assert_eq!(errors(&mut tx), [IsoTpError::InvalidFlowStatus(7)]);
    assert!(tx.tx_idle());
}

#[test]
fn out_of_order_consecutive_frame_drops_the_message_until_the_next_start() {
    let mut rx = Endpoint::new(unpadded());
    let body = message(20);
    let mut first = vec![0x10, 20];
    first.extend_from_slice(&body[..6]);
    rx.on_frame(T0, &first);
    rx.on_frame(T0, &[0x22, 0, 0, 0, 0, 0, 0, 0]);
    rx.on_frame(T0, &[0x21, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(errors(&mut rx), [IsoTpError::WrongSequence { expected: 1, got: 2 }, IsoTpError::UnexpectedConsecutive]);
    // A fresh first frame starts over and completes.
    rx.on_frame(T0, &first);
    rx.on_frame(T0, &[&[0x21][..], &body[6..13]].concat());
    rx.on_frame(T0, &[&[0x22][..], &body[13..20]].concat());
    assert_eq!(received(&mut rx), [body]);
}

#[test]
fn new_first_or_single_frame_interrupts_a_reception() {
    let mut rx = Endpoint::new(unpadded());
    rx.on_frame(T0, &[0x10, 20, 1, 2, 3, 4, 5, 6]);
    rx.on_frame(T0, &[0x21, 7, 8, 9, 10, 11, 12, 13]);
    rx.on_frame(T0, &[0x02, 0xAB, 0xCD]);
    assert_eq!(events(&mut rx), [Event::Error(IsoTpError::RxInterrupted { expected: 20, received: 13, by: "single" }), Event::Received(vec![0xAB, 0xCD])]);
    rx.on_frame(T0, &[0x10, 20, 1, 2, 3, 4, 5, 6]);
    rx.on_frame(T0, &[0x10, 8, 1, 2, 3, 4, 5, 6]);
    rx.on_frame(T0, &[0x21, 7, 8]);
    assert_eq!(events(&mut rx), [Event::Error(IsoTpError::RxInterrupted { expected: 20, received: 6, by: "first" }), Event::Received(vec![1, 2, 3, 4, 5, 6, 7, 8])]);
}

#[test]
fn truncated_consecutive_frame_drops_the_message() {
    let mut rx = Endpoint::new(unpadded());
    rx.on_frame(T0, &[0x10, 20, 1, 2, 3, 4, 5, 6]);
    rx.on_frame(T0, &[0x21, 7, 8]);
    assert_eq!(errors(&mut rx), [IsoTpError::Truncated { kind: "consecutive", dlc: 3 }]);
    assert_eq!(rx.poll_deadline(), None, "nothing waited for any more");
}

#[test]
fn n_cr_drops_a_stalled_reception() {
    let config = Config::default();
    let n_cr = config.n_cr;
    let mut rx = Endpoint::new(config);
    rx.on_frame(T0, &[0x10, 20, 1, 2, 3, 4, 5, 6]);
    rx.on_frame(ms(10), &[0x21, 7, 8, 9, 10, 11, 12, 13]);
    assert_eq!(rx.poll_deadline(), Some(ms(10) + n_cr), "each CF restarts N_Cr");
    rx.handle_timeout(ms(10) + n_cr - Duration::from_micros(1));
    assert!(errors(&mut rx).is_empty());
    rx.handle_timeout(ms(10) + n_cr);
    assert_eq!(errors(&mut rx), [IsoTpError::RxTimeout(n_cr, 13)]);
    rx.on_frame(ms(1100), &[0x22, 14, 15, 16, 17, 18, 19, 20]);
    assert_eq!(errors(&mut rx), [IsoTpError::UnexpectedConsecutive]);
}

#[test]
fn n_bs_gives_up_on_a_message_without_flow_control_and_sends_the_next() {
    let config = Config::default();
    let n_bs = config.n_bs;
    let mut tx = Endpoint::new(config);
    tx.send(message(30)).unwrap();
    tx.send(vec![7]).unwrap();
    assert_eq!(frames(&mut tx, T0).len(), 1);
    assert_eq!(tx.poll_deadline(), Some(n_bs));
    tx.handle_timeout(n_bs - Duration::from_micros(1));
    assert!(frames(&mut tx, n_bs - Duration::from_micros(1)).is_empty());
    tx.handle_timeout(n_bs);
    assert_eq!(errors(&mut tx), [IsoTpError::TxTimeout(n_bs)]);
    assert_eq!(frames(&mut tx, n_bs), [vec![0x01, 7, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]]);
    // A late flow control for the dropped message is unexpected.
    tx.on_frame(n_bs, &[0x30, 0, 0]);
    assert_eq!(errors(&mut tx), [IsoTpError::UnexpectedFlowControl]);
}

#[test]
fn queued_messages_go_one_after_another_and_the_queue_is_bounded() {
    let mut a = Endpoint::new(Config { max_tx_queue: 3, ..Config::default() });
    let mut b = Endpoint::new(Config::default());
    let bodies = [message(40), message(3), message(9)];
    for body in &bodies {
        a.send(body.clone()).unwrap();
    }
    assert_eq!(a.send(vec![1]), Err(IsoTpError::TxQueueFull(3)));
    exchange(&mut a, &mut b, T0);
    assert_eq!(received(&mut b), bodies);
    assert_eq!(events(&mut a), [Event::Sent(40), Event::Sent(3), Event::Sent(9)]);
}

#[test]
fn both_directions_at_once() {
    let mut a = Endpoint::new(Config::default());
    let mut b = Endpoint::new(Config { block_size: 1, ..Config::default() });
    a.send(message(50)).unwrap();
    b.send(message(60)).unwrap();
    exchange(&mut a, &mut b, T0);
    assert_eq!(received(&mut b), [message(50)]);
    assert_eq!(received(&mut a), [message(60)]);
}
