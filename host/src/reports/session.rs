//! `cosem session`'s output: a line per robot, peer and round (text, or
//! JSON lines with `--json`), then the figures (`{"summary": {...}}`).

use crate::evaluation::session::{Record, Summary};
use cosem_core::geometry::row_major;
use serde::Serialize;

/// The JSON lines' schema version: 2 since `status` is `Converged` only
/// for a fix the peer's estimate agreed with (`confirmed`); 3 since `e_t`
/// is taken at the meeting place (was `e_meeting`), the odometry origin's
/// in `e_t_origin`, and the summary's `wrong_at_meeting` became
/// `wrong_at_origin`; 4 since the summary's `from_scratch_ms` is timed on
/// the maps of tracking rounds (every [`FROM_SCRATCH_EVERY`]th), not on
/// the last round's; 5 since each line has `update_deferred` and the
/// summary `update_deferred` (p50, p95, max), updates being bounded by a
/// budget (`--update-budget`, by default 1,024 bytes); 6 since a line's
/// figures (`line_bytes`, `line_ms`, the summary's `line_late`); 7 since
/// each line has `e_t_local` and `e_r_local` and the summary
/// `wrong_converged_local` (against the truth as the maps hold it about
/// the closest pair of scans); 8 since each line has `adopted` (the
/// estimate is the peer's fix of the round, adopted after the robot's own
/// failed its verdict); 9 since each line has `contested` (the fix
/// contradicts the robot's history of the peer by more than drift
/// explains, or is a first fix whose overlap stopped growing, so is not
/// reported `Converged`); 10 since each line has `disputed` (the peer's
/// latest estimate disagrees with the robot's confirmed fix, so it is not
/// reported `Converged` in that round); 11 since each line has `walked`,
/// `walk` and `walk_peer` (the robots' figures of their odometry's heading
/// walk, over whose limit no estimate is reported `Converged`).
///
/// [`FROM_SCRATCH_EVERY`]: crate::evaluation::session::FROM_SCRATCH_EVERY
pub const SESSION_SCHEMA: u32 = 11;

