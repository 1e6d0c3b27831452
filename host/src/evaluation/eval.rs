//! Evaluation, as `docs/conventions.md` counts it: the starts
//! (the paper's grid, or prior-free headings and offsets), the success
//! thresholds, one outcome per start and method, and summaries whose JSON
//! field names are the same in every mode (`schema_version` 2).

use crate::error::Error;
use crate::evaluation::pair::moved_frames;
use crate::evaluation::stats::{quantile, Spread};
use crate::maps::mapping::{build_map, HostMap, PointFilter};
use crate::matching::align::{align, prepare, HostPyramid, DEFAULT_LEVELS};
use cosem_core::geometry::{errors_of, pose_deg, row_major, Isometry3};
use cosem_core::map::MapConfig;
use cosem_core::matching::{Alignment, MatchResult, MatchStatus, MAX_LEVELS};
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::Instant;

/// Version of the `cosem eval --json` schema.
pub const SCHEMA_VERSION: u32 = 2;

/// Error bounds of a success.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thresholds {
    /// Translation error bound (m).
    pub e_t: f64,
    /// Rotation error bound (degrees).
    pub e_r: f64,
}

/// Strict success: `Converged`, `e_t < 0.5 m`, `e_r < 1 degree`.
pub const STRICT: Thresholds = Thresholds { e_t: 0.5, e_r: 1.0 };
/// Loose success: `Converged`, `e_t < 2 m`, `e_r < 5 degrees`.
pub const LOOSE: Thresholds = Thresholds { e_t: 2.0, e_r: 5.0 };

impl Thresholds {
    /// Whether a result counts as a success: `Converged` and both errors
    /// under the bounds.
    pub fn met(&self, status: MatchStatus, e_t: f64, e_r: f64) -> bool {
        status == MatchStatus::Converged && e_t < self.e_t && e_r < self.e_r
    }
}

/// A start of the paper's grid: `T_init = D * T_gt` with
/// `D = Translation(dx, dy, 0) * Rz(dyaw)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Start {
    /// Shift along the model's x (m).
    pub dx: f64,
    /// Shift along the model's y (m).
    pub dy: f64,
    /// Yaw about the model's z (degrees).
    pub dyaw: f64,
}

impl Start {
    /// `T_init = D * T_gt`.
    pub fn apply(&self, gt: &Isometry3<f64>) -> Isometry3<f64> {
        pose_deg(self.dx, self.dy, 0.0, 0.0, 0.0, self.dyaw) * gt
    }
}

/// Values of one grid axis, `{-max, ..., max}` by `step`, keeping every
/// `stride`-th counting outward from zero.
fn axis(max: i32, step: i32, stride: usize) -> Vec<f64> {
    let n = max / step;
    (-n..=n).filter(|k| (k.unsigned_abs() as usize).is_multiple_of(stride)).map(|k| f64::from(k * step)).collect()
}

/// The paper's grid (1331 starts), thinned by `stride` (at least 1) on each axis.
pub fn grid(stride: usize) -> Vec<Start> {
    let stride = stride.max(1);
    let mut out = Vec::new();
    for dx in axis(10, 2, stride) {
        for dy in axis(10, 2, stride) {
            for dyaw in axis(25, 5, stride) {
                out.push(Start { dx, dy, dyaw });
            }
        }
    }
    out
}

/// The 8 corners and the centre of the paper's grid.
pub fn corners() -> Vec<Start> {
    let mut out = vec![Start { dx: 0.0, dy: 0.0, dyaw: 0.0 }];
    for dx in [-10.0, 10.0] {
        for dy in [-10.0, 10.0] {
            for dyaw in [-25.0, 25.0] {
                out.push(Start { dx, dy, dyaw });
            }
        }
    }
    out
}

/// `n` starts of the full grid chosen by a fixed seed (without repetition).
pub fn sample(n: usize, seed: u64) -> Vec<Start> {
    let mut all = grid(1);
    let mut rng = crate::rng::Rng::new(seed);
    for i in (1..all.len()).rev() {
        all.swap(i, rng.below(i as u64 + 1) as usize);
    }
    all.truncate(n.min(all.len()));
    all
}

