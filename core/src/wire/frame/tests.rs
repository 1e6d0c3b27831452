//! The frame code's tests: frames round-tripped, damaged lines repaired.

use super::*;

fn rng(state: &mut u64) -> u64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    *state
}

/// Feeds `bytes` to a fresh deframer; the payloads it yields (at most
/// four) and the damage of the last.
fn frames_of(bytes: &[u8]) -> (heapless::Vec<heapless::Vec<u8, 600>, 4>, Damage) {
    let mut d = Deframer::new();
    let mut got = heapless::Vec::new();
    let mut damage = Damage::default();
    for &b in bytes {
        if let Ok(Some(f)) = d.push_frame(b) {
            damage = f.damage;
            let _ = got.push(heapless::Vec::from_slice(f.payload).unwrap());
        }
    }
    (got, damage)
}

#[test]
fn frames_round_trip_and_survive_noise_between_them() {
    let every: [u8; 512] = core::array::from_fn(|i| i as u8);
    let payloads: [&[u8]; 5] = [b"hello robot", &[0u8; 30], &every[..241], &every[..249], &every];
    for payload in payloads {
        for parity in [0, 2, 4, 8] {
            let mut out = [0u8; MAX_FRAME];
            let Ok(n) = encode_frame_parity(payload, parity, &mut out) else {
                assert!(payload.len() > max_payload(parity));
                continue;
            };
            // COBS may take fewer code bytes than the most it could need.
            assert!(n <= frame_len(payload.len(), parity) && n + 2 >= frame_len(payload.len(), parity));
            assert!(out[..n - 1].iter().all(|&b| b != 0) && out[n - 1] == 0);
            let mut line = [0u8; MAX_FRAME + 4];
            line[..4].copy_from_slice(&[0x55, 0x13, 0x00, 0x00]);
            line[4..4 + n].copy_from_slice(&out[..n]);
            let (got, damage) = frames_of(&line[..4 + n]);
            assert_eq!(got.len(), 1);
            assert_eq!(&got[0][..], payload);
            assert!(damage.is_none());
        }
    }
    let mut out = [0u8; MAX_FRAME];
    assert_eq!(encode_frame(&[0; MAX_PAYLOAD + 1], &mut out), Err(FrameError::TooLong));
    assert_eq!(encode_frame_parity(&[1; 10], 3, &mut out), Err(FrameError::Parity));
    assert_eq!(encode_frame_parity(&[1; 10], 34, &mut out), Err(FrameError::Parity));
    assert_eq!(encode_frame(&[1; 10], &mut out[..10]), Err(FrameError::Buffer));
}

#[test]
fn one_substituted_dropped_or_duplicated_byte_anywhere_is_repaired() {
    let payloads: [&[u8]; 3] = [b"\x01\x00\x10\x00\x00robot map 42\x00", b"0123456789abcdefghij", &[0u8; 9]];
    for payload in payloads {
        for parity in [2, 4] {
            let mut out = [0u8; 64];
            let n = encode_frame_parity(payload, parity, &mut out).unwrap();
            let expect = |bytes: &[u8], what: &str, i: usize| {
                let (got, _) = frames_of(bytes);
                assert_eq!(got.len(), 1, "{what} at {i} (parity {parity}) not repaired");
                assert_eq!(&got[0][..], payload, "{what} at {i} gave a different payload");
            };
            for i in 0..n - 1 {
                for v in [1u8, 0x5A, 0xFF, out[i] ^ 0x80] {
                    let mut bad = out;
                    bad[i] = if v == 0 || v == out[i] { out[i] ^ 1 } else { v };
                    if bad[i] != 0 {
                        expect(&bad[..n], "a substitution", i);
                    }
                }
                let mut drop = [0u8; 64];
                drop[..i].copy_from_slice(&out[..i]);
                drop[i..n - 1].copy_from_slice(&out[i + 1..n]);
                // The header's bytes too: it is read with the edit.
                expect(&drop[..n - 1], "a drop", i);
                let mut dup = [0u8; 65];
                dup[..=i].copy_from_slice(&out[..=i]);
                dup[i + 1..=n].copy_from_slice(&out[i..n]);
                expect(&dup[..=n], "a duplicate", i);
            }
        }
    }
}

/// Applies `k` random substitutions, drops or duplicates (in the header
/// at most one) to `frame`; the damaged bytes in `out`.
fn damage(frame: &[u8], k: usize, st: &mut u64, out: &mut [u8; 400]) -> usize {
    let mut len = frame.len();
    out[..len].copy_from_slice(frame);
    for e in 0..k {
        let skip = if e == 0 { 0 } else { HEADER + 1 };
        let i = skip + (rng(st) % (len - 1 - skip) as u64) as usize;
        match rng(st) % 3 {
            0 => out[i] = 1 + (rng(st) % 255) as u8,
            1 => {
                out.copy_within(i + 1..len, i);
                len -= 1;
            }
            _ => {
                out.copy_within(i..len, i + 1);
                len += 1;
            }
        }
    }
    len
}

#[test]
fn damage_within_the_code_is_repaired_and_beyond_it_never_misread() {
    let mut st = 0x1234_5678_9ABC_DEF0u64;
    let payload: [u8; 60] = core::array::from_fn(|i| (i as u8).wrapping_mul(29) ^ 0x5A);
    let (mut repaired, mut tried) = ([0usize; 5], [0usize; 5]);
    for trial in 0..6000 {
        let parity = [4, 8, 16][trial % 3];
        let k = trial / 3 % 5;
        let mut frame = [0u8; 120];
        let n = encode_frame_parity(&payload, parity, &mut frame).unwrap();
        let mut bad = [0u8; 400];
        let len = damage(&frame[..n], k, &mut st, &mut bad);
        let (got, _) = frames_of(&bad[..len]);
        for g in &got {
            assert_eq!(&g[..], &payload[..], "trial {trial}: a wrong payload");
        }
        tried[k] += 1;
        repaired[k] += got.len();
    }
    // Up to two errors of any kind: always (measured: three, 65%; four,
    // 38%).
    assert_eq!(repaired[..3], tried[..3], "{repaired:?} of {tried:?}");
    assert!(repaired[3] * 2 > tried[3], "{repaired:?} of {tried:?}");
}

#[test]
fn random_bytes_never_make_a_frame() {
    let mut st = 7u64;
    let mut d = Deframer::new();
    let mut frames = 0;
    for _ in 0..200_000 {
        let b = rng(&mut st) as u8;
        // Zeros as often as between frames of 60 bytes.
        let b = if b < 4 { 0 } else { b };
        if let Ok(Some(_)) = d.push(b) {
            frames += 1;
        }
    }
    assert_eq!(frames, 0);
}

#[test]
fn oversized_frames_are_skipped_to_the_next_delimiter() {
    let mut d = Deframer::new();
    let mut errors = 0;
    for _ in 0..MAX_FRAME + 10 {
        if d.push(0x33).is_err() {
            errors += 1;
        }
    }
    assert_eq!(errors, 1);
    assert_eq!(d.push(0), Ok(None));
    let mut out = [0u8; MAX_FRAME];
    let n = encode_frame(b"after", &mut out).unwrap();
    let mut got = None;
    for &b in &out[..n] {
        if let Ok(Some(p)) = d.push(b) {
            got = Some(p.len());
        }
    }
    assert_eq!(got, Some(5));
}
