//! `cosem bench session`: the session's figures on the built-in town with
//! drift, over seeds, for 2 and 3 robots, with ground-truth labels and with
//! a network's label errors, and a slip; labels from the town's camera
//! segmentation (`cosem label`) on the first seeds; and beside them the
//! one-shot exchange every round on the same data, the baseline.

use super::{run, town_robots, Record, SessionSpec};
use crate::error::Error;
use crate::evaluation::stats::median;
use crate::maps::noise::LabelNoise;
use crate::sources::drift::Drift;
use serde::Serialize;

/// The drift of the benchmark's robots: 1% scale, 0.5 degrees per 100 m.
pub const BENCH_DRIFT: Drift = Drift { scale: 0.01, heading_deg: 0.5 };
/// The slip of the benchmark's slip runs: robot 1 at round 50 (robots 0
/// and 1 meet from about round 40).
pub const BENCH_SLIP: (usize, usize) = (1, 50);

/// One configuration of the benchmark.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Case {
    /// Robots.
    pub robots: usize,
    /// `none`, the label noise model, or `camera` (`cosem label` on the
    /// town's camera segmentation).
    pub labels: &'static str,
    /// With the slip.
    pub slip: bool,
    /// Every round a one-shot exchange (whole maps, prior-free), the baseline.
    pub one_shot: bool,
}

/// The cases: 2 and 3 robots with true and noisy labels, 2 robots with a
/// slip, 2 robots with camera labels, and 2 robots exchanging one-shot
/// every round.
pub const CASES: [Case; 7] = [
    Case { robots: 2, labels: "none", slip: false, one_shot: false },
    Case { robots: 2, labels: "network", slip: false, one_shot: false },
    Case { robots: 3, labels: "none", slip: false, one_shot: false },
    Case { robots: 3, labels: "network", slip: false, one_shot: false },
    Case { robots: 2, labels: "none", slip: true, one_shot: false },
    Case { robots: 2, labels: "camera", slip: false, one_shot: false },
    Case { robots: 2, labels: "none", slip: false, one_shot: true },
];

/// Seeds the camera case runs on (the first of the benchmark's): rendering
/// a town's camera segmentation takes most of a minute a robot.
pub const CAMERA_SEEDS: usize = 3;

/// A case's figures over the seeds.
#[derive(Clone, Debug, Serialize)]
pub struct CaseFigures {
    /// The case.
    pub case: Case,
    /// Seeds run.
    pub seeds: Vec<u64>,
    /// Rounds per session.
    pub rounds: usize,
    /// Converged and wrong, over every seed (the slip's rounds exempt).
    pub wrong_converged: usize,
    /// Converged and wrong by `e_t` at the odometry origin ([`super::Summary::wrong_at_origin`]).
    pub wrong_at_origin: usize,
    /// Converged and wrong against the truth as the maps hold it about the
    /// closest pair of scans ([`super::Summary::wrong_converged_local`]).
    pub wrong_converged_local: usize,
    /// Correct Converged ÷ estimates in meetings (first 2 rounds of each
    /// left out), pooled over the seeds.
    pub availability: Option<f64>,
    /// The lowest availability of one seed.
    pub availability_min: Option<f64>,
    /// Meetings over every seed.
    pub meetings: usize,
    /// The largest number of rounds to a meeting's first correct estimate.
    pub first_fix_rounds: Option<usize>,
    /// An update's bytes ÷ the sender's whole map's, pooled: median, p95, largest.
    pub update_bytes_ratio: Option<[f64; 3]>,
    /// Voxels an update held back (its budget), over the same updates,
    /// pooled: median, p95, largest.
    pub update_deferred: Option<[f64; 3]>,
    /// Bytes on the line a robot received from a peer in a round (its
    /// update and answer), pooled: median.
    pub bytes_per_round: Option<f64>,
    /// Median over the seeds of the tracking cost ratio.
    pub tracking_cost_ratio: Option<f64>,
    /// Median tracking round (ms) and from-scratch match (ms), medians over seeds.
    pub tracking_ms: Option<f64>,
    /// See `tracking_ms`.
    pub from_scratch_ms: Option<f64>,
    /// With the slip: the largest over the seeds.
    pub slip_caught_rounds: Option<usize>,
    /// Seconds the case's sessions took (each on one thread).
    pub seconds: f64,
}

