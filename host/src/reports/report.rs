//! The JSON of `cosem match`, `link`, `robots` and `info`, as serde types:
//! one place for the field names scripts read (kept stable; a change gets
//! a schema version).

use cosem_core::geometry::{row_major, xyz_rpy_deg};
use cosem_core::matching::global::Searched;
use cosem_core::matching::{MatchResult, MAX_LEVELS};
use cosem_core::wire::feed::GlobalReport;
use serde::Serialize;

/// A match result (`cosem match --json`, and `match` in `cosem link --json`).
#[derive(Clone, Debug, Serialize)]
pub struct MatchJson {
    /// The conventions' status string.
    pub status: &'static str,
    /// `T_model_scene`, row by row.
    pub transform: [f64; 16],
    /// x, y, z, roll, pitch, yaw (m, degrees).
    pub xyz_rpy_deg: [f64; 6],
    /// EM iterations.
    pub iterations: u32,
    /// Iterations per level, finest first.
    pub iterations_per_level: [u8; MAX_LEVELS],
    /// Inlier voxels.
    pub inliers: u32,
    /// Overlap under the result.
    pub overlap: f32,
    /// RMSE of the inliers (m).
    pub rmse: f32,
    /// The 6x6 information matrix, row by row.
    pub information: Vec<f32>,
    /// Its smallest eigenvalue.
    pub min_eigenvalue: f32,
    /// Normalised smallest eigenvalue.
    pub degeneracy: f32,
    /// Agreement of what both maps saw standing (the verdict's statistic).
    pub agreement: f32,
    /// Fraction of the scene's standing voxels the model saw around.
    pub coverage: f32,
    /// Version of this JSON (2: `agreement`, `coverage` and the prior-free
    /// search's `global`).
    pub schema_version: u32,
    /// Time of the match (ms).
    pub time_ms: f64,
    /// Time preparing both maps (ms).
    pub prepare_ms: f64,
    /// Association method.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub method: Option<&'static str>,
    /// What the prior-free alignment found (no prior given).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub global: Option<GlobalJson>,
}

impl MatchJson {
    /// The JSON of `r`.
    pub fn new(r: &MatchResult, time_ms: f64, prepare_ms: f64) -> Self {
        let t = r.transform.cast::<f64>();
        MatchJson {
            status: r.status.as_str(),
            transform: row_major(&t),
            xyz_rpy_deg: xyz_rpy_deg(&t),
            iterations: r.iterations,
            iterations_per_level: r.iterations_per_level,
            inliers: r.inliers,
            overlap: r.overlap,
            rmse: r.rmse,
            information: r.information.transpose().iter().copied().collect(),
            min_eigenvalue: r.min_eigenvalue,
            degeneracy: r.degeneracy,
            agreement: r.agreement,
            coverage: r.coverage,
            schema_version: 2,
            time_ms,
            prepare_ms,
            method: None,
            global: None,
        }
    }
}

/// What the prior-free alignment found (`global` in the JSON of `match`,
/// `link` and `robots`; schema 2: the coarse search over every heading and
/// offset replaced schema 1's landmark correspondences).
#[derive(Clone, Debug, Serialize)]
pub struct GlobalJson {
    /// The coarse search's best score (footprint cells agreeing).
    pub score: u32,
    /// The best score of a distinct placement (0: not looked for, the best
    /// one's refinement passed).
    pub runner_up: u32,
    /// Candidates refined until one passed the verdict (or all failed).
    pub refined: u8,
    /// The candidate the answer comes from (0: the best).
    pub chosen: u8,
    /// Nodes the coarse search scored.
    pub evaluations: u32,
    /// The chosen candidate's placement, row by row (the start EM refined).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub start: Option<[f64; 16]>,
    /// The search stopped at its budget of nodes: its
    /// placements are the best found until then, not proven best. Written
    /// only when true.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub exhausted: bool,
}

impl From<&Searched> for GlobalJson {
    fn from(s: &Searched) -> Self {
        let start = s.search.candidates.get(s.chosen).map(|c| row_major(&c.transform.cast::<f64>()));
        GlobalJson { start, exhausted: s.search.exhausted, ..GlobalJson::from(GlobalReport::from(s)) }
    }
}

impl From<GlobalReport> for GlobalJson {
    fn from(g: GlobalReport) -> Self {
        GlobalJson {
            score: g.score,
            runner_up: g.runner_up,
            refined: g.refined,
            chosen: g.chosen,
            evaluations: g.evaluations,
            start: None,
            exhausted: false,
        }
    }
}

