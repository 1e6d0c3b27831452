//! `cosem eval`: the paper's robustness protocol over a grid of starts.

use super::Error;
use cosem_core::map::MapConfig;
use cosem_core::matching::{MatchStatus, Matcher};
use cosem_host::align::{corners, errors, grid, prepare, sample, to_matrix, Start, DEFAULT_LEVELS};
use cosem_host::boxplot::{self, Panel};
use cosem_host::kitti::{FrameRange, Sequence};
use cosem_host::mapping::{build_map, PointFilter};
use cosem_host::pose;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// SemanticKITTI-layout folder.
    #[arg(long)]
    data: PathBuf,
    /// Robot A's frames (the model).
    #[arg(long)]
    a: FrameRange,
    /// Robot B's frames (the scene).
    #[arg(long)]
    b: FrameRange,
    /// Voxel size (m).
    #[arg(long, default_value_t = 0.2)]
    voxel: f32,
    /// `paper` (1331 starts) or `corners` (its 8 corners and centre).
    #[arg(long, default_value = "paper")]
    grid: String,
    /// Keep every K-th grid value on each axis, counting outward from zero.
    #[arg(long, conflicts_with = "limit")]
    grid_stride: Option<usize>,
    /// Keep N starts of the full grid, chosen by a fixed seed.
    #[arg(long)]
    limit: Option<usize>,
    /// Methods, comma-separated: cosem, cosem-hard, geometric.
    #[arg(long, default_value = "cosem")]
    method: String,
    /// Degrees of freedom: 6 or 4.
    #[arg(long, default_value_t = 6)]
    dof: u8,
    /// Worker threads (each match itself runs on one); default: all cores.
    #[arg(long)]
    threads: Option<usize>,
    /// Write the summary and every start's result as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write box plots of e_t and e_r per method to this SVG file.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Pass both maps through the compact wire encoding (as if received
    /// over the link) before matching: shows what quantisation costs.
    #[arg(long)]
    through_encoding: bool,
    /// Print every start.
    #[arg(long)]
    verbose: bool,
    /// Prior-free protocol instead of the grid: the scene map is moved by a
    /// known heading (36 around the circle) and offset (10 seeded, up to
    /// 50 m) and matched with no prior.
    #[arg(long)]
    global: bool,
}

