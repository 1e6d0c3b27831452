//! The courier on seeded lines: every round's messages arrive whole and
//! answered, on a clean line, a damaged one and one that drops bytes.

use super::{Courier, CourierConfig, CourierError, CourierStats, Event};
use crate::sim;
use core::cell::RefCell;
use std::vec;
use std::vec::Vec;

type Line = sim::SimLine<65536>;
type Port<'a> = sim::SimPort<'a, 65536>;

fn line(seed: u64, error_rate: f64) -> RefCell<Line> {
    RefCell::new(Line::new(sim::SimConfig {
        seed,
        error_rate,
        stall_chance: 0.0,
        bytes_per_ms: 11.52,
        half_duplex: false,
        mix: sim::Mix::THIRDS,
        send_buffer: 16,
    }))
}

/// A message of `len` bytes, distinct per side and round.
fn message(side: u8, round: u16, len: usize) -> Vec<u8> {
    (0..len).map(|i| (i as u32).wrapping_mul(31).wrapping_add(u32::from(round) * 7 + u32::from(side)) as u8).collect()
}

/// One side's state in a test: its courier, its message and what came in.
struct Side {
    courier: Courier,
    out: Vec<u8>,
    input: Vec<u8>,
    got: Option<Vec<u8>>,
    done: bool,
}

/// Runs `rounds` rounds (side `s`'s message of round `r`: `lens(s, r)`
/// bytes; each side starts a round `gap` ms after it ended the last) and
/// checks what each side received and was answered; the time it took
/// and each side's line counters.
fn run(wire: &RefCell<Line>, rounds: u16, lens: impl Fn(u8, u16) -> usize, gap: [u64; 2]) -> (u64, [CourierStats; 2]) {
    let (mut p0, mut p1) = Line::ports(wire);
    let mut sides: Vec<Side> = (0..2)
        .map(|_| Side {
            courier: Courier::new(CourierConfig::default()).unwrap(),
            out: Vec::new(),
            input: vec![0; 40_000],
            got: None,
            done: true,
        })
        .collect();
    let mut now = 0u64;
    let mut next_start = [0u64; 2];
    let mut round = [0u16; 2];
    while round.iter().any(|&r| r < rounds) || sides.iter().any(|s| !s.done) {
        assert!(
            now < 600_000,
            "rounds stuck at {round:?}\n0: {}\n1: {}",
            sides[0].courier.debug_state(),
            sides[1].courier.debug_state()
        );
        wire.borrow_mut().tick(now);
        for (s, port) in [(0usize, &mut p0), (1, &mut p1)] {
            step_side(&mut sides[s], s as u8, port, now, &mut round[s], &mut next_start[s], rounds, &lens, gap[s]);
        }
        now += 1;
    }

    // Both answer what is left for a while (the other's last answer).
    for _ in 0..3000 {
        wire.borrow_mut().tick(now);
        for (s, port) in [(0usize, &mut p0), (1, &mut p1)] {
            let side = &mut sides[s];
            assert_eq!(side.courier.step(port, &side.out, &mut side.input, now), Ok(Event::Busy));
        }
        now += 1;
    }
    (now, [sides[0].courier.stats(), sides[1].courier.stats()])
}

#[allow(clippy::too_many_arguments)]
fn step_side(
    side: &mut Side,
    me: u8,
    port: &mut Port<'_>,
    now: u64,
    round: &mut u16,
    next_start: &mut u64,
    rounds: u16,
    lens: &impl Fn(u8, u16) -> usize,
    gap: u64,
) {
    if side.done && *round < rounds && now >= *next_start {
        side.out = message(me, *round, lens(me, *round));
        side.courier.start(*round, side.out.len(), now).unwrap();
        side.done = false;
        side.got = None;
    }
    let event = side.courier.step(port, &side.out, &mut side.input, now);
    let event = event.unwrap_or_else(|e| panic!("side {me} at {now}: {e:?}: {}", side.courier.debug_state()));
    match event {
        Event::Busy => {}
        Event::Delivered(n) => {
            let peer = 1 - me;
            let r = side.courier.round().unwrap();
            assert_eq!(side.input[..n], message(peer, r, lens(peer, r))[..], "round {r}: side {me} received");
            side.got = Some(side.input[..n].to_vec());
            side.courier.reply(&[me, r as u8, n as u8]).unwrap();
            side.courier.send_answer(port).unwrap();
        }
        Event::Done => {
            let r = *round;
            let peer_len = lens(1 - me, r);
            assert_eq!(side.courier.answer(), Some(&[1 - me, r as u8, lens(me, r) as u8][..]), "round {r}");
            assert_eq!(side.got.as_ref().map(Vec::len), Some(peer_len));
            side.done = true;
            *round += 1;
            *next_start = now + gap;
        }
    }
}

