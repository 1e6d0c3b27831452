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
            let (_, map) = cosem_host::cmap::read(&file)?;
            let points: Vec<PlyPoint> = map
                .iter()
                .map(|v| {
                    let c = v.class();
                    PlyPoint {
                        position: v.position(map.resolution()),
                        color: c.map(|c| c.color()).unwrap_or([128; 3]),
                        class: c.map(|c| c.index()).unwrap_or(255),
                        label: c.map(|c| c.semantic_kitti_id()).unwrap_or(0),
                    }
                })
                .collect();
            ply::write(&output, &points).map_err(|e| format!("{}: {e}", output.display()))?;
            println!("{}: {} points", output.display(), points.len());
            Ok(())
        }
    }
}
