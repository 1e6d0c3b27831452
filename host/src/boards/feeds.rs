//! What the host feeds a robot on a board: each scan thinned to one
//! labelled point per voxel, framed as the feed protocol's messages
//! (set-up, points, end), in a deterministic order.

use crate::error::Error;
use crate::maps::mapping::PointFilter;
use crate::sources::kitti::FrameRange;
use cosem_core::geometry::{rows, Isometry3};
use cosem_core::wire::feed::{FeedMessage, Setup, MAX_POINTS_PER_MESSAGE};
use cosem_core::wire::frame::MAX_FRAME;

pub use crate::maps::thin::{thin_scan, Point};

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
