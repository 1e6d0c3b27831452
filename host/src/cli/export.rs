//! `cosem export ply`: a map as a coloured point cloud.

use super::Error;
use cosem_host::ply::{self, PlyPoint};
use std::path::PathBuf;

#[derive(clap::Subcommand, Debug)]
pub enum Format {
    /// PLY with x, y, z, SemanticKITTI colours, class index and raw label.
    Ply {
        /// Map file.
        file: PathBuf,
        /// Output PLY file.
        #[arg(short, long)]
        output: PathBuf,
    },
}

pub fn run(f: Format) -> Result<(), Error> {
    match f {
        Format::Ply { file, output } => {
            cosem_host::paths::refuse_overwrite(&output, &[&file])?;
            let (_, map) = cosem_host::cmap::read(&file)?;
            let id = cosem_core::geometry::Isometry3::identity();
            let colour = |v: &cosem_core::map::SemanticVoxel| v.class().map(|c| c.color()).unwrap_or([128; 3]);
            let points: Vec<PlyPoint> = map.iter().map(|v| PlyPoint::of(v, map.resolution(), &id, colour(v))).collect();
            ply::write(&output, &points).map_err(|e| format!("{}: {e}", output.display()))?;
            println!("{}: {} points", output.display(), points.len());
            Ok(())
        }
    }
}
