//! A seeded lossy-line simulation of the link.

use super::*;
use crate::link::LinkBuffers;
use crate::sim;

/// Link buffers for one endpoint of a test (leaked: a test's lifetime).
fn bufs() -> &'static mut LinkBuffers {
    std::boxed::Box::leak(std::boxed::Box::new(LinkBuffers::new()))
}
use crate::classes::Class;
use crate::map::{LocalMap, VoxelSink, VoxelStorage};
use crate::test_util::{map, Heap};
use crate::wire::codec::map_digest;
use core::cell::RefCell;
use std::vec;

/// A few hundred voxels: a road patch, a wall, a pole.
fn small_map(seed: u32) -> LocalMap<Heap> {
    let mut m = map(600);
    let o = (seed % 7) as f32 * 0.2;
    for i in 0..20 {
        for j in 0..10 {
            m.insert_point([o + i as f32 * 0.2, j as f32 * 0.2, 0.0], Class::Road).unwrap();
        }
        for k in 0..6 {
            m.insert_point([o + i as f32 * 0.2, 3.0, k as f32 * 0.2], Class::Building).unwrap();
        }
    }
    for k in 0..15 {
        m.insert_point([1.0, 1.5, k as f32 * 0.2], Class::Pole).unwrap();
    }
    m
}

/// A line of 64 KiB buffers at 115200 baud (11.52 bytes per millisecond).
type Line = sim::SimLine<65536>;

fn line(seed: u64, error_rate: f64, stall_chance: f64) -> std::boxed::Box<RefCell<Line>> {
    std::boxed::Box::new(RefCell::new(Line::new(sim::SimConfig {
        seed,
        error_rate,
        stall_chance,
        bytes_per_ms: 11.52,
        half_duplex: false,
        mix: sim::Mix::THIRDS,
        send_buffer: 16,
    })))
}

type Port<'a> = sim::SimPort<'a, 65536>;

/// Steps both endpoints once per simulated millisecond until both are over
/// (or `limit` ms): what each ended with.
fn drive<A: VoxelStorage, B: VoxelSink, C: VoxelStorage, D: VoxelSink>(
    wire: &RefCell<Line>,
    (e0, p0): (&mut Endpoint<'_, A, B>, &mut Port<'_>),
    (e1, p1): (&mut Endpoint<'_, C, D>, &mut Port<'_>),
    limit: u64,
) -> (Result<Progress, LinkError>, Result<Progress, LinkError>) {
    let (mut r0, mut r1) = (Ok(Progress::Busy), Ok(Progress::Busy));
    for now in 0..limit {
        wire.borrow_mut().tick(now);
        if r0 == Ok(Progress::Busy) {
            r0 = e0.step(p0, now);
        }
        if r1 == Ok(Progress::Busy) {
            r1 = e1.step(p1, now);
        }
        if r0 != Ok(Progress::Busy) && r1 != Ok(Progress::Busy) {
            break;
        }
    }
    (r0, r1)
}

#[derive(Debug, PartialEq)]
enum Outcome {
    Delivered,
    Failed(LinkError),
    Corrupted,
}

/// One transfer of a small map from A to B; returns what B ended with and
/// A's retransmissions.
fn transfer(seed: u64, error_rate: f64, stall_chance: f64) -> (Outcome, u32, u64) {
    let sent = small_map(seed as u32);
    // What B should end with: the map as the encoding carries it.
    let mut scratch_ref = vec![0u32; sent.len()];
    let digest = map_digest(&sent, &mut scratch_ref).unwrap();
    let mut scratch = vec![0u32; sent.len()];
    let mut staging = map(1000);
    let wire = line(seed, error_rate, stall_chance);
    let (mut pa, mut pb) = Line::ports(&wire);
    let config = LinkConfig::default();
    let mut a =
        Endpoint::<Heap, LocalMap<Heap>>::new(config, 0, seed as u32, 0, Some((&sent, &mut scratch)), None, bufs())
            .unwrap();
    let mut b = Endpoint::<Heap, LocalMap<Heap>>::new(config, 1, 0, 0, None, Some(&mut staging), bufs()).unwrap();
    let (_, rb) = drive(&wire, (&mut a, &mut pa), (&mut b, &mut pb), 2_000_000);
    let retrans = a.stats().retransmissions;
    let received = b.received();
    let bytes = a.stats().bytes_sent + b.stats().bytes_sent;
    let outcome = match rb {
        Ok(Progress::Done) if received => {
            // Delivered: it must be exactly what was sent.
            let mut s2 = vec![0u32; staging.len()];
            let got = map_digest(&staging, &mut s2).unwrap();
            if got == digest && staging.len() == sent.len() {
                Outcome::Delivered
            } else {
                Outcome::Corrupted
            }
        }
        Err(e) => Outcome::Failed(e),
        _ => Outcome::Failed(LinkError::Silent),
    };
    (outcome, retrans, bytes)
}

