//! `cosem bench map`: insertion throughput and memory, printed as numbers.

use super::{data_root, Error};
use cosem_core::classes::{Class, MovingObjects};
use cosem_core::map::{MapConfig, BYTES_PER_VOXEL};
use cosem_host::kitti::{FrameRange, Sequence};
use cosem_host::mapping::{new_map, PointFilter};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Subcommand, Debug)]
pub enum What {
    /// Points fused per second into a local map (single thread).
    Map(MapArgs),
}

#[derive(clap::Args, Debug)]
pub struct MapArgs {
    /// SemanticKITTI-layout folder; default `$COSEM_DATA/kitti00`, else a
    /// synthetic sequence.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Frames START:END[:STRIDE].
    #[arg(long, default_value = "0:10")]
    frames: FrameRange,
    /// Voxel size (m).
    #[arg(long, default_value_t = 0.2)]
    voxel: f32,
    /// Repetitions (the median is reported).
    #[arg(long, default_value_t = 5)]
    repeat: usize,
}

pub fn run(w: What) -> Result<(), Error> {
    match w {
        What::Map(a) => bench_map(a),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn bench_map(a: MapArgs) -> Result<(), Error> {
    let (dir, _tmp) = match a.data {
        Some(d) => (d, None),
        None => {
            let kitti = data_root().join("kitti00");
            if kitti.join("poses.txt").exists() {
                (kitti, None)
            } else {
                let tmp = std::env::temp_dir().join(format!("cosem-bench-{}", std::process::id()));
                let cfg = cosem_host::synth::SynthConfig { frames: a.frames.end, ..Default::default() };
                cosem_host::synth::write_sequence(&tmp, &cfg)?;
                println!("(no kitti00 under {}: using a synthetic sequence)", data_root().display());
                (tmp.clone(), Some(TempDir(tmp)))
            }
        }
    };
    let seq = Sequence::open(&dir)?;
    let frames = seq.load_range(a.frames)?;
    let filter = PointFilter { max_range: None, moving: MovingObjects::Skip };
    let labelled: Vec<([f32; 3], Class)> = frames
        .iter()
        .flat_map(|f| f.points.iter().zip(&f.ranges).zip(&f.labels).map(|((p, r), l)| (*p, *r, *l)))
        .filter_map(|(p, r, l)| filter.keep(r, l).map(|c| (p, c)))
        .collect();
    let raw_points: usize = frames.iter().map(|f| f.points.len()).sum();
    let config = MapConfig::with_resolution(a.voxel);
    let mut map = new_map(labelled.len(), config)?;
    let repeat = a.repeat.max(1);
    let mut insert_times = Vec::new();
    let mut full_times = Vec::new();
    for _ in 0..repeat {
        map.clear();
        let t = Instant::now();
        for (p, c) in &labelled {
            map.insert_point(*p, *c)?;
        }
        insert_times.push(t.elapsed().as_secs_f64());
        map.clear();
        // Raw labels through the class map and range filter, then fused.
        let t = Instant::now();
        for f in &frames {
            for ((p, &r), &l) in f.points.iter().zip(&f.ranges).zip(&f.labels) {
                if let Some(c) = filter.keep(r, l) {
                    map.insert_point(*p, c)?;
                }
            }
        }
        full_times.push(t.elapsed().as_secs_f64());
    }
    let ti = median(insert_times);
    let tf = median(full_times);
    let mut coarse = new_map(map.len(), config)?;
    let t = Instant::now();
    map.coarsen_into(5, &mut coarse)?;
    let t_coarse = t.elapsed().as_secs_f64();
    let file_bytes = cosem_host::cmap::encode(&map, None, None).len();
    println!("bench map: {} frames {} of {}", frames.len(), a.frames, dir.display());
    println!("  points read          {raw_points}");
    println!("  points fused         {}", labelled.len());
    println!("  voxels               {} at {} m", map.len(), a.voxel);
    println!(
        "  insert               {:.1} M points/s ({:.1} ns/point, {:.2} ms per 120k-point scan)",
        labelled.len() as f64 / ti / 1e6,
        ti / labelled.len() as f64 * 1e9,
        ti / labelled.len() as f64 * 120_000.0 * 1e3
    );
    println!("  classify + insert    {:.1} M points/s over all {raw_points} points read", raw_points as f64 / tf / 1e6);
    println!("  coarsen x5           {:.2} ms -> {} voxels at {} m", t_coarse * 1e3, coarse.len(), a.voxel * 5.0);
    println!("  memory per voxel     {BYTES_PER_VOXEL} bytes (24 voxel + 8 index, load factor <= 0.5)");
    println!("  file per voxel       {:.2} bytes ({file_bytes} bytes)", file_bytes as f64 / map.len().max(1) as f64);
    println!("  (median of {repeat} runs, single thread)");
    Ok(())
}

/// Removes a temporary folder when dropped.
pub struct TempDir(pub PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