impl GlobalJson {
    /// The figures in words.
    pub fn text(&self) -> String {
        let runner_up = if self.runner_up > 0 { format!(", runner-up {}", self.runner_up) } else { String::new() };
        let searched = if self.exhausted {
            format!(
                "stopped by its node budget after {} nodes, not every heading and offset searched",
                self.evaluations
            )
        } else {
            format!("searched every heading and offset ({} nodes)", self.evaluations)
        };
        if self.refined == 0 {
            return format!("{searched}: no placement found to refine");
        }
        format!(
            "{searched}: best score {}{runner_up}; candidate {} of {} refined",
            self.score,
            usize::from(self.chosen) + 1,
            self.refined
        )
    }
}

/// `cosem link --json`.
#[derive(Clone, Debug, Serialize)]
pub struct LinkJson {
    /// Our robot id.
    pub robot_id: u8,
    /// Bytes written to the line.
    pub bytes_sent: u64,
    /// Bytes read from the line.
    pub bytes_received: u64,
    /// Frames sent (retransmissions included).
    pub frames: u32,
    /// Valid frames received.
    pub frames_received: u32,
    /// Frames resent.
    pub retransmissions: u32,
    /// Frames rejected.
    pub bad_frames: u32,
    /// Frames received damaged and repaired by the forward error correction
    /// (counted in `frames_received` too).
    pub repaired_frames: u32,
    /// Bytes the correction rebuilt: substituted, dropped, duplicated.
    pub repaired_bytes: [u32; 3],
    /// Data frames received that brought nothing new.
    pub duplicates: u32,
    /// Acknowledgements sent.
    pub acks_sent: u32,
    /// Voxels of our map.
    pub voxels_sent: usize,
    /// Voxels of the peer's map.
    pub voxels_received: usize,
    /// Bytes of voxel encoding per voxel sent.
    pub wire_bytes_per_voxel: f64,
    /// Wall time of the exchange (s).
    pub link_time_s: f64,
    /// Baud rate the line times are given at.
    pub baud: u32,
    /// `{sent, received}`: seconds of line time at `baud` (8N1).
    pub line_time_s: std::collections::BTreeMap<&'static str, f64>,
    /// Our match (our map the model).
    #[serde(rename = "match")]
    pub result: MatchJson,
}

impl LinkJson {
    /// The figures of an exchange: what moved (`stats`), the voxels of our
    /// map and the peer's, its wall time (s), the baud rate its line times
    /// are given at, and our match.
    pub fn new(
        robot_id: u8,
        stats: &cosem_core::link::LinkStats,
        voxels: (usize, usize),
        link_time_s: f64,
        baud: u32,
        result: MatchJson,
    ) -> Self {
        let line = |bytes| crate::lines::transport::line_seconds(bytes, baud);
        LinkJson {
            robot_id,
            bytes_sent: stats.bytes_sent,
            bytes_received: stats.bytes_received,
            frames: stats.frames_sent,
            frames_received: stats.frames_received,
            retransmissions: stats.retransmissions,
            bad_frames: stats.bad_frames,
            repaired_frames: stats.repaired_frames,
            repaired_bytes: stats.repaired_bytes,
            duplicates: stats.duplicates,
            acks_sent: stats.acks_sent,
            voxels_sent: voxels.0,
            voxels_received: voxels.1,
            wire_bytes_per_voxel: stats.chunk_bytes_sent as f64 / voxels.0.max(1) as f64,
            link_time_s,
            baud,
            line_time_s: std::collections::BTreeMap::from([
                ("sent", line(stats.bytes_sent)),
                ("received", line(stats.bytes_received)),
            ]),
            result,
        }
    }
}

/// The exchange's figures in two lines (the match is printed apart).
impl std::fmt::Display for LinkJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (sent_s, received_s) = (self.line_time_s["sent"], self.line_time_s["received"]);
        writeln!(
            f,
            "robot {}: sent {} voxels in {} bytes ({:.2} bytes/voxel of encoding), received {} voxels in {} bytes",
            self.robot_id,
            self.voxels_sent,
            self.bytes_sent,
            self.wire_bytes_per_voxel,
            self.voxels_received,
            self.bytes_received
        )?;
        writeln!(
            f,
            "frames {} sent, {} received ({} repaired), {} retransmitted, {} broken; {:.2} s here; at {} baud: {sent_s:.1} s out, {received_s:.1} s in",
            self.frames,
            self.frames_received,
            self.repaired_frames,
            self.retransmissions,
            self.bad_frames,
            self.link_time_s,
            self.baud
        )
    }
}