#[test]
fn messages_of_any_length_cross_a_clean_line_every_round() {
    let wire = line(1, 0.0);
    let lens = |s: u8, r: u16| [0usize, 1, 127, 128, 129, 5000, 30_000][usize::from(r + u16::from(s)) % 7];
    run(&wire, 10, lens, [0, 0]);
}

#[test]
fn a_side_that_starts_late_still_gets_every_message_and_answer() {
    // Side 1 spends 700 ms between rounds (fusing, matching): side 0's
    // frames of the next round meet a side that has not started it.
    let wire = line(2, 0.0);
    run(&wire, 6, |_, r| 900 + 300 * usize::from(r), [0, 700]);
}

/// A clean line and lines that damage 1%, 5% and 10% of bytes (a third each substituted,
/// dropped, duplicated), six seeds each: every message arrives whole and
/// answered; the mean time of five rounds of 2-5 KB each way is printed
/// (virtual time at 115200 baud, lingering left out). Data goes in frames
/// on a clean line and in blocks where bytes are damaged often (at 5% and
/// 10% a frame short enough to survive its drops and duplicates carries
/// little).
#[test]
fn damaged_lines_cost_time_never_a_message() {
    for rate in [0.0, 0.01, 0.05, 0.10] {
        let (mut total, mut blocks) = (0u64, 0u32);
        for seed in 10..16 {
            let wire = line(seed, rate);
            let (ms, stats) = run(&wire, 5, |s, r| 2000 + 700 * usize::from(r) + usize::from(s), [0, 50]);
            total += ms - 3000;
            blocks += stats.iter().map(|s| s.blocks).sum::<u32>();
        }
        std::println!("error rate {rate}: {} ms on average, {blocks} blocks", total / 6);
        if rate == 0.0 {
            assert_eq!(blocks, 0, "a clean line: frames");
        } else if rate >= 0.05 {
            assert!(blocks > 0, "error rate {rate}: no blocks");
        }
    }
}

#[test]
fn a_message_larger_than_the_receiving_buffer_is_refused() {
    let wire = line(6, 0.0);
    let (mut p0, mut p1) = Line::ports(&wire);
    let mut a = Courier::new(CourierConfig::default()).unwrap();
    let mut b = Courier::new(CourierConfig::default()).unwrap();
    let big = vec![7u8; 5000];
    a.start(0, big.len(), 0).unwrap();
    b.start(0, 10, 0).unwrap();
    let (mut ia, mut ib) = (vec![0u8; 100], vec![0u8; 1000]);
    let mut failed = None;
    for now in 0..2000 {
        wire.borrow_mut().tick(now);
        let _ = a.step(&mut p0, &big, &mut ia, now);
        if let Err(e) = b.step(&mut p1, &[0; 10], &mut ib, now) {
            failed = Some(e);
            break;
        }
    }
    assert_eq!(failed, Some(CourierError::TooLarge(5000)));
    assert_eq!(
        Courier::new(CourierConfig { max_units: 40, ..CourierConfig::default() }).err(),
        Some(CourierError::Config)
    );
}

