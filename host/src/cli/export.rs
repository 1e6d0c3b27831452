//! `cosem export ply`: a map as a coloured point cloud. `cosem export
//! scans`: a SemanticKITTI folder's scans as PCD or PLY files and their
//! poses, the input `cosem map --format` reads. `cosem export mcap`: the
//! same as a ROS 2 recording, the input `cosem map --mcap` reads.

use super::Error;
use std::path::PathBuf;

#[derive(clap::Subcommand, Debug)]
pub enum Format {
    /// PLY with x, y, z, SemanticKITTI colours, class index and raw label.
    Ply {
        /// Map file.
        file: PathBuf,
        /// Output PLY file.
        #[arg(short, long, value_name = "OUT")]
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
        frames: cosem_host::sources::kitti::FrameRange,
        /// File format.
        #[arg(long, value_parser = super::args::named::<cosem_host::sources::cloud::CloudFormat>())]
        format: cosem_host::sources::cloud::CloudFormat,
        /// Output folder, written whole and swapped into place: a new or
        /// empty folder, or with --force an earlier export (never inside,
        /// over or around the input folder).
        #[arg(short, long, value_name = "OUT")]
        output: PathBuf,
        /// Replace an earlier export (a folder of scans and poses.txt only).
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
        frames: cosem_host::sources::kitti::FrameRange,
        /// The point cloud topic.
        #[arg(long, default_value = "/velodyne_points")]
        topic: String,
        /// Chunk compression.
        #[arg(long, default_value = "zstd",
            value_parser = super::args::named::<cosem_host::sources::recording::ChunkCompression>())]
        compression: cosem_host::sources::recording::ChunkCompression,
        /// Output MCAP file (never inside the input folder).
        #[arg(short, long, value_name = "OUT")]
        output: PathBuf,
    },
}

pub fn run(f: Format) -> Result<(), Error> {
    match f {
        Format::Ply { file, output } => {
            let n = cosem_host::maps::ply::export_map(&file, &output)?;
            println!("{}: {n} points", output.display());
        }
        Format::Scans { data, frames, format, output, force } => {
            let n = cosem_host::sources::cloud::export_scans(&data, frames, format, &output, force)?;
            println!("{}: {n} scans as {} and poses.txt", output.display(), format.extension());
        }
        Format::Mcap { data, frames, topic, compression, output } => {
            cosem_host::paths::check_output("--output", &output, &[("--data", &data)])?;
            if topic.is_empty() || topic.chars().any(|c| c.is_whitespace() || c.is_control()) {
                return Err(format!("--topic `{topic}`: expected a ROS 2 topic name such as /velodyne_points").into());
            }
            if output.is_dir() {
                return Err(format!("{}: is a folder; -o names the recording file to write", output.display()).into());
            }
            let seq = cosem_host::sources::kitti::Sequence::open(&data)?;
            let n = cosem_host::sources::recording::export(&seq, frames, &topic, compression, &output)?;
            println!("{}: {n} scans on {topic} and /tf", output.display());
        }
    }
    Ok(())
}