/// A prior-free start: robot B's map rebuilt in a frame moved by
/// `D = Translation(ox, oy, 0) * Rz(heading)`, then matched with no prior;
/// the truth becomes `T_A_B * inv(D)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GlobalStart {
    /// Heading of the move (degrees).
    pub heading_deg: f64,
    /// Offset of the move (m).
    pub offset: [f64; 2],
}

impl GlobalStart {
    /// `D`.
    pub fn moved_by(&self) -> Isometry3<f64> {
        pose_deg(self.offset[0], self.offset[1], 0.0, 0.0, 0.0, self.heading_deg)
    }
}

/// 36 headings (every 10 degrees) x 10 seeded offsets up to `radius` m;
/// with `limit`, every n-th of them so that a few still go round.
pub fn global_starts(radius: f64, limit: Option<usize>) -> Vec<GlobalStart> {
    let mut starts = Vec::new();
    let mut rng = crate::rng::Rng::new(0xC05E);
    for h in 0..36 {
        for _ in 0..10 {
            let (r, th) = (radius * rng.unit().sqrt(), rng.range(0.0, std::f64::consts::TAU));
            starts.push(GlobalStart { heading_deg: f64::from(h) * 10.0, offset: [r * th.cos(), r * th.sin()] });
        }
    }
    match limit {
        Some(k) => {
            let step = starts.len().div_ceil(k.max(1));
            starts.into_iter().step_by(step).collect()
        }
        None => starts,
    }
}

/// One start's result for one method.
#[derive(Clone, Debug, Serialize)]
pub struct Outcome {
    /// Method name.
    pub method: String,
    /// The grid start, in grid mode.
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub start: Option<Start>,
    /// The prior-free start, in global mode.
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub global_start: Option<GlobalStart>,
    /// The conventions' status string.
    pub status: &'static str,
    /// Translation error (m).
    pub e_t: f64,
    /// Rotation error (degrees).
    pub e_r: f64,
    /// EM iterations.
    pub iterations: u32,
    /// EM iterations per level, finest first.
    pub iterations_per_level: Vec<u8>,
    /// Time of the match (ms, one thread; prior-free: landmarks of the
    /// scene, correspondences and EM).
    pub time_ms: f64,
    /// Overlap under the result.
    pub overlap: f32,
    /// `T_model_scene`, row by row.
    pub transform: [f64; 16],
    /// Prior-free: the coarse search's best score and its runner-up's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub search: Option<[u32; 2]>,
    /// Agreement of what both maps saw under the answer.
    pub agreement: f32,
    /// Coverage of the scene's standing voxels by the model under the answer.
    pub coverage: f32,
    #[serde(skip)]
    matched: MatchStatus,
}

impl Outcome {
    fn new(method: &str, r: &MatchResult, truth: &Isometry3<f64>, time_ms: f64, levels: usize) -> Self {
        let (e_t, e_r) = errors_of(&r.transform, truth);
        Outcome {
            method: method.to_string(),
            start: None,
            global_start: None,
            status: r.status.as_str(),
            e_t,
            e_r,
            iterations: r.iterations,
            iterations_per_level: r.iterations_per_level[..levels.min(MAX_LEVELS)].to_vec(),
            time_ms,
            overlap: r.overlap,
            transform: row_major(&r.transform.cast::<f64>()),
            search: None,
            agreement: r.agreement,
            coverage: r.coverage,
            matched: r.status,
        }
    }