/// Frames and blocks whose CRC holds but whose fields are anything (the
/// courier's kinds with random rounds, lengths, units and runs, other
/// kinds, empty payloads) and bytes that are no frame at all: the courier
/// never panics,
/// and says what it refuses with a typed error.
#[test]
fn any_frame_is_taken_or_refused_never_a_panic() {
    use crate::wire::frame::encode_frame_parity;
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for case in 0..300 {
        let wire = line(case, 0.0);
        let (mut p0, mut p1) = Line::ports(&wire);
        let mut c = Courier::new(CourierConfig::default()).unwrap();
        let out = vec![7u8; 3000];
        let mut input = vec![0u8; 4000];
        c.start((next() % 3) as u16, out.len(), 0).unwrap();
        let mut now = 0;
        for _ in 0..20 {
            let len = (next() % 120) as usize;
            let mut payload: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            if let Some(first) = payload.first_mut() {
                *first = [0x0E, 0x0F, 0x0E, 0x0F, next() as u8][(next() % 5) as usize];
            }
            let mut frame = [0u8; crate::wire::MAX_FRAME];
            let bytes: Vec<u8> =
                match (next() % 5, encode_frame_parity(&payload, [0, 4, 8][(next() % 3) as usize], &mut frame)) {
                    // A block: its segments carry the payload (the data path of
                    // a damaged line).
                    (0, _) => {
                        let shape = crate::wire::block::BlockShape { segment: 8, parity: 4, spares: 2 };
                        let mut block = Vec::new();
                        let encoded =
                            crate::wire::block::encode_block::<crate::wire::frame::FrameError>(&payload, shape, |b| {
                                block.extend_from_slice(b);
                                Ok(())
                            });
                        if encoded.is_ok() {
                            block
                        } else {
                            (0..len).map(|_| next() as u8).collect()
                        }
                    }
                    (_, Ok(n)) if next() % 4 != 0 => frame[..n].to_vec(),
                    _ => (0..len).map(|_| next() as u8).collect(),
                };
            embedded_io::Write::write_all(&mut p1, &bytes).unwrap();
            for _ in 0..40 {
                wire.borrow_mut().tick(now);
                match c.step(&mut p0, &out, &mut input, now) {
                    Ok(_) => {}
                    Err(CourierError::TooLarge(_) | CourierError::Silent) => break,
                    Err(e) => panic!("case {case}: {e:?}"),
                }
                now += 1;
            }
        }
    }
}

/// An acknowledgement holds only the runs held beyond its count (most hold
/// none: a short frame is what survives a line that damages many bytes),
/// and the sender reads each back: those units, and none besides, are
/// acknowledged.
#[test]
fn an_acknowledgement_carries_only_the_runs_it_holds() {
    use super::receive::AckView;
    let cases: [[(u16, u16); 3]; 3] = [[(0, 0); 3], [(20, 5), (0, 0), (0, 0)], [(20, 5), (30, 2), (40, 10)]];
    let mut lengths = Vec::new();
    for runs in cases {
        let wire = line(1, 0.0);
        let (mut p0, mut p1) = Line::ports(&wire);
        let mut receiver = Courier::new(CourierConfig::default()).unwrap();
        let mut sender = Courier::new(CourierConfig::default()).unwrap();
        let out = vec![5u8; 400];
        let mut input = vec![0u8; 1000];
        sender.start(0, out.len(), 0).unwrap();
        let ack = AckView { round: 0, count: 10, runs, complete: false, reply: None };
        receiver.send_ack(&mut p0, &ack).unwrap();
        lengths.push(receiver.stats().bytes_sent);
        for now in 0..5 {
            wire.borrow_mut().tick(now);
            sender.step(&mut p1, &out, &mut input, now).unwrap();
        }
        let held = |u: usize| u < 10 || runs.iter().any(|&(s, n)| (usize::from(s)..usize::from(s + n)).contains(&u));
        for u in 0..50 {
            assert_eq!(sender.acked.get(u), held(u), "runs {runs:?}: unit {u}");
        }
    }
    // Four bytes a run (the frame's parity and stuffing aside).
    assert!(lengths[0] < lengths[1] && lengths[1] + 8 <= lengths[2], "{lengths:?}");
}