/// One robot's estimate of one peer in one round, as a JSON line.
#[derive(Clone, Debug, Serialize)]
pub struct RecordJson {
    /// The round (0 first).
    pub round: usize,
    /// The estimating robot.
    pub robot: usize,
    /// The peer.
    pub peer: usize,
    /// The conventions' status (`NoOverlap` while no copy of the peer's map is held).
    pub status: &'static str,
    /// `prior-free` or `tracking`.
    pub kind: &'static str,
    /// What became of the fix: `none`, `held`, `kept`, `withdrawn`.
    pub fix: &'static str,
    /// The fix agreed with the peer's estimate of the robot (now or since
    /// it was made): only then is the status `Converged`.
    pub confirmed: bool,
    /// The estimate is the peer's fix of this round, adopted after the
    /// robot's own estimate failed its verdict (`Tracker::adopt`).
    pub adopted: bool,
    /// The fix contradicts the robot's history of the peer (its fixes
    /// confirmed before) by more than drift explains, or is a first fix
    /// whose overlap stopped growing as the robots drove: held, but not
    /// reported `Converged` until its confirmed rounds outweigh that
    /// history, or its overlap grows (`cosem_core::session::History`).
    pub contested: bool,
    /// The peer's latest estimate that passed its verdict disagrees with
    /// this one: one of the two is wrong, and a confirmed fix is reported
    /// `NotConverged` in that round (schema 10).
    pub disputed: bool,
    /// The two robots' odometry walks more than the figure a `Converged`
    /// claim allows (`walk` and `walk_peer` together over
    /// `cosem_core::session::WALK_LIMIT_DEG`): held, but not reported
    /// `Converged` (schema 11).
    pub walked: bool,
    /// `T_own_peer`, row-major 3x4, when there is an estimate.
    #[serde(rename = "T_own_peer", skip_serializing_if = "Option::is_none")]
    pub t_own_peer: Option<[f64; 12]>,
    /// Translation error against the truth (m), at the meeting place:
    /// between where the estimate and the truth put the peer's place at the
    /// closest pair of scans (the conventions' `e_t` with the model frame's
    /// origin moved there).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_t: Option<f64>,
    /// The conventions' `e_t` at the robot's odometry origin (m): a drift's
    /// rotation error times the distance to the meeting.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_t_origin: Option<f64>,
    /// Rotation error against the truth (degrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_r: Option<f64>,
    /// `e_t` against the truth as the two maps hold it about the closest
    /// pair of scans: each robot's odometry frame averaged over its scans
    /// within the crop of its scan of the pair (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_t_local: Option<f64>,
    /// `e_r` against the same (degrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_r_local: Option<f64>,
    /// Overlap of the peer's map in the robot's under the truth.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub overlap_true: Option<f64>,
    /// The match's own overlap and agreement.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub overlap: Option<f32>,
    /// The match's agreement.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub agreement: Option<f32>,
    /// EM iterations the match used (all levels).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub iterations: Option<u32>,
    /// The match's degeneracy (the normalised smallest eigenvalue of its
    /// information; below the settings' threshold: `Degenerate`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub degeneracy: Option<f32>,
    /// The robot's figure of its odometry's heading walk (degrees): the
    /// root mean square of its last scans' turns against its map, less
    /// their fits' own noise (schema 11).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub walk: Option<f32>,
    /// The peer's figure of its odometry's heading walk (degrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub walk_peer: Option<f32>,
    /// Bytes of the peer's update and the answer.
    pub bytes_sent: usize,
    /// With a line: bytes the robot read from it this round.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub line_bytes: Option<u64>,
    /// With a line: the pair's round on it (ms).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub line_ms: Option<u64>,
    /// The update ÷ the peer's whole map (once the copy was whole once).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub update_ratio: Option<f64>,
    /// What became of the update (`Applied`, `Repeated`, ...).
    pub update: String,
    /// Voxels the update brought that the copy did not hold.
    pub update_new: u32,
    /// Voxels it brought whose record changed.
    pub update_changed: u32,
    /// Cells it removed.
    pub update_removed: u32,
    /// New or changed voxels the sender held back for later rounds: beyond
    /// its update budget (`--update-budget`).
    pub update_deferred: u32,
    /// Seconds of this estimate's work: the update applied, both maps
    /// prepared, the match (the sender's writing of the update left out).
    pub seconds: f64,
}

impl From<&Record> for RecordJson {
    fn from(r: &Record) -> Self {
        let e = r.estimate.as_ref();
        let t = e.map(|e| {
            let m = row_major(&e.result.transform.cast::<f64>());
            let mut rows = [0.0; 12];
            rows.copy_from_slice(&m[..12]);
            rows
        });
        RecordJson {
            round: r.round,
            robot: r.robot,
            peer: r.peer,
            status: e.map_or("NoOverlap", |e| e.status().as_str()),
            kind: e.map_or("prior-free", |e| e.kind.as_str()),
            fix: e.map_or("none", |e| e.fix.as_str()),
            confirmed: e.is_some_and(|e| e.confirmed),
            adopted: r.adopted,
            contested: e.is_some_and(|e| e.contested),
            disputed: e.is_some_and(|e| e.disputed),
            walked: e.is_some_and(|e| e.walked),
            t_own_peer: t,
            e_t: r.errors.map(|e| e.0),
            e_t_origin: r.origin_error,
            e_r: r.errors.map(|e| e.1),
            e_t_local: r.local_errors.map(|e| e.0),
            e_r_local: r.local_errors.map(|e| e.1),
            overlap_true: r.overlap_true,
            overlap: e.map(|e| e.result.overlap),
            agreement: e.map(|e| e.result.agreement),
            iterations: e.map(|e| e.result.iterations),
            degeneracy: e.map(|e| e.result.degeneracy),
            walk: r.walk.0,
            walk_peer: r.walk.1,
            bytes_sent: r.bytes_sent,
            line_bytes: r.line.map(|l| l.bytes),
            line_ms: r.line.map(|l| l.ms),
            update_ratio: r.update_ratio,
            update: r.applied.map_or_else(|| "OnTheLine".to_string(), |a| format!("{a:?}")),
            update_new: r.counts.new,
            update_changed: r.counts.changed,
            update_removed: r.counts.removed,
            update_deferred: r.counts.deferred,
            seconds: r.seconds,
        }
    }
}

