//! `cosem team`: a team of N robots placed in one frame.
//!
//! Each robot builds its map from its own folder and frames. The maps cross
//! a mesh of point-to-point links (every pair of robots has its own line, as
//! UARTs give: each map crosses each link once, both directions at once),
//! simulated by the core's link endpoints on a clean 115200-baud line, so
//! each robot matches what it really received. Each robot matches every
//! peer with its own map as the model (with no prior by default), so `T_a_b`
//! and `T_b_a` are separate estimates. The converged ones are checked
//! against each other around cycles and the largest consistent set is kept
//! ([`cosem_core::team::consistent_set`]); a small pose graph then places
//! every robot the kept matches connect to robot 0 in robot 0's frame
//! ([`cosem_core::team::solve`]). Robots connected among themselves but not
//! to robot 0 are a separate group in the frame of their lowest index.

use crate::error::Error;
use crate::knobs::Knob;
use crate::lines::exchange::simulate_exchange;
use crate::maps::mapping::{build_map, HostMap, PointFilter};
use crate::matching::align::{align, prepare, DEFAULT_LEVELS};
use crate::rng::Rng;
use crate::sources::kitti::FrameRange;
use crate::sources::source::{Source, SourceOptions};
use cosem_core::geometry::Isometry3;
use cosem_core::map::MapConfig;
use cosem_core::matching::{MatchSettings, MatchStatus};
use cosem_core::sim::SimConfig;
use cosem_core::team::{consistent_set, solve, RelativePose, MAX_ROBOTS};
use nalgebra::Matrix6;
use std::path::PathBuf;

/// One robot: a source of scans (a SemanticKITTI-layout folder, a
/// recording, a folder of PCD/PLY scans) and its frames.
#[derive(Clone, Debug)]
pub struct RobotSpec {
    /// The folder.
    pub data: PathBuf,
    /// Its frames; the first is the robot's anchor.
    pub frames: FrameRange,
}

/// `PATH:START:END[:STRIDE]` (`--robot`).
impl std::str::FromStr for RobotSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        // The frames are the last two or three colon-separated fields; a
        // folder may hold colons, so both readings are tried, and where
        // both name an existing folder the spec is ambiguous.
        let mut readings = Vec::new();
        for fields in [3, 2] {
            let parts: Vec<&str> = s.rsplitn(fields + 1, ':').collect();
            if parts.len() == fields + 1 && !parts[fields].is_empty() {
                let frames = parts[..fields].iter().rev().copied().collect::<Vec<_>>().join(":");
                if let Ok(r) = frames.parse::<FrameRange>() {
                    readings.push(RobotSpec { data: parts[fields].into(), frames: r });
                }
            }
        }
        let existing: Vec<&RobotSpec> = readings.iter().filter(|r| r.data.exists()).collect();
        match (&readings[..], &existing[..]) {
            (_, [a, b]) => Err(format!(
                "`{s}` reads two ways: folder {} frames {}, or folder {} frames {}; rename the folder with a colon",
                a.data.display(),
                a.frames,
                b.data.display(),
                b.frames
            )),
            (_, [one]) => Ok((*one).clone()),
            ([first, ..], []) => Ok(first.clone()),
            _ => Err(format!("`{s}`: expected DIR:START:END[:STRIDE]")),
        }
    }
}

/// The largest `--prior-noise` offset (m): a prior further off is none.
pub const MAX_PRIOR_METRES: f64 = 1000.0;

