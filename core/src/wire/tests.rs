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

/// Golden bytes of every message type: a change of the format must be a
/// deliberate change of `message::GOLDEN` (and of `PROTOCOL_VERSION`).
#[test]
fn golden_messages() {
    assert_eq!(super::message::check_golden(), Ok(()));
    assert_eq!(super::message::GOLDEN.len(), 5, "one per message type, both data tags");
    // A framed message: golden too.
    let mut payload = [0u8; 16];
    let ack = super::message::Ack { cum: 300, flags: 0, ..Default::default() };
    let n = Message::Ack(ack).encode(&mut payload).unwrap();
    let mut frame = [0u8; MAX_FRAME];
    let f = encode_frame(&payload[..n], &mut frame).unwrap();
    assert_eq!(&frame[..f], &[194, 2, 13, 104, 99, 44, 1, 2, 2, 49, 128, 150, 243, 109, 244, 217, 218, 0]);
    assert_eq!(
        f - n + super::message::DATA_HEADER,
        super::message::DATA_OVERHEAD + super::frame::DEFAULT_PARITY,
        "frame overhead: CRC, header, delimiter, parity; flags, offset and tag"
    );
}

#[test]
fn bad_messages_are_typed_errors() {
    assert_eq!(Message::decode(&[]), Err(MessageError::Empty));
    assert_eq!(Message::decode(&[1, 4, 7, 1, 0]), Err(MessageError::Version(0)), "a version 1 peer");
    assert_eq!(Message::decode(&[0x23, 7]), Err(MessageError::Version(2)), "a version 2 peer's ack");
    assert_eq!(Message::decode(&[0x21, 7, 0, 1]), Err(MessageError::Version(2)), "a version 2 peer's data");
    assert_eq!(Message::decode(&[0x33, 7]), Err(MessageError::Version(3)), "a version 3 peer's ack");
    assert_eq!(Message::decode(&[0x43, 44, 1, 1]), Err(MessageError::Version(4)), "a version 4 peer's ack");
    assert_eq!(Message::decode(&[0x6F]), Err(MessageError::Malformed), "unknown tag");
    assert_eq!(Message::decode(&[0x53, 44, 1, 1, 9]), Err(MessageError::Version(5)), "a version 5 peer's ack");
    assert_eq!(Message::decode(&[0x61]), Err(MessageError::Malformed), "version 2's data tag");
    assert_eq!(Message::decode(&[0x80]), Err(MessageError::Malformed), "data without its offset");
    assert_eq!(Message::decode(&[0x80, 7]), Err(MessageError::Malformed), "data without its tag");
    assert_eq!(Message::decode(&[0x64, 7, 2, 0]), Err(MessageError::Trailing));
    assert_eq!(Message::decode(&[0x63, 1, 0, 0]), Err(MessageError::Malformed), "an ack without its echo");
    assert_eq!(Message::decode(&[0x63, 1, 0, 0, 0, 5]), Err(MessageError::Malformed), "a sack block cut short");
    assert_eq!(Message::decode(&[0x63, 1, 0, 0, 0, 5, 0]), Err(MessageError::Malformed), "an empty sack block");
    assert_eq!(
        Message::decode(&[0x63, 1, 0, 0, 0, 1, 1, 2, 1, 3, 1, 4, 1]),
        Err(MessageError::Trailing),
        "four blocks"
    );
    assert_eq!(Message::decode(&[0x63, 1, 0, 0, 0, 0x80, 0, 1]), Err(MessageError::Malformed), "non-canonical varint");
    let far = Message::Data { offset: 1 << 14, poll: false, tag: 0, data: &[1] };
    assert_eq!(far.encode(&mut [0u8; 8]), Err(MessageError::Malformed), "an offset beyond 14 bits");
    let nan = Message::Hello(Hello {
        robot_id: 1,
        class_table: 1,
        resolution: f32::NAN,
        max_payload: 512,
        takes_map: true,
        capacity: 10,
        heard: true,
    });
    assert_eq!(nan.encode(&mut [0u8; 32]), Err(MessageError::NonFinite));
    // A NaN smuggled in by hand is refused on decode.
    let mut bytes = [0x60u8, 1, 1, 0, 0, 192, 127, 128, 4, 1, 10, 1];
    assert_eq!(Message::decode(&bytes), Err(MessageError::NonFinite));
    bytes[6] = 0x3F;
    assert!(Message::decode(&bytes).is_ok());
    assert_eq!(Message::Ack(Default::default()).encode(&mut [0u8; 2]), Err(MessageError::Buffer));
    let mut header = [0u8; 64];
    header[..super::message::GOLDEN_HEADER.1.len()].copy_from_slice(super::message::GOLDEN_HEADER.1);
    let n = super::message::GOLDEN_HEADER.1.len();
    assert_eq!(super::message::MapHeader::decode(&header[..n + 1]), Err(MessageError::Trailing));
    header[8..12].copy_from_slice(&f32::INFINITY.to_le_bytes());
    assert_eq!(super::message::MapHeader::decode(&header[..n]), Err(MessageError::NonFinite));
}