/// `cosem info --json`.
#[derive(Clone, Debug, Serialize)]
pub struct InfoJson {
    /// The file.
    pub file: String,
    /// Voxels.
    pub voxels: usize,
    /// Voxel size (m).
    pub resolution: f32,
    /// `{min, max}` corners (m).
    pub bounds: std::collections::BTreeMap<&'static str, [f32; 3]>,
    /// File size.
    pub bytes: u64,
    /// File bytes per voxel.
    pub bytes_per_voxel: f64,
    /// Memory per voxel of capacity.
    pub memory_bytes_per_voxel: usize,
    /// Encoding bytes per voxel (as on the link).
    pub wire_bytes_per_voxel: f64,
    /// Voxels per class name.
    pub classes: std::collections::BTreeMap<&'static str, usize>,
    /// Voxels of an unknown class (geometry kept without labels:
    /// `cosem map --unlabeled geometry`).
    pub unknown_class: usize,
    /// Anchor scan time (s).
    pub anchor_time: Option<f64>,
    /// Source text, escaped.
    pub source: Option<String>,
    /// Sensor model accuracy.
    pub label_accuracy: f32,
    /// The classes in the histogram's order (for the text).
    #[serde(skip)]
    pub histogram: Vec<(&'static str, usize)>,
}

impl InfoJson {
    /// What the map file `file` holds.
    pub fn of(file: &std::path::Path) -> Result<Self, crate::error::Error> {
        let (header, map) = crate::maps::cmap::read(file)?;
        let bytes =
            std::fs::metadata(file).map_err(|source| crate::error::Error::Io { path: file.into(), source })?.len();
        let voxels = map.len();
        let histogram: Vec<(&'static str, usize)> =
            crate::maps::mapping::class_histogram(&map).iter().map(|(c, n)| (c.name(), *n)).collect();
        let (lo, hi) = map.bounds().unwrap_or(([0.0; 3], [0.0; 3]));
        Ok(InfoJson {
            file: file.display().to_string(),
            voxels,
            resolution: map.resolution(),
            bounds: std::collections::BTreeMap::from([("min", lo), ("max", hi)]),
            bytes,
            bytes_per_voxel: bytes as f64 / voxels.max(1) as f64,
            memory_bytes_per_voxel: cosem_core::map::BYTES_PER_VOXEL,
            wire_bytes_per_voxel: crate::maps::cmap::wire_bytes_per_voxel(&map, cosem_core::wire::mapfile::FILE_CHUNK),
            classes: histogram.iter().copied().collect(),
            unknown_class: map.iter().filter(|v| v.class().is_none()).count(),
            anchor_time: header.anchor_time,
            // Text from the file: escaped, so no control byte reaches a terminal.
            source: header.source.as_ref().map(|s| s.escape_debug().to_string()),
            label_accuracy: header.label_accuracy,
            histogram,
        })
    }
}

impl std::fmt::Display for InfoJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "{}", self.file)?;
        if let Some(s) = &self.source {
            writeln!(f, "  source:      {s}")?;
        }
        writeln!(f, "  voxels:      {} at {} m", self.voxels, self.resolution)?;
        let (lo, hi) = (self.bounds["min"], self.bounds["max"]);
        let b = format!("[{:.1}, {:.1}, {:.1}] .. [{:.1}, {:.1}, {:.1}]", lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        writeln!(f, "  bounds:      {b} m")?;
        writeln!(f, "  file:        {} bytes, {:.2} bytes/voxel", self.bytes, self.bytes_per_voxel)?;
        writeln!(f, "  encoding:    {:.2} bytes/voxel (as on the link)", self.wire_bytes_per_voxel)?;
        writeln!(f, "  memory:      {} bytes/voxel (index included)", self.memory_bytes_per_voxel)?;
        writeln!(f, "  classes:")?;
        for (c, n) in &self.histogram {
            writeln!(f, "    {:<14} {:>8}  {:5.1}%", c, n, 100.0 * *n as f64 / self.voxels.max(1) as f64)?;
        }
        if self.unknown_class > 0 {
            let n = self.unknown_class;
            writeln!(f, "    {:<14} {:>8}  {:5.1}%", "(unknown)", n, 100.0 * n as f64 / self.voxels.max(1) as f64)?;
        }
        Ok(())
    }
}