/// `METRES,DEGREES` of a prior's noise (`--prior-noise`): metres from 0 to
/// [`MAX_PRIOR_METRES`], degrees from 0 to 180.
pub fn parse_prior_noise(s: &str) -> Result<(f64, f64), String> {
    let v: Vec<f64> =
        s.split(',').map(|x| x.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    match v[..] {
        [m, d] if (0.0..=MAX_PRIOR_METRES).contains(&m) && (0.0..=180.0).contains(&d) => Ok((m, d)),
        _ => Err(format!(
            "`{s}`: expected METRES,DEGREES: METRES from 0 to {MAX_PRIOR_METRES} (a prior further off is none: use {}), DEGREES from 0 to 180",
            Knob::NoPrior
        )),
    }
}

/// `I,J`: robot I's estimate of robot J (`--inject-false-match`).
pub fn parse_robot_pair(s: &str) -> Result<(usize, usize), String> {
    let v: Vec<usize> =
        s.split(',').map(|x| x.trim().parse::<usize>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    match v[..] {
        [i, j] => Ok((i, j)),
        _ => Err(format!("`{s}`: expected I,J")),
    }
}

/// What `cosem team` runs.
#[derive(Clone, Debug)]
pub struct TeamSpec {
    /// Robot i is the i-th.
    pub robots: Vec<RobotSpec>,
    /// Voxel size (m).
    pub voxel: f32,
    /// Prior noise (m, degrees) on the true relative poses of robots from
    /// one trajectory; `None`: no prior (the default).
    pub prior_noise: Option<(f64, f64)>,
    /// Replace each estimate `T_I_J` listed (only that direction) with one
    /// 5 m and 20 degrees off, Converged, keeping the true match's
    /// information. When both `(I, J)` and `(J, I)` are listed, the second
    /// is the inverse of the first: one false match, seen from both robots.
    pub inject_false_match: Vec<(usize, usize)>,
    /// How the robots' recordings or scan files are read.
    pub source: SourceOptions,
    /// Label noise on every robot's scans (robot i's seeded by `seed + i`).
    pub label_noise: crate::maps::noise::LabelNoise,
    /// Seed of the prior and label noise.
    pub seed: u64,
    /// Matcher settings.
    pub settings: MatchSettings,
}

/// Where one robot ended up.
#[derive(Clone, Debug)]
pub struct TeamRobot {
    /// Index (the `--robot` order).
    pub index: usize,
    /// Placed in robot 0's frame.
    pub placed: bool,
    /// The lowest index of its group (0: robot 0's group).
    pub group: usize,
    /// `T_robot0_roboti` (placed robots) or `T_group_roboti` (others).
    pub transform: Isometry3<f64>,
    /// Covariance of `transform` (left perturbation in the group's frame,
    /// order tx, ty, tz, rx, ry, rz).
    pub covariance: Matrix6<f64>,
    /// Voxels of its map.
    pub voxels: usize,
    /// Bytes it sent and received over its links.
    pub bytes_sent: u64,
    /// Bytes it received.
    pub bytes_received: u64,
    /// The true `T_group_roboti` (`T_robot0_roboti` for placed robots),
    /// when robot i's folder holds its group anchor's trajectory.
    pub truth: Option<Isometry3<f64>>,
}

/// One robot's estimate of another.
#[derive(Clone, Debug)]
pub struct TeamMatch {
    /// The estimating robot (its map the model).
    pub a: usize,
    /// The estimated robot: the estimate is `T_a_b`.
    pub b: usize,
    /// The match's status (Converged when injected).
    pub status: MatchStatus,
    /// Kept for the pose graph.
    pub accepted: bool,
    /// Why (not) kept.
    pub reason: &'static str,
    /// `T_a_b` as estimated (or injected).
    pub transform: Isometry3<f64>,
    /// Agreement of the match.
    pub agreement: f32,
}

/// The team's outcome.
#[derive(Clone, Debug)]
pub struct TeamOutcome {
    /// One per robot.
    pub robots: Vec<TeamRobot>,
    /// Every ordered pair's estimate.
    pub matches: Vec<TeamMatch>,
    /// Whether the consistency search went through every set.
    pub exhaustive: bool,
}

/// The truth `T_i_j` between robots of one trajectory (`None` otherwise).
pub struct Truth {
    sources: Vec<Source>,
    /// `T_world_anchor` of each robot sharing its trajectory with another
    /// (read once: a recording is not read again per pair).
    anchors: Vec<Option<nalgebra::Matrix4<f64>>>,
}

impl Truth {
    /// The robots' sources, to compare their poses.
    pub fn of(spec: &TeamSpec) -> Result<Truth, Error> {
        let sources: Vec<Source> =
            spec.robots.iter().map(|r| Source::open(&r.data, &spec.source)).collect::<Result<_, _>>()?;
        let shared = |i: usize| (0..sources.len()).any(|j| j != i && sources[i].same_trajectory(&sources[j]));
        let anchors = (0..sources.len())
            .map(|i| shared(i).then(|| sources[i].world_pose(spec.robots[i].frames.start).ok()).flatten())
            .collect();
        Ok(Truth { sources, anchors })
    }

    /// `T_i_j`, when robots `i` and `j` share a trajectory.
    pub fn between(&self, i: usize, j: usize) -> Option<Isometry3<f64>> {
        let (a, b) = (self.sources.get(i)?, self.sources.get(j)?);
        let (wa, wb) = (self.anchors.get(i)?.as_ref()?, self.anchors.get(j)?.as_ref()?);
        a.same_trajectory(b).then(|| crate::sources::source::relative(wa, wb))
    }
}

/// Runs the team (see the module documentation).
pub fn run(spec: &TeamSpec) -> Result<TeamOutcome, Error> {
    let n = spec.robots.len();
    if !(2..=MAX_ROBOTS).contains(&n) {
        return Err(Error::Invalid(format!("a team has 2 to {MAX_ROBOTS} robots, not {n}")));
    }
    for &(i, j) in &spec.inject_false_match {
        if i >= n || j >= n || i == j {
            return Err(Error::Invalid(format!("{} {i},{j}: two different robots of 0..{n}", Knob::InjectFalseMatch)));
        }
    }
    let truth = Truth::of(spec)?;
    let maps = robot_maps(spec, &truth)?;
    let mesh = Mesh::exchange(&maps)?;
    let (mut matches, candidates) = match_all(spec, &maps, &mesh, &truth)?;
    let list: Vec<RelativePose> = candidates.iter().map(|c| c.1).collect();
    let c = consistent_set(n, &list[..])?;
    let mut kept = Vec::new();
    for (k, (at, rel)) in candidates.iter().enumerate() {
        let ok = c.kept & (1 << k) != 0;
        matches[*at].accepted = ok;
        matches[*at].reason = if ok { "consistent" } else { "inconsistent around a cycle" };
        if ok {
            kept.push(*rel);
        }
    }
    let solution = solve(n, &kept[..], 50)?;
    let robots = (0..n)
        .map(|i| {
            let p = solution.placements[i].ok_or_else(|| Error::Invalid(format!("robot {i} not solved")))?;
            Ok(TeamRobot {
                index: i,
                placed: p.anchor == 0,
                group: usize::from(p.anchor),
                transform: p.pose,
                covariance: p.covariance,
                voxels: maps[i].len(),
                bytes_sent: mesh.sent[i],
                bytes_received: mesh.got[i],
                truth: truth.between(usize::from(p.anchor), i),
            })
        })
        .collect::<Result<Vec<_>, Error>>()?;
    Ok(TeamOutcome { robots, matches, exhaustive: c.exhaustive })
}

/// Each robot's map from its frames (label noise seeded by `seed + i`).
fn robot_maps(spec: &TeamSpec, truth: &Truth) -> Result<Vec<HostMap>, Error> {
    let config = MapConfig::with_resolution(spec.voxel);
    let mut maps = Vec::with_capacity(spec.robots.len());
    for (i, r) in spec.robots.iter().enumerate() {
        let (mut frames, _, _) = truth.sources[i].load(Some(r.frames))?;
        crate::maps::noise::corrupt_all(&mut frames, spec.label_noise, spec.seed.wrapping_add(i as u64));
        maps.push(build_map(&frames, config, &PointFilter::default())?.0);
    }
    Ok(maps)
}

/// The mesh: every pair exchanged its maps once, both ways at once.
struct Mesh {
    /// `received[i][j]`: robot j's map as robot i received it.
    received: Vec<Vec<Option<HostMap>>>,
    sent: Vec<u64>,
    got: Vec<u64>,
}

impl Mesh {
    fn exchange(maps: &[HostMap]) -> Result<Mesh, Error> {
        let n = maps.len();
        let mut mesh = Mesh {
            received: (0..n).map(|_| (0..n).map(|_| None).collect()).collect(),
            sent: vec![0; n],
            got: vec![0; n],
        };
        for i in 0..n {
            for j in i + 1..n {
                let x = simulate_exchange(&maps[i], &maps[j], SimConfig::clean(115_200, (i * n + j) as u64))?;
                if !x.delivered {
                    return Err(Error::Invalid(format!(
                        "the link between robots {i} and {j} did not deliver both maps"
                    )));
                }
                let [at_i, at_j] = x.received;
                mesh.received[i][j] = Some(at_i);
                mesh.received[j][i] = Some(at_j);
                let [si, sj] = x.stats;
                mesh.sent[i] += si.bytes_sent;
                mesh.got[i] += si.bytes_received;
                mesh.sent[j] += sj.bytes_sent;
                mesh.got[j] += sj.bytes_received;
            }
        }
        Ok(mesh)
    }
}

/// The converged estimates, each with its place in the list of matches.
type Candidates = Vec<(usize, RelativePose)>;

/// Every robot matches every peer, its own map the model (injected false
/// matches replacing the listed estimates); the converged ones are the
/// candidates of the consistency check (with their place in the list).
fn match_all(
    spec: &TeamSpec,
    maps: &[HostMap],
    mesh: &Mesh,
    truth: &Truth,
) -> Result<(Vec<TeamMatch>, Candidates), Error> {
    let n = maps.len();
    let mut rng = Rng::new(spec.seed);
    let mut matches = Vec::new();
    let mut candidates = Vec::new();
    for (a, own) in maps.iter().enumerate() {
        let model = prepare(own, DEFAULT_LEVELS)?;
        for b in (0..n).filter(|&b| b != a) {
            let Some(scene_map) = mesh.received[a][b].as_ref() else { continue };
            let scene = prepare(scene_map, DEFAULT_LEVELS)?;
            let prior = match (spec.prior_noise, truth.between(a, b)) {
                (Some((m, deg)), Some(t)) => Some(perturbed(&t, m, deg, &mut rng).cast::<f32>()),
                _ => None,
            };
            let (r, _) =
                align(spec.settings, prior.as_ref(), (&model, &scene)).map_err(|e| Error::Invalid(e.to_string()))?;
            let mut m = TeamMatch {
                a,
                b,
                status: r.status,
                accepted: false,
                reason: "",
                transform: r.transform.cast::<f64>(),
                agreement: r.agreement,
            };
            if spec.inject_false_match.contains(&(a, b)) {
                let earlier = matches
                    .iter()
                    .find(|x: &&TeamMatch| (x.a, x.b) == (b, a) && spec.inject_false_match.contains(&(b, a)));
                m.transform = match earlier {
                    Some(x) => x.transform.inverse(),
                    None => cosem_core::geometry::pose_deg(5.0, 0.0, 0.0, 0.0, 0.0, 20.0) * m.transform,
                };
                m.status = MatchStatus::Converged;
            }
            if m.status == MatchStatus::Converged {
                let information = r.information.cast::<f64>();
                let rel = RelativePose { a: a as u8, b: b as u8, transform: m.transform, information };
                candidates.push((matches.len(), rel));
            } else {
                m.reason = "not converged";
            }
            matches.push(m);
        }
    }
    Ok((matches, candidates))
}

/// Which robots' placements a cycle verified: robot 0, and every robot
/// joined to it by kept matches each of which lies on a cycle through at
/// least three robots (a match that is a bridge of the graph of kept
/// pairs, e.g. the only link of a two-robot team, nothing can check: both
/// directions of one pair come from the same two maps). `kept` lists the
/// kept matches as (estimating robot, estimated robot).
pub fn verified_placements(robots: usize, kept: impl IntoIterator<Item = (usize, usize)>) -> Vec<bool> {
    let mut pairs: Vec<(usize, usize)> = kept
        .into_iter()
        .filter(|(a, b)| a != b && *a < robots && *b < robots)
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    // Whether `from` reaches `to` over `pairs` without pair `skip`.
    let reaches = |from: usize, to: usize, skip: Option<usize>, only: &dyn Fn(usize) -> bool| {
        let mut seen = vec![false; robots];
        let mut stack = vec![from];
        seen[from] = true;
        while let Some(r) = stack.pop() {
            if r == to {
                return true;
            }
            for (k, &(a, b)) in pairs.iter().enumerate() {
                if Some(k) == skip || !only(k) {
                    continue;
                }
                let next = if a == r {
                    b
                } else if b == r {
                    a
                } else {
                    continue;
                };
                if !std::mem::replace(&mut seen[next], true) {
                    stack.push(next);
                }
            }
        }
        false
    };
    let on_cycle: Vec<bool> = pairs.iter().enumerate().map(|(k, &(a, b))| reaches(a, b, Some(k), &|_| true)).collect();
    (0..robots).map(|r| robots > 0 && reaches(0, r, None, &|k| on_cycle[k])).collect()
}

/// `t` moved by a seeded shift of `metres` and a yaw of `degrees`, each with
/// a random sign and direction.
fn perturbed(t: &Isometry3<f64>, metres: f64, degrees: f64, rng: &mut Rng) -> Isometry3<f64> {
    let heading = rng.unit() * std::f64::consts::TAU;
    let sign = if rng.unit() < 0.5 { -1.0 } else { 1.0 };
    let d =
        cosem_core::geometry::pose_deg(metres * heading.cos(), metres * heading.sin(), 0.0, 0.0, 0.0, sign * degrees);
    d * t
}

#[cfg(test)]
mod verified_tests {
    use super::verified_placements;

    #[test]
    fn only_placements_through_cycles_are_verified() {
        // Two robots, both directions: no cycle.
        assert_eq!(verified_placements(2, [(0, 1), (1, 0)]), vec![true, false]);
        // A triangle and a robot hanging off it by one pair.
        assert_eq!(verified_placements(4, [(0, 1), (1, 2), (2, 0), (2, 3), (3, 2)]), vec![true, true, true, false]);
        // Disconnected: robot 2 is not placed at all.
        assert_eq!(verified_placements(3, [(0, 1), (1, 0)]), vec![true, false, false]);
        // A square: every pair on a cycle.
        assert_eq!(verified_placements(4, [(0, 1), (1, 2), (2, 3), (3, 0)]), vec![true; 4]);
    }
}
