//! `cosem session`: robots that keep driving (see
//! `cosem_host::evaluation::session`).

use super::Error;
use cosem_core::session::UpdateBudget;
use cosem_host::boards::pump::LineFault;
use cosem_host::evaluation::session::{self, run, SessionSpec};
use cosem_host::evaluation::team::RobotSpec;
use cosem_host::reports::session::{record_text, summary_text, RecordJson, SummaryFields, SummaryJson, SESSION_SCHEMA};
use cosem_host::reports::session_recording::SessionRecorder;
use cosem_host::sources::drift::Drift;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// A robot: a source of scans (a SemanticKITTI-layout folder, a ROS 2
    /// recording .mcap, or a folder of PCD/PLY scans with poses.txt) and
    /// its frames, PATH:START:END[:STRIDE]; 2 or 3 robots. Default: the
    /// built-in town (`cosem synth --town`, built in a temporary folder),
    /// its robots on all their frames.
    #[arg(long = "robot", num_args = 1)]
    robots: Vec<RobotSpec>,
    /// Without --robot: the town's robots, 2 or 3.
    #[arg(long, conflicts_with = "robots", value_parser = clap::value_parser!(u8).range(2..=3))]
    town_robots: Option<u8>,
    #[command(flatten)]
    source: super::args::SourceArgs,
    /// Scans each robot fuses a round.
    #[arg(long, default_value_t = session::DEFAULT_EVERY, value_parser = super::args::at_least::<1>)]
    every: usize,
    /// Odometry drift of every robot: S,H, a scale error S (0.01 or 1%, its
    /// sign drawn per robot) and a heading random walk of H degrees per
    /// 100 m (its variance grows as H^2 per 100 m driven).
    #[arg(long, default_value = "0,0")]
    drift: Drift,
    /// A sudden 2 m / 10 degree jump of robot ROBOT's odometry at round
    /// ROUND: ROBOT,ROUND.
    #[arg(long, value_parser = cosem_host::evaluation::team::parse_robot_pair)]
    slip: Option<(usize, usize)>,
    /// Label noise on every scan: none, network[:SEVERITY] or iid:P (see
    /// `cosem eval --help`).
    #[arg(long, default_value = "none")]
    label_noise: cosem_host::maps::noise::LabelNoise,
    /// Seed of drift and label noise (robot i: SEED + i).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Voxel size of the robots' maps (m) [default: 0.5; 0.7 with
    /// --on-board].
    #[arg(long, value_parser = super::args::voxel)]
    voxel: Option<f32>,
    /// Voxels a robot's map holds, and each of its copies of a peer's;
    /// beyond, what is farthest from the robot goes. One for every robot,
    /// or one per robot (8000,3000: a robot that holds less is sent the
    /// part of a peer's map nearest the peer) [default: 8000; with
    /// --on-board the boards' 4096, fixed].
    #[arg(long, value_parser = capacity)]
    capacity: Option<Capacities>,
    /// Points farther than this from their sensor are left out (m).
    #[arg(long, default_value_t = session::DEFAULT_CROP, value_parser = super::args::crop)]
    crop: f32,
    /// EM iterations, the verdict's thresholds, the prior-free search's
    /// budget (default: the robots', 30 iterations and 40,000 nodes).
    #[command(flatten)]
    tuning: super::args::Tuning,
    /// Every round as a one-shot exchange, the baseline to compare with:
    /// each robot's whole map sent afresh, each peer matched prior-free.
    #[arg(long)]
    one_shot: bool,
    /// What each robot's update to a peer may take a round: bytes, a share
    /// of the robot's map sent whole with the peer's answer (`15%`), or
    /// `none`. What changed beyond it waits for the next rounds, what is
    /// farthest from the robot first (a snapshot is sent whole). Default:
    /// 15% on the host, 1024 bytes on the boards (which take bytes only).
    #[arg(long)]
    update_budget: Option<Budget>,
    /// JSON lines: one per robot, peer and round, then {"summary": {...}}.
    #[arg(long)]
    json: bool,
    /// Write the session as a ROS 2 recording (MCAP) to view in Foxglove:
    /// each robot's map every round (/robot_<i>/map), its odometry and the
    /// Converged estimates on /tf.
    #[arg(long, value_name = "OUT")]
    mcap_out: Option<std::path::PathBuf>,
    /// Run the two robots on emulated boards (QEMU mps2-an386, the
    /// firmware's `session` binary): each fed its rounds over a UART,
    /// trading updates with the other over another; every round checked
    /// against the host's twin of the same robots.
    #[arg(long, conflicts_with_all = ["one_shot", "mcap_out", "capacity"])]
    on_board: bool,
    /// With --on-board: the session firmware.
    #[arg(long, requires = "on_board", default_value = cosem_host::boards::session_board::SESSION_FIRMWARE)]
    firmware: std::path::PathBuf,
    /// A line between every two robots, what it does to bytes: corrupt=P
    /// (a bit of each byte flipped with probability P) or lossy=P (bytes
    /// substituted, dropped and duplicated alike; lossy=0: a clean line).
    /// On the host each pair's updates are then traded over a simulated
    /// line of --baud by the boards' courier, in virtual time: an update
    /// reaches the peer in the round by whose end it is across (until
    /// then the peer estimates on the copy it held: `OnTheLine`), and each
    /// says the bytes it took on the line and its milliseconds; with
    /// --on-board, the line between the boards' UART0s. `none`: the host
    /// hands updates over whole, the boards' UARTs are joined.
    #[arg(long, default_value = "none")]
    line: LineFault,
    /// With --line on the host: the simulated line's rate (bits a second,
    /// 8N1).
    #[arg(long, default_value_t = 115_200, value_parser = clap::value_parser!(u32).range(1_200..=10_000_000))]
    baud: u32,
    /// With --on-board: kill the emulators after this long (s).
    #[arg(long, requires = "on_board", default_value_t = 3600.0)]
    timeout: f64,
}