    /// Whether the outcome meets `t`.
    pub fn meets(&self, t: &Thresholds) -> bool {
        t.met(self.matched, self.e_t, self.e_r)
    }
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let at = match (&self.start, &self.global_start) {
            (Some(s), _) => format!("dx {:>5.1} dy {:>5.1} dyaw {:>5.1}", s.dx, s.dy, s.dyaw),
            (_, Some(g)) => format!("heading {:>5.1} offset {:>6.1},{:>6.1}", g.heading_deg, g.offset[0], g.offset[1]),
            _ => String::new(),
        };
        write!(
            f,
            "  {} {at}: {:<12} e_t {:.3} m, e_r {:.3} deg, {} it, overlap {:.2}, {:.1} ms",
            self.method, self.status, self.e_t, self.e_r, self.iterations, self.overlap, self.time_ms
        )
    }
}

/// What a method achieved over all starts. Field names are the schema's
/// (`schema_version` 2): the same in grid and global mode.
#[derive(Clone, Debug, Serialize)]
pub struct MethodSummary {
    /// Starts evaluated.
    pub starts: usize,
    /// Fraction (0-1) of starts with strict success.
    pub success_strict: f64,
    /// Fraction (0-1) of starts with loose success.
    pub success_loose: f64,
    /// Median translation error (m) over all starts.
    pub et_median_m: Option<f64>,
    /// Mean translation error (m).
    pub et_mean_m: Option<f64>,
    /// 95th percentile of the translation error (m).
    pub et_p95_m: Option<f64>,
    /// Largest translation error (m).
    pub et_max_m: Option<f64>,
    /// Median rotation error (degrees).
    pub er_median_deg: Option<f64>,
    /// Mean rotation error (degrees).
    pub er_mean_deg: Option<f64>,
    /// 95th percentile of the rotation error (degrees).
    pub er_p95_deg: Option<f64>,
    /// Largest rotation error (degrees).
    pub er_max_deg: Option<f64>,
    /// Median time per match (ms, one thread).
    pub time_ms_median: Option<f64>,
    /// Median EM iterations.
    pub iterations_median: Option<f64>,
    /// Median EM iterations per level, finest first.
    pub iterations_per_level_median: Vec<Option<f64>>,
    /// Median agreement of what both maps saw standing (the verdict's
    /// statistic), over all starts.
    pub agreement_median: Option<f64>,
    /// Smallest agreement among the strict successes (the weakest true
    /// answer's margin over the verdict's threshold).
    pub agreement_min_success: Option<f64>,
}

impl MethodSummary {
    /// The summary of one method's outcomes.
    pub fn of(outcomes: &[&Outcome]) -> Self {
        let n = outcomes.len().max(1) as f64;
        let col = |f: &dyn Fn(&Outcome) -> f64| outcomes.iter().map(|o| f(o)).collect::<Vec<f64>>();
        let (et, er) = (Spread::of(&col(&|o| o.e_t)), Spread::of(&col(&|o| o.e_r)));
        let levels = outcomes.iter().map(|o| o.iterations_per_level.len()).max().unwrap_or(0);
        let per_level = (0..levels)
            .map(|l| quantile(&col(&|o| f64::from(o.iterations_per_level.get(l).copied().unwrap_or(0))), 0.5))
            .collect();
        let ok: Vec<f64> = outcomes.iter().filter(|o| o.meets(&STRICT)).map(|o| f64::from(o.agreement)).collect();
        MethodSummary {
            starts: outcomes.len(),
            success_strict: outcomes.iter().filter(|o| o.meets(&STRICT)).count() as f64 / n,
            success_loose: outcomes.iter().filter(|o| o.meets(&LOOSE)).count() as f64 / n,
            et_median_m: et.median,
            et_mean_m: et.mean,
            et_p95_m: et.p95,
            et_max_m: et.max,
            er_median_deg: er.median,
            er_mean_deg: er.mean,
            er_p95_deg: er.p95,
            er_max_deg: er.max,
            time_ms_median: quantile(&col(&|o| o.time_ms), 0.5),
            iterations_median: quantile(&col(&|o| f64::from(o.iterations)), 0.5),
            iterations_per_level_median: per_level,
            agreement_median: quantile(&col(&|o| f64::from(o.agreement)), 0.5),
            agreement_min_success: quantile(&ok, 0.0),
        }
    }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map(|v| format!("{v:.digits$}")).unwrap_or_else(|| "-".into())
}