fn run(rate: f64, stalls: f64, n: u64) -> (usize, usize, f64) {
    let (mut delivered, mut corrupted, mut retrans) = (0, 0, 0u64);
    for seed in 1..=n {
        let (o, r, _) = transfer(seed, rate, stalls);
        match o {
            Outcome::Delivered => delivered += 1,
            Outcome::Corrupted => corrupted += 1,
            Outcome::Failed(_) => {}
        }
        retrans += u64::from(r);
    }
    std::println!(
        "byte error rate {:.1}%: {delivered}/{n} delivered, {corrupted} corrupted, {:.2} retransmissions per transfer",
        rate * 100.0,
        retrans as f64 / n as f64
    );
    (delivered, corrupted, retrans as f64 / n as f64)
}

#[test]
fn clean_line_delivers_without_retransmission() {
    let (o, r, bytes) = transfer(1, 0.0, 0.0);
    assert_eq!(o, Outcome::Delivered);
    assert_eq!(r, 0);
    assert!(bytes > 0);
}

#[test]
fn thousand_transfers_at_low_error_rates_all_arrive() {
    for rate in [0.001, 0.01] {
        let (delivered, corrupted, _) = run(rate, 0.0005, 1000);
        assert_eq!(corrupted, 0);
        assert_eq!(delivered, 1000, "at {rate}");
    }
}

#[test]
fn thousand_transfers_at_five_percent_mostly_arrive_and_never_corrupt() {
    let (delivered, corrupted, _) = run(0.05, 0.0005, 1000);
    assert_eq!(corrupted, 0);
    assert_eq!(delivered, 1000);
}

#[test]
fn silent_peer_is_a_typed_error_in_bounded_time() {
    let sent = small_map(1);
    let mut scratch = vec![0u32; sent.len()];
    let wire = line(3, 0.0, 0.0);
    let (mut pa, _pb) = Line::ports(&wire);
    let config = LinkConfig::default();
    let mut a =
        Endpoint::<Heap, LocalMap<Heap>>::new(config, 0, 1, 0, Some((&sent, &mut scratch)), None, bufs()).unwrap();
    let mut result = Ok(Progress::Busy);
    let mut when = 0;
    for now in 0..200_000u64 {
        result = a.step(&mut pa, now);
        if result != Ok(Progress::Busy) {
            when = now;
            break;
        }
    }
    assert!(matches!(result, Err(LinkError::GaveUp { seq: 0 }) | Err(LinkError::Silent)), "{result:?}");
    assert!(when <= u64::from(config.silence_ms) + 1, "{when}");
}

/// The keys of `map`'s `most` voxels nearest its anchor (the origin of the
/// test maps, which reject when full: the middle of their bounds).
fn nearest_keys(map: &LocalMap<Heap>, most: usize) -> std::vec::Vec<crate::map::VoxelKey> {
    let (lo, hi) = map.bounds().unwrap();
    let centre = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
    assert_eq!(map.keep_centre(), centre, "a map with no anchor keeps around its middle");
    let mut idx = vec![0u32; map.len()];
    let n = map.nearest(centre, most, &mut idx);
    let mut keys: std::vec::Vec<_> = idx[..n].iter().map(|&i| map.voxel(i as usize).unwrap().key).collect();
    keys.sort_by_key(|k| (k.x, k.y, k.z));
    keys
}

