//! What `cosem team` reports, on the host and on boards: the JSON (schema
//! 2: stable field names, `verified` added to 1) and its text, built from
//! a team's outcome ([`crate::evaluation::team::TeamOutcome`]) or from the boards'
//! reports ([`crate::boards::team_board::BoardRun`]). The command line only parses
//! and prints.

use crate::boards::team_board::{placement_difference, BoardRun, TeamReports};
use crate::error::Error;
use crate::evaluation::team::{verified_placements, TeamOutcome, Truth};
use cosem_core::geometry::{errors_of, from_rows, row_major};
use cosem_core::matching::MatchStatus;
use cosem_core::wire::share::Estimate;
use serde::Serialize;
use std::collections::BTreeMap;

/// One robot of a team: where it was placed.
#[derive(Clone, Debug, Serialize)]
pub struct TeamRobotJson {
    /// Its index (the `--robot` order).
    pub index: usize,
    /// Placed in robot 0's frame.
    pub placed: bool,
    /// Whether a cycle of matches through at least three robots checked
    /// the placement (false: it rests on matches nothing could check,
    /// such as the only pair of a two-robot team).
    pub verified: bool,
    /// The lowest index of its group (0: robot 0's).
    pub group: usize,
    /// `T_robot0_roboti`, row by row (placed robots).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transform: Option<[f64; 16]>,
    /// Its covariance, row by row (tx, ty, tz, rx, ry, rz).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub covariance: Option<Vec<f64>>,
    /// Robots of a group not connected to robot 0: `T_group_roboti`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub group_transform: Option<[f64; 16]>,
    /// Voxels of its map.
    pub voxels: usize,
    /// Bytes it sent over its links.
    pub bytes_sent: u64,
    /// Bytes it received.
    pub bytes_received: u64,
    /// Translation error against the truth (m), where known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_t: Option<f64>,
    /// Rotation error against the truth (degrees), where known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_r: Option<f64>,
}

/// One robot's estimate of another, on the host.
#[derive(Clone, Debug, Serialize)]
pub struct TeamMatchJson {
    /// The estimating robot.
    pub a: usize,
    /// The estimated robot.
    pub b: usize,
    /// The match's status.
    pub status: &'static str,
    /// Kept for the pose graph.
    pub accepted: bool,
    /// Why (not) kept.
    pub reason: &'static str,
    /// Agreement of the match.
    pub agreement: f32,
}

/// `cosem team --json` on the host.
#[derive(Clone, Debug, Serialize)]
pub struct TeamJson {
    /// 2.
    pub schema_version: u32,
    /// How the robots were linked.
    pub links: &'static str,
    /// One per robot.
    pub robots: Vec<TeamRobotJson>,
    /// Every ordered pair's estimate.
    pub matches: Vec<TeamMatchJson>,
    /// Whether the consistency search went through every set.
    pub consistency_exhaustive: bool,
}

/// One board's estimate of another robot.
#[derive(Clone, Debug, Serialize)]
pub struct BoardMatchJson {
    /// The estimating robot.
    pub a: usize,
    /// The estimated robot.
    pub b: usize,
    /// Null when the maps never met (the link failed).
    pub status: Option<&'static str>,
    /// Kept by the lead board's consistency check.
    pub accepted: bool,
    /// Why (not) kept.
    pub reason: &'static str,
    /// Overlap of the match.
    pub overlap: f32,
}

/// One board of an on-board team.
#[derive(Clone, Debug, Serialize)]
pub struct BoardJson {
    /// Its robot's index.
    pub index: usize,
    /// QEMU's exit code (`None`: killed).
    pub exit_code: Option<i32>,
    /// Whether it reported its end.
    pub finished: bool,
    /// Where it stopped, when it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<BTreeMap<&'static str, String>>,
    /// Robots whose estimates this board holds (all of them when sharing
    /// went through).
    pub heard: Vec<usize>,
    /// Points it was fed.
    pub points: u32,
    /// Voxels of its map.
    pub map_voxels: u32,
    /// Instructions mapping.
    pub map_instructions: u64,
    /// Over all its matches.
    pub prepare_instructions: u64,
    /// Over all its matches.
    pub locate_instructions: u64,
    /// Over all its matches.
    pub match_instructions: u64,
    /// Consistency and pose graph.
    pub solve_instructions: u64,
    /// Peak stack (bytes).
    pub peak_stack_bytes: u32,
    /// Over all its matches: bytes its peers sent that came in (taken by
    /// its receive interrupts into the rings) while it prepared and matched.
    pub link_bytes_while_matching: u32,
    /// Milliseconds its links took on board.
    pub link_ms_onboard: u32,
    /// Milliseconds sharing estimates took on board.
    pub share_ms_onboard: u32,
    /// Largest translation difference (m) from the host's run of this robot.
    pub difference_to_host_m: Option<f64>,
    /// Largest translation difference (m) from board 0's placements.
    pub difference_to_board0_m: Option<f64>,
    /// Same groups (anchors) as the host's run.
    pub same_groups_as_host: Option<bool>,
}

