//! `cosem session --on-board`'s output: a line per robot and round (the
//! board's estimate, its error against the truth, how far it is from the
//! host's twin, what the round moved and cost), then whether the boards
//! equal their twin.

use crate::boards::session_board::{round_difference, SessionBoardsRun};
use cosem_core::matching::MatchStatus;
use cosem_core::wire::feed::RoundReport;
use serde::Serialize;

/// The JSON lines' schema version: 2 since `e_t` is taken at the meeting
/// place, the odometry origin's in `e_t_origin`; 3 since the lines say the
/// robots' walk figures (`walk`, `walk_peer`) and `walked`.
pub const SESSION_BOARD_SCHEMA: u32 = 3;

/// A board's figure must equal its twin's to this (m).
pub const TWIN_TOLERANCE_M: f64 = 1e-4;

/// Instructions a round may take on a board (the budget).
pub const ROUND_INSTRUCTIONS: u64 = 300_000_000;

/// One robot's round on its board, as a JSON line.
#[derive(Clone, Debug, Serialize)]
pub struct BoardRoundJson {
    /// The round (0 first).
    pub round: u16,
    /// The robot.
    pub robot: usize,
    /// Its peer.
    pub peer: usize,
    /// The conventions' status, or `none` while no copy is held.
    pub status: &'static str,
    /// `prior-free` or `tracking`.
    pub kind: &'static str,
    /// `T_own_peer`, row-major 3x4.
    #[serde(rename = "T_own_peer")]
    pub t_own_peer: [f64; 12],
    /// Translation error against the truth at the meeting place (m), as
    /// `cosem session`'s.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_t: Option<f64>,
    /// Rotation error against the truth (degrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_r: Option<f64>,
    /// The conventions' `e_t` at the odometry origin (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_t_origin: Option<f64>,
    /// Metres between the board's and the twin's translation.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub twin_dt: Option<f64>,
    /// Bytes of the update the robot sent.
    pub update_bytes: u32,
    /// Bytes it wrote to and read from the line this round.
    pub line_bytes: [u32; 2],
    /// Milliseconds of the exchange (the board's clock).
    pub exchange_ms: u32,
    /// Instructions: fusing, the updates, preparing, the estimate.
    pub instructions: [u64; 4],
    /// The estimate's work as the round's budget counted it (instructions
    /// at the fitted costs; `cosem_core::matching::Work`).
    pub work: u64,
    /// Whether the round's work budget cut the estimate short.
    pub work_cut: bool,
    /// The robot's figure of its odometry's heading walk (degrees,
    /// `cosem_core::session::OdometryWalk::excess`), once it has one.
    pub walk: Option<f64>,
    /// Its peer's, as the peer's board said it this round.
    pub walk_peer: Option<f64>,
    /// Whether the estimate passed the verdict but the pair's walk held it
    /// back from `Converged` (`cosem_core::session::Estimate::walked`).
    pub walked: bool,
}

/// What a session on boards showed.
pub struct SessionBoardReport<'a> {
    run: &'a SessionBoardsRun,
}

/// The report of `run`.
pub fn report(run: &SessionBoardsRun) -> SessionBoardReport<'_> {
    SessionBoardReport { run }
}

/// A round report's walk figure: `None` while the robot had none (negative).
fn figure(walk: f32) -> Option<f64> {
    (walk >= 0.0).then_some(f64::from(walk))
}

fn status_name(code: u8) -> &'static str {
    MatchStatus::from_code(code).map_or("none", |s| s.as_str())
}