impl MethodSummary {
    /// The summary in words, as `cosem eval` prints it (`mode` grid or
    /// global, `voxel` the finest level's cell).
    pub fn text(&self, name: &str, mode: &str, voxel: f32) -> String {
        let prefix = if mode == "global" { "prior-free " } else { "" };
        let levels: Vec<String> = self.iterations_per_level_median.iter().map(|v| opt(*v, 1)).collect();
        let mut out = format!(
            "{prefix}{name}: strict {:.1}%, loose {:.1}% of {} starts\n",
            100.0 * self.success_strict,
            100.0 * self.success_loose,
            self.starts
        );
        let (et, er) = (
            [self.et_median_m, self.et_mean_m, self.et_p95_m, self.et_max_m],
            [self.er_median_deg, self.er_mean_deg, self.er_p95_deg, self.er_max_deg],
        );
        for (label, v, unit) in [("e_t", et, "m"), ("e_r", er, "deg")] {
            let [a, b, c, d] = v.map(|x| opt(x, 3));
            out += &format!("  {label}  median {a}  mean {b}  p95 {c}  max {d} {unit}\n");
        }
        out += &format!(
            "  time per match median {} ms (single thread), iterations median {} (per level, {voxel} m first: [{}])\n",
            opt(self.time_ms_median, 1),
            opt(self.iterations_median, 1),
            levels.join(", ")
        );
        out += &format!(
            "  agreement median {} (weakest success {})\n",
            opt(self.agreement_median, 3),
            opt(self.agreement_min_success, 3)
        );
        out
    }
}

/// The two maps an evaluation matched.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct MapsInfo {
    /// Voxels of robot A's map.
    pub a_voxels: usize,
    /// Voxels of robot B's map.
    pub b_voxels: usize,
    /// Overlap of B in A under the truth.
    pub overlap: f32,
}

/// `cosem eval --json`.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    /// [`SCHEMA_VERSION`].
    pub schema_version: u32,
    /// `grid` or `global`.
    pub mode: &'static str,
    /// The maps.
    pub maps: MapsInfo,
    /// Starts per method.
    pub starts: usize,
    /// Voxel size (m).
    pub voxel: f32,
    /// Degrees of freedom matched.
    pub dof: u8,
    /// Preparation time per map (ms).
    pub preparation_ms: f64,
    /// `T_A_B`, row by row.
    pub ground_truth: [f64; 16],
    /// Per method.
    pub methods: BTreeMap<String, MethodSummary>,
    /// Every start of every method.
    pub results: Vec<Outcome>,
}

impl EvalReport {
    /// The report of `results` (summaries per method, in name order).
    pub fn new(
        mode: &'static str,
        maps: MapsInfo,
        voxel: f32,
        dof: u8,
        prep_ms: f64,
        gt: &Isometry3<f64>,
        results: Vec<Outcome>,
    ) -> Self {
        let mut by_method: BTreeMap<String, Vec<&Outcome>> = BTreeMap::new();
        for o in &results {
            by_method.entry(o.method.clone()).or_default().push(o);
        }
        let methods: BTreeMap<String, MethodSummary> =
            by_method.into_iter().map(|(k, v)| (k, MethodSummary::of(&v))).collect();
        let starts = methods.values().map(|m| m.starts).max().unwrap_or(0);
        EvalReport {
            schema_version: SCHEMA_VERSION,
            mode,
            maps,
            starts,
            voxel,
            dof,
            preparation_ms: prep_ms,
            ground_truth: row_major(gt),
            methods,
            results,
        }
    }
}