/// One session of the benchmark: its records and summary.
struct Run {
    case: usize,
    seed: u64,
    out: super::SessionRun,
    seconds: f64,
}

/// Runs every case on every seed (sessions in parallel with the
/// `parallel` feature, each on one thread), the towns built in `dir`
/// (`frames` scans per robot; `None`: the town's default).
pub fn bench_session(dir: &std::path::Path, seeds: &[u64], frames: Option<usize>) -> Result<Vec<CaseFigures>, Error> {
    // The towns, built in parallel: the LiDAR towns (3 robots) of every
    // seed, and the camera case's own towns with camera segmentation,
    // labelled, of the first seeds.
    let camera = CASES.iter().position(|c| c.labels == "camera");
    let builds: Vec<(u64, bool)> = seeds
        .iter()
        .map(|&seed| (seed, false))
        .chain(seeds.iter().take(CAMERA_SEEDS).map(|&seed| (seed, true)))
        .collect();
    let built = crate::evaluation::eval::for_each_start(&builds, |&(seed, with_camera)| {
        if with_camera {
            camera_town(dir, seed, frames)
        } else {
            town_robots(&dir.join(format!("town-{seed}")), 3, seed, frames)
        }
    });
    let (mut jobs, mut towns, mut camera_towns) = (Vec::new(), Vec::new(), std::collections::HashMap::new());
    for (&(seed, with_camera), robots) in builds.iter().zip(built) {
        if with_camera {
            camera_towns.insert(seed, robots?);
            continue;
        }
        towns.push(robots?);
        for case in 0..CASES.len() {
            jobs.push((case, seed, towns.len() - 1));
        }
    }
    jobs.retain(|&(case, seed, _)| Some(case) != camera || camera_towns.contains_key(&seed));
    // The longest first (3 robots: three pairs a round), so that the last
    // sessions left to run are short ones and no core waits long on them.
    jobs.sort_by_key(|&(case, seed, _)| (std::cmp::Reverse(CASES[case].robots), case, seed));
    let runs = crate::evaluation::eval::for_each_start(&jobs, |&(case, seed, town)| -> Result<Run, Error> {
        let c = CASES[case];
        let robots = match camera_towns.get(&seed) {
            Some(labelled) if Some(case) == camera => labelled.clone(),
            _ => towns[town][..c.robots].to_vec(),
        };
        let spec = SessionSpec {
            robots,
            every: super::DEFAULT_EVERY,
            voxel: super::DEFAULT_VOXEL,
            capacity: vec![super::DEFAULT_CAPACITY],
            crop: super::DEFAULT_CROP,
            drift: BENCH_DRIFT,
            slip: c.slip.then_some(BENCH_SLIP),
            label_noise: if c.labels == "network" { LabelNoise::Network(1.0) } else { LabelNoise::None },
            seed,
            source: Default::default(),
            alignment: super::DEFAULT_ALIGNMENT,
            one_shot: c.one_shot,
            update_budget: Some(super::DEFAULT_UPDATE_BUDGET),
            line: None,
        };
        let t = std::time::Instant::now();
        let out = run(&spec, |_: &super::RoundView<'_>| {})?;
        Ok(Run { case, seed, out, seconds: t.elapsed().as_secs_f64() })
    });
    let runs: Vec<Run> = runs.into_iter().collect::<Result<_, _>>()?;
    Ok((0..CASES.len()).map(|c| figures(c, &runs.iter().filter(|r| r.case == c).collect::<Vec<_>>())).collect())
}

/// A case's figures from its runs.
fn figures(case: usize, runs: &[&Run]) -> CaseFigures {
    let summaries: Vec<&super::Summary> = runs.iter().map(|r| &r.out.summary).collect();
    let records: Vec<&Record> = runs.iter().flat_map(|r| &r.out.records).collect();
    let per_seed: Vec<f64> = summaries.iter().filter_map(|s| s.availability).collect();
    let (available, in_meetings) = summaries.iter().fold((0, 0), |(a, m), s| (a + s.available, m + s.in_meetings));
    let (update_bytes_ratio, update_deferred) = super::figures::update_figures(records.iter().copied());
    let opt_median = |v: Vec<f64>| median(&v);
    CaseFigures {
        case: CASES[case],
        seeds: runs.iter().map(|r| r.seed).collect(),
        rounds: runs.iter().map(|r| r.out.rounds).max().unwrap_or(0),
        wrong_converged: summaries.iter().map(|s| s.wrong_converged).sum(),
        wrong_at_origin: summaries.iter().map(|s| s.wrong_at_origin).sum(),
        wrong_converged_local: summaries.iter().map(|s| s.wrong_converged_local).sum(),
        availability: (in_meetings > 0).then(|| available as f64 / in_meetings as f64),
        availability_min: per_seed.iter().copied().reduce(f64::min),
        meetings: summaries.iter().map(|s| s.meetings).sum(),
        first_fix_rounds: summaries.iter().filter_map(|s| s.first_fix_rounds).max(),
        update_bytes_ratio,
        update_deferred,
        bytes_per_round: opt_median(records.iter().map(|r| r.bytes_sent as f64).collect()),
        tracking_cost_ratio: opt_median(summaries.iter().filter_map(|s| s.tracking_cost_ratio).collect()),
        tracking_ms: opt_median(summaries.iter().filter_map(|s| s.tracking_ms).collect()),
        from_scratch_ms: opt_median(summaries.iter().map(|s| s.from_scratch_ms).collect()),
        slip_caught_rounds: summaries.iter().filter_map(|s| s.slip_caught_rounds).max(),
        seconds: runs.iter().map(|r| r.seconds).sum(),
    }
}

/// A 2-robot town of `seed` with camera segmentation (the town's default:
/// Cityscapes ids, corrupted as a network's), each robot's scans labelled
/// from it as `cosem label` does; the labelled folders keep the town's
/// world. Their maps' classes are the camera's, and so is the overlap that
/// defines meetings there.
fn camera_town(
    dir: &std::path::Path,
    seed: u64,
    frames: Option<usize>,
) -> Result<Vec<crate::evaluation::team::RobotSpec>, Error> {
    use crate::camera::label::{label_sequence, LabelOptions};
    use crate::worlds::town::{write_town, TownConfig};
    let d = TownConfig::default();
    let cfg = TownConfig { robots: 2, seed, frames: frames.unwrap_or(d.frames), ..d };
    let town = dir.join(format!("camera-town-{seed}"));
    write_town(&town, &cfg).map_err(|source| Error::Io { path: town.clone(), source })?;
    let range = crate::sources::kitti::FrameRange { start: 0, end: cfg.frames, stride: 1 };
    let seg_classes = cfg.seg.map(|r| r.classes).ok_or_else(|| Error::Invalid("the town renders no camera".into()))?;
    (0..2)
        .map(|i| {
            let data = town.join(format!("robot_{i}"));
            let out = town.join(format!("labelled_{i}"));
            let opts = LabelOptions {
                seg: data.join("seg_2"),
                data: data.clone(),
                camera: 2,
                classes: seg_classes,
                probabilities: false,
                image_size: None,
                occlusion: true,
                frames: vec![range],
                out: out.clone(),
                copy_scans: false,
                void_channel: Default::default(),
                scale_to_images: false,
            };
            label_sequence(&opts)?;
            Ok(crate::evaluation::team::RobotSpec { data: out, frames: range })
        })
        .collect()
}
