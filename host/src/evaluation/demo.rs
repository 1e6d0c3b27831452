//! The main job on built-in data (`cosem demo`): synthesise a street, build
//! two robots' maps from the two halves of the drive, send robot B's map
//! through the map file encoding, match it against robot A's from a prior
//! 5 m and 15 degrees off, and tell the estimate against the truth.

use crate::error::Error;
use crate::evaluation::eval::Start;
use crate::evaluation::pair::{Pair, PairSpec};
use crate::knobs::Knob;
use crate::maps::mapping::{class_histogram, HostMap};
use crate::matching::align::{prepare, DEFAULT_LEVELS};
use crate::poses::pose_words;
use crate::sources::kitti::FrameRange;
use crate::worlds::synth::{write_sequence, SynthConfig};
use cosem_core::geometry::{errors_of, Isometry3};
use cosem_core::map::overlap;
use cosem_core::matching::MatchSettings;
use std::io::Write;
use std::path::Path;

/// What the demo runs on.
#[derive(Clone, Copy, Debug)]
pub struct Demo {
    /// Frames to synthesise (at least 2); robot A maps the first half.
    pub frames: usize,
    /// Seed of the street.
    pub seed: u64,
    /// Voxel size (m).
    pub voxel: f32,
    /// Keep the maps as files in the folder.
    pub keep_maps: bool,
}

fn describe(out: &mut impl Write, name: &str, range: FrameRange, map: &HostMap, voxel: f32) -> std::io::Result<()> {
    let top: Vec<String> = class_histogram(map).iter().take(6).map(|(c, n)| format!("{} {}", c.name(), n)).collect();
    writeln!(
        out,
        "robot {name}: frames {range}, {} voxels at {voxel} m; largest classes: {}",
        map.len(),
        top.join(", ")
    )
}

/// Runs the demo in `dir`, telling what happens on `out`.
pub fn run(d: &Demo, dir: &Path, out: &mut impl Write) -> Result<(), Error> {
    let io = |source| Error::Io { path: "(output)".into(), source };
    if d.frames < 2 {
        return Err(Error::Invalid(format!("{} {}: at least 2", Knob::Frames, d.frames)));
    }
    let t0 = std::time::Instant::now();
    write_sequence(dir, &SynthConfig { frames: d.frames, seed: d.seed, ..SynthConfig::default() })
        .map_err(|source| Error::Io { path: dir.to_path_buf(), source })?;
    writeln!(out, "synthetic street: {} frames, seed {}, in {}", d.frames, d.seed, dir.display()).map_err(io)?;
    let half = d.frames / 2;
    let (ra, rb) =
        (FrameRange { start: 0, end: half, stride: 1 }, FrameRange { start: half, end: d.frames, stride: 1 });
    let pair = Pair::load(&PairSpec::new(dir, ra, rb, d.voxel))?;
    // Robot B's map travels as bytes, in the compact (quantised) encoding:
    // what arrives encodes back to exactly what was sent.
    let (bytes_b, received_b) = crate::maps::cmap::round_trip(&pair.map_b, &format!("synthetic {rb}"))?;
    if d.keep_maps {
        crate::maps::cmap::write(&dir.join("robot_a.cmap"), &pair.map_a, None, Some(&format!("synthetic {ra}")))?;
        let b = dir.join("robot_b.cmap");
        crate::paths::write_file(&b, &bytes_b).map_err(|source| Error::Io { path: b, source })?;
    }
    describe(out, "A (model)", ra, &pair.map_a, d.voxel).map_err(io)?;
    describe(out, "B (scene)", rb, &received_b, d.voxel).map_err(io)?;
    let per_voxel = bytes_b.len() as f64 / received_b.len().max(1) as f64;
    writeln!(out, "robot B's map: {} bytes as a map file ({per_voxel:.1} bytes/voxel)", bytes_b.len()).map_err(io)?;
    writeln!(out, "ground truth T_A_B: {}", pose_words(&pair.gt)).map_err(io)?;
    let o = |t: &Isometry3<f64>| 100.0 * overlap(&pair.map_a, &received_b, &t.cast::<f32>());
    let (og, oi) = (o(&pair.gt), o(&Isometry3::identity()));
    writeln!(out, "overlap of B in A: {og:.1}% under the ground truth, {oi:.1}% under the identity").map_err(io)?;
    // The prior: the truth moved 5 m and turned 15 degrees (paper-grid style).
    let prior = Start { dx: 3.0, dy: 4.0, dyaw: 15.0 }.apply(&pair.gt);
    writeln!(out, "prior (5 m, 15 deg off): {}", pose_words(&prior)).map_err(io)?;
    let tp = std::time::Instant::now();
    let (pa, pb) = (prepare(&pair.map_a, DEFAULT_LEVELS)?, prepare(&received_b, DEFAULT_LEVELS)?);
    let prep_ms = tp.elapsed().as_secs_f64() * 1e3;
    let tm = std::time::Instant::now();
    let (r, _) = crate::matching::align::align(MatchSettings::default(), Some(&prior.cast::<f32>()), (&pa, &pb))?;
    let match_ms = tm.elapsed().as_secs_f64() * 1e3;
    writeln!(out, "estimate  T_A_B: {}", pose_words(&r.transform.cast::<f64>())).map_err(io)?;
    writeln!(
        out,
        "match: {} after {} iterations, {} inliers, overlap {:.1}%, agreement {:.1}%, rmse {:.3} m, in {match_ms:.1} ms (+{prep_ms:.1} ms preparing both maps)",
        r.status.as_str(),
        r.iterations,
        r.inliers,
        100.0 * r.overlap,
        100.0 * r.agreement,
        r.rmse
    )
    .map_err(io)?;
    let (et, er) = errors_of(&r.transform, &pair.gt);
    writeln!(out, "error against the truth: {et:.3} m, {er:.3} deg").map_err(io)?;
    writeln!(out, "done in {:.2} s", t0.elapsed().as_secs_f64()).map_err(io)?;
    Ok(())
}