impl EvalReport {
    /// Box plots of e_t and e_r per method (SVG, like the paper's Fig. 5).
    pub fn plot(&self, caption: &str) -> String {
        use crate::evaluation::boxplot::{render, Panel};
        let series = |f: fn(&Outcome) -> f64| -> Vec<(&str, Vec<f64>)> {
            let names = self.methods.keys().map(String::as_str);
            names.map(|n| (n, self.results.iter().filter(|o| o.method == n).map(f).collect())).collect()
        };
        render(
            &[
                Panel { title: "translation error e_t", unit: "m", series: series(|o| o.e_t) },
                Panel { title: "rotation error e_r", unit: "deg", series: series(|o| o.e_r) },
            ],
            caption,
        )
    }
}

/// Runs `f` over `items`, on the current rayon pool with the `parallel`
/// feature, else in order; results keep the items' order.
pub fn for_each_start<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync + Send) -> Vec<R> {
    #[cfg(feature = "parallel")]
    {
        use rayon::prelude::*;
        items.par_iter().map(f).collect()
    }
    #[cfg(not(feature = "parallel"))]
    {
        items.iter().map(f).collect()
    }
}

/// What `cosem eval` runs on a pair.
pub enum Protocol {
    /// The paper's: each method (its settings) from each start of a grid.
    Grid {
        /// The starts.
        starts: Vec<Start>,
        /// The methods' settings.
        methods: Vec<Alignment>,
    },
    /// Prior-free: the scene's map moved by each start (rebuilt from its
    /// moved frames) and matched with no prior.
    Global {
        /// The starts.
        starts: Vec<GlobalStart>,
        /// The method's settings.
        settings: Alignment,
    },
}

impl Protocol {
    /// The matches it runs.
    pub fn matches(&self) -> usize {
        match self {
            Protocol::Grid { starts, methods } => starts.len() * methods.len(),
            Protocol::Global { starts, .. } => starts.len(),
        }
    }
}

/// Runs `protocol` on `pair` (loaded from `spec`): both maps prepared
/// (`on_prepared` is told the maps and the milliseconds per map), then
/// every match (`progress` after each); the report of it all.
pub fn evaluate(
    pair: &crate::evaluation::pair::Pair,
    spec: &crate::evaluation::pair::PairSpec,
    protocol: &Protocol,
    on_prepared: impl FnOnce(&MapsInfo, f64),
    progress: &(dyn Fn() + Sync),
) -> Result<EvalReport, Error> {
    let maps = MapsInfo { a_voxels: pair.map_a.len(), b_voxels: pair.map_b.len(), overlap: pair.overlap() };
    let t0 = Instant::now();
    let (pa, pb) = (prepare(&pair.map_a, DEFAULT_LEVELS)?, prepare(&pair.map_b, DEFAULT_LEVELS)?);
    let prep_ms = t0.elapsed().as_secs_f64() * 1e3 / 2.0;
    on_prepared(&maps, prep_ms);
    let (mode, dof, results) = match protocol {
        Protocol::Grid { starts, methods } => {
            let mut results = Vec::new();
            for s in methods {
                results.extend(run_grid(s.settings.method.name(), *s, (&pa, &pb), &pair.gt, starts, progress)?);
            }
            ("grid", methods.first().map_or(6, |s| s.settings.dof.count()), results)
        }
        Protocol::Global { starts, settings: s } => {
            let config = (spec.config, &spec.filter);
            let results = run_global(
                s.settings.method.name(),
                *s,
                &pair.map_a,
                &pair.frames_b,
                config,
                &pair.gt,
                starts,
                progress,
            )?;
            ("global", s.settings.dof.count(), results)
        }
    };
    Ok(EvalReport::new(mode, maps, spec.config.resolution, dof, prep_ms, &pair.gt, results))
}

/// Matches the prepared maps from every grid start with `settings` (one
/// untimed warm-up match first, so short runs time the steady state);
/// `progress` is called after each match.
pub fn run_grid(
    method: &str,
    settings: Alignment,
    pyramids: (&HostPyramid<'_>, &HostPyramid<'_>),
    gt: &Isometry3<f64>,
    starts: &[Start],
    progress: &(dyn Fn() + Sync),
) -> Result<Vec<Outcome>, Error> {
    let one = |s: &Start| align(settings, Some(&s.apply(gt).cast::<f32>()), pyramids).map(|(r, _)| r);
    if let Some(first) = starts.first() {
        one(first)?;
    }
    let levels = pyramids.0.levels();
    let outcomes = for_each_start(starts, |s| {
        let t = Instant::now();
        let r = one(s)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        progress();
        Ok(Outcome { start: Some(*s), ..Outcome::new(method, &r, gt, ms, levels) })
    });
    outcomes.into_iter().collect()
}

