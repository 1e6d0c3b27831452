//! `cosem robots`: two robots on emulated Cortex-M4F boards map, exchange
//! maps over their UART0s and match on board; printed beside the host's own
//! run of the same pipeline on the same fed data and the ground truth.

use super::args::{pose, voxel};
use super::{show, Error};
use cosem_core::geometry::Isometry3;
use cosem_host::boards::board::Board;
use cosem_host::boards::firmware::DEFAULT_FIRMWARE;
use cosem_host::boards::pump::LineFault;
use cosem_host::boards::robots::{run_robots, RobotsSpec};
use cosem_host::reports::robots::{exit_code, RobotsJson};
use cosem_host::sources::kitti::FrameRange;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The scans: a SemanticKITTI-layout folder, a ROS 2 recording (.mcap)
    /// or a folder of PCD/PLY scans with poses.txt.
    #[arg(long)]
    data: PathBuf,
    #[command(flatten)]
    source: super::args::SourceArgs,
    /// Robot A's frames.
    #[arg(long)]
    a: FrameRange,
    /// Robot B's frames.
    #[arg(long)]
    b: FrameRange,
    /// Voxel size on board (m); each scan is fed as one point per voxel.
    /// Default: the boards' own (0.5 on mps2-an386, 0.7 on stm32f405; the
    /// larger of the two).
    #[arg(long, value_parser = voxel)]
    voxel: Option<f32>,
    /// Points farther than this from their sensor are not fed (m).
    #[arg(long, default_value_t = super::args::ROBOT_CROP, value_parser = super::args::crop)]
    crop: f32,
    /// Robot A's prior `T_A_B` as x,y,z,roll,pitch,yaw (m, degrees); robot B
    /// gets its inverse. Default: the ground truth moved by 2 m and turned
    /// by 10 degrees.
    #[arg(long, allow_hyphen_values = true, conflicts_with = "no_prior", value_parser = pose)]
    prior: Option<Isometry3<f64>>,
    /// Give the robots no prior: each aligns from the maps alone, on board.
    #[arg(long)]
    no_prior: bool,
    /// Print JSON.
    #[arg(long)]
    pub(super) json: bool,
    /// The firmware's robot binary for mps2-an386 boards (at the default
    /// path, built or brought up to date first).
    #[arg(long, default_value = DEFAULT_FIRMWARE)]
    firmware: PathBuf,
    /// Robot A's board: mps2-an386 (512 KiB: 8,192 voxels), stm32f405
    /// (192 KiB: 3,008 voxels of 0.7 m) or stm32f405-sender (it maps and
    /// sends its map, and is told the other robot's result).
    #[arg(long, default_value = "mps2-an386")]
    board_a: Board,
    /// Robot B's board (see --board-a).
    #[arg(long, default_value = "mps2-an386")]
    board_b: Board,
    /// What the line between the UART0s does: none, silent, corrupt=P (a
    /// bit of each byte flipped with probability P) or lossy=P (substituted, dropped, duplicated alike).
    #[arg(long, default_value = "none")]
    line: LineFault,
    /// A robot gives up on the link after this long without a valid frame (s).
    #[arg(long, default_value = "30", value_parser = super::args::seconds)]
    silence: f64,
    /// Kill both emulators after this long (s, at most a day).
    #[arg(long, default_value = "900", value_parser = super::args::seconds)]
    timeout: f64,
    /// Label noise on every scan before it is fed: none, network[:SEVERITY]
    /// or iid:P (see `cosem eval --help`); robot i's seed is --seed + i.
    #[arg(long, default_value = "none")]
    label_noise: cosem_host::maps::noise::LabelNoise,
    /// Seed of the label noise.
    #[arg(long, default_value = "1")]
    seed: u64,
}

pub fn run(a: Args) -> Result<u8, Error> {
    let spec = RobotsSpec {
        source: cosem_host::sources::source::Source::open(&a.data, &a.source.options())?,
        ranges: [a.a, a.b],
        voxel: a.voxel.unwrap_or(a.board_a.default_voxel().max(a.board_b.default_voxel())),
        crop: a.crop,
        prior: a.prior,
        no_prior: a.no_prior,
        firmware: a.firmware,
        boards: [a.board_a, a.board_b],
        line: a.line,
        silence_s: a.silence,
        timeout_s: a.timeout,
        label_noise: (a.label_noise, a.seed),
    };
    let run = run_robots(&spec)?;
    show(a.json, &RobotsJson::of(&run))?;
    exit_code(&run).ok_or_else(|| "a robot did not report a match".into())
}