/// `cosem team --on-board --json`.
#[derive(Clone, Debug, Serialize)]
pub struct TeamBoardJson {
    /// 2.
    pub schema_version: u32,
    /// How the boards were linked.
    pub links: &'static str,
    /// Always true.
    pub on_board: bool,
    /// One per robot, as the lead board placed them.
    pub robots: Vec<TeamRobotJson>,
    /// Every board's estimates.
    pub matches: Vec<BoardMatchJson>,
    /// Whether the lead board's consistency search went through every set.
    pub consistency_exhaustive: bool,
    /// One per board.
    pub boards: Vec<BoardJson>,
    /// Largest difference (m) between any board's placements and the host's.
    pub host_difference_m: Option<f64>,
    /// Wall time of the run (s).
    pub wall_time_s: f64,
}

/// Marks the placements a cycle verified, from the kept matches.
fn mark_verified(robots: &mut [TeamRobotJson], kept: impl IntoIterator<Item = (usize, usize)>) {
    let verified = verified_placements(robots.len(), kept);
    for r in robots {
        r.verified = r.placed && verified.get(r.index).copied().unwrap_or(false);
    }
}

impl TeamJson {
    /// The report of a team run on the host.
    pub fn of(out: &TeamOutcome) -> TeamJson {
        let members = |g: usize| out.robots.iter().filter(|r| r.group == g).count();
        let mut robots: Vec<TeamRobotJson> = out
            .robots
            .iter()
            .map(|r| {
                // Errors against the truth in the frame the robot is reported in.
                let in_group = !r.placed && members(r.group) > 1;
                let errors =
                    r.truth.filter(|_| r.placed || in_group).map(|t| errors_of(&r.transform.cast::<f32>(), &t));
                TeamRobotJson {
                    index: r.index,
                    placed: r.placed,
                    verified: false,
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
            })
            .collect();
        mark_verified(&mut robots, out.matches.iter().filter(|m| m.accepted).map(|m| (m.a, m.b)));
        let matches = out
            .matches
            .iter()
            .map(|m| TeamMatchJson {
                a: m.a,
                b: m.b,
                status: m.status.as_str(),
                accepted: m.accepted,
                reason: m.reason,
                agreement: m.agreement,
            })
            .collect();
        TeamJson {
            schema_version: 2,
            links: "mesh of point-to-point links (each map crosses each link once)",
            robots,
            matches,
            consistency_exhaustive: out.exhaustive,
        }
    }

    /// 0 when every robot is placed in robot 0's frame, else 5 (no
    /// overlap: some robot could not be placed).
    pub fn exit_code(&self) -> u8 {
        if self.robots.iter().all(|r| r.placed) {
            0
        } else {
            5
        }
    }
}

impl std::fmt::Display for TeamJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for r in &self.robots {
            writeln!(
                f,
                "robot {}: {}; {} voxels, {} bytes sent, {} received",
                r.index,
                place_text(r),
                r.voxels,
                r.bytes_sent,
                r.bytes_received
            )?;
        }
        for m in &self.matches {
            let kept = if m.accepted { "kept" } else { "left out" };
            writeln!(f, "T_{}_{}: {}, agreement {:.2}, {kept} ({})", m.a, m.b, m.status, m.agreement, m.reason)?;
        }
        Ok(())
    }
}

/// Where a robot ended up, and its errors, as text.
fn place_text(r: &TeamRobotJson) -> String {
    let place = match (r.placed, r.transform, r.group_transform) {
        (true, Some(t), _) => format!(
            "placed at ({:.3}, {:.3}, {:.3}) m in robot 0's frame{}",
            t[3],
            t[7],
            t[11],
            if r.verified || r.index == 0 { "" } else { " (verified by no cycle)" }
        ),
        (_, _, Some(_)) if r.group == r.index => "unplaced; anchor of its own group".to_string(),
        (_, _, Some(t)) => {
            format!("unplaced; at ({:.3}, {:.3}, {:.3}) m in robot {}'s frame", t[3], t[7], t[11], r.group)
        }
        _ if r.group != r.index => format!("unplaced (in a group with robot {})", r.group),
        _ => "unplaced".to_string(),
    };
    let err = r.e_t.zip(r.e_r).map(|(t, d)| format!(", e_t {t:.3} m, e_r {d:.3} deg")).unwrap_or_default();
    format!("{place}{err}")
}

