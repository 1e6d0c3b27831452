//! `cosem export ply`: a map as a coloured point cloud. `cosem export
//! scans`: a SemanticKITTI folder's scans as PCD or PLY files and their
//! poses, the input `cosem map --format` reads. `cosem export mcap`: the
//! same as a ROS 2 recording, the input `cosem map --mcap` reads.

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
    /// A SemanticKITTI folder's scans as labelled point clouds, one file a
    /// scan in the LiDAR's frame (x, y, z, label: the raw label word), and
    /// `poses.txt`: each scan's LiDAR pose in KITTI's layout.
    Scans {
        /// SemanticKITTI-layout folder.
        #[arg(long)]
        data: PathBuf,
        /// Frames START:END[:STRIDE] (END exclusive).
        #[arg(long)]
        frames: cosem_host::kitti::FrameRange,
        /// File format.
        #[arg(long)]
        format: cosem_host::cloud::CloudFormat,
        /// Output folder (created; never inside the input folder; a folder
        /// that already holds scans or poses only with --force).
        #[arg(short, long)]
        output: PathBuf,
        /// Write into a folder that already holds scans or poses (files of
        /// the same names are replaced).
        #[arg(long)]
        force: bool,
    },
    /// A SemanticKITTI folder's scans as a ROS 2 recording (MCAP, zstd):
    /// PointCloud2 in frame `velodyne` (x, y, z, label) on --topic and the
    /// LiDAR's pose `world -> velodyne` on /tf at each scan's stamp.
    Mcap {
        /// SemanticKITTI-layout folder.
        #[arg(long)]
        data: PathBuf,
        /// Frames START:END[:STRIDE] (END exclusive).
        #[arg(long)]
        frames: cosem_host::kitti::FrameRange,
        /// The point cloud topic.
        #[arg(long, default_value = "/velodyne_points")]
        topic: String,
        /// Chunk compression.
        #[arg(long, value_enum, default_value = "zstd")]
        compression: cosem_host::recording::ChunkCompression,
        /// Output MCAP file (never inside the input folder).
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
        Format::Scans { data, frames, format, output, force } => {
            use cosem_host::cloud::{write_pcd, write_ply, write_poses, CloudFormat};
            cosem_host::paths::refuse_inside(&output, &[&data])?;
            if !force {
                refuse_used_folder(&output)?;
            }
            let seq = cosem_host::kitti::Sequence::open(&data)?;
            std::fs::create_dir_all(&output).map_err(|e| format!("{}: {e}", output.display()))?;
            let mut poses = Vec::new();
            let ext = match format {
                CloudFormat::Pcd => "pcd",
                CloudFormat::Ply => "ply",
            };
            for i in frames.frames() {
                let scan = seq.read_scan(i)?;
                poses.push(seq.velodyne_matrix(i)?);
                let points: Vec<[f32; 3]> = scan.points.iter().map(|p| [p[0], p[1], p[2]]).collect();
                let path = output.join(format!("{i:06}.{ext}"));
                match format {
                    CloudFormat::Pcd => write_pcd(&path, &points, &scan.labels)?,
                    CloudFormat::Ply => write_ply(&path, &points, &scan.labels)?,
                }
            }
            write_poses(&output.join("poses.txt"), &poses)?;
            println!("{}: {} scans as {ext} and poses.txt", output.display(), poses.len());
            Ok(())
        }
        Format::Mcap { data, frames, topic, compression, output } => {
            cosem_host::paths::refuse_inside(&output, &[&data])?;
            if output.is_dir() {
                return Err(format!("{}: is a folder; -o names the recording file to write", output.display()).into());
            }
            let seq = cosem_host::kitti::Sequence::open(&data)?;
            let n = cosem_host::recording::export(&seq, frames, &topic, compression, &output)?;
            println!("{}: {n} scans on {topic} and /tf", output.display());
            Ok(())
        }
    }
}

/// Refuses an existing folder that holds scans or poses already (a
/// SemanticKITTI folder, an earlier export): they would be replaced.
fn refuse_used_folder(output: &std::path::Path) -> Result<(), Error> {
    let Ok(entries) = std::fs::read_dir(output) else { return Ok(()) };
    let held = entries
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .find(|n| n == "poses.txt" || n == "velodyne" || n == "labels" || n.ends_with(".pcd") || n.ends_with(".ply"));
    match held {
        Some(name) => Err(format!(
            "{}: already holds {name}: scans and poses are not replaced without --force (or choose a new folder)",
            output.display()
        )
        .into()),
        None => Ok(()),
    }
}
