//! Wire tests: the voxel codec.

use super::codec::*;
use super::frame::*;
use super::message::*;
use crate::classes::Class;
use crate::map::{LocalMap, VoxelKey};
use crate::test_util::{map, Heap};
use proptest::prelude::*;
use std::vec;

/// An encoder with its own codec model.
struct Enc<'a> {
    e: MapEncoder<'a, Heap>,
    m: std::boxed::Box<CodecModel>,
}

impl<'a> Enc<'a> {
    fn new(map: &'a LocalMap<Heap>, scratch: &'a mut [u32]) -> Result<Self, EncodeError> {
        let mut m = std::boxed::Box::new(CodecModel::new());
        Ok(Enc { e: MapEncoder::new(map, scratch, &mut m)?, m })
    }
    fn next_chunk(&mut self, out: &mut [u8]) -> Result<usize, EncodeError> {
        self.e.next_chunk(&mut self.m, out)
    }
    fn digest(&self) -> u32 {
        self.e.digest()
    }
}

/// A decoder with its own codec model.
struct Dec {
    d: MapDecoder,
    m: std::boxed::Box<CodecModel>,
}

impl Dec {
    fn new(voxels: usize) -> Self {
        let mut m = std::boxed::Box::new(CodecModel::new());
        Dec { d: MapDecoder::new(voxels, &mut m), m }
    }
    fn decode_chunk(&mut self, chunk: &[u8], map: &mut LocalMap<Heap>) -> Result<usize, DecodeError> {
        self.d.decode_chunk(&mut self.m, chunk, map)
    }
    fn is_complete(&self) -> bool {
        self.d.is_complete()
    }
    fn decoded(&self) -> usize {
        self.d.decoded()
    }
    fn digest(&self) -> u32 {
        self.d.digest()
    }
}
use std::vec::Vec;

/// Encodes a whole map into chunks of at most `chunk` bytes.
fn encode_all(m: &LocalMap<Heap>, chunk: usize) -> Vec<Vec<u8>> {
    let mut scratch = vec![0u32; m.len()];
    let mut enc = Enc::new(m, &mut scratch).unwrap();
    let mut out = Vec::new();
    let mut buf = vec![0u8; chunk];
    loop {
        let n = enc.next_chunk(&mut buf).unwrap();
        if n == 0 {
            break;
        }
        assert!(n <= chunk);
        out.push(buf[..n].to_vec());
    }
    out
}

fn decode_all(chunks: &[Vec<u8>], voxels: usize) -> Result<LocalMap<Heap>, DecodeError> {
    let mut m = map(voxels);
    let mut dec = Dec::new(voxels);
    for c in chunks {
        dec.decode_chunk(c, &mut m)?;
    }
    assert!(dec.is_complete());
    Ok(m)
}

/// A patch of street: a gently curved road surface, a wall and poles,
/// sampled densely as a LiDAR would (about `n` * 10 voxels).
fn street(n: usize) -> LocalMap<Heap> {
    let mut m = map(40 * n);
    for i in 0..n {
        let x = i as f32 * 0.2;
        for j in 0..8 {
            let y = j as f32 * 0.2 - 0.8;
            m.insert_point([x, y, 0.05 * (x * 0.3).sin()], if j < 6 { Class::Road } else { Class::Sidewalk }).unwrap();
        }
        m.insert_point([x, 4.0, 0.5], Class::Building).unwrap();
        m.insert_point([x, 4.0, 0.7], Class::Building).unwrap();
        if i % 17 == 0 {
            for k in 0..10 {
                m.insert_point([x, 2.0, k as f32 * 0.2], Class::Pole).unwrap();
            }
        }
    }
    m
}

#[test]
fn morton_round_trips_and_orders() {
    for k in [VoxelKey::new(0, 0, 0), VoxelKey::new(-1, 2, -3), VoxelKey::new(i16::MIN, i16::MAX, 77)] {
        assert_eq!(key_of(morton(k)), Some(k));
    }
    assert!(morton(VoxelKey::new(-1, 0, 0)) < morton(VoxelKey::new(0, 0, 0)));
    assert_eq!(morton(VoxelKey::new(1, 0, 0)) - morton(VoxelKey::new(0, 0, 0)), 1);
    assert_eq!(key_of(1 << 48), None);
}