/// The prior-free protocol: for each start, robot B's frames are moved by
/// `D`, its map rebuilt and prepared, and matched against robot A's with no
/// prior (landmarks, then EM); timed from the scene's landmarks on.
#[allow(clippy::too_many_arguments)]
pub fn run_global(
    method: &str,
    settings: Alignment,
    map_a: &HostMap,
    frames_b: &[crate::sources::kitti::Frame],
    map_config: (MapConfig, &PointFilter),
    gt: &Isometry3<f64>,
    starts: &[GlobalStart],
    progress: &(dyn Fn() + Sync),
) -> Result<Vec<Outcome>, Error> {
    let pa = prepare(map_a, DEFAULT_LEVELS)?;
    let outcomes = for_each_start(starts, |s| -> Result<Outcome, Error> {
        let d = s.moved_by();
        let (map_b, _) = build_map(&moved_frames(frames_b, &d), map_config.0, map_config.1)?;
        let pb = prepare(&map_b, DEFAULT_LEVELS)?;
        let t = Instant::now();
        let (r, found) = align(settings, None, (&pa, &pb))?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        progress();
        let truth = gt * d.inverse();
        let search = found.map(|f| f.search.scores().into());
        Ok(Outcome { global_start: Some(*s), search, ..Outcome::new(method, &r, &truth, ms, pa.levels()) })
    });
    outcomes.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_sizes() {
        assert_eq!(grid(1).len(), 1331);
        // Stride 5: {-10, 0, 10} x {-10, 0, 10} x {-25, 0, 25}.
        assert_eq!(grid(5).len(), 27);
        assert!(grid(5).contains(&Start { dx: 0.0, dy: 0.0, dyaw: 0.0 }));
        assert_eq!(grid(2).len(), 5 * 5 * 5);
        assert_eq!(global_starts(50.0, None).len(), 360);
        assert_eq!(global_starts(50.0, Some(36)).len(), 36);
    }

    #[test]
    fn thresholds_need_convergence() {
        assert!(STRICT.met(MatchStatus::Converged, 0.49, 0.99));
        assert!(!STRICT.met(MatchStatus::NotConverged, 0.0, 0.0));
        assert!(!STRICT.met(MatchStatus::Converged, 0.5, 0.0));
        assert!(LOOSE.met(MatchStatus::Converged, 1.9, 4.9));
    }

    #[test]
    fn start_applies_on_the_left() {
        let gt = pose_deg(1.0, 2.0, 0.5, 1.0, 2.0, 30.0);
        let est = Start { dx: 3.0, dy: 4.0, dyaw: 10.0 }.apply(&gt);
        let (et, er) = cosem_core::geometry::pose_errors(&est, &gt);
        assert!((et - 5.0).abs() < 1e-9 && (er - 10.0).abs() < 1e-9, "{et} {er}");
    }
}

/// A map of one place for `cosem eval --negatives`: `DIR[:START:END[:STRIDE]]`
/// (default: the folder's first scan).
#[derive(Clone, Debug, PartialEq)]
pub struct Place {
    /// SemanticKITTI-layout folder.
    pub data: std::path::PathBuf,
    /// Its frames (`None`: the first scan in velodyne/).
    pub frames: Option<crate::sources::kitti::FrameRange>,
}

