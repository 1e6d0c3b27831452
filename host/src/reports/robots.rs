//! `cosem robots` as JSON (stable field names, a schema version) and as
//! text: each board's report beside the host's twin run and the truth.

use crate::boards::emulator::{firmware_stage, lost_reason};
use crate::boards::robots::{Outcome, RobotRun, RobotsRun};
use crate::lines::transport::line_seconds;
use crate::poses::{from_row_major, pose_text};
use crate::reports::report::GlobalJson;
use cosem_core::geometry::{errors_of, from_rows, row_major, Isometry3};
use cosem_core::matching::MatchStatus;
use serde::Serialize;
use std::collections::BTreeMap;

/// One robot in `cosem robots --json`: its report, or where it stopped.
#[derive(Clone, Debug, Serialize)]
#[serde(untagged)]
pub enum RobotJson {
    /// It reported a match.
    Report(Box<ReportJson>),
    /// It stopped, or said nothing.
    Failed {
        /// Robot id.
        id: usize,
        /// Always null.
        status: Option<&'static str>,
        /// `{stage, message}`.
        error: BTreeMap<&'static str, String>,
        /// QEMU's exit code.
        exit_code: Option<i32>,
    },
}

/// A robot's report as JSON (field names kept for scripts).
#[derive(Clone, Debug, Serialize)]
pub struct ReportJson {
    /// Robot id (0: A, 1: B).
    pub id: usize,
    /// Its board (`mps2-an386`, `stm32f405`).
    pub board: &'static str,
    /// Static RAM of its firmware (bytes, from the ELF; the stack comes on
    /// top, `peak_stack_bytes`).
    pub static_ram_bytes: u64,
    /// Status string.
    pub status: &'static str,
    /// `T_own_peer`, row by row.
    pub transform: [f64; 16],
    /// Instructions of the prior-free alignment and the match.
    pub instructions: u64,
    /// Voxels of its own map.
    pub map_voxels: u32,
    /// Bytes it wrote to the link.
    pub bytes_sent: u64,
    /// Bytes it read from the link.
    pub bytes_received: u64,
    /// Instructions inserting points.
    pub map_instructions: u64,
    /// Instructions preparing both maps.
    pub prepare_instructions: u64,
    /// Instructions of the match.
    pub match_instructions: u64,
    /// Points fed.
    pub points: u32,
    /// Voxels received.
    pub received_voxels: u32,
    /// Frames resent on the link.
    pub retransmissions: u32,
    /// Link time on the robot's clock (ms).
    pub link_ms_onboard: u32,
    /// Link time at 115200 baud from the bytes (s).
    pub link_time_115200_s: f64,
    /// EM iterations.
    pub iterations: u16,
    /// Inlier voxels.
    pub inliers: u32,
    /// Overlap.
    pub overlap: f32,
    /// Peak stack (bytes).
    pub peak_stack_bytes: u32,
    /// Bytes that came in on the link line while the robot prepared and
    /// matched, taken by its receive interrupt (0 for a robot that does
    /// not match).
    pub link_bytes_while_matching: u32,
    /// QEMU's exit code.
    pub exit_code: Option<i32>,
    /// Instructions of the prior-free alignment.
    pub locate_instructions: u64,
    /// What the prior-free alignment found.
    pub global: Option<GlobalJson>,
    /// Translation error against the truth (m).
    pub e_t: f64,
    /// Rotation error against the truth (degrees).
    pub e_r: f64,
}

/// The host's own run of robot A's match.
#[derive(Clone, Debug, Serialize)]
pub struct HostJson {
    /// `T_A_B`, row by row.
    pub transform: [f64; 16],
    /// Status string.
    pub status: &'static str,
    /// Translation error (m).
    pub e_t: f64,
    /// Rotation error (degrees).
    pub e_r: f64,
    /// What the prior-free alignment found.
    pub global: Option<GlobalJson>,
    /// Wall time of the host's run of both robots (ms).
    pub time_ms: f64,
}