/// At least 100,000 random and mutated frames through the deframer and the
/// message decoder: no panic, no hang, and no accepted frame the CRC should
/// have rejected.
#[test]
fn hundred_thousand_frames_without_a_panic() {
    let mut s = 0x2545_F491_4F6C_DD1Du64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let mut d = Deframer::new();
    let mut good = [0u8; MAX_FRAME];
    let mut payload = [0u8; 64];
    let (mut accepted, mut frames) = (0u32, 0u32);
    for i in 0..100_000u32 {
        let len = (next() % 80) as usize;
        let mut bytes = [0u8; 128];
        let n = if i % 2 == 0 {
            // Pure noise, sometimes with a delimiter inside.
            for b in bytes.iter_mut().take(len) {
                *b = next() as u8;
            }
            len
        } else {
            // A valid frame of a valid message, then mutated.
            let p = Message::Data { offset: i as u16, poll: i % 3 == 0, tag: i as u8, data: &payload[..len.min(40)] }
                .encode(&mut payload.clone())
                .unwrap_or(0);
            let m = encode_frame(&payload[..p.min(payload.len())], &mut good).unwrap();
            let m = m.min(bytes.len());
            bytes[..m].copy_from_slice(&good[..m]);
            for _ in 0..(next() % 4) {
                let at = (next() as usize) % m.max(1);
                bytes[at] ^= (next() as u8) | 1;
            }
            m
        };
        frames += 1;
        for &b in &bytes[..n] {
            if let Ok(Some(p)) = d.push(b) {
                accepted += 1;
                let _ = Message::decode(p);
            }
        }
        let _ = d.push(0);
        payload[0] = next() as u8;
    }
    assert!(frames >= 100_000);
    // Unmutated frames (about 1 in 4 of the odd ones) pass; corrupted ones
    // essentially never do.
    assert!(accepted < 30_000, "{accepted}");
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

/// Golden bytes of every feed and robot message.
#[test]
fn golden_feed_messages() {
    assert_eq!(super::feed::check_golden(), Ok(()));
    // One framed: the feeder and the robot put exactly this on the line.
    let mut frame = [0u8; MAX_FRAME];
    let n = super::feed::FeedMessage::EndOfFeed { scans: 5, points: 26_309 }.to_frame(&mut frame).unwrap();
    let (msg, bytes) = &super::feed::GOLDEN_FEED[3];
    assert_eq!(msg, &super::feed::FeedMessage::EndOfFeed { scans: 5, points: 26_309 });
    let mut plain = [0u8; MAX_FRAME];
    let m = encode_frame(bytes, &mut plain).unwrap();
    assert_eq!(&frame[..n], &plain[..m]);
}

/// A set-up whose voxel size is outside the feed's range (or not a
/// number) is refused as such, on encoding and on decoding.
#[test]
fn feed_setup_voxel_size_is_bounded() {
    use super::feed::{FeedError, FeedMessage, Setup};
    let mut buf = [0u8; 64];
    for resolution in [f32::NAN, f32::INFINITY, 0.0, 0.005, 0.015, 10.5, 1e30, -0.5] {
        let msg = FeedMessage::Setup(Setup { robot_id: 0, resolution, prior: None, silence_ms: 1 });
        assert_eq!(msg.encode(&mut buf), Err(FeedError::Resolution), "{resolution}");
    }
    // The golden set-up with its voxel size (bytes 3..7) set to 20 m.
    let mut bytes = super::feed::GOLDEN_FEED[1].1.to_vec();
    bytes[3..7].copy_from_slice(&20.0f32.to_le_bytes());
    assert_eq!(FeedMessage::decode(&bytes), Err(FeedError::Resolution));
}

/// Golden bytes of a codec chunk and of a whole `.cmap` file.
#[test]
fn golden_chunk_and_map_file() {
    use super::mapfile::*;
    let (mut a, mut b) = (crate::test_util::map(8), crate::test_util::map(8));
    assert_eq!(check_golden(&mut a, &mut b), Ok(()));
    assert_eq!(encode_all(&a, 64), vec![GOLDEN_CHUNK.to_vec()]);
    let mut c = crate::test_util::heap_map(8, crate::map::MapConfig::with_resolution(0.5));
    let mut dec = Dec::new(3);
    assert_eq!(dec.decode_chunk(GOLDEN_CHUNK, &mut c), Ok(3));
    for v in a.iter() {
        let w = c.get(v.key).unwrap();
        assert_eq!(w.class(), v.class());
    }
}

/// Every truncation and every single-byte change of a map file is a typed
/// error; truncations say so, with the offset of the part cut.
#[test]
fn map_file_corruptions_are_named() {
    use super::mapfile::*;
    let m = street(60);
    let header = header_of(&m, None, Some("street"));
    let mut bytes = Vec::new();
    let (mut scratch, mut chunk) = (vec![0u32; m.len()], vec![0u8; 256]);
    write(&m, &header, &mut scratch, &mut chunk, |b| {
        bytes.extend_from_slice(b);
        true
    })
    .unwrap();
    let mut back = map(m.len());
    assert_eq!(read_into(&bytes, &mut back).unwrap(), header);
    assert_eq!(back.len(), m.len());
    for cut in 0..bytes.len() {
        match read_into(&bytes[..cut], &mut back) {
            Err(MapFileError::Truncated { .. }) => {}
            Err(MapFileError::Magic) if cut == 0 => {}
            other => panic!("cut at {cut} of {}: {other:?}", bytes.len()),
        }
    }
    for i in 0..bytes.len() {
        let mut b = bytes.clone();
        b[i] ^= 0x5A;
        assert!(read_into(&b, &mut back).is_err(), "flip at {i} accepted");
    }
    // A valid checksum over bad records is still rejected.
    let mut forged = bytes[..bytes.len() - 4].to_vec();
    forged.extend_from_slice(&[0x05, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]);
    let crc = super::crc32(&forged);
    forged.extend_from_slice(&crc.to_le_bytes());
    assert!(matches!(read_into(&forged, &mut back), Err(MapFileError::Chunk { .. })));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Random bytes through the feed decoders and the map-file reader:
    /// typed errors, never a panic (the fuzz targets' property, in the
    /// normal test command).
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400), prefix in 0usize..3) {
        use super::feed::{FeedMessage, RobotMessage};
        let _ = FeedMessage::decode(&bytes);
        let _ = RobotMessage::decode(&bytes);
        let mut with_version = vec![super::feed::FEED_VERSION];
        with_version.extend_from_slice(&bytes);
        let _ = FeedMessage::decode(&with_version);
        let _ = RobotMessage::decode(&with_version);
        // Map files: random, and random after a valid preamble.
        let mut m = map(64);
        let _ = super::mapfile::read_into(&bytes, &mut m);
        let mut file = super::mapfile::GOLDEN_FILE[..10 + 11 * prefix].to_vec();
        file.extend_from_slice(&bytes);
        let _ = super::mapfile::read_into(&file, &mut m);
        prop_assert!(m.len() <= 64);
    }

    /// Random bytes after a block's descriptors (and alone) through the
    /// block deframer: no panic, and no payload but whole frames'.
    #[test]
    fn random_segments_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..1500), cut in 0usize..100) {
        let shape = super::block::BlockShape { segment: 8, parity: 2, spares: 4 };
        let mut line = Vec::new();
        super::block::encode_block(&[7u8; 60], shape, |b: &[u8]| -> Result<(), super::FrameError> {
            line.extend_from_slice(b);
            Ok(())
        }).unwrap();
        line.truncate(2 * super::block::DESCRIPTOR_FRAME + cut);
        line.extend_from_slice(&bytes);
        let mut d = super::block::BlockDeframer::new();
        for &b in &line {
            if let (Ok(Some(f)), _) = d.push(b) {
                prop_assert!(f.payload == [7u8; 60] || f.segments == 0);
            }
        }
    }
}

