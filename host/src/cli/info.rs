//! `cosem info`: what a map file holds.

use super::{print_json, Error};
use cosem_core::map::BYTES_PER_VOXEL;
use cosem_host::mapping::class_histogram;
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Map file.
    file: PathBuf,
    /// Print JSON.
    #[arg(long)]
    pub(super) json: bool,
}

pub fn run(a: Args) -> Result<(), Error> {
    let (header, map) = cosem_host::cmap::read(&a.file)?;
    let bytes = std::fs::metadata(&a.file)?.len();
    let voxels = map.len();
    let per_voxel = bytes as f64 / voxels.max(1) as f64;
    let hist = class_histogram(&map);
    let (lo, hi) = map.bounds().unwrap_or(([0.0; 3], [0.0; 3]));
    let wire = cosem_host::cmap::wire_bytes_per_voxel(&map, cosem_core::wire::mapfile::FILE_CHUNK);
    // The source is text from the file: escaped, so no control byte reaches a terminal.
    let source = header.source.as_ref().map(|s| s.escape_debug().to_string());
    if a.json {
        return print_json(&cosem_host::report::InfoJson {
            file: a.file.display().to_string(),
            voxels,
            resolution: map.resolution(),
            bounds: BTreeMap::from([("min", lo), ("max", hi)]),
            bytes,
            bytes_per_voxel: per_voxel,
            memory_bytes_per_voxel: BYTES_PER_VOXEL,
            wire_bytes_per_voxel: wire,
            classes: hist.iter().map(|(c, n)| (c.name(), *n)).collect(),
            anchor_time: header.anchor_time,
            source,
            label_accuracy: header.label_accuracy,
        });
    }
    println!("{}", a.file.display());
    if let Some(s) = &source {
        println!("  source:      {s}");
    }
    println!("  voxels:      {voxels} at {} m", map.resolution());
    println!(
        "  bounds:      [{:.1}, {:.1}, {:.1}] .. [{:.1}, {:.1}, {:.1}] m",
        lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    );
    println!("  file:        {bytes} bytes, {per_voxel:.2} bytes/voxel");
    println!("  encoding:    {wire:.2} bytes/voxel (as on the link)");
    println!("  memory:      {BYTES_PER_VOXEL} bytes/voxel (index included)");
    println!("  classes:");
    for (c, n) in &hist {
        println!("    {:<14} {:>8}  {:5.1}%", c.name(), n, 100.0 * *n as f64 / voxels.max(1) as f64);
    }
    Ok(())
}