/// `cosem robots --json`.
#[derive(Clone, Debug, Serialize)]
pub struct RobotsJson {
    /// Version of this JSON (3: each robot's `board` and
    /// `static_ram_bytes`; 2: `global` holds the prior-free search's
    /// figures, schema 1 landmark correspondences).
    pub schema_version: u32,
    /// Robot A then B.
    pub robots: Vec<RobotJson>,
    /// The host's run of robot A.
    pub host: HostJson,
    /// Robot A's prior `T_A_B`, row by row (null: none).
    pub prior: Option<[f64; 16]>,
    /// The host's run of robot B.
    pub host_b: HostBJson,
    /// `T_A_B`, row by row.
    pub ground_truth: [f64; 16],
    /// Bytes the line carried from each robot.
    pub line_bytes: [u64; 2],
    /// Wall time of the emulated run (s).
    pub wall_time_s: f64,
    /// The label noise the fed scans carried, and its seed (absent: the
    /// ground truth's labels).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub label_noise: Option<String>,
}

/// The host's run of robot B's match.
#[derive(Clone, Debug, Serialize)]
pub struct HostBJson {
    /// `T_B_A`, row by row.
    pub transform: [f64; 16],
    /// Status string.
    pub status: &'static str,
}

fn status_str(code: u8) -> &'static str {
    MatchStatus::from_code(code).map(MatchStatus::as_str).unwrap_or("?")
}

fn robot_json(i: usize, run: &RobotRun, truth: &Isometry3<f64>) -> RobotJson {
    let failed = |stage: &str, message: &str| RobotJson::Failed {
        id: i,
        status: None,
        error: BTreeMap::from([("stage", stage.to_string()), ("message", message.to_string())]),
        exit_code: run.exit_code,
    };
    let rep = match &run.outcome {
        Outcome::Report(r) => r,
        Outcome::Failed { stage, message } => return failed(stage, message),
        Outcome::Lost(why) => return failed(firmware_stage(run.exit_code), &lost_reason(why, run.exit_code)),
    };
    let t = rep.result.transform();
    let (e_t, e_r) = errors_of(&t, truth);
    RobotJson::Report(Box::new(ReportJson {
        id: i,
        board: run.board.as_str(),
        static_ram_bytes: run.static_ram_bytes,
        status: status_str(rep.result.status),
        transform: row_major(&t.cast::<f64>()),
        instructions: rep.locate_instructions + rep.match_instructions,
        map_voxels: rep.map_voxels,
        bytes_sent: rep.bytes_sent,
        bytes_received: rep.bytes_received,
        map_instructions: rep.map_instructions,
        prepare_instructions: rep.prepare_instructions,
        match_instructions: rep.match_instructions,
        points: rep.points,
        received_voxels: rep.received_voxels,
        retransmissions: rep.retransmissions,
        link_ms_onboard: rep.link_ms,
        link_time_115200_s: line_seconds(rep.bytes_sent.max(rep.bytes_received), 115_200),
        iterations: rep.result.iterations,
        inliers: rep.result.inliers,
        overlap: rep.result.overlap,
        peak_stack_bytes: rep.peak_stack,
        link_bytes_while_matching: rep.link_bytes_while_matching,
        exit_code: run.exit_code,
        locate_instructions: rep.locate_instructions,
        global: rep.global.map(Into::into),
        e_t,
        e_r,
    }))
}

impl RobotsJson {
    /// Everything `cosem robots` reports: the boards' runs beside the
    /// host's twin run (`host[i]`: robot i's report computed here) and the
    /// truth `T_A_B`.
    pub fn of(run: &RobotsRun) -> RobotsJson {
        let (gt, host) = (&run.truth, &run.host);
        let truths = [*gt, gt.inverse()];
        let robots = run.pair.robots.iter().zip(&truths).enumerate().map(|(i, (r, t))| robot_json(i, r, t)).collect();
        let (ha, hb) = (host[0].result.transform(), host[1].result.transform());
        let (e_t, e_r) = errors_of(&ha, gt);
        RobotsJson {
            schema_version: 3,
            robots,
            host: HostJson {
                transform: row_major(&ha.cast::<f64>()),
                status: status_str(host[0].result.status),
                e_t,
                e_r,
                global: host[0].global.map(Into::into),
                time_ms: run.host_ms,
            },
            prior: run.prior.as_ref().map(|p| row_major(&from_rows(p).cast::<f64>())),
            host_b: HostBJson { transform: row_major(&hb.cast::<f64>()), status: status_str(host[1].result.status) },
            ground_truth: row_major(gt),
            line_bytes: run.pair.line_bytes,
            wall_time_s: run.pair.wall_s,
            label_noise: run.label_noise.clone(),
        }
    }
}

