//! `cosem eval`: the paper's robustness protocol over a grid of starts.

use super::Error;
use cosem_core::map::MapConfig;
use cosem_core::matching::{MatchStatus, Matcher};
use cosem_host::align::{corners, errors, grid, prepare, sample, to_matrix, Start, DEFAULT_LEVELS};
use cosem_host::kitti::{FrameRange, Sequence};
use cosem_host::mapping::{build_map, PointFilter};
use cosem_host::pose;
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
    #[arg(long)]
    grid_stride: Option<usize>,
    /// Keep N starts of the full grid, chosen by a fixed seed.
    #[arg(long)]
    limit: Option<usize>,
    /// Methods, comma-separated.
    #[arg(long, default_value = "cosem")]
    method: String,
    /// Degrees of freedom: 6 or 4.
    #[arg(long, default_value_t = 6)]
    dof: u8,
    /// Print every start.
    #[arg(long)]
    verbose: bool,
    /// Write the summary and every start's result as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i]
}

pub fn run(a: Args) -> Result<(), Error> {
    let seq = Sequence::open(&a.data)?;
    let config = MapConfig::with_resolution(a.voxel);
    let filter = PointFilter::default();
    let (map_a, _) = build_map(&seq.load_range(a.a)?, config, &filter)?;
    let (map_b, _) = build_map(&seq.load_range(a.b)?, config, &filter)?;
    let gt = seq.relative_pose(a.a.start, a.b.start)?;
    let t0 = Instant::now();
    let pa = prepare(&map_a, DEFAULT_LEVELS)?;
    let pb = prepare(&map_b, DEFAULT_LEVELS)?;
    let prep_ms = t0.elapsed().as_secs_f64() * 1e3 / 2.0;
    let overlap = cosem_core::map::overlap(&map_a, &map_b, &pose::to_isometry(&gt));
    println!(
        "maps: A {} voxels, B {} voxels, overlap {:.1}% under the ground truth; preparation {:.1} ms per map",
        map_a.len(),
        map_b.len(),
        100.0 * overlap,
        prep_ms
    );
    let starts: Vec<Start> = match (a.limit, a.grid_stride, a.grid.as_str()) {
        (Some(n), _, _) => sample(n, 0xC05E),
        (None, Some(k), _) => grid(k),
        (None, None, "paper") => grid(1),
        (None, None, "corners") => corners(),
        (None, None, g) => return Err(format!("--grid {g}: expected paper or corners").into()),
    };
    let mut methods_json = serde_json::Map::new();
    let mut results_json = Vec::new();
    for name in a.method.split(',') {
        let settings = super::matching::settings(name.trim(), a.dof)?;
        let matcher = Matcher::new(settings);
        let mut et = Vec::new();
        let mut er = Vec::new();
        let mut times = Vec::new();
        let mut iters = Vec::new();
        let (mut strict, mut loose) = (0usize, 0usize);
        for s in &starts {
            let init = pose::to_isometry(&s.apply(&gt));
            let t = Instant::now();
            let r = matcher.align(&pa, &pb, &init)?;
            times.push(t.elapsed().as_secs_f64() * 1e3);
            let (e_t, e_r) = errors(&to_matrix(&r.transform), &gt);
            let conv = r.status == MatchStatus::Converged;
            strict += usize::from(conv && e_t < 0.5 && e_r < 1.0);
            loose += usize::from(conv && e_t < 2.0 && e_r < 5.0);
            if a.verbose {
                if let (Some(window), Some(fm), Some(fs)) = (settings.search, pa.footprint(), pb.footprint()) {
                    let ts = Instant::now();
                    if let Some(o) = cosem_core::matching::search::search(
                        fm,
                        fs,
                        &init,
                        &window,
                        settings.method != cosem_core::matching::Method::Geometric,
                    ) {
                        let (st, sr) = errors(&to_matrix(&o.transform), &gt);
                        println!(
                            "  search: e_t {st:.2} m e_r {sr:.2} deg, score {} (prior {}), {} nodes, {:.1} ms",
                            o.score,
                            o.prior_score,
                            o.evaluations,
                            ts.elapsed().as_secs_f64() * 1e3
                        );
                    }
                }
                println!(
                    "  start dx {:>5.1} dy {:>5.1} dyaw {:>5.1}: {:<12} e_t {:.3} m e_r {:.3} deg, {} it {:?}, ovl {:.2}, deg {:.4}, {:.1} ms",
                    s.dx, s.dy, s.dyaw, r.status.as_str(), e_t, e_r, r.iterations, &r.iterations_per_level[..DEFAULT_LEVELS],
                    r.overlap, r.degeneracy, times.last().copied().unwrap_or(0.0)
                );
            }
            results_json.push(json!({
                "method": name.trim(), "dx": s.dx, "dy": s.dy, "dyaw": s.dyaw,
                "status": r.status.as_str(), "e_t": e_t, "e_r": e_r,
                "iterations": r.iterations, "time_ms": times.last().copied().unwrap_or(0.0),
                "overlap": r.overlap, "transform": pose::to_row_major(&to_matrix(&r.transform)),
            }));
            et.push(e_t);
            er.push(e_r);
            iters.push(f64::from(r.iterations));
        }
        for v in [&mut et, &mut er, &mut times, &mut iters] {
            v.sort_by(|x, y| x.total_cmp(y));
        }
        let n = starts.len() as f64;
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        methods_json.insert(
            name.trim().to_string(),
            json!({
                "success_strict": strict as f64 / n,
                "success_loose": loose as f64 / n,
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
            }),
        );
        println!(
            "{name}: {} starts, strict {:.1}%, loose {:.1}%; e_t median {:.3} p95 {:.3} max {:.3} m; e_r median {:.3} p95 {:.3} max {:.3} deg; {:.1} ms/match, {} iterations (medians)",
            starts.len(),
            100.0 * strict as f64 / n,
            100.0 * loose as f64 / n,
            percentile(&et, 0.5),
            percentile(&et, 0.95),
            et.last().copied().unwrap_or(f64::NAN),
            percentile(&er, 0.5),
            percentile(&er, 0.95),
            er.last().copied().unwrap_or(f64::NAN),
            percentile(&times, 0.5),
            percentile(&iters, 0.5),
        );
    }
    if let Some(path) = &a.json {
        let out = json!({
            "maps": {"a_voxels": map_a.len(), "b_voxels": map_b.len(), "overlap": overlap},
            "starts": starts.len(),
            "preparation_ms": prep_ms,
            "ground_truth": pose::to_row_major(&gt),
            "methods": methods_json,
            "results": results_json,
        });
        std::fs::write(path, serde_json::to_string_pretty(&out)?).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}
