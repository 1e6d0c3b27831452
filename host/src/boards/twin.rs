//! The host's twin of a pair of boards: the core's robots with each
//! board's capacities and memory, over a clean simulated line, in the
//! core's simulation; what the boards must agree with.

use crate::boards::board::Board;
use crate::boards::feeds::Feed;
use crate::error::Error;
use cosem_core::map::{SceneMap, ScenePoint};
use cosem_core::matching::{PyramidCapacity, VecPyramidStorage};
use cosem_core::robot::{Capacity, Robot, RobotConfig};
use cosem_core::sim::{self, SimRobot, Wire};
use cosem_core::wire::feed::RobotReport;

/// A received map as a board holds it: a scene of its capacity's points.
pub(crate) type Received = SceneMap<Vec<ScenePoint>>;

/// An empty received map of `voxels` points (voxels of `resolution` m).
pub(crate) fn received_scene(voxels: usize, resolution: f32) -> Result<Received, Error> {
    SceneMap::new(vec![ScenePoint::EMPTY; voxels], resolution)
        .map_err(|e| Error::Invalid(format!("received map: {e:?}")))
}

/// A team robot's pyramid storages (model, scene) on the heap, of a board's
/// capacities (the model's level 0 is its map, with extras).
pub(crate) fn board_pyramids(c: Capacity) -> (impl Fn() -> VecPyramidStorage, impl Fn() -> VecPyramidStorage) {
    let model = move || {
        VecPyramidStorage::new(PyramidCapacity {
            voxels: c.voxels,
            entries: c.coarse,
            slots: c.coarse,
            words: c.model_words,
        })
    };
    let scene = move || {
        VecPyramidStorage::new(PyramidCapacity { voxels: 0, entries: c.coarse, slots: 0, words: c.scene_words })
    };
    (model, scene)
}

/// The two robots' pipeline run on this host, exactly as on the boards:
/// the core's robot step machines with each board's capacities, the maps
/// exchanged over a clean simulated 115200-baud line, in the core's
/// simulation ([`sim::run`]). Returns each robot's report (`T_own_peer`).
pub fn host_run(feeds: [&Feed; 2], boards: [Board; 2]) -> Result<[RobotReport; 2], Error> {
    if !boards.iter().any(|b| b.matches()) {
        return Err(Error::Invalid("neither robot's board can match: one must hold both maps".into()));
    }
    let bytes = [feeds[0].bytes()?, feeds[1].bytes()?];
    let resolution = feeds[0].setup.resolution;
    // Each board's memory, as its firmware declares it: two regions of
    // words sized by its capacities.
    let capacity = boards.map(Board::capacity);
    let mut own = capacity.map(|c| vec![0u32; c.own_words()]);
    let mut turn = capacity.map(|c| vec![0u32; c.turn_words()]);
    let mut points = capacity.map(|c| vec![ScenePoint::EMPTY; c.voxels]);
    let mut received = Vec::new();
    for p in &mut points {
        received
            .push(SceneMap::new(&mut p[..], resolution).map_err(|e| Error::Invalid(format!("received map: {e:?}")))?);
    }
    let robot_config = RobotConfig::default();
    // Each robot in its board's role: the full robot, or one that sends
    // its map and is told the result (a small board's).
    let mut robots: Vec<Box<SimRobot<'_, '_, RobotReport>>> = Vec::new();
    let memory = |e: cosem_core::robot::RobotError| Error::Invalid(format!("host run: {e}"));
    for (((board, own), turn), received) in boards.iter().zip(&mut own).zip(&mut turn).zip(&mut received) {
        let c = board.capacity();
        robots.push(if board.matches() {
            Box::new(Robot::new(robot_config, own, turn, c, received).map_err(memory)?)
        } else {
            Box::new(Robot::sender(robot_config, own, turn, c).map_err(memory)?)
        });
    }
    let mut polled: Vec<&mut SimRobot<'_, '_, RobotReport>> = robots.iter_mut().map(|r| &mut **r).collect();
    let out = sim::run(&mut polled, &[&bytes[0], &bytes[1]], &[Wire::clean(0, 1, 115_200, 1)], 3_600_000);
    let named = |i: usize| match out.get(i).and_then(|o| o.result) {
        Some(Ok(r)) => Ok(r),
        Some(Err(e)) => Err(Error::Invalid(format!("host run of robot {i}: {} stage: {e}", e.stage().as_str()))),
        None => Err(Error::Invalid(format!("host run of robot {i}: no report within an hour of robot time"))),
    };
    Ok([named(0)?, named(1)?])
}