/// The last line.
#[derive(Clone, Debug, Serialize)]
pub struct SummaryJson<'a> {
    /// The figures.
    pub summary: SummaryFields<'a>,
}

/// The figures and the schema version.
#[derive(Clone, Debug, Serialize)]
pub struct SummaryFields<'a> {
    /// [`SESSION_SCHEMA`].
    pub schema_version: u32,
    /// Rounds run.
    pub rounds: usize,
    /// The figures.
    #[serde(flatten)]
    pub figures: &'a Summary,
}

/// A record as a line of text.
pub fn record_text(r: &Record) -> String {
    let j = RecordJson::from(r);
    let errors = match (j.e_t, j.e_r, j.e_t_origin) {
        (Some(t), Some(a), Some(o)) => format!("e_t {t:6.3} m  e_r {a:6.3} deg  e_t_origin {o:6.3} m"),
        (Some(t), Some(a), None) => format!("e_t {t:6.3} m  e_r {a:6.3} deg"),
        _ => "(no truth)".into(),
    };
    let overlap = j.overlap_true.map_or(String::new(), |o| format!("  overlap_true {o:.2}"));
    let ratio = j.update_ratio.map_or(String::new(), |q| format!(" ({:.0}% of the map)", 100.0 * q));
    let line = match (j.line_bytes, j.line_ms) {
        (Some(b), Some(ms)) => format!("  line {b} B, {ms} ms"),
        _ => String::new(),
    };
    format!(
        "round {:3}  robot {} <- {}  {:<12} {:<10} {:<9} {errors}{overlap}  update {} B{ratio} {}{line}  {:.0} ms",
        j.round,
        j.robot,
        j.peer,
        j.status,
        j.kind,
        match (j.adopted, j.contested, j.disputed, j.walked) {
            (true, ..) => "adopted",
            (_, true, ..) => "contested",
            (_, _, true, _) => "disputed",
            (.., true) => "walked",
            _ => j.fix,
        },
        j.bytes_sent,
        j.update,
        j.seconds * 1e3
    )
}

/// The figures as text.
pub fn summary_text(s: &Summary, rounds: usize) -> String {
    let opt = |v: Option<f64>, unit: &str| v.map_or("-".to_string(), |v| format!("{v:.3}{unit}"));
    let ratio = s.update_bytes_ratio.map_or("-".into(), |[a, b, c]| format!("p50 {a:.3}, p95 {b:.3}, max {c:.3}"));
    let deferred = s.update_deferred.map_or("-".into(), |[a, b, c]| format!("p50 {a:.0}, p95 {b:.0}, max {c:.0}"));
    let mut out = format!(
        "rounds {rounds}; estimates with a truth {}\nwrong Converged   {} (by e_t at the odometry origin: {}; against the maps' local truth: {})\nmeetings          {}\navailability      {}\nfirst fix         {} rounds (largest)\nupdate / map      {ratio}\nheld back         {deferred} voxels an update\nbytes             {}\ntracking round    {} (from scratch {:.1} ms; ratio {})\n",
        s.with_truth,
        s.wrong_converged,
        s.wrong_at_origin,
        s.wrong_converged_local,
        s.meetings,
        opt(s.availability, ""),
        s.first_fix_rounds.map_or("-".into(), |v| v.to_string()),
        s.bytes,
        opt(s.tracking_ms, " ms"),
        s.from_scratch_ms,
        opt(s.tracking_cost_ratio, ""),
    );
    if let Some(d) = s.slip_caught_rounds {
        out.push_str(&format!("slip caught in     {d} rounds\n"));
    }
    if let (Some(bytes), Some([a, b, c]), Some(late)) = (s.line_bytes, s.line_ms, s.line_late) {
        out.push_str(&format!(
            "on the lines      {bytes} bytes read; a pair's round p50 {a:.0}, p95 {b:.0}, max {c:.0} ms; {late} later than its scans\n"
        ));
    }
    out
}