/// `--update-budget`: bytes (at least
/// [`cosem_core::session::MIN_UPDATE_BUDGET`]), a share of the map in
/// percent (`15%`, to a tenth of a percent, more than 0 and at most 100),
/// or `none`.
#[derive(Clone, Copy, Debug)]
struct Budget(Option<UpdateBudget>);

impl std::str::FromStr for Budget {
    type Err = String;
    fn from_str(s: &str) -> Result<Budget, String> {
        let t = s.trim();
        if t == "none" {
            return Ok(Budget(None));
        }
        let budget = match t.strip_suffix('%') {
            Some(p) => p
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|p| p.is_finite())
                .map(|p| (p * 10.0).round())
                .filter(|m| (1.0..=1000.0).contains(m))
                .map(|m| UpdateBudget::PerMille(m as u16)),
            None => t.parse::<u32>().ok().map(UpdateBudget::Bytes),
        };
        budget.filter(|b| b.is_valid()).map(|b| Budget(Some(b))).ok_or_else(|| {
            format!(
                "`{s}`: expected an update's bytes ({} or more), a share of the map (`15%`: 0.1% to 100%), or `none`",
                cosem_core::session::MIN_UPDATE_BUDGET
            )
        })
    }
}

/// `--capacity`: one or one per robot (at most 3), each 64 to
/// [`cosem_host::evaluation::session::MAX_CAPACITY`] voxels.
#[derive(Clone, Debug)]
struct Capacities(Vec<usize>);

impl std::fmt::Display for Capacities {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts: Vec<String> = self.0.iter().map(usize::to_string).collect();
        f.write_str(&parts.join(","))
    }
}

fn capacity(s: &str) -> Result<Capacities, String> {
    let most = cosem_host::evaluation::session::MAX_CAPACITY;
    let each: Vec<Option<usize>> =
        s.split(',').map(|p| p.trim().parse::<usize>().ok().filter(|v| (64..=most).contains(v))).collect();
    match each.iter().copied().collect::<Option<Vec<usize>>>() {
        Some(v) if (1..=3).contains(&v.len()) => Ok(Capacities(v)),
        _ => Err(format!("`{s}`: expected a map capacity of 64 to {most} voxels, or one per robot (N,N[,N])")),
    }
}

pub fn run_session(a: Args) -> Result<(), Error> {
    let _town = if a.robots.is_empty() {
        let tmp = cosem_host::paths::TempDir::new("cosem-session-town");
        let n = a.town_robots.map_or(2, usize::from);
        let robots = cosem_host::evaluation::session::town_robots(&tmp.0, n, a.seed, None)?;
        eprintln!("the built-in town (seed {}): {n} robots in {}", a.seed, tmp.0.display());
        Some((tmp, robots))
    } else {
        None
    };
    let robots = _town.as_ref().map_or_else(|| a.robots.clone(), |t| t.1.clone());
    let n = robots.len();
    if !(2..=3).contains(&n) {
        return Err(format!("--robot: 2 or 3 robots, not {n}").into());
    }
    let spec = spec_of(&a, robots)?;
    if a.on_board {
        return on_board(&spec, &a);
    }
    if let Some(out) = &a.mcap_out {
        let inputs: Vec<(&str, &std::path::Path)> = spec.robots.iter().map(|r| ("--robot", r.data.as_path())).collect();
        cosem_host::paths::check_output("--mcap-out", out, &inputs)?;
    }
    let mut recorder = a.mcap_out.as_deref().map(|p| SessionRecorder::create(p, spec.robots.len())).transpose()?;
    let json = a.json;
    let mut failed = None;
    let out = run(&spec, |view| {
        if let Some(rec) = recorder.as_mut() {
            if let Err(e) = rec.round(view) {
                failed = Some(e.to_string());
            }
        }
        for r in view.records {
            let line = if json {
                serde_json::to_string(&RecordJson::from(r)).map_err(|e| e.to_string())
            } else {
                Ok(record_text(r))
            };
            match line {
                Ok(l) => println!("{l}"),
                Err(e) => failed = Some(e),
            }
        }
    })?;
    if let Some(e) = failed {
        return Err(e.into());
    }
    if let Some(rec) = recorder {
        rec.finish()?;
    }
    if json {
        let fields = SummaryFields { schema_version: SESSION_SCHEMA, rounds: out.rounds, figures: &out.summary };
        println!("{}", serde_json::to_string(&SummaryJson { summary: fields })?);
    } else {
        print!("{}", summary_text(&out.summary, out.rounds));
    }
    Ok(())
}