impl TeamBoardJson {
    /// The report of a team on boards: the lead board's (the first that
    /// finished) placements, every board's estimates and figures, and how
    /// each board's placements differ from the host's run (`host`) and
    /// from board 0's.
    pub fn of(boards: &[BoardRun], host: &[TeamReports], truth: &Truth, wall_s: f64) -> Result<TeamBoardJson, Error> {
        let Some(lead) = boards.iter().find(|b| b.reports.end.is_some()).map(|b| &b.reports) else {
            let why: Vec<String> = boards
                .iter()
                .enumerate()
                .map(|(i, b)| match &b.reports.failed {
                    Some((stage, message)) => format!("board {i} stopped at {stage}: {message}"),
                    None => format!("board {i}: no last message (exit {:?})", b.exit_code),
                })
                .collect();
            return Err(Error::Invalid(format!("no board finished: {}", why.join("; "))));
        };
        let end = lead.end.ok_or_else(|| Error::Invalid("no board finished".into()))?;
        let mut robots = board_robots(boards, lead, truth);
        let matches = board_matches(boards, end.kept);
        mark_verified(&mut robots, matches.iter().filter(|m| m.accepted).map(|m| (m.a, m.b)));
        let boards_json: Vec<BoardJson> =
            boards.iter().enumerate().map(|(i, b)| board_json(i, b, host.get(i), &boards[0].reports)).collect();
        let host_difference = boards_json
            .iter()
            .map(|b| b.difference_to_host_m.unwrap_or(f64::INFINITY))
            .fold(None, |m: Option<f64>, d| Some(m.map_or(d, |m| m.max(d))));
        Ok(TeamBoardJson {
            schema_version: 2,
            links: "mesh of point-to-point UART links (each map crosses each link once)",
            on_board: true,
            robots,
            matches,
            consistency_exhaustive: end.exhaustive,
            boards: boards_json,
            host_difference_m: host_difference,
            wall_time_s: wall_s,
        })
    }

    /// 0 when every board finished and placed every robot in robot 0's
    /// frame; 5 when a robot is unplaced; 1 when a board stopped.
    pub fn exit_code(&self) -> u8 {
        if !self.boards.iter().all(|b| b.finished) {
            1
        } else if self.robots.iter().all(|r| r.placed) {
            0
        } else {
            5
        }
    }
}

/// The robots as the lead board placed them.
fn board_robots(boards: &[BoardRun], lead: &TeamReports, truth: &Truth) -> Vec<TeamRobotJson> {
    // Every robot's bytes over its links, from its own board.
    let bytes = |i: usize| {
        let m = boards.get(i).map_or(&[][..], |b| &b.reports.matched[..]);
        (m.iter().map(|x| x.1.bytes_sent).sum::<u64>(), m.iter().map(|x| x.1.bytes_received).sum::<u64>())
    };
    lead.placed
        .iter()
        .map(|p| {
            let (i, g) = (usize::from(p.index), usize::from(p.anchor));
            let placed = g == 0;
            let members = lead.placed.iter().filter(|q| q.anchor == p.anchor).count();
            let in_group = !placed && members > 1;
            let t = from_rows(&p.transform);
            let errors = truth.between(g, i).filter(|_| placed || in_group).map(|gt| errors_of(&t, &gt));
            let cov = Estimate { information: p.covariance, ..Estimate::none(0, 0) }.information();
            let (sent, received) = bytes(i);
            TeamRobotJson {
                index: i,
                placed,
                verified: false,
                group: g,
                transform: placed.then(|| row_major(&t.cast::<f64>())),
                covariance: placed.then(|| cov.iter().flatten().map(|&v| f64::from(v)).collect()),
                group_transform: in_group.then(|| row_major(&t.cast::<f64>())),
                voxels: boards.get(i).and_then(|b| b.reports.matched.first()).map_or(0, |m| m.1.map_voxels as usize),
                bytes_sent: sent,
                bytes_received: received,
                e_t: errors.map(|e| e.0),
                e_r: errors.map(|e| e.1),
            }
        })
        .collect()
}