/// A peer that holds less than our map (its `Hello` says how much) gets
/// the part that fits: as many voxels as it holds, those nearest the
/// map's anchor, whole and digest-checked, on a clean line and a lossy one.
#[test]
fn a_map_larger_than_the_peer_holds_goes_as_its_nearest_part() {
    let sent = small_map(1);
    for (seed, errors) in [(5, 0.0), (6, 0.02)] {
        let mut scratch = vec![0u32; sent.len()];
        let mut tiny = map(40);
        {
            let wire = line(seed, errors, 0.0);
            let (mut pa, mut pb) = Line::ports(&wire);
            let config = LinkConfig::default();
            let mut a =
                Endpoint::<Heap, LocalMap<Heap>>::new(config, 0, 1, 0, Some((&sent, &mut scratch)), None, bufs())
                    .unwrap();
            let mut b = Endpoint::<Heap, LocalMap<Heap>>::new(config, 1, 0, 0, None, Some(&mut tiny), bufs()).unwrap();
            let (ra, rb) = drive(&wire, (&mut a, &mut pa), (&mut b, &mut pb), 200_000);
            assert_eq!((ra, rb), (Ok(Progress::Done), Ok(Progress::Done)), "error rate {errors}");
            assert!(b.received() && a.sent());
        }
        assert_eq!(tiny.len(), 40);
        let mut got: std::vec::Vec<_> = tiny.iter().map(|v| v.key).collect();
        got.sort_by_key(|k| (k.x, k.y, k.z));
        assert_eq!(got, nearest_keys(&sent, 40));
    }
}

#[test]
fn both_ways_at_once() {
    let (m0, m1) = (small_map(2), small_map(5));
    let (mut s0, mut s1) = (vec![0u32; m0.len()], vec![0u32; m1.len()]);
    let (mut st0, mut st1) = (map(1000), map(1000));
    let wire = line(9, 0.01, 0.0);
    let (mut p0, mut p1) = Line::ports(&wire);
    let config = LinkConfig::default();
    let mut e0 = Endpoint::new(config, 0, 100, 0, Some((&m0, &mut s0)), Some(&mut st0), bufs()).unwrap();
    let mut e1 = Endpoint::new(config, 1, 200, 0, Some((&m1, &mut s1)), Some(&mut st1), bufs()).unwrap();
    let (r0, r1) = drive(&wire, (&mut e0, &mut p0), (&mut e1, &mut p1), 100_000);
    assert_eq!((r0, r1), (Ok(Progress::Done), Ok(Progress::Done)));
    assert_eq!(st0.len(), m1.len());
    assert_eq!(st1.len(), m0.len());
}

#[test]
fn half_duplex_line_takes_turns_without_collisions() {
    let (m0, m1) = (small_map(3), small_map(4));
    let (mut s0, mut s1) = (vec![0u32; m0.len()], vec![0u32; m1.len()]);
    let (mut st0, mut st1) = (map(1000), map(1000));
    let wire = std::boxed::Box::new(RefCell::new(Line::new(sim::SimConfig {
        seed: 11,
        error_rate: 0.001,
        stall_chance: 0.0,
        bytes_per_ms: 11.52,
        half_duplex: true,
        mix: sim::Mix::THIRDS,
        send_buffer: 16,
    })));
    let (mut p0, mut p1) = Line::ports(&wire);
    let config = LinkConfig { half_duplex: true, ..LinkConfig::default() };
    let mut e0 = Endpoint::new(config, 0, 100, 0, Some((&m0, &mut s0)), Some(&mut st0), bufs()).unwrap();
    let mut e1 = Endpoint::new(config, 1, 200, 0, Some((&m1, &mut s1)), Some(&mut st1), bufs()).unwrap();
    let (r0, r1) = drive(&wire, (&mut e0, &mut p0), (&mut e1, &mut p1), 200_000);
    assert_eq!((r0, r1), (Ok(Progress::Done), Ok(Progress::Done)));
    assert_eq!((st0.len(), st1.len()), (m1.len(), m0.len()));
    // Only the opening hellos and a rare ack crossing a resend may overlap.
    let collisions = wire.borrow().collisions();
    assert!(collisions < 10, "{collisions} collisions");
}

/// A street of a few thousand voxels (about 4 KB encoded): road, two
/// walls, poles.
fn street_map(seed: u32) -> LocalMap<Heap> {
    let mut m = map(4000);
    let o = (seed % 5) as f32 * 0.2;
    for i in 0..120 {
        let x = o + i as f32 * 0.2;
        for j in 0..16 {
            m.insert_point([x, j as f32 * 0.2, 0.0], Class::Road).unwrap();
        }
        for k in 0..5 {
            m.insert_point([x, -0.4, k as f32 * 0.2], Class::Building).unwrap();
            m.insert_point([x, 3.6, k as f32 * 0.2], Class::Building).unwrap();
        }
        if i % 15 == 0 {
            for k in 0..12 {
                m.insert_point([x, 0.2, k as f32 * 0.2], Class::Pole).unwrap();
            }
        }
    }
    m
}

