//! `cosem demo`: the main job on built-in data (`cosem_host::evaluation::demo`).

use super::Error;
use cosem_host::evaluation::demo::{run as run_demo, Demo};
use cosem_host::paths::TempDir;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Frames to synthesise (2 to 100,000); robot A maps the first half,
    /// robot B the second.
    #[arg(long, default_value_t = 20, value_parser = super::args::frames_count)]
    frames: usize,
    /// Seed of the synthetic street.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Voxel size (m).
    #[arg(long, default_value_t = super::args::HOST.voxel, value_parser = super::args::voxel)]
    voxel: f32,
    /// Keep the synthetic sequence and maps in this folder (default: a
    /// temporary folder, removed at the end).
    #[arg(long, value_name = "OUT")]
    out: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<(), Error> {
    let tmp = TempDir::new("cosem-demo");
    let dir = a.out.clone().unwrap_or_else(|| tmp.0.clone());
    let demo = Demo { frames: a.frames, seed: a.seed, voxel: a.voxel, keep_maps: a.out.is_some() };
    Ok(run_demo(&demo, &dir, &mut std::io::stdout().lock())?)
}
