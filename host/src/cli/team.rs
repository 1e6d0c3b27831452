//! `cosem team`: N robots placed in robot 0's frame (see
//! `cosem_host::team`).

use super::{print_json, Error};
use cosem_core::geometry::{errors_of, row_major};
use cosem_core::matching::MatchSettings;
use cosem_host::kitti::FrameRange;
use cosem_host::team::{run as run_team, RobotSpec, TeamSpec};
use serde::Serialize;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// A robot: a source of scans (a SemanticKITTI-layout folder, a ROS 2
    /// recording .mcap, or a folder of PCD/PLY scans with poses.txt) and
    /// its frames, PATH:START:END[:STRIDE]; robot i is the i-th (2 to 8).
    #[arg(long = "robot", required = true, value_parser = robot)]
    pub(super) robots: Vec<RobotSpec>,
    #[command(flatten)]
    pub(super) source: super::args::SourceArgs,
    /// Voxel size (m; default 0.2, or 0.5 with --on-board).
    #[arg(long, value_parser = super::args::positive_f32)]
    pub(super) voxel: Option<f32>,
    /// No prior: every robot searches every heading and offset (the default).
    #[arg(long, conflicts_with = "prior_noise")]
    pub(super) no_prior: bool,
    /// A prior for robots of one trajectory: the true relative pose moved
    /// by METRES and DEGREES (seeded): METRES,DEGREES.
    #[arg(long, value_parser = pair_f64)]
    pub(super) prior_noise: Option<(f64, f64)>,
    /// Replace robot I's estimate of robot J (only that direction) with one
    /// 5 m and 20 degrees off, Converged: I,J. Repeatable; given as I,J and
    /// J,I, one false match seen from both robots.
    #[arg(long, value_parser = pair_usize)]
    pub(super) inject_false_match: Vec<(usize, usize)>,
    /// Label noise on every scan: none, network[:SEVERITY] or iid:P (see
    /// `cosem eval --help`).
    #[arg(long, default_value = "none")]
    pub(super) label_noise: cosem_host::noise::LabelNoise,
    /// Seed of the prior and label noise.
    #[arg(long, default_value_t = 1)]
    pub(super) seed: u64,
    /// JSON on standard output.
    #[arg(long)]
    pub(super) json: bool,
    /// Run each robot on an emulated board (QEMU mps2-an386, 2 to 5
    /// robots, no prior): fed its thinned scans, it maps, exchanges,
    /// matches, checks consistency and solves the pose graph on board;
    /// shown beside the host's run of the same robots on the same points.
    #[arg(long, conflicts_with_all = ["prior_noise", "inject_false_match"])]
    pub(super) on_board: bool,
    /// With --on-board: points farther than this from their sensor are not
    /// fed (m).
    #[arg(long, default_value = "25", value_parser = super::args::positive_f32)]
    pub(super) crop: f32,
    /// With --on-board: the firmware's team binary (at the default path,
    /// built or brought up to date first).
    #[arg(long, default_value = cosem_host::team_board::DEFAULT_TEAM_FIRMWARE)]
    pub(super) firmware: std::path::PathBuf,
    /// With --on-board: a robot gives up on a peer after this long without a
    /// valid frame (s).
    #[arg(long, default_value = "60", value_parser = super::args::positive)]
    pub(super) silence: f64,
    /// With --on-board: kill the emulators after this long (s).
    #[arg(long, default_value = "1800", value_parser = super::args::positive)]
    pub(super) timeout: f64,
}

fn robot(s: &str) -> Result<RobotSpec, String> {
    // The frames are the last two or three colon-separated fields.
    for fields in [3, 2] {
        let parts: Vec<&str> = s.rsplitn(fields + 1, ':').collect();
        if parts.len() == fields + 1 {
            let frames = parts[..fields].iter().rev().copied().collect::<Vec<_>>().join(":");
            if let Ok(r) = frames.parse::<FrameRange>() {
                return Ok(RobotSpec { data: parts[fields].into(), frames: r });
            }
        }
    }
    Err(format!("`{s}`: expected DIR:START:END[:STRIDE]"))
}

/// The largest error of a prior (m): a prior a kilometre off is no prior.
const MAX_PRIOR_METRES: f64 = 1000.0;

fn pair_f64(s: &str) -> Result<(f64, f64), String> {
    let v: Vec<f64> =
        s.split(',').map(|x| x.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    match v[..] {
        [m, d] if (0.0..=MAX_PRIOR_METRES).contains(&m) && (0.0..=180.0).contains(&d) => Ok((m, d)),
        _ => Err(format!(
            "`{s}`: expected METRES,DEGREES: METRES from 0 to {MAX_PRIOR_METRES} (a prior further off is none: use --no-prior), DEGREES from 0 to 180"
        )),
    }
}

fn pair_usize(s: &str) -> Result<(usize, usize), String> {
    let v: Vec<usize> =
        s.split(',').map(|x| x.trim().parse::<usize>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    match v[..] {
        [i, j] => Ok((i, j)),
        _ => Err(format!("`{s}`: expected I,J")),
    }
}

#[derive(Serialize)]
pub(super) struct RobotJson {
    pub(super) index: usize,
    pub(super) placed: bool,
    /// Whether a cycle of matches through at least three robots checked
    /// the placement (false: it rests on matches nothing could check,
    /// such as the only pair of a two-robot team).
    pub(super) verified: bool,
    pub(super) group: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) transform: Option<[f64; 16]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) covariance: Option<Vec<f64>>,
    /// Robots of a group not connected to robot 0: `T_group_roboti`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) group_transform: Option<[f64; 16]>,
    pub(super) voxels: usize,
    pub(super) bytes_sent: u64,
    pub(super) bytes_received: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) e_t: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) e_r: Option<f64>,
}

