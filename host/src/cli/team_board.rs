//! `cosem team --on-board`: each robot on its own emulated board (see
//! `cosem_host::team_board`), beside the host's run of the same robots.

use super::team::{Args, RobotJson};
use super::{print_json, Error};
use cosem_core::geometry::{errors_of, from_rows, row_major};
use cosem_core::matching::{MatchSettings, MatchStatus};
use cosem_core::wire::share::Estimate;
use cosem_host::robots::firmware;
use cosem_host::team::TeamSpec;
use cosem_host::team_board::{host_team_run, placement_difference, run_boards, team_feeds, TeamReports, MAX_BOARDS};
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::Duration;

#[derive(Serialize)]
struct MatchJson {
    a: usize,
    b: usize,
    /// Null when the maps never met (the link failed).
    status: Option<&'static str>,
    accepted: bool,
    reason: &'static str,
    overlap: f32,
}

#[derive(Serialize)]
struct BoardJson {
    index: usize,
    exit_code: Option<i32>,
    finished: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<BTreeMap<&'static str, String>>,
    /// Robots whose estimates this board holds (all of them when sharing
    /// went through).
    heard: Vec<usize>,
    points: u32,
    map_voxels: u32,
    map_instructions: u64,
    /// Over all its matches.
    prepare_instructions: u64,
    locate_instructions: u64,
    match_instructions: u64,
    solve_instructions: u64,
    peak_stack_bytes: u32,
    /// Over all its matches: bytes its peers sent that came in (taken by
    /// its receive interrupts into the rings) while it prepared and matched.
    link_bytes_while_matching: u32,
    link_ms_onboard: u32,
    share_ms_onboard: u32,
    /// Largest translation difference (m) from the host's run of this robot.
    difference_to_host_m: Option<f64>,
    /// Largest translation difference (m) from board 0's placements.
    difference_to_board0_m: Option<f64>,
    /// Same groups (anchors) as the host's run.
    same_groups_as_host: Option<bool>,
}

#[derive(Serialize)]
struct TeamBoardJson {
    schema_version: u32,
    links: &'static str,
    on_board: bool,
    robots: Vec<RobotJson>,
    matches: Vec<MatchJson>,
    consistency_exhaustive: bool,
    boards: Vec<BoardJson>,
    /// Largest difference (m) between any board's placements and the host's.
    host_difference_m: Option<f64>,
    wall_time_s: f64,
}

