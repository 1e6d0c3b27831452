//! Wire tests: the messages (golden bytes, typed errors, random and
//! mutated frames), the feed's and the map file's.

use super::*;

/// Golden bytes of every message type: a change of the format must be a
/// deliberate change of `message::GOLDEN` (and of `PROTOCOL_VERSION`).
#[test]
fn golden_messages() {
    assert_eq!(crate::wire::message::check_golden(), Ok(()));
    assert_eq!(crate::wire::message::GOLDEN.len(), 5, "one per message type, both data tags");
    // A framed message: golden too.
    let mut payload = [0u8; 16];
    let ack = crate::wire::message::Ack { cum: 300, flags: 0, ..Default::default() };
    let n = Message::Ack(ack).encode(&mut payload).unwrap();
    let mut frame = [0u8; MAX_FRAME];
    let f = encode_frame(&payload[..n], &mut frame).unwrap();
    assert_eq!(&frame[..f], &[194, 2, 13, 104, 99, 44, 1, 2, 2, 49, 128, 150, 243, 109, 244, 217, 218, 0]);
    assert_eq!(
        f - n + crate::wire::message::DATA_HEADER,
        crate::wire::message::DATA_OVERHEAD + crate::wire::frame::DEFAULT_PARITY,
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
    header[..crate::wire::message::GOLDEN_HEADER.1.len()].copy_from_slice(crate::wire::message::GOLDEN_HEADER.1);
    let n = crate::wire::message::GOLDEN_HEADER.1.len();
    assert_eq!(crate::wire::message::MapHeader::decode(&header[..n + 1]), Err(MessageError::Trailing));
    header[8..12].copy_from_slice(&f32::INFINITY.to_le_bytes());
    assert_eq!(crate::wire::message::MapHeader::decode(&header[..n]), Err(MessageError::NonFinite));
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

/// Golden bytes of every feed and robot message.
#[test]
fn golden_feed_messages() {
    assert_eq!(crate::wire::feed::check_golden(), Ok(()));
    // One framed: the feeder and the robot put exactly this on the line.
    let mut frame = [0u8; MAX_FRAME];
    let n = crate::wire::feed::FeedMessage::EndOfFeed { scans: 5, points: 26_309 }.to_frame(&mut frame).unwrap();
    let (msg, bytes) = &crate::wire::feed::GOLDEN_FEED[3];
    assert_eq!(msg, &crate::wire::feed::FeedMessage::EndOfFeed { scans: 5, points: 26_309 });
    let mut plain = [0u8; MAX_FRAME];
    let m = encode_frame(bytes, &mut plain).unwrap();
    assert_eq!(&frame[..n], &plain[..m]);
}

/// A set-up whose voxel size is outside the feed's range (or not a
/// number) is refused as such, on encoding and on decoding.
#[test]
fn feed_setup_voxel_size_is_bounded() {
    use crate::wire::feed::{FeedError, FeedMessage, Setup};
    let mut buf = [0u8; 64];
    for resolution in [f32::NAN, f32::INFINITY, 0.0, 0.005, 0.015, 10.5, 1e30, -0.5] {
        let msg = FeedMessage::Setup(Setup { robot_id: 0, resolution, prior: None, silence_ms: 1 });
        assert_eq!(msg.encode(&mut buf), Err(FeedError::Resolution), "{resolution}");
    }
    // The golden set-up with its voxel size (bytes 3..7) set to 20 m.
    let mut bytes = crate::wire::feed::GOLDEN_FEED[1].1.to_vec();
    bytes[3..7].copy_from_slice(&20.0f32.to_le_bytes());
    assert_eq!(FeedMessage::decode(&bytes), Err(FeedError::Resolution));
}

/// Golden bytes of a codec chunk and of a whole `.cmap` file.
#[test]
fn golden_chunk_and_map_file() {
    use crate::wire::mapfile::*;
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
    use crate::wire::mapfile::*;
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
    let crc = crate::wire::crc32(&forged);
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
        use crate::wire::feed::{FeedMessage, RobotMessage};
        let _ = FeedMessage::decode(&bytes);
        let _ = RobotMessage::decode(&bytes);
        let mut with_version = vec![crate::wire::feed::FEED_VERSION];
        with_version.extend_from_slice(&bytes);
        let _ = FeedMessage::decode(&with_version);
        let _ = RobotMessage::decode(&with_version);
        // Map files: random, and random after a valid preamble.
        let mut m = map(64);
        let _ = crate::wire::mapfile::read_into(&bytes, &mut m);
        let mut file = crate::wire::mapfile::GOLDEN_FILE[..10 + 11 * prefix].to_vec();
        file.extend_from_slice(&bytes);
        let _ = crate::wire::mapfile::read_into(&file, &mut m);
        prop_assert!(m.len() <= 64);
    }

    /// Random bytes after a block's descriptors (and alone) through the
    /// block deframer: no panic, and no payload but whole frames'.
    #[test]
    fn random_segments_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..1500), cut in 0usize..100) {
        let shape = crate::wire::block::BlockShape { segment: 8, parity: 2, spares: 4 };
        let mut line = Vec::new();
        crate::wire::block::encode_block(&[7u8; 60], shape, |b: &[u8]| -> Result<(), crate::wire::FrameError> {
            line.extend_from_slice(b);
            Ok(())
        }).unwrap();
        line.truncate(2 * crate::wire::block::DESCRIPTOR_FRAME + cut);
        line.extend_from_slice(&bytes);
        let mut d = crate::wire::block::BlockDeframer::new();
        for &b in &line {
            if let (Ok(Some(f)), _) = d.push(b) {
                prop_assert!(f.payload == [7u8; 60] || f.segments == 0);
            }
        }
    }
}