/// The exit code of `cosem robots`: the worse status of the two robots
/// (see [`crate::reports::report::exit_code`]); `None`: a robot did not
/// report.
pub fn exit_code(run: &RobotsRun) -> Option<u8> {
    let statuses = run.pair.robots.iter().map(|r| match &r.outcome {
        Outcome::Report(rep) => Some(crate::reports::report::status_code(rep.result.status)),
        _ => None,
    });
    statuses.collect::<Option<Vec<u8>>>().map(|c| c.into_iter().max().unwrap_or(0))
}

impl std::fmt::Display for ReportJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (name, peer, i) = if self.id == 0 { ("A", "B", 0) } else { ("B", "A", 1) };
        if let Some(g) = &self.global {
            let m = self.locate_instructions as f64 / 1e6;
            writeln!(f, "robot {name} (id {i}): no prior; {}; prior-free search {m:.1} M instructions", g.text())?;
        }
        let t = pose_text(&from_row_major(&self.transform));
        writeln!(
            f,
            "robot {name} (id {i}): {}, T_{name}_{peer} = {t} (e_t {:.3} m, e_r {:.3} deg)",
            self.status, self.e_t, self.e_r
        )?;
        let line_s = line_seconds(self.bytes_sent.max(self.bytes_received), 115_200);
        writeln!(
            f,
            "  map {} voxels from {} fed points; sent {} B, received {} B ({} retransmissions; {line_s:.1} s at 115200 baud)",
            self.map_voxels, self.points, self.bytes_sent, self.bytes_received, self.retransmissions
        )?;
        let m = |v: u64| v as f64 / 1e6;
        writeln!(
            f,
            "  instructions: mapping {:.1} M, preparation {:.1} M, match {:.1} M; peak stack {} B; \
             {} B came in on the link while matching; exit {:?}",
            m(self.map_instructions),
            m(self.prepare_instructions),
            m(self.match_instructions),
            self.peak_stack_bytes,
            self.link_bytes_while_matching,
            self.exit_code
        )
    }
}

impl std::fmt::Display for RobotsJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for robot in &self.robots {
            match robot {
                RobotJson::Report(rep) => write!(f, "{rep}")?,
                RobotJson::Failed { id, error, exit_code, .. } => {
                    let get = |k| error.get(k).map(String::as_str).unwrap_or("");
                    writeln!(f, "robot {id}: failed at {}: {}; exit {exit_code:?}", get("stage"), get("message"))?;
                }
            }
        }
        let h = &self.host;
        let t = pose_text(&from_row_major(&h.transform));
        let (e_t, e_r, ms) = (h.e_t, h.e_r, h.time_ms);
        writeln!(
            f,
            "host (same fed data): {}, T_A_B = {t} (e_t {e_t:.3} m, e_r {e_r:.3} deg); {ms:.1} ms for both robots",
            h.status
        )?;
        if let Some(g) = &h.global {
            writeln!(f, "host, no prior: {}", g.text())?;
        }
        writeln!(
            f,
            "host, robot B's match: {}, T_B_A = {}",
            self.host_b.status,
            pose_text(&from_row_major(&self.host_b.transform))
        )?;
        writeln!(
            f,
            "ground truth: T_A_B = {}; wall time {:.1} s",
            pose_text(&from_row_major(&self.ground_truth)),
            self.wall_time_s
        )
    }
}
