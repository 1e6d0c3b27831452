//! `cosem demo`: the main job on built-in data. Synthesises a street, builds
//! two robots' maps from the two halves of the drive, sends robot B's map
//! through the map file encoding, matches it against robot A's from a prior
//! 5 m and 15 degrees off, and prints the estimate against the truth.

use super::bench::TempDir;
use super::{class_histogram, Error};
use cosem_core::map::{overlap, MapConfig};
use cosem_core::matching::{MatchSettings, Matcher};
use cosem_host::align::{errors, prepare, to_matrix, Start, DEFAULT_LEVELS};
use cosem_host::kitti::{FrameRange, Sequence};
use cosem_host::mapping::{build_map, PointFilter};
use cosem_host::pose;
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
    #[arg(long, default_value_t = 0.2)]
    voxel: f32,
    /// Keep the synthetic sequence and maps in this folder (default: a
    /// temporary folder, removed at the end).
    #[arg(long)]
    out: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<(), Error> {
    if a.frames < 2 {
        return Err("--frames must be at least 2".into());
    }
    let (dir, _tmp) = match &a.out {
        Some(d) => (d.clone(), None),
        None => {
            let d = std::env::temp_dir().join(format!("cosem-demo-{}", std::process::id()));
            (d.clone(), Some(TempDir(d)))
        }
    };
    let t0 = std::time::Instant::now();
    let cfg = SynthConfig { frames: a.frames, seed: a.seed, ..SynthConfig::default() };
    write_sequence(&dir, &cfg)?;
    println!("synthetic street: {} frames, seed {}, in {}", a.frames, a.seed, dir.display());
    let seq = Sequence::open(&dir)?;
    let half = a.frames / 2;
    let ra = FrameRange { start: 0, end: half, stride: 1 };
    let rb = FrameRange { start: half, end: a.frames, stride: 1 };
    let config = MapConfig::with_resolution(a.voxel);
    let filter = PointFilter::default();
    let (map_a, stats_a) = build_map(&seq.load_range(ra)?, config, &filter)?;
    let (map_b, stats_b) = build_map(&seq.load_range(rb)?, config, &filter)?;
    // Robot B's map travels as bytes, in the compact (quantised) encoding:
    // what arrives encodes back to exactly what was sent.
    let bytes_b = cosem_host::cmap::encode(&map_b, None, Some(format!("synthetic {rb}")));
    let (_, received_b) = cosem_host::cmap::decode(&bytes_b, &dir.join("robot_b.cmap"))?;
    if received_b.len() != map_b.len()
        || cosem_host::cmap::encode(&received_b, None, Some(format!("synthetic {rb}"))) != bytes_b
    {
        return Err("robot B's map changed through the map encoding".into());
    }
    if a.out.is_some() {
        cosem_host::cmap::write(&dir.join("robot_a.cmap"), &map_a, None, Some(format!("synthetic {ra}")))?;
        std::fs::write(dir.join("robot_b.cmap"), &bytes_b)?;
    }
    for (name, range, map, stats) in [("A (model)", ra, &map_a, stats_a), ("B (scene)", rb, &received_b, stats_b)] {
        let hist = class_histogram(map);
        let top: Vec<String> = hist.iter().take(6).map(|(c, n)| format!("{} {}", c.name(), n)).collect();
        println!(
            "robot {name}: frames {range}, {} points fused, {} voxels at {} m; largest classes: {}",
            stats.kept,
            map.len(),
            a.voxel,
            top.join(", ")
        );
    }
    println!(
        "robot B's map: {} bytes as a map file ({:.1} bytes/voxel)",
        bytes_b.len(),
        bytes_b.len() as f64 / received_b.len() as f64
    );
    let gt = seq.relative_pose(ra.start, rb.start)?;
    let g = pose::to_xyz_rpy_deg(&gt);
    println!(
        "ground truth T_A_B: x {:.3} m, y {:.3} m, z {:.3} m, roll {:.2}, pitch {:.2}, yaw {:.2} deg",
        g[0], g[1], g[2], g[3], g[4], g[5]
    );
    let iso = pose::to_isometry(&gt);
    println!(
        "overlap of B in A: {:.1}% under the ground truth, {:.1}% under the identity",
        100.0 * overlap(&map_a, &received_b, &iso),
        100.0 * overlap(&map_a, &received_b, &nalgebra::Isometry3::identity())
    );
    // The prior: the truth moved 5 m and turned 15 degrees (paper-grid style).
    let start = Start { dx: 3.0, dy: 4.0, dyaw: 15.0 };
    let prior = start.apply(&gt);
    let p = pose::to_xyz_rpy_deg(&prior);
    println!(
        "prior (5 m, 15 deg off): x {:.3} m, y {:.3} m, z {:.3} m, roll {:.2}, pitch {:.2}, yaw {:.2} deg",
        p[0], p[1], p[2], p[3], p[4], p[5]
    );
    let tp = std::time::Instant::now();
    let pa = prepare(&map_a, DEFAULT_LEVELS)?;
    let pb = prepare(&received_b, DEFAULT_LEVELS)?;
    let prep_ms = tp.elapsed().as_secs_f64() * 1e3;
    let tm = std::time::Instant::now();
    let r = Matcher::new(MatchSettings::default()).align(&pa, &pb, &pose::to_isometry(&prior))?;
    let match_ms = tm.elapsed().as_secs_f64() * 1e3;
    let est = to_matrix(&r.transform);
    let e = pose::to_xyz_rpy_deg(&est);
    let (et, er) = errors(&est, &gt);
    println!(
        "estimate  T_A_B: x {:.3} m, y {:.3} m, z {:.3} m, roll {:.2}, pitch {:.2}, yaw {:.2} deg",
        e[0], e[1], e[2], e[3], e[4], e[5]
    );
    println!(
        "match: {} after {} iterations, {} inliers, overlap {:.1}%, rmse {:.3} m, in {:.1} ms (+{:.1} ms preparing both maps)",
        r.status.as_str(),
        r.iterations,
        r.inliers,
        100.0 * r.overlap,
        r.rmse,
        match_ms,
        prep_ms
    );
    println!("error against the truth: {:.3} m, {:.3} deg", et, er);
    println!("done in {:.2} s", t0.elapsed().as_secs_f64());
    Ok(())
}