/// An update's removals are runs of ranks: written and read back in order,
/// refused out of order, and a message whose runs lie is a typed error
/// (never a panic, never ranks past what it holds).
#[test]
fn update_removals_are_runs_of_ranks() {
    use super::update::{write_update, Removed, UpdateError, UpdateHeader, UpdateModel, UpdateView};
    let header = |removals: u32| UpdateHeader {
        epoch: 1,
        base: 4,
        version: 5,
        voxels: 10,
        digest: 0,
        removals,
        upserts: 0,
        changed: 0,
    };
    let unchanged = core::iter::empty();
    let ranks = [0u32, 1, 2, 9, 10, 40, 1000, 1001];
    let mut out = vec![0u8; 256];
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let removed = Removed { cut: None, ranks: ranks.iter().copied(), count: 8 };
    let n = write_update(&header(8), removed, unchanged, none, &mut UpdateModel::new(), &mut out).unwrap();
    // Fixed fields, six varints of a byte, no cut (a byte), 4 runs of 2
    // bytes but the last's gap (959: 2 bytes), the CRC.
    assert_eq!(n, super::update::UPDATE_HEADER + 6 + 1 + 9 + 4);
    let view = UpdateView::parse(&out[..n]).unwrap();
    assert_eq!(view.removed().collect::<Vec<_>>(), ranks);
    assert_eq!(view.cut, None);
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let removed = Removed { cut: None, ranks: [5u32, 3].into_iter(), count: 2 };
    let disorder = write_update(&header(2), removed, core::iter::empty(), none, &mut UpdateModel::new(), &mut out);
    assert_eq!(disorder, Err(UpdateError::Removal));
    // Runs that lie: more removals announced than the runs hold, and a run
    // past u32::MAX (the CRC made to match).
    let forged = |body: &[u8], removals: u8| {
        // Epoch 1, digest 0; base 4, version 5 (a step of 1), 10 voxels.
        let mut bytes = vec![super::update::UPDATE_KIND, 1, 0, 0, 0, 0, 0, 4, 1, 10, removals, 0, 0];
        bytes.push(0); // no cut
        bytes.extend_from_slice(body);
        let crc = super::crc32(&bytes);
        bytes.extend_from_slice(&crc.to_le_bytes());
        UpdateView::parse(&bytes).map(|v| v.removed().count())
    };
    assert_eq!(forged(&[0, 2], 3), Ok(3));
    // A header varint beyond 32 bits, or one that does not end: refused.
    let mut wide = vec![super::update::UPDATE_KIND, 1, 0, 0, 0, 0, 0, 0x80, 0x80, 0x80, 0x80, 0x10, 1, 10, 0, 0, 0, 0];
    let crc = super::crc32(&wide);
    wide.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(UpdateView::parse(&wide).map(|_| ()), Err(UpdateError::Counts));
    let mut endless = vec![super::update::UPDATE_KIND, 1, 0, 0, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF];
    let crc = super::crc32(&endless);
    endless.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(UpdateView::parse(&endless).map(|_| ()), Err(UpdateError::Truncated));
    assert_eq!(forged(&[0, 2], 4), Err(UpdateError::Truncated));
    assert_eq!(forged(&[0, 2], 2), Err(UpdateError::Counts), "a run past the removals announced");
    assert_eq!(forged(&[0xFF, 0xFF, 0xFF, 0xFF, 0x0F, 5], 6), Err(UpdateError::Removal));
}

