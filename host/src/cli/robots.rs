//! `cosem robots`: two robots on emulated Cortex-M4F boards map, exchange
//! maps over their UART0s and match on board; printed beside the host's own
//! run of the same pipeline on the same fed data and the ground truth.

use super::args::{pose, positive, positive_f32};
use super::{print_json, Error};
use cosem_core::geometry::Isometry3;
use cosem_host::board::Board;
use cosem_host::kitti::FrameRange;
use cosem_host::report::status_code;
use cosem_host::robots::{
    default_prior, feeds, firmware, host_run, run_pair, summarise, LineFault, Outcome, DEFAULT_FIRMWARE,
};
use std::path::PathBuf;
use std::time::Duration;

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
    #[arg(long, default_value = "0.5", value_parser = positive_f32)]
    voxel: f32,
    /// Points farther than this from their sensor are not fed (m).
    #[arg(long, default_value = "25", value_parser = positive_f32)]
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
    /// Robot A's board: mps2-an386 (the full robot) or stm32f405 (192 KiB:
    /// it maps and sends its map, and is told the other robot's result).
    #[arg(long, default_value = "mps2-an386")]
    board_a: Board,
    /// Robot B's board (see --board-a).
    #[arg(long, default_value = "mps2-an386")]
    board_b: Board,
    /// What the line between the UART0s does: none, silent, or corrupt=P
    /// (each byte flipped with probability P).
    #[arg(long, default_value = "none")]
    line: LineFault,
    /// A robot gives up on the link after this long without a valid frame (s).
    #[arg(long, default_value = "30", value_parser = positive)]
    silence: f64,
    /// Kill both emulators after this long (s, at most a day).
    #[arg(long, default_value = "900", value_parser = positive)]
    timeout: f64,
    /// Label noise on every scan before it is fed: none, network[:SEVERITY]
    /// or iid:P (see `cosem eval --help`); robot i's seed is --seed + i.
    #[arg(long, default_value = "none")]
    label_noise: cosem_host::noise::LabelNoise,
    /// Seed of the label noise.
    #[arg(long, default_value = "1")]
    seed: u64,
}

pub fn run(a: Args) -> Result<u8, Error> {
    let seq = cosem_host::source::Source::open(&a.data, &a.source.options())?;
    let gt = seq.relative_pose(a.a.start, a.b.start)?;
    let prior = (!a.no_prior).then(|| a.prior.unwrap_or_else(|| default_prior(&gt)));
    let silence_ms = (a.silence * 1000.0).min(f64::from(u32::MAX)) as u32;
    let feeds = feeds(&seq, [a.a, a.b], a.voxel, a.crop, prior.as_ref(), silence_ms, a.label_noise, a.seed)?;
    // The host runs both robots' pipeline too, as the boards do.
    let t = std::time::Instant::now();
    let boards = [a.board_a, a.board_b];
    if !boards.iter().any(|b| b.matches()) {
        return Err("--board-a and --board-b: one robot must be able to match (an mps2-an386 board)".into());
    }
    let host = host_run([&feeds[0], &feeds[1]], boards)?;
    let host_ms = t.elapsed().as_secs_f64() * 1e3;
    let elf = |b: Board| match b {
        Board::Mps2An386 => firmware(&a.firmware),
        Board::Stm32f405 => firmware(std::path::Path::new(b.default_firmware())),
    };
    let elves = [elf(boards[0])?, elf(boards[1])?];
    let timeout = Duration::from_secs_f64(a.timeout.min(86_400.0));
    let run = run_pair([&elves[0], &elves[1]], boards, [&feeds[0], &feeds[1]], a.line, timeout)?;
    let mut report = summarise(&run, feeds[0].setup.prior.as_ref(), &host, host_ms, &gt);
    if a.label_noise != cosem_host::noise::LabelNoise::None {
        report.label_noise = Some(format!("{:?}, seed {} (+ robot id)", a.label_noise, a.seed));
    }
    if a.json {
        print_json(&report)?;
    } else {
        print!("{report}");
    }
    // The worse of the two robots: a robot that did not report is an
    // error; else the worse status.
    let mut code = 0;
    for r in &run.robots {
        match &r.outcome {
            Outcome::Report(rep) => code = code.max(status_code(rep.result.status)),
            _ => return Err("a robot did not report a match".into()),
        }
    }
    Ok(code)
}
