//! Two robots' maps from one sequence, with the ground truth between them:
//! what `eval`, `bench` and `robots` start from.

use crate::error::Error;
use crate::maps::mapping::{build_map, HostMap, PointFilter, Unlabeled};
use crate::maps::noise::{corrupt_all, LabelNoise, NoiseStats};
use crate::sources::kitti::{Frame, FrameRange};
use crate::sources::source::{Source, SourceOptions};
use cosem_core::geometry::Isometry3;
use cosem_core::map::MapConfig;
use nalgebra::Matrix4;
use std::path::{Path, PathBuf};

/// Which frames of which folder make robot A's and robot B's maps.
#[derive(Clone, Debug)]
pub struct PairSpec {
    /// The scans: a SemanticKITTI-layout folder, a recording or a folder of
    /// PCD/PLY scans ([`Source::open`]).
    pub data: PathBuf,
    /// How a recording's or a user's scans are read.
    pub source: SourceOptions,
    /// Robot A's frames (the model).
    pub a: FrameRange,
    /// Robot B's frames (the scene).
    pub b: FrameRange,
    /// Map configuration of both robots.
    pub config: MapConfig,
    /// Which points enter the maps.
    pub filter: PointFilter,
    /// Label noise put on every scan before mapping, and its seed.
    pub noise: (LabelNoise, u64),
}

impl PairSpec {
    /// Robots A and B of `data` at `voxel` metres, default filter.
    pub fn new(data: impl AsRef<Path>, a: FrameRange, b: FrameRange, voxel: f32) -> Self {
        PairSpec {
            data: data.as_ref().to_path_buf(),
            source: SourceOptions::default(),
            a,
            b,
            config: MapConfig::with_resolution(voxel),
            filter: PointFilter::default(),
            noise: (LabelNoise::None, 0),
        }
    }

    /// The map settings alone (voxel size, filter, no noise), for maps of
    /// places named elsewhere (`eval --negatives`).
    pub fn places(voxel: f32) -> Self {
        let one = FrameRange { start: 0, end: 1, stride: 1 };
        PairSpec::new(".", one, one, voxel)
    }

    /// The same pair with `noise` on its labels (seeded).
    pub fn with_noise(self, noise: LabelNoise, seed: u64) -> Self {
        PairSpec { noise: (noise, seed), ..self }
    }

    /// The same pair with unlabelled points kept or dropped.
    pub fn with_unlabeled(mut self, unlabeled: Unlabeled) -> Self {
        self.filter.unlabeled = unlabeled;
        self
    }

    /// The same pair read with `options` (a recording's topic, a class
    /// table, ...).
    pub fn with_source(self, options: SourceOptions) -> Self {
        PairSpec { source: options, ..self }
    }

    /// Opens the spec's source.
    pub fn open(&self) -> Result<Source, Error> {
        Source::open(&self.data, &self.source)
    }

    /// Reads a range's frames with this spec's label noise; with the
    /// anchor's pose `T_world_anchor`.
    pub fn frames(&self, source: &Source, range: FrameRange) -> Result<(Vec<Frame>, Matrix4<f64>, NoiseStats), Error> {
        let (mut frames, anchor, _) = source.load(Some(range))?;
        let stats = corrupt_all(&mut frames, self.noise.0, self.noise.1);
        Ok((frames, anchor, stats))
    }

    /// The folder's last path component, for captions.
    pub fn name(&self) -> String {
        self.data.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
    }
}

/// Two robots' maps and the truth `T_A_B`.
pub struct Pair {
    /// Robot A's map (the model).
    pub map_a: HostMap,
    /// Robot B's map (the scene).
    pub map_b: HostMap,
    /// Robot B's frames, in B's anchor frame (to rebuild B's map moved).
    pub frames_b: Vec<Frame>,
    /// `T_A_B = inv(V_A0) * V_B0`.
    pub gt: Isometry3<f64>,
    /// What the label noise changed (both maps' frames).
    pub noise: NoiseStats,
}

impl Pair {
    /// Reads both ranges and builds both maps.
    pub fn load(spec: &PairSpec) -> Result<Pair, Error> {
        let seq = spec.open()?;
        let (frames_a, anchor_a, na) = spec.frames(&seq, spec.a)?;
        let (map_a, _) = build_map(&frames_a, spec.config, &spec.filter)?;
        let (frames_b, anchor_b, nb) = spec.frames(&seq, spec.b)?;
        let (map_b, _) = build_map(&frames_b, spec.config, &spec.filter)?;
        // The truth from the anchors the loads gave (a recording is not read again).
        let gt = crate::sources::source::relative(&anchor_a, &anchor_b);
        let noise = NoiseStats { points: na.points + nb.points, changed: na.changed + nb.changed };
        Ok(Pair { map_a, map_b, frames_b, gt, noise })
    }

    /// Both maps passed through the map-file encoding (as received over the
    /// link): what quantisation costs.
    pub fn through_encoding(&mut self) -> Result<(), Error> {
        self.map_a = through_encoding(&self.map_a)?;
        self.map_b = through_encoding(&self.map_b)?;
        Ok(())
    }

    /// The conventions' overlap of B in A under the truth.
    pub fn overlap(&self) -> f32 {
        cosem_core::map::overlap(&self.map_a, &self.map_b, &self.gt.cast::<f32>())
    }
}

/// A map as it arrives through the compact encoding.
pub fn through_encoding(map: &HostMap) -> Result<HostMap, Error> {
    let name = Path::new("(encoded map)");
    Ok(crate::maps::cmap::decode(&crate::maps::cmap::encode(map, None, None), name)?.1)
}

/// `frames` moved by `d` (points rebuilt in the frame `d` maps them to).
pub fn moved_frames(frames: &[Frame], d: &Isometry3<f64>) -> Vec<Frame> {
    frames
        .iter()
        .map(|f| {
            let mut f = f.clone();
            for p in &mut f.points {
                let q = d * nalgebra::Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                *p = [q.x as f32, q.y as f32, q.z as f32];
            }
            f
        })
        .collect()
}
