//! The robot step machine: fed, linked and aligned as on a board.

use super::*;
use crate::classes::Class;
use crate::map::{SceneMap, ScenePoint};
use crate::sim::{self, ScriptPort, SimConfig, SimLine, SimRobot, Wire};
use crate::test_util::heap_map;
use crate::wire::feed::pack_point;
use crate::wire::feed::{FeedMessage, RobotMessage, RobotReport, Setup};
use std::vec::Vec;

#[test]
fn points_insert_and_bad_classes_are_named() {
    let mut map = heap_map(64, map_config(0.5));
    let mut data = Vec::new();
    data.extend_from_slice(&pack_point([1.02, 2.0, 0.3], Class::Trunk));
    data.extend_from_slice(&pack_point([1.04, 2.1, 0.3], Class::Trunk));
    assert_eq!(insert_points(&mut map, &data), Ok(2));
    assert_eq!(map.len(), 1);
    assert_eq!(map.voxels()[0].class(), Some(Class::Trunk));
    data[13] = 19;
    assert_eq!(insert_points(&mut map, &data), Err(PointsError::Feed(FeedError::Class { offset: 7, class: 19 })));
    assert!(matches!(insert_points(&mut map, &data[..5]), Err(PointsError::Feed(FeedError::PointBytes { len: 5 }))));
}

/// The feed of robot `id` of the self-test street: every voxel of its map
/// as one point, in messages of up to 64.
fn feed_of(id: u8, prior: Option<[f32; 12]>) -> Vec<u8> {
    let mut m = heap_map(4096, map_config(0.5));
    crate::selftest::build_map(id, &mut m).unwrap();
    let points: Vec<u8> = m.iter().flat_map(|v| pack_point(v.position(0.5), v.class().unwrap())).collect();
    let mut out = Vec::new();
    let mut frame = [0u8; crate::wire::MAX_FRAME];
    let mut push = |msg: FeedMessage<'_>| {
        let n = msg.to_frame(&mut frame).unwrap();
        out.extend_from_slice(&frame[..n]);
    };
    push(FeedMessage::Setup(Setup { robot_id: id, resolution: 0.5, prior, silence_ms: 5000 }));
    for part in points.chunks(crate::wire::feed::MAX_POINTS_PER_MESSAGE * crate::wire::feed::POINT_BYTES) {
        push(FeedMessage::Points { scan: 0, data: part });
    }
    push(FeedMessage::EndOfFeed { scans: 1, points: (points.len() / crate::wire::feed::POINT_BYTES) as u32 });
    out
}

/// The test robots' capacities.
const CAP: Capacity =
    Capacity { voxels: 4096, coarse: 4096, model_words: 20_000, scene_words: 20_000, ..Capacity::BOARD };

/// What a robot receives its peer's map into, as on a board.
fn received_points() -> Vec<ScenePoint> {
    std::vec![ScenePoint::EMPTY; 4096]
}

/// A robot's two regions of words for `c`.
fn memory(c: Capacity) -> (Vec<u32>, Vec<u32>) {
    filled(c, 0)
}

/// A robot's two regions of words for `c`, every word `fill`.
fn filled(c: Capacity, fill: u32) -> (Vec<u32>, Vec<u32>) {
    (std::vec![fill; c.own_words()], std::vec![fill; c.turn_words()])
}

