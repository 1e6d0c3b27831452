//! `cosem map`: frames -> local map -> `.cmap` file. Frames from a
//! SemanticKITTI-layout folder (`--data`, `--frames`), or from a user's
//! scans as PCD or PLY files with their poses (`--format`, `--poses`).

use super::Error;
use cosem_core::classes::MovingObjects;
use cosem_core::map::{MapConfig, SensorModel};
use cosem_host::evaluation::job::MapJob;
use cosem_host::maps::mapping::PointFilter;
use cosem_host::maps::noise::LabelNoise;
use cosem_host::sources::kitti::FrameRange;
use cosem_host::sources::source::Source;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The scans: a SemanticKITTI-layout folder (velodyne/, labels/,
    /// poses.txt, calib.txt), a ROS 2 recording (.mcap, as --mcap), or a
    /// folder of .pcd or .ply scans with poses.txt.
    #[arg(long, required_unless_present_any = ["format", "mcap"], conflicts_with_all = ["format", "mcap"])]
    data: Option<PathBuf>,
    /// Frames START:END[:STRIDE] (END exclusive); the first is the anchor.
    /// Needed for a SemanticKITTI folder; of a recording, 0-based indices
    /// among the topic's messages, of scan files, among the files in name
    /// order (default: all of them).
    #[arg(long, conflicts_with = "format")]
    frames: Option<FrameRange>,
    /// A ROS 2 recording (MCAP): PointCloud2 scans on --points, poses from
    /// /tf and /tf_static (zstd or lz4 chunks read).
    #[arg(long, conflicts_with = "format")]
    mcap: Option<PathBuf>,
    /// Read scans from these files instead, one per scan in the sensor's
    /// frame, in order (the first is the anchor): labelled point clouds
    /// (fields x, y, z and an integer label holding the SemanticKITTI id in
    /// its low 16 bits; NaN points skipped).
    #[arg(long, requires = "poses", value_parser = super::args::named::<cosem_host::sources::cloud::CloudFormat>())]
    format: Option<cosem_host::sources::cloud::CloudFormat>,
    /// The scans' files (with --format).
    #[arg(requires = "format")]
    files: Vec<PathBuf>,
    /// With --format: the sensor's pose for each scan in KITTI's layout (one
    /// line each: 12 numbers, the row-major 3x4 pose in the map frame).
    #[arg(long, requires = "format")]
    poses: Option<PathBuf>,
    /// How a recording or scan files are read, and a class table for a
    /// user's label ids (`[ids]`: `1 = "road"`, `0 = "unlabeled"`, ...;
    /// an id it does not name is an error).
    #[command(flatten)]
    source: super::args::SourceArgs,
    /// Voxel size (m).
    #[arg(long, default_value_t = super::args::HOST.voxel, value_parser = super::args::voxel)]
    voxel: f32,
    /// Drop points farther than this from their sensor (m); no limit by default.
    #[arg(long, value_parser = super::args::crop)]
    max_range: Option<f32>,
    /// Keep moving objects, mapped to their static class.
    #[arg(long)]
    keep_moving: bool,
    /// Unlabelled points (id 0; a camera's labels leave so the points
    /// outside its view): drop, or geometry (voxels of an unknown class).
    #[arg(long, default_value = "drop", value_parser = super::args::named::<cosem_host::maps::mapping::Unlabeled>())]
    unlabeled: cosem_host::maps::mapping::Unlabeled,
    /// Probability that a point's label is right (Bayes sensor model).
    #[arg(long, default_value_t = SensorModel::default().accuracy, value_parser = super::args::accuracy)]
    label_accuracy: f32,
    /// Label noise on every scan: none, network[:SEVERITY] or iid:P (see
    /// `cosem eval --help`).
    #[arg(long, default_value = "none")]
    label_noise: LabelNoise,
    /// Seed of the label noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output map file.
    #[arg(short, long, value_name = "OUT")]
    output: PathBuf,
}

pub fn run(a: Args) -> Result<(), Error> {
    let t0 = Instant::now();
    // Every file read is an input: the output is never one of them.
    let mut inputs: Vec<(&str, &std::path::Path)> = a.files.iter().map(|p| ("FILES", p.as_path())).collect();
    let named = [("--poses", &a.poses), ("--mcap", &a.mcap), ("--classes", &a.source.classes), ("--data", &a.data)];
    inputs.extend(named.into_iter().filter_map(|(n, p)| Some((n, p.as_deref()?))));
    cosem_host::paths::check_output("--output", &a.output, &inputs)?;
    let options = a.source.options();
    // Three spellings of one thing: a source of scans and a range of them.
    let source = match (&a.format, &a.poses, &a.data, &a.mcap) {
        (_, _, _, Some(file)) => Source::recording(file, &options)?,
        (Some(format), Some(poses), _, _) => {
            if a.files.is_empty() {
                return Err("--format needs the scans' files".into());
            }
            Source::scans(*format, &a.files, poses, &options)?
        }
        (_, _, Some(data), _) => Source::open(data, &options)?,
        _ => return Err("give --data and --frames, --mcap, or --format, the files and --poses".into()),
    };
    let name = match (&a.mcap, &a.format) {
        (Some(_), _) => format!("{} {}", source.name(), a.source.points),
        (_, Some(format)) => format!("{} {format:?} scans from {}", a.files.len(), a.files[0].display()),
        _ => source.name(),
    };
    let range = a.frames.map_or(if a.format.is_some() { String::new() } else { "all".into() }, |r| r.to_string());
    let moving = if a.keep_moving { MovingObjects::AsStatic } else { MovingObjects::Skip };
    let job = MapJob {
        frames: a.frames,
        config: MapConfig {
            resolution: a.voxel,
            sensor: SensorModel { accuracy: a.label_accuracy },
            ..MapConfig::default()
        },
        filter: PointFilter { max_range: a.max_range, moving, unlabeled: a.unlabeled },
        noise: (a.label_noise, a.seed),
    };
    let w = job.run(&source, &format!("{name} {range}"), &a.output)?;
    if w.skipped > 0 {
        eprintln!("{} points with a NaN coordinate skipped", w.skipped);
    }
    for warning in w.stats.warnings(a.voxel) {
        eprintln!("warning: {warning}");
    }
    let (points, kept, voxels, bytes) = (w.stats.points, w.stats.kept, w.voxels, w.bytes);
    let unknown = match w.stats.unknown_class {
        0 => String::new(),
        n => format!(" (and {n} unlabelled as geometry)"),
    };
    println!(
        "{}: {} frames, {points} points, {kept} kept{unknown}, {voxels} voxels at {} m, {bytes} bytes ({:.1} bytes/voxel) in {:.2} s",
        a.output.display(),
        w.frames,
        a.voxel,
        bytes as f64 / voxels.max(1) as f64,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