impl std::str::FromStr for Place {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        // The frames follow the first ':' after the last '/'.
        let name_start = s.rfind('/').map_or(0, |i| i + 1);
        match s[name_start..].find(':').map(|i| i + name_start) {
            Some(at) => {
                let frames =
                    s[at + 1..].parse().map_err(|e: crate::sources::kitti::KittiError| format!("`{s}`: {e}"))?;
                Ok(Place { data: s[..at].into(), frames: Some(frames) })
            }
            None => Ok(Place { data: s.into(), frames: None }),
        }
    }
}

impl std::fmt::Display for Place {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let name = self.data.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        match &self.frames {
            Some(r) => write!(f, "{name}:{r}"),
            None => write!(f, "{name}"),
        }
    }
}

/// One negative case: two maps of different places matched.
#[derive(Clone, Debug, Serialize)]
pub struct NegativeCase {
    /// The model's place.
    pub model: String,
    /// The scene's place.
    pub scene: String,
    /// `none`, `identity` or `random`.
    pub prior: &'static str,
    /// The status reported.
    pub status: &'static str,
    /// Overlap under the answer.
    pub overlap: f32,
    /// Agreement of what both saw under the answer.
    pub agreement: f32,
    /// Coverage of the scene by the model under the answer.
    pub coverage: f32,
    /// Prior-free: the coarse search's best score and its runner-up's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub search: Option<[u32; 2]>,
    #[serde(skip)]
    accepted: bool,
}

/// Counts of one kind of prior.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct NegativeCount {
    /// Cases.
    pub cases: usize,
    /// Reported `Converged` (all wrong: the places differ).
    pub false_accepts: usize,
}

/// `cosem eval --negatives --json`.
#[derive(Clone, Debug, Serialize)]
pub struct NegativeReport {
    /// [`SCHEMA_VERSION`].
    pub schema_version: u32,
    /// `negatives`.
    pub mode: &'static str,
    /// Places, in order.
    pub places: Vec<String>,
    /// Ordered pairs matched (model, scene).
    pub pairs: usize,
    /// Pairs of one folder left out because their maps overlap (>= 1% under the truth).
    pub overlapping_pairs: usize,
    /// All cases.
    pub cases: usize,
    /// Cases reported `Converged`.
    pub false_accepts: usize,
    /// The largest agreement of any case: the worst negative's value of the
    /// verdict's statistic (to set against the weakest true pair's).
    pub agreement_max: f32,
    /// By kind of prior: `none`, `identity`, `random`.
    pub by_prior: BTreeMap<&'static str, NegativeCount>,
    /// Every case.
    pub results: Vec<NegativeCase>,
}

impl std::fmt::Display for NegativeReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (n, pairs, left) = (self.places.len(), self.pairs, self.overlapping_pairs);
        writeln!(
            f,
            "negatives: {n} places, {pairs} ordered pairs ({left} overlapping left out), {} cases",
            self.cases
        )?;
        for (kind, c) in &self.by_prior {
            writeln!(f, "  prior {kind:<9} {:>4} cases, {:>3} false accepts", c.cases, c.false_accepts)?;
        }
        writeln!(f, "  in all           {:>4} cases, {:>3} false accepts", self.cases, self.false_accepts)?;
        writeln!(f, "  largest agreement of a negative: {:.3}", self.agreement_max)
    }
}

/// A place's map (default: its first scan), its source and anchor pose.
fn place_map(
    p: &Place,
    spec: &crate::evaluation::pair::PairSpec,
) -> Result<(crate::sources::source::Source, nalgebra::Matrix4<f64>, HostMap), Error> {
    let seq = crate::sources::source::Source::open(&p.data, &spec.source)?;
    let range = match (p.frames, seq.folder()) {
        (Some(r), _) => r,
        (None, Some(folder)) => {
            let first = folder
                .scan_frames()?
                .first()
                .copied()
                .ok_or_else(|| Error::Invalid(format!("{}: no scans", p.data.display())))?;
            crate::sources::kitti::FrameRange { start: first, end: first + 1, stride: 1 }
        }
        (None, None) => crate::sources::kitti::FrameRange { start: 0, end: 1, stride: 1 },
    };
    let (frames, anchor, _) = spec.frames(&seq, range)?;
    let (map, _) = build_map(&frames, spec.config, &spec.filter)?;
    Ok((seq, anchor, map))
}