/// The session `a` asks for, its robots `robots`.
fn spec_of(a: &Args, robots: Vec<RobotSpec>) -> Result<SessionSpec, Error> {
    let n = robots.len();
    let capacity = a.capacity.clone().unwrap_or(Capacities(vec![session::DEFAULT_CAPACITY]));
    let given = capacity.0.len();
    if given != 1 && given != n {
        return Err(format!("--capacity {capacity}: one capacity, or one per robot ({n})").into());
    }
    if let Some((robot, _)) = a.slip {
        if robot >= n {
            return Err(format!("--slip {robot},..: no robot {robot} of 0..{n}").into());
        }
    }
    if a.one_shot && !a.on_board && a.line != LineFault::None {
        return Err("--line with --one-shot: a one-shot round sends whole maps afresh; a line is for updates".into());
    }
    if a.on_board && matches!(a.update_budget, Some(Budget(Some(UpdateBudget::PerMille(_))))) {
        return Err("--update-budget with --on-board: a board's budget is in bytes (or none), not a share".into());
    }
    let tuned = [a.tuning.em_iterations.is_some(), a.tuning.min_overlap.is_some(), a.tuning.min_agreement.is_some()];
    if a.on_board && (tuned.contains(&true) || a.tuning.search_nodes.is_some()) {
        return Err("--on-board: the boards run the session robots' own pipeline (no --em-iterations, --min-overlap, --min-agreement or --search-nodes)".into());
    }
    Ok(SessionSpec {
        robots,
        every: a.every,
        voxel: a.voxel.unwrap_or(if a.on_board {
            cosem_host::boards::session_board::BOARD_VOXEL
        } else {
            session::DEFAULT_VOXEL
        }),
        capacity: if a.on_board { vec![cosem_core::robot::session::SESSION_VOXELS] } else { capacity.0 },
        crop: a.crop,
        drift: a.drift,
        slip: a.slip,
        label_noise: a.label_noise,
        seed: a.seed,
        source: a.source.options(),
        alignment: a.tuning.apply(session::DEFAULT_ALIGNMENT),
        one_shot: a.one_shot,
        update_budget: match a.update_budget {
            Some(b) => b.0,
            None if a.on_board => Some(UpdateBudget::Bytes(cosem_core::session::DEFAULT_UPDATE_BUDGET)),
            None => Some(cosem_core::session::DEFAULT_UPDATE_SHARE),
        },
        line: match (a.on_board, a.line) {
            // The boards' line is their UARTs' own (the relay's fault).
            (true, _) | (false, LineFault::None) => None,
            (false, LineFault::Silent) => {
                return Err("--line silent: a session's line must carry something (on the host; --on-board may)".into())
            }
            (false, l) => Some(session::line::SessionLine { fault: l.fault(), baud: a.baud }),
        },
    })
}

/// `--on-board`: the session on two emulated boards, every round beside
/// the host's twin and the truth.
fn on_board(spec: &SessionSpec, a: &Args) -> Result<(), Error> {
    use cosem_host::boards::session_board::{run_session_on_boards, SessionBoardsSpec};
    if spec.robots.len() != 2 {
        return Err(format!("--on-board: 2 robots, not {}", spec.robots.len()).into());
    }
    let run = run_session_on_boards(&SessionBoardsSpec {
        session: spec,
        firmware: &a.firmware,
        timeout: std::time::Duration::from_secs_f64(a.timeout.clamp(1.0, 86_400.0)),
        silence_ms: 60_000,
        line: a.line,
    })?;
    let report = cosem_host::reports::session_board::report(&run);
    if a.json {
        for line in report.lines_json()? {
            println!("{line}");
        }
    } else {
        print!("{}", report.text());
    }
    if report.ok() {
        Ok(())
    } else {
        Err("the boards' session failed or differs from the host's twin (see above)".into())
    }
}
