//! `cosem demo`: the main job on built-in data. Synthesises a street, builds
//! two robots' maps from the two halves of the drive, sends robot B's map
//! through the map file encoding, and describes both against the truth.

use super::bench::TempDir;
use super::{class_histogram, Error};
use cosem_core::map::{overlap, MapConfig};
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
    // Robot B's map travels as bytes; what arrives must be what was sent.
    let bytes_b = cosem_host::cmap::encode(&map_b, None, Some(format!("synthetic {rb}")));
    let (_, received_b) = cosem_host::cmap::decode(&bytes_b, &dir.join("robot_b.cmap"))?;
    if received_b.voxels() != map_b.voxels() {
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
    println!("done in {:.2} s", t0.elapsed().as_secs_f64());
    Ok(())
}