/// A peer that reads late (a slow host, an emulator starved of CPU, a
/// robot busy elsewhere) behind a deep send buffer: what the sender wrote
/// waits in the line, round trips grow with the queue. The sender must not
/// fill it with copies the peer reads much later (a storm of resends:
/// before, megabytes for a 10 KB map on emulated boards under a CPU hog).
/// Slow lines of 115200, 20000 and 5000 baud, and one whose peer does not
/// look at it for 5 s in the middle (busy matching).
#[test]
fn a_peer_that_reads_late_gets_no_storm_of_resends() {
    for (seed, bytes_per_ms, busy) in [(1u64, 11.52, 0..0), (2, 2.0, 0..0), (3, 0.5, 0..0), (4, 11.52, 50..5050)] {
        let (m0, m1) = (street_map(2), street_map(3));
        let (mut s0, mut s1) = (vec![0u32; m0.len()], vec![0u32; m1.len()]);
        let (mut st0, mut st1) = (map(4000), map(4000));
        let config = sim::SimConfig { bytes_per_ms, send_buffer: 65536, ..sim::SimConfig::clean(115_200, seed) };
        let wire = std::boxed::Box::new(RefCell::new(Line::new(config)));
        let (mut p0, mut p1) = Line::ports(&wire);
        let config = LinkConfig::default();
        let mut e0 = Endpoint::new(config, 0, 100, 0, Some((&m0, &mut s0)), Some(&mut st0), bufs()).unwrap();
        let mut e1 = Endpoint::new(config, 1, 200, 0, Some((&m1, &mut s1)), Some(&mut st1), bufs()).unwrap();
        let (mut r0, mut r1) = (Ok(Progress::Busy), Ok(Progress::Busy));
        for now in 0..2_000_000 {
            wire.borrow_mut().tick(now);
            if r0 == Ok(Progress::Busy) {
                r0 = e0.step(&mut p0, now);
            }
            if r1 == Ok(Progress::Busy) && !busy.contains(&now) {
                r1 = e1.step(&mut p1, now);
            }
            if r0 != Ok(Progress::Busy) && r1 != Ok(Progress::Busy) {
                break;
            }
        }
        assert_eq!((r0, r1), (Ok(Progress::Done), Ok(Progress::Done)));
        let stats = [e0.stats(), e1.stats()];
        assert_eq!((st0.len(), st1.len()), (m1.len(), m0.len()));
        for s in stats {
            let ratio = s.bytes_sent as f64 / s.chunk_bytes_sent as f64;
            std::println!(
                "{bytes_per_ms} B/ms, busy {busy:?}: sent {} B for {} B of map ({ratio:.2}x), {} resends",
                s.bytes_sent,
                s.chunk_bytes_sent,
                s.retransmissions
            );
            // Probes while the peer is busy: one per 800 ms at most.
            let probes = (busy.end - busy.start) / 800;
            assert!(ratio < 2.0 && u64::from(s.retransmissions) <= 6 + probes, "{ratio:.2}x the map's bytes: {s:?}");
        }
    }
}

