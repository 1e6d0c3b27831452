//! Two session robots (robots that keep driving), fed round by round and
//! trading updates over simulated lines, as on boards.

use super::super::*;
use super::{SessionParts, SessionRobot};
use crate::classes::Class;
use crate::geometry::{from_xyz_rpy, rows};
use crate::link::courier::CourierConfig;
use crate::map::VecStorage;
use crate::matching::{MatchStatus, VecPyramidStorage};
use crate::session::ShadowEntry;
use crate::sim::{self, SimConfig, SimRobot, Wire};
use crate::test_util::heap_pyramid;
use crate::wire::feed::{pack_point, FeedMessage, RobotMessage, RoundReport, SessionEnd, Setup, POINT_BYTES};
use std::vec;
use std::vec::Vec;

/// A small deterministic generator.
struct Lcg(u64);

impl Lcg {
    fn unit(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }
}

const CAPACITY: usize = 6_000;
const ROUNDS: u16 = 24;

/// Where a robot is on the street after `s` metres (a gentle curve).
fn place(s: f32) -> [f32; 3] {
    [s, 0.002 * s * s, 0.0]
}

/// A number in 0..1 fixed by `k` (where the street's things stand).
fn hash(k: i32) -> f32 {
    let h = (k as u32).wrapping_mul(2_654_435_761) ^ 0x9E37_79B9;
    (h.wrapping_mul(2_246_822_519) >> 8) as f32 / (1u32 << 24) as f32
}

/// 1,500 points of the street around `at`, one in ten mislabelled: a
/// building wall on the left with gaps, hedges on the right, the road, a
/// pole in some 8 m bays (at a place of its own in each), parked cars.
fn scan(at: [f32; 3], rng: &mut Lcg) -> Vec<([f32; 3], Class)> {
    let mut points = Vec::new();
    while points.len() < 2_500 {
        let (u, v) = (rng.unit(), rng.unit());
        let along = at[0] - 20.0 + 40.0 * u;
        let y = 0.002 * along * along;
        let bay = libm::floorf(along / 8.0) as i32;
        let lot = libm::floorf(along / 5.0) as i32;
        let (p, class) = match (v * 5.0) as u32 {
            0 if hash(lot) > 0.3 => ([along, y + 6.0 + 2.0 * hash(lot + 99), 3.0 * rng.unit()], Class::Building),
            1 if hash(lot + 7) > 0.4 => ([along, y - 6.0, (1.0 + hash(lot + 3)) * rng.unit()], Class::Vegetation),
            2 => ([along, y - 6.0 + 12.0 * rng.unit(), 0.0], Class::Road),
            3 if hash(lot + 11) > 0.6 => ([along, y - 3.5 + rng.unit(), 1.5 * rng.unit()], Class::Car),
            4 if hash(bay + 5) > 0.35 => {
                let x = 8.0 * bay as f32 + 8.0 * hash(bay + 13);
                ([x, 0.002 * x * x + 4.0, 4.0 * rng.unit()], Class::Pole)
            }
            _ => continue,
        };
        points.push((p, if rng.unit() < 0.1 { Class::Trunk } else { class }));
    }
    points
}

/// Robot `id`'s feed: `ROUNDS` rounds of 2 scans 1.5 m apart, starting
/// `start` metres along the street, in its odometry frame (`T_world_odom`
/// `odom`): the anchor before each scan, its points, the round's mark; its
/// updates bounded to `budget` bytes (0: unbounded).
fn feed(id: u8, start: f32, odom: &Isometry3<f32>, budget: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut frame = [0u8; crate::wire::MAX_FRAME];
    let mut push = |msg: FeedMessage<'_>| {
        let n = msg.to_frame(&mut frame).unwrap();
        out.extend_from_slice(&frame[..n]);
    };
    push(FeedMessage::Setup(Setup { robot_id: id, resolution: 0.5, prior: None, silence_ms: 60_000 }));
    push(FeedMessage::Session { update_budget: budget });
    let to_odom = odom.inverse();
    let mut rng = Lcg(u64::from(id) + 1);
    let mut total = 0u32;
    for round in 0..ROUNDS {
        let mut points = 0u32;
        for k in 0..2 {
            let at = place(start + 3.0 * f32::from(round) + 1.5 * k as f32);
            let here = to_odom * nalgebra::Point3::from(at);
            push(FeedMessage::Anchor { at: [here.x, here.y, here.z] });
            let data: Vec<u8> = scan(at, &mut rng)
                .into_iter()
                .flat_map(|(p, c)| {
                    let q = to_odom * nalgebra::Point3::from(p);
                    pack_point([q.x, q.y, q.z], c)
                })
                .collect();
            for part in data.chunks(crate::wire::feed::MAX_POINTS_PER_MESSAGE * POINT_BYTES) {
                push(FeedMessage::Points { scan: k, data: part });
            }
            points += (data.len() / POINT_BYTES) as u32;
        }
        push(FeedMessage::EndOfRound { round, points });
        total += points;
    }
    push(FeedMessage::EndOfFeed { scans: 2 * ROUNDS, points: total });
    out
}