impl SessionBoardReport<'_> {
    fn line(&self, robot: usize, r: &RoundReport) -> BoardRoundJson {
        let truth = self.run.truth.get(usize::from(r.round)).and_then(|t| t[robot]);
        let t = r.result.transform().cast::<f64>();
        let e = truth.filter(|_| MatchStatus::from_code(r.result.status).is_some()).map(|g| g.errors(&t));
        let twin = self.run.host.get(robot).and_then(|h| h.rounds.iter().find(|x| x.round == r.round));
        BoardRoundJson {
            round: r.round,
            robot,
            peer: 1 - robot,
            status: status_name(r.result.status),
            kind: if r.kind == 1 { "tracking" } else { "prior-free" },
            t_own_peer: r.result.transform.map(f64::from),
            e_t: e.map(|e| e.0),
            e_r: e.map(|e| e.1),
            e_t_origin: e.map(|e| e.2),
            twin_dt: twin.and_then(|w| round_difference(std::slice::from_ref(r), std::slice::from_ref(w)).map(|d| d.0)),
            update_bytes: r.update_bytes,
            line_bytes: r.line_bytes,
            exchange_ms: r.exchange_ms,
            instructions: [r.map_instructions, r.update_instructions, r.prepare_instructions, r.match_instructions],
            work: r.match_work,
            work_cut: r.work_cut,
            walk: figure(r.walk),
            walk_peer: self
                .run
                .boards
                .get(1 - robot)
                .and_then(|b| b.reports.rounds.iter().find(|x| x.round == r.round))
                .and_then(|x| figure(x.walk)),
            walked: r.walked,
        }
    }

    /// Whether every board ran every round, equal to its twin.
    pub fn ok(&self) -> bool {
        self.run.boards.iter().zip(&self.run.host).all(|(b, h)| {
            b.reports.failed.is_none()
                && b.reports.rounds.len() == self.run.rounds
                && round_difference(&b.reports.rounds, &h.rounds).is_some_and(|(d, same)| same && d <= TWIN_TOLERANCE_M)
        })
    }

    /// Every round's JSON line, then `{"summary": {...}}`.
    pub fn lines_json(&self) -> Result<Vec<String>, serde_json::Error> {
        let mut out = Vec::new();
        for (i, b) in self.run.boards.iter().enumerate() {
            for r in &b.reports.rounds {
                out.push(serde_json::to_string(&self.line(i, r))?);
            }
        }
        out.push(serde_json::to_string(&serde_json::json!({ "summary": self.summary() }))?);
        Ok(out)
    }

    fn summary(&self) -> serde_json::Value {
        let per_board: Vec<serde_json::Value> = self
            .run
            .boards
            .iter()
            .zip(&self.run.host)
            .enumerate()
            .map(|(i, (b, h))| {
                let lines: Vec<BoardRoundJson> = b.reports.rounds.iter().map(|r| self.line(i, r)).collect();
                let fixes = lines.iter().filter(|l| l.status == "Converged").count();
                let wrong = lines
                    .iter()
                    .filter(|l| l.status == "Converged" && !l.e_t.zip(l.e_r).is_some_and(|(t, r)| t < 0.5 && r < 1.0))
                    .count();
                let most = lines.iter().map(|l| l.instructions.iter().sum::<u64>()).max().unwrap_or(0);
                let diff = round_difference(&b.reports.rounds, &h.rounds);
                serde_json::json!({
                    "robot": i,
                    "rounds": b.reports.rounds.len(),
                    "failed": b.reports.failed.as_ref().map(|(s, m)| format!("{s}: {m}")),
                    "exit_code": b.exit_code,
                    "converged": fixes,
                    "wrong_converged": wrong,
                    "walked": lines.iter().filter(|l| l.walked).count(),
                    "walk": lines.last().and_then(|l| l.walk),
                    "twin_max_dt": diff.map(|d| d.0),
                    "twin_same_verdicts": diff.map(|d| d.1),
                    "most_round_instructions": most,
                    "line_bytes": b.reports.end.map(|e| e.line_bytes),
                    "peak_stack_bytes": b.reports.end.map(|e| e.peak_stack),
                    "static_ram_bytes": b.static_ram_bytes,
                })
            })
            .collect();
        serde_json::json!({
            "schema_version": SESSION_BOARD_SCHEMA,
            "rounds": self.run.rounds,
            "equal_to_twin": self.ok(),
            "boards": per_board,
            "twin_s": self.run.wall_s.0,
            "boards_wall_s": self.run.wall_s.1,
        })
    }

    /// The text: a line per robot and round, then a line per board.
    pub fn text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        for (i, b) in self.run.boards.iter().enumerate() {
            for r in &b.reports.rounds {
                let l = self.line(i, r);
                let e = match (l.e_t, l.e_r) {
                    (Some(t), Some(a)) => format!("e_t {t:.3} m e_r {a:.2} deg"),
                    _ => "no truth".into(),
                };
                let _ = writeln!(
                    s,
                    "round {:>3} robot {i} -> {}: {:<12} {:<10} {e} | twin {} | update {} B, line {}/{} B, {} ms | {:.2e} instructions",
                    l.round,
                    l.peer,
                    l.status,
                    l.kind,
                    l.twin_dt.map_or("missing".into(), |d| format!("{d:.1e} m")),
                    l.update_bytes,
                    l.line_bytes[0],
                    l.line_bytes[1],
                    l.exchange_ms,
                    l.instructions.iter().sum::<u64>() as f64,
                );
            }
        }
        let summary = self.summary();
        for b in summary["boards"].as_array().into_iter().flatten() {
            let _ = writeln!(
                s,
                "board {}: {} rounds, {} Converged ({} wrong), twin: max {} m apart, same verdicts {}, at most {} instructions a round (budget {ROUND_INSTRUCTIONS}), {} B static RAM, peak stack {} B{}",
                b["robot"], b["rounds"], b["converged"], b["wrong_converged"], b["twin_max_dt"], b["twin_same_verdicts"],
                b["most_round_instructions"], b["static_ram_bytes"], b["peak_stack_bytes"],
                b["failed"].as_str().map_or(String::new(), |f| format!(", stopped: {f}")),
            );
        }
        let _ = writeln!(
            s,
            "boards equal to the host's twin: {} (twin {:.1} s, boards {:.1} s of wall time)",
            self.ok(),
            self.run.wall_s.0,
            self.run.wall_s.1
        );
        s
    }
}