/// An update's cut names every cell at least its threshold from its centre
/// (in 32nds of a cell, integers: both sides find the same cells); it reads
/// back as written, beside ranks, and a cut that lies (a centre out of
/// range, a threshold longer than any distance, a cut in a snapshot) is a
/// typed error.
#[test]
fn an_update_cut_names_the_far_cells_and_is_checked() {
    use super::update::{write_update, Cut, Removed, UpdateError, UpdateHeader, UpdateModel, UpdateView};
    use crate::map::VoxelKey;
    let cut = Cut { threshold: 1000, ..Cut::about([1.0, -2.0, 0.0], 0.5) };
    assert_eq!(cut.centre, [64, -128, 0]);
    // Cell (2, -4, 0)'s centre is (80, -112, 16): 16 from the centre's on
    // each axis.
    assert_eq!(cut.distance_sq(VoxelKey::new(2, -4, 0)), 3 * 16 * 16);
    assert!(!cut.removes(VoxelKey::new(2, -4, 0)));
    // Cell (7, -4, 0): 176, 16, 16.
    assert_eq!(cut.distance_sq(VoxelKey::new(7, -4, 0)), 176 * 176 + 2 * 16 * 16);
    assert!(cut.removes(VoxelKey::new(7, -4, 0)));
    // Far keys and a centre not finite do not overflow or panic.
    let wild = Cut { threshold: 0, ..Cut::about([f32::NAN, 1e30, -1e30], 0.5) };
    assert_eq!(wild.centre, [0, Cut::MAX_CENTRE, -Cut::MAX_CENTRE]);
    assert!(wild.removes(VoxelKey::new(i16::MIN, i16::MAX, 0)));
    let header = |base: u32| UpdateHeader {
        epoch: 1,
        base,
        version: 5,
        voxels: 10,
        digest: 0,
        removals: 2,
        upserts: 0,
        changed: 0,
    };
    let mut out = vec![0u8; 256];
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let removed = Removed { cut: Some(cut), ranks: [3u32, 4].into_iter(), count: 2 };
    let n = write_update(&header(4), removed, core::iter::empty(), none, &mut UpdateModel::new(), &mut out).unwrap();
    let view = UpdateView::parse(&out[..n]).unwrap();
    assert_eq!(view.cut, Some(cut));
    assert_eq!(view.removed().collect::<Vec<_>>(), [3, 4]);
    // Forged: the cut's bytes as given (the CRC made to match).
    let forged = |cut: &[u8], base: u8| {
        // Epoch 1, digest 0; the base, version 5, 10 voxels, nothing else.
        let mut bytes = vec![super::update::UPDATE_KIND, 1, 0, 0, 0, 0, 0, base, 5 - base, 10, 0, 0, 0];
        bytes.extend_from_slice(cut);
        let crc = super::crc32(&bytes);
        bytes.extend_from_slice(&crc.to_le_bytes());
        UpdateView::parse(&bytes).map(|v| v.cut)
    };
    // 1001 (the threshold + 1), then 64, -128 and 0 zigzagged.
    let good = [0xE9, 0x07, 0x80, 0x01, 0xFF, 0x01, 0];
    assert_eq!(forged(&good, 4), Ok(Some(cut)));
    // A centre of 2^23: past the largest.
    assert_eq!(forged(&[0xE9, 0x07, 0x80, 0x80, 0x80, 0x08, 0, 0], 4), Err(UpdateError::Counts));
    let endless = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x01, 0, 0, 0];
    assert_eq!(forged(&endless, 4), Err(UpdateError::Counts), "a threshold past any distance");
    assert_eq!(forged(&good[..6], 4), Err(UpdateError::Counts), "a centre cut short");
    assert_eq!(forged(&good, 0), Err(UpdateError::Counts), "a snapshot has nothing to cut");
}