/// A session robot's memory on the heap.
struct Memory {
    scratch: Vec<u32>,
    out: Vec<u8>,
    input: Vec<u8>,
    search: Vec<u32>,
    reach: Vec<crate::matching::Reach>,
}

impl Memory {
    fn new() -> Self {
        Memory {
            scratch: vec![0; CAPACITY],
            out: vec![0; 24 * CAPACITY],
            input: vec![0; 24 * CAPACITY],
            search: vec![0; crate::matching::search::SearchScratch::WINDOWED],
            reach: vec![crate::matching::Reach::EMPTY; super::SESSION_REACH],
        }
    }
}

type TestRobot<'a> = SessionRobot<'a, VecStorage, VecStorage, Vec<ShadowEntry>, VecPyramidStorage, VecPyramidStorage>;

fn robot(memory: &mut Memory) -> TestRobot<'_> {
    robot_holding(memory, CAPACITY)
}

/// A robot whose copy of its peer's map holds `copy` voxels.
fn robot_holding(memory: &mut Memory, copy: usize) -> TestRobot<'_> {
    let parts = SessionParts {
        map: VecStorage::with_capacity(CAPACITY),
        copy: VecStorage::with_capacity(copy),
        records: (vec![ShadowEntry::default(); CAPACITY], vec![ShadowEntry::default(); CAPACITY]),
        scratch: &mut memory.scratch,
        out: &mut memory.out,
        input: &mut memory.input,
        model: heap_pyramid(CAPACITY, 4096, 20_000),
        scene: heap_pyramid(CAPACITY, 4096, 20_000),
        search: &mut memory.search,
        reach: &mut memory.reach,
    };
    SessionRobot::new(RobotConfig::default(), CourierConfig::default(), parts).unwrap()
}

/// What a robot told its feeder: its rounds and its end.
fn told(bytes: &[u8]) -> (Vec<RoundReport>, Option<SessionEnd>) {
    let mut deframer = crate::wire::frame::Deframer::new();
    let (mut rounds, mut end) = (Vec::new(), None);
    for &b in bytes {
        if let Ok(Some(p)) = deframer.push(b) {
            match RobotMessage::decode(p).unwrap() {
                RobotMessage::Round(r) => rounds.push(r),
                RobotMessage::SessionEnd(e) => end = Some(e),
                RobotMessage::Ready => {}
                other => panic!("{other:?}"),
            }
        }
    }
    (rounds, end)
}

/// Runs the pair over `line`: each robot's rounds and end.
fn run_pair(feeds: &[Vec<u8>; 2], line: SimConfig) -> [(Vec<RoundReport>, SessionEnd); 2] {
    run_pair_holding(feeds, line, [CAPACITY; 2])
}

/// [`run_pair`] with robot i's copy holding `copies[i]` voxels.
fn run_pair_holding(feeds: &[Vec<u8>; 2], line: SimConfig, copies: [usize; 2]) -> [(Vec<RoundReport>, SessionEnd); 2] {
    let (mut ma, mut mb) = (Memory::new(), Memory::new());
    let (mut a, mut b) = (robot_holding(&mut ma, copies[0]), robot_holding(&mut mb, copies[1]));
    let out = sim::run(
        &mut [&mut a as &mut SimRobot<'_, '_, SessionEnd>, &mut b],
        &[&feeds[0], &feeds[1]],
        &[Wire { a: 0, b: 1, line }],
        3_600_000,
    );
    [0, 1].map(|i| {
        let end = out[i].result.expect("still busy").expect("failed");
        let (rounds, told_end) = told(&out[i].told);
        assert_eq!(told_end, Some(end));
        (rounds, end)
    })
}

/// The pair's truth: robot 0's odometry is the world's; robot 1 starts 9 m
/// behind, its odometry turned by 25 degrees and shifted.
fn pair() -> ([Vec<u8>; 2], Isometry3<f32>) {
    pair_bounded(crate::session::DEFAULT_UPDATE_BUDGET)
}

