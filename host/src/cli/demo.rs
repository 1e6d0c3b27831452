//! `cosem demo`: the main job on built-in data. Synthesises a street, builds
//! two robots' maps from the two halves of the drive, sends robot B's map
//! through the map file encoding, matches it against robot A's from a prior
//! 5 m and 15 degrees off, and prints the estimate against the truth.

use super::{Error, TempDir};
use cosem_core::geometry::{errors_of, Isometry3};
use cosem_core::map::overlap;
use cosem_core::matching::{MatchSettings, Matcher};
use cosem_host::align::{prepare, DEFAULT_LEVELS};
use cosem_host::eval::Start;
use cosem_host::kitti::FrameRange;
use cosem_host::mapping::{class_histogram, HostMap};
use cosem_host::pair::{Pair, PairSpec};
use cosem_host::report::pose_words;
use cosem_host::synth::{write_sequence, SynthConfig};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Frames to synthesise; robot A maps the first half, robot B the second.
    #[arg(long, default_value_t = 20)]
    frames: usize,
    /// Seed of the synthetic street.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Voxel size (m).
    #[arg(long, default_value = "0.2", value_parser = super::args::positive_f32)]
    voxel: f32,
    /// Keep the synthetic sequence and maps in this folder (default: a
    /// temporary folder, removed at the end).
    #[arg(long)]
    out: Option<PathBuf>,
}

fn describe(name: &str, range: FrameRange, map: &HostMap, voxel: f32) {
    let top: Vec<String> = class_histogram(map).iter().take(6).map(|(c, n)| format!("{} {}", c.name(), n)).collect();
    println!("robot {name}: frames {range}, {} voxels at {voxel} m; largest classes: {}", map.len(), top.join(", "));
}

pub fn run(a: Args) -> Result<(), Error> {
    if a.frames < 2 {
        return Err("--frames must be at least 2".into());
    }
    let tmp = TempDir::new("cosem-demo");
    let dir = a.out.clone().unwrap_or_else(|| tmp.0.clone());
    let t0 = std::time::Instant::now();
    write_sequence(&dir, &SynthConfig { frames: a.frames, seed: a.seed, ..SynthConfig::default() })?;
    println!("synthetic street: {} frames, seed {}, in {}", a.frames, a.seed, dir.display());
    let half = a.frames / 2;
    let (ra, rb) =
        (FrameRange { start: 0, end: half, stride: 1 }, FrameRange { start: half, end: a.frames, stride: 1 });
    let pair = Pair::load(&PairSpec::new(&dir, ra, rb, a.voxel))?;
    // Robot B's map travels as bytes, in the compact (quantised) encoding:
    // what arrives encodes back to exactly what was sent.
    let (bytes_b, received_b) = cosem_host::cmap::round_trip(&pair.map_b, &format!("synthetic {rb}"))?;
    if a.out.is_some() {
        cosem_host::cmap::write(&dir.join("robot_a.cmap"), &pair.map_a, None, Some(&format!("synthetic {ra}")))?;
        std::fs::write(dir.join("robot_b.cmap"), &bytes_b)?;
    }
    describe("A (model)", ra, &pair.map_a, a.voxel);
    describe("B (scene)", rb, &received_b, a.voxel);
    let per_voxel = bytes_b.len() as f64 / received_b.len().max(1) as f64;
    println!("robot B's map: {} bytes as a map file ({per_voxel:.1} bytes/voxel)", bytes_b.len());
    println!("ground truth T_A_B: {}", pose_words(&pair.gt));
    let o = |t: &Isometry3<f64>| 100.0 * overlap(&pair.map_a, &received_b, &t.cast::<f32>());
    println!(
        "overlap of B in A: {:.1}% under the ground truth, {:.1}% under the identity",
        o(&pair.gt),
        o(&Isometry3::identity())
    );
    // The prior: the truth moved 5 m and turned 15 degrees (paper-grid style).
    let prior = Start { dx: 3.0, dy: 4.0, dyaw: 15.0 }.apply(&pair.gt);
    println!("prior (5 m, 15 deg off): {}", pose_words(&prior));
    let tp = std::time::Instant::now();
    let (pa, pb) = (prepare(&pair.map_a, DEFAULT_LEVELS)?, prepare(&received_b, DEFAULT_LEVELS)?);
    let prep_ms = tp.elapsed().as_secs_f64() * 1e3;
    let tm = std::time::Instant::now();
    let r = Matcher::new(MatchSettings::default()).align(&pa, &pb, &prior.cast::<f32>())?;
    let match_ms = tm.elapsed().as_secs_f64() * 1e3;
    println!("estimate  T_A_B: {}", pose_words(&r.transform.cast::<f64>()));
    println!(
        "match: {} after {} iterations, {} inliers, overlap {:.1}%, rmse {:.3} m, in {match_ms:.1} ms (+{prep_ms:.1} ms preparing both maps)",
        r.status.as_str(),
        r.iterations,
        r.inliers,
        100.0 * r.overlap,
        r.rmse
    );
    let (et, er) = errors_of(&r.transform, &pair.gt);
    println!("error against the truth: {et:.3} m, {er:.3} deg");
    println!("done in {:.2} s", t0.elapsed().as_secs_f64());
    Ok(())
}