/// An update's changed voxels: each named by its rank in the base map and
/// coded against the record held there, read back exactly (ranks and
/// records); ranks out of order are refused when writing, and a section
/// that names a rank the base does not hold, or is cut short, is a typed
/// error, never a panic.
#[test]
fn update_changes_are_ranks_and_records_against_the_held_ones() {
    use super::update::{write_update, ChangeSink, Removed, UpdateError, UpdateHeader, UpdateModel, UpdateView};
    // A base of 40 cells, rank k holding a record of its own.
    let record =
        |class: u32, confidence: u32, p: [u32; 3]| class | confidence << 5 | p[0] << 10 | p[1] << 14 | p[2] << 18;
    let held: Vec<u32> = (0..40u32).map(|k| record(k % 19, k % 8, [k % 4, (k / 4) % 4, 1])).collect();
    struct Copy(Vec<u32>, Vec<(u32, u32)>);
    impl ChangeSink for Copy {
        fn held(&mut self, rank: u32) -> Option<u32> {
            self.0.get(rank as usize).copied()
        }
        fn change(&mut self, rank: u32, _held: u32, record: u32) -> Result<(), super::DecodeError> {
            self.1.push((rank, record));
            Ok(())
        }
    }
    // Confidence up two levels, a class changed (and to none: 31), a mean
    // moved across the cell.
    let changes = [
        (0u32, held[0], record(0, 2, [0, 0, 1])),
        (7, held[7], record(12, 7, [3, 1, 1])),
        (8, held[8], record(31, 0, [0, 2, 1])),
        (39, held[39], record(1, 7, [0, 1, 1])),
    ];
    let header =
        UpdateHeader { epoch: 1, base: 4, version: 5, voxels: 40, digest: 0, removals: 0, upserts: 0, changed: 4 };
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let removed = Removed { cut: None, ranks: core::iter::empty(), count: 0 };
    let mut out = vec![0u8; 256];
    let (mut sent, mut got) = (UpdateModel::new(), UpdateModel::new());
    let n = write_update(&header, removed, changes.iter().copied(), none, &mut sent, &mut out).unwrap();
    let view = UpdateView::parse(&out[..n]).unwrap();
    let mut copy = Copy(held.clone(), Vec::new());
    view.decode_changes(&mut got.changes, &mut copy).unwrap();
    assert_eq!(copy.1, changes.iter().map(|&(r, _, now)| (r, now)).collect::<Vec<_>>());
    // Out of order: refused when writing.
    let removed = Removed { cut: None, ranks: core::iter::empty(), count: 0 };
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let disorder = [changes[1], changes[0], changes[2], changes[3]];
    let mut m = UpdateModel::new();
    let mut other = vec![0u8; 256];
    let r = write_update(&header, removed, disorder.into_iter(), none, &mut m, &mut other);
    assert_eq!(r, Err(UpdateError::Changed));
    // A base that holds fewer cells than a rank named: a typed error.
    let mut short = Copy(held[..20].to_vec(), Vec::new());
    let r = view.decode_changes(&mut UpdateModel::new().changes, &mut short);
    assert_eq!(r, Err(UpdateError::Changed));
    // Every byte of the section changed in turn (the CRC made to match):
    // an error or some records, never a panic; cut short: an error.
    // The section's length after the fixed fields, six varints of a byte
    // and the cut's byte.
    let at = super::update::UPDATE_HEADER + 6 + 1;
    for i in at..n - 4 {
        for b in [0u8, 0x55, 0xFF] {
            let mut forged = out[..n].to_vec();
            forged[i] = b;
            let crc = super::crc32(&forged[..n - 4]);
            forged[n - 4..].copy_from_slice(&crc.to_le_bytes());
            if let Ok(v) = UpdateView::parse(&forged) {
                let _ = v.decode_changes(&mut UpdateModel::new().changes, &mut Copy(held.clone(), Vec::new()));
            }
        }
    }
    let mut cut_short = out[..n].to_vec();
    cut_short[at] -= 1;
    cut_short.truncate(n - 5);
    let crc = super::crc32(&cut_short);
    cut_short.extend_from_slice(&crc.to_le_bytes());
    assert!(
        UpdateView::parse(&cut_short).is_err() || {
            let v = UpdateView::parse(&cut_short).unwrap();
            v.decode_changes(&mut UpdateModel::new().changes, &mut Copy(held.clone(), Vec::new())).is_err()
        }
    );
}