/// [`pair`] with updates bounded to `budget` bytes (0: unbounded).
fn pair_bounded(budget: u32) -> ([Vec<u8>; 2], Isometry3<f32>) {
    let odom_b = from_xyz_rpy(-9.0, 4.0, 0.0, 0.0, 0.0, 25f32.to_radians());
    ([feed(0, 0.0, &Isometry3::identity(), budget), feed(1, -9.0, &odom_b, budget)], odom_b)
}

#[test]
fn two_session_robots_keep_their_copies_and_track_each_other() {
    let (feeds, truth) = pair();
    let [(ra, ea), (rb, eb)] = run_pair(&feeds, SimConfig::clean(115_200, 5));
    for (me, rounds, end, t) in [(0, &ra, ea, truth), (1, &rb, eb, truth.inverse())] {
        assert_eq!(rounds.len(), usize::from(ROUNDS), "robot {me}");
        assert_eq!(end.rounds, ROUNDS);
        // Every update applied: the copy is the peer's map, digest checked.
        assert!(rounds.iter().all(|r| r.applied == 0), "robot {me}: {:?}", rounds.iter().map(|r| r.applied));
        // After the first round, updates are what changed, not the map,
        // within the budget.
        for r in &rounds[1..] {
            let [new, changed, _] = r.update_counts;
            assert!(new + changed < r.map_voxels, "robot {me} round {}: {:?}", r.round, r.update_counts);
            assert!(r.update_bytes <= crate::session::DEFAULT_UPDATE_BUDGET, "robot {me} round {}", r.round);
        }
        // Fixes, most of them tracked, and right to the street's
        // along-track slack (no aliased place: the street's things repeat
        // 8 m or more apart).
        let errors = |r: &RoundReport| {
            let d = r.result.transform() * t.inverse();
            (d.translation.vector.norm(), d.rotation.angle().to_degrees())
        };
        let fixed: Vec<&RoundReport> =
            rounds.iter().filter(|r| r.result.status == MatchStatus::Converged.code()).collect();
        let close = fixed.iter().filter(|r| errors(r).0 < 0.3 && errors(r).1 < 0.5).count();
        // (A fix is reported once the peer's estimate agreed: a round late.)
        assert!(close >= 14, "robot {me}: {close} fixes within 0.3 m and 0.5 degrees");
        assert!(fixed.iter().all(|r| errors(r).0 < 1.0 && errors(r).1 < 1.0), "robot {me}");
        assert!(rounds.iter().filter(|r| r.kind == 1).count() >= 12, "robot {me}: tracking");
        // The first rounds after the snapshot change more than the budget.
        let budget = crate::session::DEFAULT_UPDATE_BUDGET;
        assert!(rounds[1..].iter().any(|r| r.update_bytes + 32 >= budget), "robot {me}: the budget never bound");
        std::println!(
            "robot {me}: update bytes {:?}, line bytes {:?}",
            rounds.iter().map(|r| r.update_bytes).collect::<Vec<_>>(),
            end.line_bytes
        );
    }
}

#[test]
fn a_damaged_line_changes_the_bytes_not_the_estimates() {
    let (feeds, _) = pair();
    let clean = run_pair(&feeds, SimConfig::clean(115_200, 5));
    let damaged = SimConfig { error_rate: 0.03, ..SimConfig::clean(115_200, 6) };
    let lossy = run_pair(&feeds, damaged);
    for me in 0..2 {
        let strip = |r: &RoundReport| RoundReport { line_bytes: [0; 2], resent: 0, exchange_ms: 0, ..*r };
        let a: Vec<RoundReport> = clean[me].0.iter().map(strip).collect();
        let b: Vec<RoundReport> = lossy[me].0.iter().map(strip).collect();
        assert_eq!(a, b, "robot {me}");
        // The damage cost each robot bytes on the line (repairs), and
        // some messages went again.
        assert!(lossy[me].1.line_bytes[0] > clean[me].1.line_bytes[0], "robot {me}");
    }
    assert!(lossy.iter().map(|(_, end)| end.resent).sum::<u32>() > 0);
    // And the same run twice is the same run.
    assert_eq!(run_pair(&feeds, SimConfig::clean(115_200, 5)), clean);
}

#[test]
fn a_pair_robot_refuses_a_session_feed_and_a_session_robot_a_pair_feed() {
    let mut m = Memory::new();
    let mut r = robot(&mut m);
    let mut bytes = Vec::new();
    let mut frame = [0u8; crate::wire::MAX_FRAME];
    for msg in [
        FeedMessage::Setup(Setup { robot_id: 0, resolution: 0.5, prior: None, silence_ms: 1000 }),
        FeedMessage::Points { scan: 0, data: &pack_point([1.0, 1.0, 0.0], Class::Road) },
    ] {
        let n = msg.to_frame(&mut frame).unwrap();
        bytes.extend_from_slice(&frame[..n]);
    }
    // A line to a peer that is not there.
    let wire = Wire::clean(0, 1, 115_200, 1);
    let out = sim::run(&mut [&mut r as &mut SimRobot<'_, '_, SessionEnd>], &[&bytes], &[wire], 10_000);
    assert_eq!(out[0].result, Some(Err(RobotError::Feed(crate::wire::feed::FeedError::Order))));
    let _ = rows(&Isometry3::<f32>::identity());
}