/// `cosem label --json` (fields in name order, as they always were).
#[derive(Clone, Debug, Serialize)]
pub struct LabelJson {
    /// In-view points whose new class equals the existing one.
    pub agreeing: usize,
    /// `agreeing / compared` (none without labels to compare with).
    pub agreement: Option<f64>,
    /// The agreement as the class set can say it.
    pub agreement_in_class_set: Option<f64>,
    /// The segmentation's class set.
    pub classes: &'static str,
    /// In-view points whose existing label has a class.
    pub compared: usize,
    /// Per class against the existing labels: recall, precision, top
    /// confusions (schema 2; empty without labels to compare with).
    pub per_class: Vec<crate::camera::label::ClassAgreement>,
    /// Frames labelled.
    pub frames: usize,
    /// Points projecting into the image and seen by the camera.
    pub in_view: usize,
    /// Seconds projecting and labelling.
    pub label_seconds: f64,
    /// In-view points given a class.
    pub labelled: usize,
    /// Points hidden behind nearer points.
    pub occluded: usize,
    /// The output folder.
    pub out: String,
    /// Points read.
    pub points: usize,
    /// Points labelled per second.
    pub points_per_second: f64,
    /// Whether the segmentation gave probabilities.
    pub probabilities: bool,
    /// The camera's image size the projection was scaled from.
    pub scaled_from_image_size: Option<[u32; 2]>,
    /// Version of this JSON (2: `per_class`).
    pub schema_version: u32,
    /// Seconds in all, reading and writing included.
    pub wall_seconds: f64,
}

impl LabelJson {
    /// The figures of a labelling run with `opts`, `wall` seconds in all.
    pub fn of(s: &crate::camera::label::LabelStats, opts: &crate::camera::label::LabelOptions, wall: f64) -> Self {
        LabelJson {
            agreeing: s.agreeing,
            agreement: s.agreement(),
            agreement_in_class_set: s.agreement_in_set(),
            classes: opts.classes.name(),
            compared: s.compared,
            per_class: s.per_class(),
            frames: s.frames,
            in_view: s.in_view,
            label_seconds: s.label_seconds,
            labelled: s.labelled,
            occluded: s.occluded,
            out: opts.out.display().to_string(),
            points: s.points,
            points_per_second: s.points as f64 / s.label_seconds.max(1e-9),
            probabilities: opts.probabilities,
            scaled_from_image_size: s.scaled_from.map(|(w, h)| [w, h]),
            schema_version: 2,
            wall_seconds: wall,
        }
    }
}

/// A match result in words, as `cosem match` and `cosem link` print it.
pub fn result_text(r: &MatchResult, global: Option<&Searched>) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(out, "status      {}", r.status.as_str());
    if let Some(g) = global {
        let _ = writeln!(out, "global      {}", GlobalJson::from(g).text());
    }
    let t = r.transform.cast::<f64>();
    let (m, x) = (t.to_homogeneous(), xyz_rpy_deg(&t));
    let _ = writeln!(out, "T_model_scene");
    for i in 0..4 {
        let _ = writeln!(out, "  {:>12.6} {:>12.6} {:>12.6} {:>12.6}", m[(i, 0)], m[(i, 1)], m[(i, 2)], m[(i, 3)]);
    }
    let _ =
        writeln!(out, "x,y,z,roll,pitch,yaw  {:.4},{:.4},{:.4},{:.4},{:.4},{:.4}", x[0], x[1], x[2], x[3], x[4], x[5]);
    let used = r.iterations_per_level.iter().rposition(|&n| n > 0).map_or(1, |i| i + 1);
    let per_level = &r.iterations_per_level[..used.max(crate::matching::align::DEFAULT_LEVELS)];
    let _ = writeln!(out, "iterations  {} (per level, fine to coarse: {per_level:?})", r.iterations);
    let _ = writeln!(out, "inliers     {}   overlap {:.1}%   rmse {:.4} m", r.inliers, 100.0 * r.overlap, r.rmse);
    let _ = writeln!(
        out,
        "agreement   {:.1}% of what both saw standing (coverage {:.1}%)",
        100.0 * r.agreement,
        100.0 * r.coverage
    );
    let _ = writeln!(out, "information min eigenvalue {:.4e}, normalised {:.4}", r.min_eigenvalue, r.degeneracy);
    out
}

/// The exit code of `cosem match`, `link` and `robots` for a status: 0
/// Converged, 3 NotConverged, 4 Degenerate, 5 NoOverlap (1 is an error, 2
/// a usage error).
pub fn exit_code(status: cosem_core::matching::MatchStatus) -> u8 {
    use cosem_core::matching::MatchStatus::*;
    match status {
        Converged => 0,
        NotConverged => 3,
        Degenerate => 4,
        NoOverlap => 5,
    }
}

/// [`exit_code`] of a status as a wire code (an unknown code is an error: 1).
pub fn status_code(code: u8) -> u8 {
    cosem_core::matching::MatchStatus::from_code(code).map(exit_code).unwrap_or(1)
}