/// Every board's estimates, and which the lead board kept (`kept`: bit k
/// for its k-th converged candidate, in the order a, then b).
fn board_matches(boards: &[BoardRun], kept: u64) -> Vec<BoardMatchJson> {
    let mut matches = Vec::new();
    let mut k = 0;
    for (i, b) in boards.iter().enumerate() {
        let mut mine: Vec<_> = b.reports.matched.iter().collect();
        mine.sort_by_key(|m| m.0);
        for (peer, r) in mine {
            let status = MatchStatus::from_code(r.result.status);
            let converged = status == Some(MatchStatus::Converged);
            let accepted = converged && k < 64 && kept & (1 << k) != 0;
            k += usize::from(converged);
            let reason = match (status, accepted) {
                (None, _) => "the maps never met",
                (Some(_), _) if !converged => "not converged",
                (_, true) => "consistent",
                (_, false) => "inconsistent around a cycle",
            };
            let (status, overlap) = (status.map(|s| s.as_str()), r.result.overlap);
            matches.push(BoardMatchJson { a: i, b: usize::from(*peer), status, accepted, reason, overlap });
        }
    }
    matches
}

/// One board's figures, and how its placements differ from the host's
/// run of its robot and from board 0's.
fn board_json(i: usize, b: &BoardRun, host: Option<&TeamReports>, board0: &TeamReports) -> BoardJson {
    let r = &b.reports;
    let sum = |f: fn(&cosem_core::wire::feed::RobotReport) -> u64| r.matched.iter().map(|m| f(&m.1)).sum();
    let to_host = host.and_then(|h| placement_difference(r, h));
    BoardJson {
        index: i,
        exit_code: b.exit_code,
        finished: r.end.is_some(),
        error: r.failed.as_ref().map(|(s, m)| BTreeMap::from([("stage", s.clone()), ("message", m.clone())])),
        heard: (0..cosem_core::team::MAX_ROBOTS).filter(|&k| r.end.is_some_and(|e| e.heard & (1 << k) != 0)).collect(),
        points: r.matched.first().map_or(0, |m| m.1.points),
        map_voxels: r.matched.first().map_or(0, |m| m.1.map_voxels),
        map_instructions: r.matched.first().map_or(0, |m| m.1.map_instructions),
        prepare_instructions: sum(|m| m.prepare_instructions),
        locate_instructions: sum(|m| m.locate_instructions),
        match_instructions: sum(|m| m.match_instructions),
        solve_instructions: r.end.map_or(0, |e| e.solve_instructions),
        peak_stack_bytes: r.end.map_or(0, |e| e.peak_stack),
        link_bytes_while_matching: r.matched.iter().map(|m| m.1.link_bytes_while_matching).sum(),
        link_ms_onboard: r.matched.iter().map(|m| m.1.link_ms).sum(),
        share_ms_onboard: r.end.map_or(0, |e| e.share_ms),
        difference_to_host_m: to_host.map(|d| d.0),
        difference_to_board0_m: placement_difference(r, board0).map(|d| d.0),
        same_groups_as_host: to_host.map(|d| d.1),
    }
}

impl std::fmt::Display for TeamBoardJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for r in &self.robots {
            let p = place_text(r);
            writeln!(
                f,
                "robot {}: {p}; {} voxels, {} B sent, {} B received",
                r.index, r.voxels, r.bytes_sent, r.bytes_received
            )?;
        }
        for m in &self.matches {
            let kept = if m.accepted { "kept" } else { "left out" };
            let status = m.status.unwrap_or("no exchange");
            writeln!(f, "T_{}_{}: {status}, overlap {:.2}, {kept} ({})", m.a, m.b, m.overlap, m.reason)?;
        }
        let mi = |v: u64| v as f64 / 1e6;
        for b in &self.boards {
            match &b.error {
                Some(e) => {
                    writeln!(f, "board {}: stopped at {}: {}; exit {:?}", b.index, e["stage"], e["message"], b.exit_code)?
                }
                None => writeln!(
                    f,
                    "board {}: map {:.1} M, prepare {:.1} M, locate {:.1} M, match {:.1} M, consistency and pose graph {:.1} M instructions; peak stack {} B; {} B came in while matching; {} robots heard; differs from the host by {} m; exit {:?}",
                    b.index,
                    mi(b.map_instructions),
                    mi(b.prepare_instructions),
                    mi(b.locate_instructions),
                    mi(b.match_instructions),
                    mi(b.solve_instructions),
                    b.peak_stack_bytes,
                    b.link_bytes_while_matching,
                    b.heard.len(),
                    b.difference_to_host_m.map_or("?".into(), |d| format!("{d:.1e}")),
                    b.exit_code
                )?,
            }
        }
        writeln!(f, "wall time {:.1} s", self.wall_time_s)
    }
}
