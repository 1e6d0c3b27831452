//! A session's robots as boards are fed them: per round, for each scan the
//! robot's odometry position (where its bounded map keeps what is near)
//! and the scan thinned to a labelled point a voxel, then the round's end;
//! and, where the robots share a world, the truth of every round, taken as
//! `cosem session` takes it.

use super::robot::Robot;
use super::Truth;
use super::{figures, SessionSpec};
use crate::error::Error;
use crate::maps::mapping::PointFilter;
use crate::sources::source::Source;
use cosem_core::wire::feed::{FeedMessage, Setup, MAX_POINTS_PER_MESSAGE};
use cosem_core::wire::frame::MAX_FRAME;

/// What the boards of a session are fed, and what their rounds are
/// measured against.
pub struct BoardFeeds {
    /// Each robot's framed feed.
    pub feeds: Vec<Vec<u8>>,
    /// Rounds.
    pub rounds: usize,
    /// Per round, each robot's truth of the other (robot 0's of robot 1,
    /// then robot 1's of robot 0), where the robots share a world.
    pub truth: Vec<[Option<Truth>; 2]>,
}

/// The feeds of a two-robot session (`spec`'s robots, drift, slip and
/// label noise as `cosem session` applies them), each robot giving up on
/// its peer after `silence_ms` of silence.
pub fn board_feeds(spec: &SessionSpec, silence_ms: u32) -> Result<BoardFeeds, Error> {
    if spec.robots.len() != 2 {
        return Err(Error::Invalid(format!("a session on boards has 2 robots, not {}", spec.robots.len())));
    }
    let sources: Vec<Source> =
        spec.robots.iter().map(|r| Source::open(&r.data, &spec.source)).collect::<Result<_, _>>()?;
    let shared_world = sources[0].shares_world(&sources[1]);
    let mut robots: Vec<Robot> = (0..2).map(|i| Robot::load(spec, i, &sources[i])).collect::<Result<_, _>>()?;
    let rounds = super::rounds_of(spec, &robots)?;
    let filter = PointFilter::default();
    let mut feeds = Vec::new();
    for (i, r) in robots.iter().enumerate() {
        let setup = Setup { robot_id: i as u8, resolution: spec.voxel, prior: None, silence_ms };
        let budget = match spec.update_budget {
            None => 0,
            Some(cosem_core::session::UpdateBudget::Bytes(b)) => b,
            Some(b) => return Err(Error::Invalid(format!("a board's update budget is in bytes (not {b:?})"))),
        };
        feeds.push(robot_feed(r, setup, (rounds, spec.every), budget, spec.crop, &filter)?);
    }
    let mut truth = Vec::new();
    for _ in 0..rounds {
        for r in &mut robots {
            r.drive(spec.every)?;
        }
        let at = |a: usize, b: usize| {
            shared_world.then(|| figures::truth(&robots[a], &robots[b], f64::from(spec.crop))).flatten()
        };
        truth.push([at(0, 1), at(1, 0)]);
    }
    Ok(BoardFeeds { feeds, rounds, truth })
}

/// One robot's framed feed: the set-up, the session mark, `rounds` rounds
/// of `every` scans (fewer, or none, once its scans run out), the end.
fn robot_feed(
    r: &Robot,
    setup: Setup,
    (rounds, every): (usize, usize),
    budget: u32,
    crop: f32,
    filter: &PointFilter,
) -> Result<Vec<u8>, Error> {
    let mut out = Vec::new();
    let mut frame = [0u8; MAX_FRAME];
    let mut push = |msg: FeedMessage<'_>| -> Result<(), Error> {
        let n = msg.to_frame(&mut frame).map_err(|e| Error::Invalid(format!("feed message: {e}")))?;
        out.extend_from_slice(&frame[..n]);
        Ok(())
    };
    push(FeedMessage::Setup(setup))?;
    push(FeedMessage::Session { update_budget: budget })?;
    let (mut scans, mut total) = (0u16, 0u32);
    for round in 0..rounds {
        let mut points = 0u32;
        for k in (round * every..(round + 1) * every).filter(|&k| k < r.scans()) {
            let f = r.frame(k);
            let at = f.pose.translation.vector.cast::<f32>();
            push(FeedMessage::Anchor { at: [at.x, at.y, at.z] })?;
            let thinned = crate::maps::thin::thin_scan(f, setup.resolution, crop, filter);
            for part in thinned.chunks(MAX_POINTS_PER_MESSAGE) {
                let data: Vec<u8> = part.iter().flatten().copied().collect();
                push(FeedMessage::Points { scan: scans, data: &data })?;
            }
            points += thinned.len() as u32;
            scans += 1;
        }
        let round = u16::try_from(round).map_err(|_| Error::Invalid("more than 65,535 rounds".into()))?;
        push(FeedMessage::EndOfRound { round, points })?;
        total += points;
    }
    push(FeedMessage::EndOfFeed { scans, points: total })?;
    Ok(out)
}
