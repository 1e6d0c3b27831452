//! What the host feeds a robot on a board: each scan thinned to one
//! labelled point per voxel, framed as the feed protocol's messages
//! (set-up, points, end), in a deterministic order.

use crate::error::Error;
use crate::maps::mapping::PointFilter;
use crate::sources::kitti::{Frame, FrameRange};
use cosem_core::classes::{Class, NUM_CLASSES};
use cosem_core::geometry::{rows, Isometry3};
use cosem_core::wire::feed::{self, FeedMessage, Setup, MAX_POINTS_PER_MESSAGE, POINT_BYTES};
use cosem_core::wire::frame::MAX_FRAME;
use std::collections::BTreeMap;

/// One fed point.
pub type Point = [u8; POINT_BYTES];

/// Thins one scan (already in the anchor frame) to one labelled point per
/// voxel of `resolution`: the mean of the voxel's points of its most common
/// class (ties to the lower class index), within `crop` metres of the
/// sensor. Points come out in key order, so the feed is deterministic.
pub fn thin_scan(frame: &Frame, resolution: f32, crop: f32, filter: &PointFilter) -> Vec<Point> {
    let inv = 1.0 / resolution;
    // Per voxel: per class, count and sum.
    type PerClass = [(u32, [f64; 3]); NUM_CLASSES];
    let mut cells: BTreeMap<(i32, i32, i32), PerClass> = BTreeMap::new();
    for ((p, &r), &l) in frame.points.iter().zip(&frame.ranges).zip(&frame.labels) {
        if r > crop {
            continue;
        }
        // The boards' robots keep the default filter: classes only.
        let Some(Some(class)) = filter.keep(r, l) else { continue };
        let k = ((p[0] * inv).floor() as i32, (p[1] * inv).floor() as i32, (p[2] * inv).floor() as i32);
        let cell = cells.entry(k).or_insert([(0, [0.0; 3]); NUM_CLASSES]);
        let c = &mut cell[usize::from(class.index())];
        c.0 += 1;
        for (sum, v) in c.1.iter_mut().zip(p) {
            *sum += f64::from(*v);
        }
    }
    cells
        .values()
        .filter_map(|cell| {
            let (best, (n, sum)) = cell.iter().enumerate().max_by(|a, b| a.1 .0.cmp(&b.1 .0).then(b.0.cmp(&a.0)))?;
            let class = Class::from_index(best as u8)?;
            let mean =
                [(sum[0] / f64::from(*n)) as f32, (sum[1] / f64::from(*n)) as f32, (sum[2] / f64::from(*n)) as f32];
            Some(feed::pack_point(mean, class))
        })
        .collect()
}

/// What one robot is fed.
#[derive(Clone, Debug)]
pub struct Feed {
    /// Its set-up.
    pub setup: Setup,
    /// Its scans, thinned.
    pub scans: Vec<Vec<Point>>,
}

impl Feed {
    /// Points over all scans.
    pub fn points(&self) -> usize {
        self.scans.iter().map(Vec::len).sum()
    }

    /// The feed as framed bytes: the set-up, the points in messages of up
    /// to [`MAX_POINTS_PER_MESSAGE`], the end.
    pub fn bytes(&self) -> Result<Vec<u8>, Error> {
        self.bytes_in_team(None)
    }

    /// The feed as framed bytes for a robot of a team of `team` robots
    /// (`None`: a pair robot): [`FeedMessage::Team`] after the set-up.
    pub fn bytes_in_team(&self, team: Option<u8>) -> Result<Vec<u8>, Error> {
        let mut out = Vec::new();
        let mut frame = [0u8; MAX_FRAME];
        let mut push = |msg: FeedMessage<'_>| -> Result<(), Error> {
            let n = msg.to_frame(&mut frame).map_err(|e| Error::Invalid(format!("feed message: {e}")))?;
            out.extend_from_slice(&frame[..n]);
            Ok(())
        };
        push(FeedMessage::Setup(self.setup))?;
        if let Some(robots) = team {
            push(FeedMessage::Team { robots })?;
        }
        for (i, scan) in self.scans.iter().enumerate() {
            for part in scan.chunks(MAX_POINTS_PER_MESSAGE) {
                let data: Vec<u8> = part.iter().flatten().copied().collect();
                push(FeedMessage::Points { scan: i as u16, data: &data })?;
            }
        }
        push(FeedMessage::EndOfFeed { scans: self.scans.len() as u16, points: self.points() as u32 })?;
        Ok(out)
    }
}

/// Both robots' feeds from one sequence: robot A (id 0) maps `a`, robot B
/// (id 1) `b`; each scan thinned to one point per `voxel` within `crop` m,
/// its labels first corrupted by `noise` (seeded with `seed` plus the
/// robot's id, as `cosem team` does). A gets the prior `T_A_B`, B its
/// inverse (none: both without).
#[allow(clippy::too_many_arguments)]
pub fn feeds(
    seq: &crate::sources::source::Source,
    ranges: [FrameRange; 2],
    voxel: f32,
    crop: f32,
    prior_ab: Option<&Isometry3<f64>>,
    silence_ms: u32,
    noise: crate::maps::noise::LabelNoise,
    seed: u64,
) -> Result<[Feed; 2], Error> {
    let filter = PointFilter::default();
    let priors = [prior_ab.copied(), prior_ab.map(Isometry3::inverse)];
    let mut out = Vec::new();
    for (id, (range, prior)) in ranges.into_iter().zip(priors).enumerate() {
        let (mut frames, _, _) = seq.load(Some(range))?;
        crate::maps::noise::corrupt_all(&mut frames, noise, seed.wrapping_add(id as u64));
        let scans = frames.iter().map(|f| thin_scan(f, voxel, crop, &filter)).collect();
        let prior = prior.map(|p| rows(&p.cast::<f32>()));
        let setup = Setup { robot_id: id as u8, resolution: voxel, prior, silence_ms };
        out.push(Feed { setup, scans });
    }
    let [a, b]: [Feed; 2] = out.try_into().map_err(|_| Error::Invalid("two feeds expected".into()))?;
    Ok([a, b])
}