#[derive(Serialize)]
pub(super) struct MatchJson {
    pub(super) a: usize,
    pub(super) b: usize,
    pub(super) status: &'static str,
    pub(super) accepted: bool,
    pub(super) reason: &'static str,
    pub(super) agreement: f32,
}

#[derive(Serialize)]
struct TeamJson {
    schema_version: u32,
    links: &'static str,
    pub(super) robots: Vec<RobotJson>,
    matches: Vec<MatchJson>,
    consistency_exhaustive: bool,
}

/// Exit code: 0 when every robot is placed in robot 0's frame, else 5
/// (no overlap: some robot could not be placed).
pub fn run(a: Args) -> Result<u8, Error> {
    if a.on_board {
        return super::team_board::run(a);
    }
    let spec = TeamSpec {
        robots: a.robots,
        voxel: a.voxel.unwrap_or(0.2),
        prior_noise: a.prior_noise,
        inject_false_match: a.inject_false_match,
        source: a.source.options(),
        label_noise: a.label_noise,
        seed: a.seed,
        settings: MatchSettings::default(),
    };
    let out = run_team(&spec)?;
    let code = if out.robots.iter().all(|r| r.placed) { 0 } else { 5 };
    let members = |g: usize| out.robots.iter().filter(|r| r.group == g).count();
    let kept = out.matches.iter().filter(|m| m.accepted).map(|m| (m.a, m.b));
    let verified = cosem_host::team::verified_placements(out.robots.len(), kept);
    let robots = out.robots.iter().map(|r| {
        // Errors against the truth in the frame the robot is reported in.
        let in_group = !r.placed && members(r.group) > 1;
        let errors = r.truth.filter(|_| r.placed || in_group).map(|t| errors_of(&r.transform.cast::<f32>(), &t));
        RobotJson {
            index: r.index,
            placed: r.placed,
            verified: r.placed && verified.get(r.index).copied().unwrap_or(false),
            group: r.group,
            transform: r.placed.then(|| row_major(&r.transform)),
            covariance: r.placed.then(|| r.covariance.transpose().iter().copied().collect()),
            group_transform: in_group.then(|| row_major(&r.transform)),
            voxels: r.voxels,
            bytes_sent: r.bytes_sent,
            bytes_received: r.bytes_received,
            e_t: errors.map(|e| e.0),
            e_r: errors.map(|e| e.1),
        }
    });
    let robots: Vec<RobotJson> = robots.collect();
    if a.json {
        let matches = out
            .matches
            .iter()
            .map(|m| MatchJson {
                a: m.a,
                b: m.b,
                status: m.status.as_str(),
                accepted: m.accepted,
                reason: m.reason,
                agreement: m.agreement,
            })
            .collect();
        let links = "mesh of point-to-point links (each map crosses each link once)";
        print_json(&TeamJson { schema_version: 2, links, robots, matches, consistency_exhaustive: out.exhaustive })?;
        return Ok(code);
    }
    for r in &robots {
        let place = match (r.placed, r.transform) {
            (true, Some(t)) => format!(
                "placed at ({:.3}, {:.3}, {:.3}) m in robot 0's frame{}",
                t[3],
                t[7],
                t[11],
                if r.verified || r.index == 0 { "" } else { " (verified by no cycle)" }
            ),
            _ if r.group != r.index => match r.group_transform {
                Some(t) => {
                    format!("unplaced; at ({:.3}, {:.3}, {:.3}) m in robot {}'s frame", t[3], t[7], t[11], r.group)
                }
                None => format!("unplaced (in a group with robot {})", r.group),
            },
            _ if r.group_transform.is_some() => "unplaced; anchor of its own group".to_string(),
            _ => "unplaced".to_string(),
        };
        let err = r.e_t.zip(r.e_r).map(|(t, d)| format!(", e_t {t:.3} m, e_r {d:.3} deg")).unwrap_or_default();
        println!(
            "robot {}: {place}{err}; {} voxels, {} bytes sent, {} received",
            r.index, r.voxels, r.bytes_sent, r.bytes_received
        );
    }
    for m in &out.matches {
        let kept = if m.accepted { "kept" } else { "left out" };
        println!("T_{}_{}: {}, agreement {:.2}, {kept} ({})", m.a, m.b, m.status.as_str(), m.agreement, m.reason);
    }
    Ok(code)
}