/// The stream order is the Morton order of the keys, whether the scratch
/// has the room to sort each index beside its code (two words a voxel) or
/// not; a subset with an index twice is refused either way.
#[test]
fn the_stream_order_is_the_same_with_or_without_room_beside_it() {
    let mut m = street(300);
    for p in [[-40.0, -3.0, -2.0], [-0.1, 7.5, 1.0], [55.0, -60.0, 9.0]] {
        m.insert_point(p, Class::Car).unwrap();
    }
    let n = m.len();
    let (mut narrow, mut wide) = (vec![0u32; n], vec![0u32; 2 * n + 5]);
    let slow = stream_order(&m, &mut narrow).unwrap().to_vec();
    let fast = stream_order(&m, &mut wide).unwrap().to_vec();
    assert_eq!(slow, fast);
    let codes: Vec<u64> = fast.iter().map(|&i| morton(m.voxel(i as usize).unwrap().key)).collect();
    assert!(codes.windows(2).all(|w| w[0] < w[1]), "not in Morton order");
    let mut model = CodecModel::new();
    let pick = |s: &mut [u32]| {
        for (k, w) in s.iter_mut().take(60).enumerate() {
            *w = (n - 1 - 7 * k) as u32;
        }
    };
    let (mut a, mut b) = (vec![0u32; 60], vec![0u32; 120]);
    pick(&mut a);
    pick(&mut b);
    let ea = MapEncoder::subset(&m, &mut a, 60, &mut model).unwrap().order().to_vec();
    let eb = MapEncoder::subset(&m, &mut b, 60, &mut model).unwrap().order().to_vec();
    assert_eq!(ea, eb);
    b[..60].copy_from_slice(&ea);
    b[59] = b[3];
    assert!(MapEncoder::subset(&m, &mut b, 60, &mut model).is_err(), "an index twice");
}

/// An update's digest: the same hash of a voxel on every platform (golden
/// values), summed in any order, every voxel's record in it.
#[test]
fn an_update_digest_is_a_sum_of_voxel_hashes() {
    use super::update::{digest_of, voxel_hash};
    assert_eq!(
        [voxel_hash(0, 0), voxel_hash(1, 0), voxel_hash(0, 1), voxel_hash(0xABCD_1234_5678, 0x2A_5F3C)],
        [GOLDEN_HASHES[0], GOLDEN_HASHES[1], GOLDEN_HASHES[2], GOLDEN_HASHES[3]]
    );
    let m = street(100);
    let recs: Vec<(u64, u32)> = m.iter().map(|v| (morton(v.key), voxel_record(v))).collect();
    let forward = digest_of(recs.iter().copied());
    assert_eq!(forward, digest_of(recs.iter().rev().copied()));
    assert_eq!(digest_of(core::iter::empty()), 0);
    let mut other = recs.clone();
    other[7].1 ^= 1 << 10;
    assert_ne!(forward, digest_of(other.iter().copied()), "a record changed");
    assert_ne!(forward, digest_of(recs.iter().skip(1).copied()), "a voxel missing");
}

/// `voxel_hash` of (0, 0), (1, 0), (0, 1) and (0xABCD_1234_5678, 0x2A_5F3C).
const GOLDEN_HASHES: [u32; 4] = [1_129_584_368, 232_706_675, 3_424_891_686, 1_229_442_652];

#[test]
fn round_trip_is_lossy_but_idempotent() {
    let m = street(500);
    let chunks = encode_all(&m, 256);
    let d = decode_all(&chunks, m.len()).unwrap();
    assert_eq!(d.len(), m.len());
    for v in m.iter() {
        let w = d.get(v.key).unwrap();
        assert_eq!(w.class(), v.class());
        for (a, b) in v.position(0.2).iter().zip(w.position(0.2)) {
            // Half a step of the position's precision.
            let half = 0.2 / (1u32 << (POSITION_BITS + 1)) as f32;
            assert!((a - b).abs() <= half + 1e-4, "{a} {b}");
        }
    }
    // Decoded maps encode to the same bytes, whatever the chunk size.
    assert_eq!(encode_all(&d, 256), chunks);
    let big: Vec<u8> = encode_all(&m, 1 << 16).concat();
    let again: Vec<u8> = encode_all(&decode_all(&encode_all(&m, 1 << 16), m.len()).unwrap(), 1 << 16).concat();
    assert_eq!(big, again);
    let bytes: usize = chunks.iter().map(Vec::len).sum();
    assert!((bytes as f64 / m.len() as f64) < 2.5, "{} bytes/voxel", bytes as f64 / m.len() as f64);
}