/// Exit code: 0 when every board finished and placed every robot in robot
/// 0's frame; 5 when a robot is unplaced; an error when a board stopped.
pub fn run(a: Args) -> Result<u8, Error> {
    let n = a.robots.len();
    if !(2..=MAX_BOARDS).contains(&n) {
        return Err(format!("--on-board: 2 to {MAX_BOARDS} robots (each board has four peer UARTs), not {n}").into());
    }
    let spec = TeamSpec {
        robots: a.robots.clone(),
        voxel: a.voxel.unwrap_or(0.5),
        prior_noise: None,
        inject_false_match: Vec::new(),
        source: a.source.options(),
        label_noise: a.label_noise,
        seed: a.seed,
        settings: MatchSettings::default(),
    };
    let silence_ms = (a.silence * 1000.0).min(f64::from(u32::MAX)) as u32;
    let feeds = team_feeds(&spec, a.crop, silence_ms)?;
    let host = host_team_run(&feeds)?;
    let elf = firmware(&a.firmware)?;
    let (boards, wall_s) = run_boards(&elf, &feeds, Duration::from_secs_f64(a.timeout.min(86_400.0)), true)?;
    // The truth T_i_j when both robots come from one trajectory.
    let seqs = spec
        .robots
        .iter()
        .map(|r| cosem_host::source::Source::open(&r.data, &spec.source))
        .collect::<Result<Vec<_>, _>>()?;
    let truth = |i: usize, j: usize| {
        seqs[i]
            .same_trajectory(&seqs[j])
            .then(|| seqs[i].relative_pose(spec.robots[i].frames.start, spec.robots[j].frames.start).ok())
            .flatten()
    };
    let Some(first) = boards.iter().position(|b| b.reports.end.is_some()) else {
        let why: Vec<String> = boards
            .iter()
            .enumerate()
            .map(|(i, b)| match &b.reports.failed {
                Some((stage, message)) => format!("board {i} stopped at {stage}: {message}"),
                None => format!("board {i}: no last message (exit {:?})", b.exit_code),
            })
            .collect();
        return Err(format!("no board finished: {}", why.join("; ")).into());
    };
    let lead: &TeamReports = &boards[first].reports;
    let end = lead.end.ok_or("no board finished")?;
    // Every robot's bytes over its links, from its own board.
    let bytes = |i: usize| {
        let m = &boards[i].reports.matched;
        (m.iter().map(|x| x.1.bytes_sent).sum::<u64>(), m.iter().map(|x| x.1.bytes_received).sum::<u64>())
    };
    let mut robots: Vec<RobotJson> = lead
        .placed
        .iter()
        .map(|p| {
            let (i, g) = (usize::from(p.index), usize::from(p.anchor));
            let placed = g == 0;
            let members = lead.placed.iter().filter(|q| q.anchor == p.anchor).count();
            let in_group = !placed && members > 1;
            let t = from_rows(&p.transform);
            let errors = truth(g, i).filter(|_| placed || in_group).map(|gt| errors_of(&t, &gt));
            let cov = Estimate { information: p.covariance, ..Estimate::none(0, 0) }.information();
            let (sent, received) = bytes(i);
            RobotJson {
                index: i,
                placed,
                verified: false,
                group: g,
                transform: placed.then(|| row_major(&t.cast::<f64>())),
                covariance: placed.then(|| cov.iter().flatten().map(|&v| f64::from(v)).collect()),
                group_transform: in_group.then(|| row_major(&t.cast::<f64>())),
                voxels: boards[i].reports.matched.first().map_or(0, |m| m.1.map_voxels as usize),
                bytes_sent: sent,
                bytes_received: received,
                e_t: errors.map(|e| e.0),
                e_r: errors.map(|e| e.1),
            }
        })
        .collect();
    // Which estimates the lead board kept: its candidates are the converged
    // estimates in the order a, then b.
    let mut matches = Vec::new();
    let mut k = 0;
    for (i, b) in boards.iter().enumerate() {
        let mut mine: Vec<_> = b.reports.matched.iter().collect();
        mine.sort_by_key(|m| m.0);
        for (peer, r) in mine {
            let status = MatchStatus::from_code(r.result.status);
            let converged = status == Some(MatchStatus::Converged);
            let accepted = converged && end.kept & (1 << k) != 0;
            k += usize::from(converged);
            let reason = match (status, accepted) {
                (None, _) => "the maps never met",
                (Some(_), _) if !converged => "not converged",
                (_, true) => "consistent",
                (_, false) => "inconsistent around a cycle",
            };
            matches.push(MatchJson {
                a: i,
                b: usize::from(*peer),
                status: status.map(|s| s.as_str()),
                accepted,
                reason,
                overlap: r.result.overlap,
            });
        }
    }
    let kept = matches.iter().filter(|m| m.accepted).map(|m| (m.a, m.b));
    let verified = cosem_host::team::verified_placements(n, kept);
    for r in &mut robots {
        r.verified = r.placed && verified.get(r.index).copied().unwrap_or(false);
    }
    let mut host_difference: Option<f64> = None;
    let boards_json: Vec<BoardJson> = boards
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let r = &b.reports;
            let sum = |f: fn(&cosem_core::wire::feed::RobotReport) -> u64| r.matched.iter().map(|m| f(&m.1)).sum();
            let to_host = placement_difference(r, &host[i]);
            if let Some((d, _)) = to_host {
                host_difference = Some(host_difference.map_or(d, |h| h.max(d)));
            } else {
                host_difference = Some(f64::INFINITY);
            }
            BoardJson {
                index: i,
                exit_code: b.exit_code,
                finished: r.end.is_some(),
                error: r.failed.as_ref().map(|(s, m)| BTreeMap::from([("stage", s.clone()), ("message", m.clone())])),
                heard: (0..n).filter(|&k| r.end.is_some_and(|e| e.heard & (1 << k) != 0)).collect(),
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
                difference_to_board0_m: placement_difference(r, &boards[0].reports).map(|d| d.0),
                same_groups_as_host: to_host.map(|d| d.1),
            }
        })
        .collect();
    let all_finished = boards.iter().all(|b| b.reports.end.is_some());
    let code = if !all_finished {
        1
    } else if robots.iter().all(|r| r.placed) {
        0
    } else {
        5
    };
    let out = TeamBoardJson {
        schema_version: 2,
        links: "mesh of point-to-point UART links (each map crosses each link once)",
        on_board: true,
        robots,
        matches,
        consistency_exhaustive: end.exhaustive,
        boards: boards_json,
        host_difference_m: host_difference,
        wall_time_s: wall_s,
    };
    if a.json {
        print_json(&out)?;
    } else {
        print_text(&out);
    }
    Ok(code)
}

fn print_text(out: &TeamBoardJson) {
    for r in &out.robots {
        let place = match (r.placed, r.transform, r.group_transform) {
            (true, Some(t), _) => format!(
                "placed at ({:.3}, {:.3}, {:.3}) m in robot 0's frame{}",
                t[3],
                t[7],
                t[11],
                if r.verified || r.index == 0 { "" } else { " (verified by no cycle)" }
            ),
            (_, _, Some(t)) => {
                format!("unplaced; at ({:.3}, {:.3}, {:.3}) m in robot {}'s frame", t[3], t[7], t[11], r.group)
            }
            _ => "unplaced".to_string(),
        };
        let err = r.e_t.zip(r.e_r).map(|(t, d)| format!(", e_t {t:.3} m, e_r {d:.3} deg")).unwrap_or_default();
        println!(
            "robot {}: {place}{err}; {} voxels, {} B sent, {} B received",
            r.index, r.voxels, r.bytes_sent, r.bytes_received
        );
    }
    for m in &out.matches {
        let kept = if m.accepted { "kept" } else { "left out" };
        println!(
            "T_{}_{}: {}, overlap {:.2}, {kept} ({})",
            m.a,
            m.b,
            m.status.unwrap_or("no exchange"),
            m.overlap,
            m.reason
        );
    }
    let mi = |v: u64| v as f64 / 1e6;
    for b in &out.boards {
        match &b.error {
            Some(e) => println!("board {}: stopped at {}: {}; exit {:?}", b.index, e["stage"], e["message"], b.exit_code),
            None => println!(
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
            ),
        }
    }
    println!("wall time {:.1} s", out.wall_time_s);
}