/// A map received into a [`crate::map::SceneMap`] over a lossy line holds
/// exactly what the same map received into a `LocalMap` gives a scene:
/// the same voxels in the same (arrival) order, reduced to scene points;
/// one that does not fit is refused as too large.
#[test]
fn a_map_received_as_a_scene_is_the_received_map_reduced() {
    use crate::map::{SceneMap, ScenePoint};
    let sent = small_map(7);
    let config = LinkConfig::default();
    let mut whole = map(1000);
    {
        let wire = line(7, 0.01, 0.0);
        let (mut pa, mut pb) = Line::ports(&wire);
        let mut scratch = vec![0u32; sent.len()];
        let mut a =
            Endpoint::<Heap, LocalMap<Heap>>::new(config, 0, 7, 0, Some((&sent, &mut scratch)), None, bufs()).unwrap();
        let mut b = Endpoint::<Heap, LocalMap<Heap>>::new(config, 1, 0, 0, None, Some(&mut whole), bufs()).unwrap();
        let (_, rb) = drive(&wire, (&mut a, &mut pa), (&mut b, &mut pb), 2_000_000);
        assert_eq!(rb, Ok(Progress::Done));
    }
    let mut scene = SceneMap::new(vec![ScenePoint::EMPTY; 1000], sent.resolution()).unwrap();
    {
        let wire = line(8, 0.01, 0.0);
        let (mut pa, mut pb) = Line::ports(&wire);
        let mut scratch = vec![0u32; sent.len()];
        let mut a = Endpoint::<Heap, SceneMap<std::vec::Vec<ScenePoint>>>::new(
            config,
            0,
            7,
            0,
            Some((&sent, &mut scratch)),
            None,
            bufs(),
        )
        .unwrap();
        let mut b = Endpoint::<Heap, _>::new(config, 1, 0, 0, None, Some(&mut scene), bufs()).unwrap();
        let (_, rb) = drive(&wire, (&mut a, &mut pa), (&mut b, &mut pb), 2_000_000);
        assert_eq!(rb, Ok(Progress::Done));
    }
    assert_eq!(whole.len(), sent.len());
    let reduced: std::vec::Vec<ScenePoint> = whole.voxels().iter().map(|v| ScenePoint::of(v).unwrap()).collect();
    assert_eq!(scene.points(), &reduced[..]);
    // A scene one point short of the map: it gets all but the farthest voxel.
    let mut small = SceneMap::new(vec![ScenePoint::EMPTY; sent.len() - 1], sent.resolution()).unwrap();
    {
        let wire = line(9, 0.0, 0.0);
        let (mut pa, mut pb) = Line::ports(&wire);
        let mut scratch = vec![0u32; sent.len()];
        let mut a =
            Endpoint::<Heap, LocalMap<Heap>>::new(config, 0, 7, 0, Some((&sent, &mut scratch)), None, bufs()).unwrap();
        let mut b = Endpoint::<Heap, _>::new(config, 1, 0, 0, None, Some(&mut small), bufs()).unwrap();
        let (_, rb) = drive(&wire, (&mut a, &mut pa), (&mut b, &mut pb), 2_000_000);
        assert_eq!(rb, Ok(Progress::Done));
    }
    assert_eq!(small.len(), sent.len() - 1);
}

/// A peer speaking another protocol version, or sending a Hello whose
/// voxel size is NaN, is named at its first intact frame, not left to the
/// silence timeout.
#[test]
fn a_peer_of_another_version_or_with_a_bad_hello_is_named_at_once() {
    use crate::wire::{encode_frame, Hello, Message, MAX_FRAME, PROTOCOL_VERSION};
    use embedded_io::Write as _;
    let resolution = crate::map::MapConfig::default().resolution;
    for (version, res, want) in
        [(3u8, resolution, LinkError::Version(3)), (PROTOCOL_VERSION, f32::NAN, LinkError::BadHello)]
    {
        let wire = line(9, 0.0, 0.0);
        let (mut pa, mut pb) = Line::ports(&wire);
        let mut staging = map(100);
        let mut b =
            Endpoint::<Heap, LocalMap<Heap>>::new(LinkConfig::default(), 1, 0, 0, None, Some(&mut staging), bufs())
                .unwrap();
        let hello = Hello {
            robot_id: 0,
            class_table: crate::classes::CLASS_TABLE_VERSION,
            resolution: 1.0,
            max_payload: 512,
            takes_map: true,
            capacity: 100,
            heard: false,
        };
        let mut payload = [0u8; 64];
        let n = Message::Hello(hello).encode(&mut payload).unwrap();
        // The version bits, and the resolution (an f32 after the robot id
        // and the class table's varint: found by its bytes).
        payload[0] = (payload[0] & 0x0F) | (version << 4);
        let at = payload[..n].windows(4).position(|w| w == 1.0f32.to_le_bytes()).unwrap();
        payload[at..at + 4].copy_from_slice(&res.to_le_bytes());
        let mut frame = [0u8; MAX_FRAME];
        let len = encode_frame(&payload[..n], &mut frame).unwrap();
        pa.write_all(&frame[..len]).unwrap();
        let mut result = Ok(Progress::Busy);
        for now in 0..100 {
            wire.borrow_mut().tick(now);
            result = b.step(&mut pb, now);
            if result != Ok(Progress::Busy) {
                break;
            }
        }
        assert_eq!(result, Err(want));
        let text = std::format!("{want}");
        assert!(text.contains("version") || text.contains("resolution"), "{text}");
    }
}