#[test]
fn decoder_rejects_disorder_duplicates_and_overruns() {
    let m = street(100);
    let chunks = encode_all(&m, 64);
    assert!(chunks.len() > 3);
    // Chunks continue from the previous one: a replayed chunk decodes to
    // other keys, which the map digest exposes (the link also numbers chunks).
    let mut scratch = vec![0u32; m.len()];
    let digest = Enc::new(&m, &mut scratch).unwrap().digest();
    let mut target = map(m.len() * 2);
    let mut dec = Dec::new(m.len() * 2);
    dec.decode_chunk(&chunks[0], &mut target).unwrap();
    let _ = dec.decode_chunk(&chunks[0], &mut target);
    for c in &chunks[1..] {
        let _ = dec.decode_chunk(c, &mut target);
    }
    assert_ne!(dec.digest(), digest);
    // More voxels than announced.
    let mut dec = Dec::new(1);
    assert_eq!(dec.decode_chunk(&chunks[0], &mut map(10)), Err(DecodeError::TooMany));
    // A full map.
    let mut dec = Dec::new(m.len());
    let mut small = map(3);
    assert_eq!(dec.decode_chunk(&chunks[0], &mut small), Err(DecodeError::Full));
    // Empty and trailing.
    assert_eq!(Dec::new(9).decode_chunk(&[0], &mut map(9)), Err(DecodeError::Empty));
    let mut long = chunks[0].clone();
    long.push(0);
    assert_eq!(Dec::new(m.len()).decode_chunk(&long, &mut map(m.len())), Err(DecodeError::Trailing));
    let short = &chunks[0][..chunks[0].len() - 1];
    assert_eq!(Dec::new(m.len()).decode_chunk(short, &mut map(m.len())), Err(DecodeError::Truncated));
    assert_eq!(Dec::new(m.len()).decode_chunk(&[0x80; 9], &mut map(9)), Err(DecodeError::Varint));
}

#[test]
fn digest_is_independent_of_chunking() {
    let m = street(200);
    let mut scratch = vec![0u32; m.len()];
    let digest = Enc::new(&m, &mut scratch).unwrap().digest();
    for chunk in [MIN_CHUNK, 100, 4096] {
        let chunks = encode_all(&m, chunk);
        let mut d = map(m.len());
        let mut dec = Dec::new(m.len());
        for c in &chunks {
            dec.decode_chunk(c, &mut d).unwrap();
        }
        assert_eq!(dec.digest(), digest, "chunk size {chunk}");
    }
    // A different map has a different digest.
    let other = street(201);
    let mut scratch = vec![0u32; other.len()];
    assert_ne!(Enc::new(&other, &mut scratch).unwrap().digest(), digest);
}

#[test]
fn encoder_needs_room() {
    let m = street(10);
    let mut scratch = vec![0u32; 2];
    assert!(matches!(Enc::new(&m, &mut scratch), Err(EncodeError::Scratch)));
    let mut scratch = vec![0u32; m.len()];
    let mut enc = Enc::new(&m, &mut scratch).unwrap();
    assert_eq!(enc.next_chunk(&mut [0u8; MIN_CHUNK - 1]), Err(EncodeError::Buffer));
    assert!(enc.next_chunk(&mut [0u8; MIN_CHUNK]).unwrap() > 0);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Any map round-trips, idempotently, with any chunk size.
    #[test]
    fn any_map_round_trips(
        points in prop::collection::vec(([-300.0f32..300.0, -300.0f32..300.0, -20.0f32..20.0], 0u8..19), 1..300),
        chunk in MIN_CHUNK..400usize,
    ) {
        let mut m = map(points.len());
        for (p, c) in &points {
            m.insert_point(*p, Class::from_index(*c).unwrap()).unwrap();
        }
        let chunks = encode_all(&m, chunk);
        let d = decode_all(&chunks, m.len()).unwrap();
        prop_assert_eq!(d.len(), m.len());
        prop_assert_eq!(encode_all(&d, chunk), chunks);
    }

    /// Arbitrary and mutated chunks never panic; the decoder only errors or
    /// inserts voxels it could account for.
    #[test]
    fn garbage_never_panics(
        bytes in prop::collection::vec(any::<u8>(), 0..200),
        flips in prop::collection::vec((any::<usize>(), any::<u8>()), 0..8),
    ) {
        let mut m = map(64);
        let _ = Dec::new(64).decode_chunk(&bytes, &mut m);
        prop_assert!(m.len() <= 64);
        let good = encode_all(&street(40), 300);
        let mut c = good[0].clone();
        for (i, x) in flips {
            let n = c.len();
            c[i % n] ^= x;
        }
        let mut m = map(500);
        let mut dec = Dec::new(500);
        if dec.decode_chunk(&c, &mut m).is_ok() {
            prop_assert_eq!(m.len(), dec.decoded());
        }
    }
}

mod messages;
mod update;
