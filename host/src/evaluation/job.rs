//! `cosem map` as a pipeline: a source's frames -> label noise (when
//! asked) -> a map -> a `.cmap` file, with what each step kept.

use crate::error::Error;
use crate::maps::mapping::{build_map, BuildStats, PointFilter};
use crate::maps::noise::LabelNoise;
use crate::sources::kitti::FrameRange;
use crate::sources::source::Source;
use cosem_core::map::MapConfig;
use std::path::Path;

/// What to build from a source.
#[derive(Clone, Debug)]
pub struct MapJob {
    /// The frames (`None`: all the source has).
    pub frames: Option<FrameRange>,
    /// The map's settings.
    pub config: MapConfig,
    /// Which points are kept.
    pub filter: PointFilter,
    /// Label noise on every scan, and its seed.
    pub noise: (LabelNoise, u64),
}

/// What a job built and wrote.
#[derive(Clone, Debug)]
pub struct MapWritten {
    /// Frames read.
    pub frames: usize,
    /// Points read and kept.
    pub stats: BuildStats,
    /// Voxels of the map.
    pub voxels: usize,
    /// Bytes of the file.
    pub bytes: usize,
    /// Points skipped for a NaN coordinate.
    pub skipped: usize,
}

impl MapJob {
    /// Runs the job on `source` and writes the map to `output` (described
    /// in its header as `what`, and the label noise if any).
    pub fn run(&self, source: &Source, what: &str, output: &Path) -> Result<MapWritten, Error> {
        let (mut frames, _, skipped) = source.load(self.frames)?;
        let (noise, seed) = self.noise;
        let changed = crate::maps::noise::corrupt_all(&mut frames, noise, seed);
        let (map, stats) = build_map(&frames, self.config, &self.filter)?;
        let described = match noise {
            LabelNoise::None => what.to_string(),
            n => format!("{what} label noise {n:?} seed {seed} ({:.1}% changed)", 100.0 * changed.rate()),
        };
        let anchor_time = frames.first().and_then(|f| f.time);
        let bytes = crate::maps::cmap::write(output, &map, anchor_time, Some(&described))?;
        Ok(MapWritten { frames: frames.len(), stats, voxels: map.len(), bytes, skipped })
    }
}