/// A robot's memory need not be zeroed (a board's may hold whatever the
/// RAM held): every buffer carved from it is plain integers, and each
/// stage writes what it reads. The same reports from any contents.
#[test]
fn a_robot_runs_the_same_in_memory_of_any_contents() {
    let truth = crate::selftest::truth();
    let prior = crate::geometry::from_xyz_rpy(1.0, 0.5, 0.0, 0.0, 0.0, 0.05) * truth;
    let feeds =
        [feed_of(0, Some(crate::geometry::rows(&prior))), feed_of(1, Some(crate::geometry::rows(&prior.inverse())))];
    let run = |fill: u32| {
        let (mut pa, mut pb) = (std::vec![ScenePoint::EMPTY; 4096], std::vec![ScenePoint::EMPTY; 4096]);
        let (mut rec_a, mut rec_b) =
            (SceneMap::new(&mut pa[..], 0.5).unwrap(), SceneMap::new(&mut pb[..], 0.5).unwrap());
        let ((mut oa, mut ta), (mut ob, mut tb)) = (filled(CAP, fill), filled(CAP, fill.rotate_left(7)));
        let mut a = Robot::new(RobotConfig::default(), &mut oa, &mut ta, CAP, &mut rec_a).unwrap();
        let mut b = Robot::new(RobotConfig::default(), &mut ob, &mut tb, CAP, &mut rec_b).unwrap();
        let out = sim::run(
            &mut [&mut a as &mut SimRobot<'_, '_, RobotReport>, &mut b],
            &[&feeds[0], &feeds[1]],
            &[Wire::clean(0, 1, 115_200, 3)],
            600_000,
        );
        [0, 1].map(|i| out[i].result.unwrap().unwrap())
    };
    let zeroed = run(0);
    assert_eq!(zeroed[0].result.status, crate::matching::MatchStatus::Converged.code());
    for fill in [u32::MAX, 0xDEAD_BEEF, 0x7FC0_0001] {
        assert_eq!(run(fill), zeroed, "memory filled with {fill:#x}");
    }
}

/// Two robots, stepped as on boards over a simulated 115200-baud line,
/// each end to end: both converge on the truth from a prior, in opposite
/// directions.
#[test]
fn two_robots_map_link_and_align() {
    let truth = crate::selftest::truth();
    let prior = crate::geometry::from_xyz_rpy(1.5, -1.0, 0.0, 0.0, 0.0, 0.1) * truth;
    let feeds =
        [feed_of(0, Some(crate::geometry::rows(&prior))), feed_of(1, Some(crate::geometry::rows(&prior.inverse())))];
    let (mut pa, mut pb) = (received_points(), received_points());
    let (mut rec_a, mut rec_b) = (SceneMap::new(&mut pa[..], 0.5).unwrap(), SceneMap::new(&mut pb[..], 0.5).unwrap());
    let ((mut oa, mut ta), (mut ob, mut tb)) = (memory(CAP), memory(CAP));
    let mut a = Robot::new(RobotConfig::default(), &mut oa, &mut ta, CAP, &mut rec_a).unwrap();
    let mut b = Robot::new(RobotConfig::default(), &mut ob, &mut tb, CAP, &mut rec_b).unwrap();
    let out = sim::run(
        &mut [&mut a as &mut SimRobot<'_, '_, RobotReport>, &mut b],
        &[&feeds[0], &feeds[1]],
        &[Wire::clean(0, 1, 115_200, 3)],
        600_000,
    );
    let [ra, rb] = [0, 1].map(|i| out[i].result.unwrap().unwrap());
    for (r, t) in [(ra, truth), (rb, truth.inverse())] {
        assert_eq!(r.result.status, crate::matching::MatchStatus::Converged.code());
        let d = r.result.transform() * t.inverse();
        assert!(d.translation.vector.norm() < 0.1 && d.rotation.angle().to_degrees() < 0.3, "{d:?}");
        assert!(r.map_voxels > 800 && r.received_voxels > 800 && r.bytes_sent > 0);
    }
    assert_eq!((ra.map_voxels, ra.received_voxels), (rb.received_voxels, rb.map_voxels));
    // Each told its feeder it listens, then its report.
    for (ended, r) in out.iter().zip([ra, rb]) {
        let mut d = crate::wire::Deframer::new();
        let msgs: Vec<_> = ended.told.iter().filter_map(|&b| d.push(b).ok().flatten().map(|p| p.to_vec())).collect();
        assert_eq!(msgs.len(), 2);
        assert_eq!(RobotMessage::decode(&msgs[1]), Ok(RobotMessage::Report(r)));
    }
    // Polled again, a finished robot says so.
    let mut feed = ScriptPort::<256>::new(&[], 1);
    let line = core::cell::RefCell::new(SimLine::<64>::new(SimConfig::clean(115_200, 1)));
    let (port, _) = SimLine::ports(&line);
    assert_eq!(a.poll(&mut feed, &mut [port], 0, &()), Err(RobotError::Finished));
}