/// The ordered pairs of different places, and how many pairs were left
/// out for overlapping (folders of one sequence may hold one place).
fn negative_pairs(
    maps: &[(crate::sources::source::Source, nalgebra::Matrix4<f64>, HostMap)],
) -> (Vec<(usize, usize)>, usize) {
    let mut pairs = Vec::new();
    let mut overlapping = 0;
    for (i, a) in maps.iter().enumerate() {
        for (j, b) in maps.iter().enumerate() {
            if i == j {
                continue;
            }
            if a.0.same_trajectory(&b.0) {
                let t = crate::sources::source::relative(&a.1, &b.1);
                if cosem_core::map::overlap(&a.2, &b.2, &t.cast::<f32>()) >= 0.01 {
                    overlapping += 1;
                    continue;
                }
            }
            pairs.push((i, j));
        }
    }
    (pairs, overlapping)
}

/// Matches every ordered pair of maps of different places (of one sequence:
/// only when they overlap by under 1% under the truth) with no prior, the
/// identity prior and `random_priors` seeded random priors (+-20 m, any
/// heading). Every `Converged` is a false accept.
pub fn run_negatives(
    places: &[Place],
    spec: &crate::evaluation::pair::PairSpec,
    settings: Alignment,
    random_priors: usize,
    progress: &(dyn Fn() + Sync),
) -> Result<NegativeReport, Error> {
    let maps = places.iter().map(|p| place_map(p, spec)).collect::<Result<Vec<_>, _>>()?;
    let pyramids: Vec<_> = maps.iter().map(|m| prepare(&m.2, DEFAULT_LEVELS)).collect::<Result<_, _>>()?;
    let (pairs, overlapping) = negative_pairs(&maps);
    let mut rng = crate::rng::Rng::new(0x0E6A_7105);
    let mut jobs = Vec::new();
    for &(i, j) in &pairs {
        jobs.push((i, j, "none", None));
        jobs.push((i, j, "identity", Some(Isometry3::<f64>::identity())));
        for _ in 0..random_priors {
            let (x, y, yaw) = (rng.range(-20.0, 20.0), rng.range(-20.0, 20.0), rng.range(-180.0, 180.0));
            jobs.push((i, j, "random", Some(pose_deg(x, y, 0.0, 0.0, 0.0, yaw))));
        }
    }
    let cases = for_each_start(&jobs, |&(i, j, kind, prior)| -> Result<NegativeCase, Error> {
        let (pm, ps) = (&pyramids[i], &pyramids[j]);
        let (r, found) = align(settings, prior.map(|p| p.cast::<f32>()).as_ref(), (pm, ps))?;
        let search = found.map(|f| f.search.scores().into());
        progress();
        Ok(NegativeCase {
            model: places[i].to_string(),
            scene: places[j].to_string(),
            prior: kind,
            status: r.status.as_str(),
            overlap: r.overlap,
            agreement: r.agreement,
            coverage: r.coverage,
            search,
            accepted: r.status == MatchStatus::Converged,
        })
    });
    let results: Vec<NegativeCase> = cases.into_iter().collect::<Result<_, _>>()?;
    let mut by_prior: BTreeMap<&'static str, NegativeCount> = BTreeMap::new();
    for c in &results {
        let e = by_prior.entry(c.prior).or_default();
        e.cases += 1;
        e.false_accepts += usize::from(c.accepted);
    }
    Ok(NegativeReport {
        schema_version: SCHEMA_VERSION,
        mode: "negatives",
        places: places.iter().map(ToString::to_string).collect(),
        pairs: pairs.len(),
        overlapping_pairs: overlapping,
        cases: results.len(),
        false_accepts: results.iter().filter(|c| c.accepted).count(),
        agreement_max: results.iter().map(|c| c.agreement).fold(0.0, f32::max),
        by_prior,
        results,
    })
}