/// A robot that holds less of its peer's map than the peer has (a smaller
/// board) says so before the first round and is never sent more: its copy
/// is the part of the peer's map that fits, every update applied; the
/// peer still holds all of the smaller robot's map.
#[test]
fn a_robot_that_holds_less_is_sent_what_fits() {
    const SMALL: usize = 2_000;
    // Unbounded updates: every copy holds all that fits, every round.
    let (feeds, _) = pair_bounded(0);
    let [(ra, _), (rb, _)] = run_pair_holding(&feeds, SimConfig::clean(115_200, 7), [CAPACITY, SMALL]);
    assert_eq!((ra.len(), rb.len()), (usize::from(ROUNDS), usize::from(ROUNDS)));
    for (a, b) in ra.iter().zip(&rb) {
        assert_eq!((a.applied, b.applied), (0, 0), "round {}", a.round);
        assert_eq!(b.copy_voxels, a.map_voxels.min(SMALL as u32), "round {}: robot 1 holds what fits", a.round);
        assert_eq!(a.copy_voxels, b.map_voxels, "round {}: robot 0 holds all", a.round);
    }
    assert!(ra.iter().any(|r| r.map_voxels > SMALL as u32), "robot 0's map outgrew what robot 1 holds");
}

/// A message's head carries the sender's estimate (when it has one), what
/// the sender says of it, its place and its walk figure; a head of another
/// length, or a number that is not finite, says nothing of what it spoils.
/// Golden bytes: the flag is 1 (passed), 2 (`Converged`) or 3 (a recall
/// waiting for its vouch), the rows, the place and the walk little-endian
/// `f32` (the walk -1 while the sender has none).
#[test]
fn a_head_carries_the_estimate_the_place_and_the_walk() {
    use super::{Head, Said, ESTIMATE_BYTES};
    let t = from_xyz_rpy(12.5, -3.0, 0.25, 0.01, -0.02, 0.7);
    let at = Some([40.25, -7.5, 0.5]);
    let mut head = [0u8; ESTIMATE_BYTES];
    for (said, flag) in [(Said::Passed, 1), (Said::Converged, 2), (Said::Recalling, 3)] {
        Head { estimate: Some((t, said)), at, walk: Some(0.125) }.write(&mut head);
        assert_eq!(head[0], flag);
        assert_eq!(head[49..53], 40.25f32.to_le_bytes());
        assert_eq!(head[61..65], 0.125f32.to_le_bytes());
        let read = Head::read(&head);
        assert_eq!(read.estimate.map(|(e, s)| (rows(&e), s)), Some((rows(&t), said)));
        assert_eq!((read.at, read.walk), (at, Some(0.125)));
    }
    let bare = Head { estimate: None, at, walk: None };
    bare.write(&mut head);
    assert_eq!(head[0], 0);
    assert_eq!(head[61..65], (-1.0f32).to_le_bytes());
    assert_eq!(Head::read(&head), bare);
    // A flag the format does not have: no estimate.
    Head { estimate: Some((t, Said::Converged)), at, walk: None }.write(&mut head);
    head[0] = 4;
    assert_eq!(Head::read(&head), bare);
    // A place that is not finite: the estimate still read, no place.
    Head { estimate: Some((t, Said::Passed)), at: Some([f32::NAN, 0.0, 0.0]), walk: None }.write(&mut head);
    let read = Head::read(&head);
    assert!(read.estimate.is_some() && read.at.is_none());
    // An estimate that is not finite: none, the place still read.
    Head { estimate: Some((t, Said::Passed)), at, walk: None }.write(&mut head);
    head[1..5].copy_from_slice(&f32::INFINITY.to_le_bytes());
    assert_eq!(Head::read(&head), bare);
    // A walk that is not finite, or negative: none.
    for w in [f32::NAN, f32::INFINITY, -0.5] {
        bare.write(&mut head);
        head[61..65].copy_from_slice(&w.to_le_bytes());
        assert_eq!(Head::read(&head), bare);
    }
    let nothing = Head { estimate: None, at: None, walk: None };
    assert_eq!(Head::read(&head[..ESTIMATE_BYTES - 1]), nothing);
}