/// One start's outcome.
struct Outcome {
    start: Start,
    status: MatchStatus,
    et: f64,
    er: f64,
    iterations: u32,
    per_level: [u8; cosem_core::matching::MAX_LEVELS],
    time_ms: f64,
    overlap: f32,
    transform: Vec<f64>,
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn sorted(v: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut v: Vec<f64> = v.collect();
    v.sort_by(|a, b| a.total_cmp(b));
    v
}

pub fn run(a: Args) -> Result<(), Error> {
    if a.global {
        return run_global(&a);
    }
    let methods: Vec<(String, cosem_core::matching::MatchSettings)> = a
        .method
        .split(',')
        .map(|m| super::matching::settings(m.trim(), a.dof).map(|s| (m.trim().to_string(), s)))
        .collect::<Result<_, _>>()?;
    let starts: Vec<Start> = match (a.limit, a.grid_stride, a.grid.as_str()) {
        (Some(n), _, _) => sample(n, 0xC05E),
        (None, Some(k), _) => grid(k),
        (None, None, "paper") => grid(1),
        (None, None, "corners") => corners(),
        (None, None, g) => return Err(format!("--grid {g}: expected paper or corners").into()),
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.threads.unwrap_or(0)).build()?;
    let seq = Sequence::open(&a.data)?;
    let config = MapConfig::with_resolution(a.voxel);
    let filter = PointFilter::default();
    let (mut map_a, _) = build_map(&seq.load_range(a.a)?, config, &filter)?;
    let (mut map_b, _) = build_map(&seq.load_range(a.b)?, config, &filter)?;
    if a.through_encoding {
        let name = std::path::Path::new("(encoded map)");
        map_a = cosem_host::cmap::decode(&cosem_host::cmap::encode(&map_a, None, None), name)?.1;
        map_b = cosem_host::cmap::decode(&cosem_host::cmap::encode(&map_b, None, None), name)?.1;
        println!("maps passed through the wire encoding");
    }
    let gt = seq.relative_pose(a.a.start, a.b.start)?;
    let t0 = Instant::now();
    let pa = prepare(&map_a, DEFAULT_LEVELS)?;
    let pb = prepare(&map_b, DEFAULT_LEVELS)?;
    let prep_ms = t0.elapsed().as_secs_f64() * 1e3 / 2.0;
    let overlap = cosem_core::map::overlap(&map_a, &map_b, &pose::to_isometry(&gt));
    println!(
        "maps: A {} voxels, B {} voxels at {} m, overlap {:.1}% under the ground truth; preparation {:.1} ms per map",
        map_a.len(),
        map_b.len(),
        a.voxel,
        100.0 * overlap,
        prep_ms
    );
    println!("{} starts x {} method(s) on {} thread(s)", starts.len(), methods.len(), pool.current_num_threads());
    let bar = ProgressBar::new((starts.len() * methods.len()) as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} matches, {elapsed} elapsed, eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut methods_json = serde_json::Map::new();
    let mut results_json = Vec::new();
    let mut panels_t: Vec<(&str, Vec<f64>)> = Vec::new();
    let mut panels_r: Vec<(&str, Vec<f64>)> = Vec::new();
    for (name, settings) in &methods {
        let matcher = Matcher::new(*settings);
        // One untimed warm-up match per worker (caches, page faults), so
        // that short runs time the steady state.
        if let Some(first) = starts.first() {
            let init = pose::to_isometry(&first.apply(&gt));
            pool.broadcast(|_| matcher.align(&pa, &pb, &init).map(|_| ()))
                .into_iter()
                .collect::<Result<Vec<()>, _>>()?;
        }
        let outcomes: Vec<Result<Outcome, cosem_core::matching::MatchError>> = pool.install(|| {
            starts
                .par_iter()
                .map(|s| {
                    let init = pose::to_isometry(&s.apply(&gt));
                    let t = Instant::now();
                    let r = matcher.align(&pa, &pb, &init)?;
                    let time_ms = t.elapsed().as_secs_f64() * 1e3;
                    let m = to_matrix(&r.transform);
                    let (et, er) = errors(&m, &gt);
                    bar.inc(1);
                    Ok(Outcome {
                        start: *s,
                        status: r.status,
                        et,
                        er,
                        iterations: r.iterations,
                        per_level: r.iterations_per_level,
                        time_ms,
                        overlap: r.overlap,
                        transform: pose::to_row_major(&m),
                    })
                })
                .collect()
        });
        let outcomes: Vec<Outcome> = outcomes.into_iter().collect::<Result<_, _>>()?;
        let conv = |o: &Outcome| o.status == MatchStatus::Converged;
        let strict = outcomes.iter().filter(|o| conv(o) && o.et < 0.5 && o.er < 1.0).count();
        let loose = outcomes.iter().filter(|o| conv(o) && o.et < 2.0 && o.er < 5.0).count();
        let et = sorted(outcomes.iter().map(|o| o.et));
        let er = sorted(outcomes.iter().map(|o| o.er));
        let times = sorted(outcomes.iter().map(|o| o.time_ms));
        let iters = sorted(outcomes.iter().map(|o| f64::from(o.iterations)));
        // Median iterations at each level, finest first.
        let per_level: Vec<f64> = (0..DEFAULT_LEVELS)
            .map(|l| percentile(&sorted(outcomes.iter().map(|o| f64::from(o.per_level[l]))), 0.5))
            .collect();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let n = outcomes.len().max(1) as f64;
        let (s_strict, s_loose) = (strict as f64 / n, loose as f64 / n);
        if a.verbose {
            for o in &outcomes {
                println!(
                    "  {name} start dx {:>5.1} dy {:>5.1} dyaw {:>5.1}: {:<12} e_t {:.3} m, e_r {:.3} deg, {} it, overlap {:.2}, {:.1} ms",
                    o.start.dx, o.start.dy, o.start.dyaw, o.status.as_str(), o.et, o.er, o.iterations, o.overlap, o.time_ms
                );
            }
        }
        bar.suspend(|| {
            println!(
                "{name}: strict {:.1}%, loose {:.1}% of {} starts",
                100.0 * s_strict,
                100.0 * s_loose,
                outcomes.len()
            );
            println!(
                "  e_t  median {:.3}  mean {:.3}  p95 {:.3}  max {:.3} m",
                percentile(&et, 0.5),
                mean(&et),
                percentile(&et, 0.95),
                et.last().copied().unwrap_or(f64::NAN)
            );
            println!(
                "  e_r  median {:.3}  mean {:.3}  p95 {:.3}  max {:.3} deg",
                percentile(&er, 0.5),
                mean(&er),
                percentile(&er, 0.95),
                er.last().copied().unwrap_or(f64::NAN)
            );
            println!(
                "  time per match median {:.1} ms (single thread), iterations median {} (per level, {} m first: {:?})",
                percentile(&times, 0.5),
                percentile(&iters, 0.5),
                a.voxel,
                per_level
            );
        });
        methods_json.insert(
            name.clone(),
            json!({
                "success_strict": s_strict,
                "success_loose": s_loose,
                "et_median_m": percentile(&et, 0.5),
                "et_mean_m": mean(&et),
                "et_p95_m": percentile(&et, 0.95),
                "et_max_m": et.last().copied().unwrap_or(f64::NAN),
                "er_median_deg": percentile(&er, 0.5),
                "er_mean_deg": mean(&er),
                "er_p95_deg": percentile(&er, 0.95),
                "er_max_deg": er.last().copied().unwrap_or(f64::NAN),
                "time_ms_median": percentile(&times, 0.5),
                "iterations_median": percentile(&iters, 0.5),
                "iterations_per_level_median": per_level,
            }),
        );
        for o in &outcomes {
            results_json.push(json!({
                "method": name, "dx": o.start.dx, "dy": o.start.dy, "dyaw": o.start.dyaw,
                "status": o.status.as_str(), "e_t": o.et, "e_r": o.er, "iterations": o.iterations,
                "iterations_per_level": &o.per_level[..DEFAULT_LEVELS],
                "time_ms": o.time_ms, "overlap": o.overlap, "transform": o.transform,
            }));
        }
        panels_t.push((name.as_str(), outcomes.iter().map(|o| o.et).collect()));
        panels_r.push((name.as_str(), outcomes.iter().map(|o| o.er).collect()));
    }
    bar.finish_and_clear();
    if let Some(path) = &a.json {
        let out = json!({
            "maps": {"a_voxels": map_a.len(), "b_voxels": map_b.len(), "overlap": overlap},
            "starts": starts.len(),
            "voxel": a.voxel,
            "dof": a.dof,
            "preparation_ms": prep_ms,
            "ground_truth": pose::to_row_major(&gt),
            "methods": methods_json,
            "results": results_json,
        });
        std::fs::write(path, serde_json::to_string_pretty(&out)?).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    if let Some(path) = &a.plot {
        let caption = format!(
            "{} A={} B={}, {} starts, {} m voxels",
            a.data.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
            a.a,
            a.b,
            starts.len(),
            a.voxel
        );
        let svg = boxplot::render(
            &[
                Panel { title: "translation error e_t", unit: "m", series: panels_t },
                Panel { title: "rotation error e_r", unit: "deg", series: panels_r },
            ],
            &caption,
        );
        std::fs::write(path, svg).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

/// One prior-free start: the scene map moved by `D` (a heading and an
/// offset), then matched with no prior.
struct GlobalStart {
    heading_deg: f64,
    offset: [f64; 2],
}

/// `--global`: 36 headings x 10 seeded offsets up to 50 m; each start
/// rebuilds robot B's map in a frame moved by `D = Translation(ox, oy, 0) *
/// Rz(heading)`, so the ground truth becomes `T_A_B * inv(D)`, and matches it
/// with no prior (landmarks, then EM).
fn run_global(a: &Args) -> Result<(), Error> {
    let settings = super::matching::settings(a.method.split(',').next().unwrap_or("cosem").trim(), a.dof)?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.threads.unwrap_or(0)).build()?;
    let seq = Sequence::open(&a.data)?;
    let config = MapConfig::with_resolution(a.voxel);
    let filter = PointFilter::default();
    let (map_a, _) = build_map(&seq.load_range(a.a)?, config, &filter)?;
    let frames_b = seq.load_range(a.b)?;
    let gt = seq.relative_pose(a.a.start, a.b.start)?;
    let pa = prepare(&map_a, DEFAULT_LEVELS)?;
    let la = super::matching::landmarks(&map_a)?;
    let mut starts = Vec::new();
    let mut rng = cosem_host::rng::Rng::new(0xC05E);
    for h in 0..36 {
        for _ in 0..10 {
            let (r, th) = (50.0 * rng.unit().sqrt(), rng.range(0.0, std::f64::consts::TAU));
            starts.push(GlobalStart { heading_deg: f64::from(h) * 10.0, offset: [r * th.cos(), r * th.sin()] });
        }
    }
    if let Some(k) = a.limit {
        // Every n-th start, so a few still go round the circle.
        let step = starts.len().div_ceil(k.max(1));
        starts = starts.into_iter().step_by(step).collect();
    }
    println!(
        "prior-free: {} starts (of 36 headings x 10 offsets up to 50 m), map A {} voxels, {} landmarks, on {} thread(s)",
        starts.len(),
        map_a.len(),
        la.len(),
        pool.current_num_threads()
    );
    let bar = ProgressBar::new(starts.len() as u64);
    let matcher = Matcher::new(settings);
    // (status, e_t, e_r, ms, agreeing landmarks) per start.
    type Row = (MatchStatus, f64, f64, f64, u32);
    let outcomes: Vec<Result<Row, Error>> = pool.install(|| {
        starts
            .par_iter()
            .map(|s| {
                let d = pose::from_xyz_rpy_deg(s.offset[0], s.offset[1], 0.0, 0.0, 0.0, s.heading_deg);
                let moved: Vec<_> = frames_b
                    .iter()
                    .map(|f| {
                        let mut f = f.clone();
                        for p in &mut f.points {
                            let q = d * nalgebra::Vector4::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]), 1.0);
                            *p = [q.x as f32, q.y as f32, q.z as f32];
                        }
                        f
                    })
                    .collect();
                let (map_b, _) = build_map(&moved, config, &filter)?;
                let pb = prepare(&map_b, DEFAULT_LEVELS)?;
                let t = Instant::now();
                let lb = super::matching::landmarks(&map_b)?;
                let (r, outcome) = cosem_core::matching::global::align_without_prior(
                    &matcher,
                    &pa,
                    &pb,
                    (&la, &lb),
                    &cosem_core::matching::global::GlobalSettings::default(),
                )?;
                let ms = t.elapsed().as_secs_f64() * 1e3;
                let truth = gt * cosem_host::kitti::rigid_inverse(&d);
                let (et, er) = errors(&to_matrix(&r.transform), &truth);
                bar.inc(1);
                Ok((r.status, et, er, ms, outcome.map(|o| o.agreeing).unwrap_or(0)))
            })
            .collect()
    });
    bar.finish_and_clear();
    let outcomes: Vec<_> = outcomes.into_iter().collect::<Result<_, _>>()?;
    let n = outcomes.len().max(1) as f64;
    let conv = |s: &MatchStatus| *s == MatchStatus::Converged;
    let strict = outcomes.iter().filter(|o| conv(&o.0) && o.1 < 0.5 && o.2 < 1.0).count() as f64 / n;
    let loose = outcomes.iter().filter(|o| conv(&o.0) && o.1 < 2.0 && o.2 < 5.0).count() as f64 / n;
    let (et, er) = (sorted(outcomes.iter().map(|o| o.1)), sorted(outcomes.iter().map(|o| o.2)));
    let times = sorted(outcomes.iter().map(|o| o.3));
    let agreeing = sorted(outcomes.iter().map(|o| f64::from(o.4)));
    println!(
        "prior-free {}: strict {:.1}%, loose {:.1}% of {} starts",
        settings.method.name(),
        100.0 * strict,
        100.0 * loose,
        outcomes.len()
    );
    println!(
        "  e_t median {:.3} p95 {:.3} m; e_r median {:.3} p95 {:.3} deg",
        percentile(&et, 0.5),
        percentile(&et, 0.95),
        percentile(&er, 0.5),
        percentile(&er, 0.95)
    );
    println!(
        "  time per alignment (scene landmarks, correspondences, EM) median {:.1} ms; agreeing landmarks median {}",
        percentile(&times, 0.5),
        percentile(&agreeing, 0.5)
    );
    if let Some(path) = &a.json {
        let results: Vec<_> = starts
            .iter()
            .zip(&outcomes)
            .map(|(s, o)| json!({"heading_deg": s.heading_deg, "offset": s.offset, "status": o.0.as_str(), "e_t": o.1, "e_r": o.2, "time_ms": o.3, "agreeing": o.4}))
            .collect();
        let out = json!({"mode": "global", "starts": outcomes.len(), "success_strict": strict, "success_loose": loose,
            "e_t_median": percentile(&et, 0.5), "e_r_median": percentile(&er, 0.5), "time_ms_median": percentile(&times, 0.5), "results": results});
        std::fs::write(path, serde_json::to_string_pretty(&out)?).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}