/// A one-sided exchange over a line with byte errors: robot B takes no
/// map (a small board), sends its own and is told robot A's result, which
/// it reports inverted as its own `T_B_A` with A's status.
#[test]
fn a_robot_that_takes_no_map_is_told_the_result() {
    let truth = crate::selftest::truth();
    let prior = crate::geometry::from_xyz_rpy(1.5, -1.0, 0.0, 0.0, 0.0, 0.1) * truth;
    let feeds = [feed_of(0, Some(crate::geometry::rows(&prior))), feed_of(1, None)];
    let mut pa = received_points();
    let mut rec_a = SceneMap::new(&mut pa[..], 0.5).unwrap();
    let ((mut oa, mut ta), (mut ob, mut tb)) = (memory(CAP), memory(Capacity::sender(4096)));
    let mut a = Robot::new(RobotConfig::default(), &mut oa, &mut ta, CAP, &mut rec_a).unwrap();
    let mut b = Robot::sender(RobotConfig::default(), &mut ob, &mut tb, Capacity::sender(4096)).unwrap();
    {
        let wire = Wire { a: 0, b: 1, line: SimConfig { error_rate: 0.01, ..SimConfig::clean(115_200, 5) } };
        let out = sim::run(
            &mut [&mut a as &mut SimRobot<'_, '_, RobotReport>, &mut b],
            &[&feeds[0], &feeds[1]],
            &[wire],
            600_000,
        );
        let [ra, rb] = [0, 1].map(|i| out[i].result.and_then(|r| r.ok()));
        let (ra, rb) = (ra.expect("robot A reported"), rb.expect("robot B reported"));
        assert_eq!(ra.result.status, crate::matching::MatchStatus::Converged.code());
        assert_eq!(rb.result.status, ra.result.status);
        // B's transform is A's, inverted; A received B's map, B none.
        let d = rb.result.transform() * ra.result.transform();
        assert!(d.translation.vector.norm() < 1e-4 && d.rotation.angle() < 1e-5, "{d:?}");
        assert!(ra.received_voxels > 800 && rb.received_voxels == 0 && ra.received_voxels == rb.map_voxels);
        // Only B's map crossed: A sent little more than its hello and acks.
        assert!(rb.bytes_sent > 5 * ra.bytes_sent, "A {} B {}", ra.bytes_sent, rb.bytes_sent);
    }
}

/// A robot whose feed breaks off, or whose feeder counts wrong, stops with
/// a typed error and tells its feeder where.
#[test]
fn a_bad_feed_is_reported() {
    let feed = feed_of(0, None);
    let mut points = received_points();
    let mut rec = SceneMap::new(&mut points[..], 0.5).unwrap();
    let (mut own, mut turn) = memory(CAP);
    let mut robot = Robot::new(RobotConfig { feed_silence_ms: 100 }, &mut own, &mut turn, CAP, &mut rec).unwrap();
    let half = &feed[..feed.len() / 2];
    let mut port = ScriptPort::<256>::new(half, 64);
    let line = core::cell::RefCell::new(SimLine::<64>::new(SimConfig::clean(10_000, 1)));
    let (link, _) = SimLine::ports(&line);
    let mut links = [link];
    let mut now = 0;
    let err = loop {
        match robot.poll(&mut port, &mut links, now, &()) {
            Ok(Poll::Busy) => now += 1,
            Ok(Poll::Done(_)) => panic!("finished on half a feed"),
            Err(e) => break e,
        }
    };
    assert!(matches!(err, RobotError::FeederSilent { points } if points > 0), "{err:?}");
    // It said it listens, then where it stopped.
    let mut d = crate::wire::Deframer::new();
    let msgs: Vec<_> = port.output.iter().filter_map(|&b| d.push(b).ok().flatten().map(|p| p.to_vec())).collect();
    assert_eq!(msgs.len(), 2);
    assert_eq!(RobotMessage::decode(&msgs[0]), Ok(RobotMessage::Ready));
    assert!(matches!(RobotMessage::decode(&msgs[1]), Ok(RobotMessage::Failed { stage: Stage::Feed, .. })));
}
