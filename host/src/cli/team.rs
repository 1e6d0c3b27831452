//! `cosem team`: N robots placed in robot 0's frame (see
//! `cosem_host::evaluation::team`).

use super::{show, Error};
use cosem_core::matching::MatchSettings;
use cosem_host::evaluation::team::{parse_prior_noise, parse_robot_pair, run as run_team, RobotSpec, TeamSpec};
use cosem_host::reports::team::TeamJson;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// A robot: a source of scans (a SemanticKITTI-layout folder, a ROS 2
    /// recording .mcap, or a folder of PCD/PLY scans with poses.txt) and
    /// its frames, PATH:START:END[:STRIDE]; robot i is the i-th (2 to 8).
    #[arg(long = "robot", required = true)]
    pub(super) robots: Vec<RobotSpec>,
    #[command(flatten)]
    pub(super) source: super::args::SourceArgs,
    /// Voxel size (m; default 0.2; on board the board's: 0.5 or 1).
    #[arg(long, value_parser = super::args::voxel)]
    pub(super) voxel: Option<f32>,
    /// No prior: every robot searches every heading and offset (the default).
    #[arg(long, conflicts_with = "prior_noise")]
    pub(super) no_prior: bool,
    /// A prior for robots of one trajectory: the true relative pose moved
    /// by METRES and DEGREES (seeded): METRES,DEGREES.
    #[arg(long, value_parser = parse_prior_noise)]
    pub(super) prior_noise: Option<(f64, f64)>,
    /// Replace robot I's estimate of robot J (only that direction) with one
    /// 5 m and 20 degrees off, Converged: I,J. Repeatable; given as I,J and
    /// J,I, one false match seen from both robots.
    #[arg(long, value_parser = parse_robot_pair)]
    pub(super) inject_false_match: Vec<(usize, usize)>,
    /// Label noise on every scan: none, network[:SEVERITY] or iid:P (see
    /// `cosem eval --help`).
    #[arg(long, default_value = "none")]
    pub(super) label_noise: cosem_host::maps::noise::LabelNoise,
    /// Seed of the prior and label noise.
    #[arg(long, default_value_t = 1)]
    pub(super) seed: u64,
    /// JSON on standard output.
    #[arg(long)]
    pub(super) json: bool,
    /// Run each robot on an emulated board (2 to 5 robots on mps2-an386, 2
    /// or 3 on stm32f405; no prior): fed its thinned scans, it maps,
    /// exchanges, matches, checks consistency and solves the pose graph on
    /// board; shown beside the host's run of the same robots on the same
    /// points.
    #[arg(long, conflicts_with_all = ["prior_noise", "inject_false_match"])]
    pub(super) on_board: bool,
    /// With --on-board: points farther than this from their sensor are not
    /// fed (m).
    #[arg(long, default_value_t = super::args::ROBOT_CROP, value_parser = super::args::crop)]
    pub(super) crop: f32,
    /// With --on-board: the boards, mps2-an386 or stm32f405 (voxels of 0.5
    /// or 1 m by default).
    #[arg(long, default_value = "mps2-an386")]
    pub(super) board: cosem_host::boards::board::Board,
    /// With --on-board: the firmware's team binary (default: the board's,
    /// built or brought up to date first).
    #[arg(long)]
    pub(super) firmware: Option<std::path::PathBuf>,
    /// With --on-board: a robot gives up on a peer after this long without a
    /// valid frame (s).
    #[arg(long, default_value = "60", value_parser = super::args::seconds)]
    pub(super) silence: f64,
    /// With --on-board: kill the emulators after this long (s).
    #[arg(long, default_value = "1800", value_parser = super::args::seconds)]
    pub(super) timeout: f64,
}

/// The team the arguments name (`default_voxel` without --voxel).
pub(super) fn spec(a: &Args, default_voxel: f32) -> TeamSpec {
    TeamSpec {
        robots: a.robots.clone(),
        voxel: a.voxel.unwrap_or(default_voxel),
        prior_noise: a.prior_noise,
        inject_false_match: a.inject_false_match.clone(),
        source: a.source.options(),
        label_noise: a.label_noise,
        seed: a.seed,
        settings: MatchSettings::default(),
    }
}

/// Exit code: 0 when every robot is placed in robot 0's frame; 5 when one
/// is not; 1 when a board stopped (`--on-board`: each robot on its own
/// emulated board, see `cosem_host::boards::team_board`, beside the host's run).
pub fn run(a: Args) -> Result<u8, Error> {
    if a.on_board {
        // No prior and no injected match on board (clap refuses them).
        let spec = spec(&a, a.board.default_team_voxel());
        let silence_ms = (a.silence * 1000.0).min(f64::from(u32::MAX)) as u32;
        let timeout = std::time::Duration::from_secs_f64(a.timeout.min(86_400.0));
        let board = (a.board, a.firmware.as_deref());
        let run = cosem_host::boards::team_board::run_on_boards(&spec, a.crop, silence_ms, board, timeout)?;
        let out = cosem_host::reports::team::TeamBoardJson::of(&run.boards, &run.host, &run.truth, run.wall_s)?;
        show(a.json, &out)?;
        return Ok(out.exit_code());
    }
    let spec = spec(&a, 0.2);
    let out = TeamJson::of(&run_team(&spec)?);
    show(a.json, &out)?;
    Ok(out.exit_code())
}
