//! `cosem eval`: the paper's robustness protocol over a grid of starts, or
//! the prior-free protocol (`--global`).

use super::args::{settings, DofArg, MethodArg};
use super::Error;
use cosem_core::matching::MatchSettings;
use cosem_host::align::{prepare, DEFAULT_LEVELS};
use cosem_host::eval::{
    corners, global_starts, grid, run_global, run_grid, run_negatives, sample, EvalReport, MapsInfo, Outcome, Place,
    Start,
};
use cosem_host::kitti::FrameRange;
use cosem_host::noise::LabelNoise;
use cosem_host::pair::{Pair, PairSpec};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::time::Instant;

/// Which grid of starts.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum GridArg {
    /// The paper's 1331 starts.
    Paper,
    /// Its 8 corners and centre.
    Corners,
}

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The scans: a SemanticKITTI-layout folder, a ROS 2 recording (.mcap)
    /// or a folder of PCD/PLY scans with poses.txt; the truth between A and
    /// B is the source's own poses.
    #[arg(long, required_unless_present = "negatives")]
    data: Option<PathBuf>,
    #[command(flatten)]
    source: super::args::SourceArgs,
    /// Robot A's frames (the model).
    #[arg(long, required_unless_present = "negatives")]
    a: Option<FrameRange>,
    /// Robot B's frames (the scene).
    #[arg(long, required_unless_present = "negatives")]
    b: Option<FrameRange>,
    /// Negatives instead: maps of different places, DIR[:START:END] each
    /// (default the folder's first scan); every ordered pair is matched with
    /// no prior, the identity prior and --random-priors seeded random priors
    /// (+-20 m, any heading); each Converged is a false accept.
    #[arg(long, num_args = 2.., conflicts_with_all = ["data", "global", "grid_stride", "limit"])]
    negatives: Vec<Place>,
    /// The verdict's threshold on the agreement of what both maps saw
    /// (default: the matcher's, 0.40): to measure other operating points.
    #[arg(long)]
    min_agreement: Option<f32>,
    /// Random priors per negative pair.
    #[arg(long, default_value_t = 3)]
    random_priors: usize,
    /// Voxel size (m).
    #[arg(long, default_value = "0.2", value_parser = super::args::positive_f32)]
    voxel: f32,
    /// The grid of starts.
    #[arg(long, value_enum, default_value = "paper", conflicts_with_all = ["grid_stride", "limit"])]
    grid: GridArg,
    /// Keep every K-th grid value (K >= 1) on each axis, counting outward from zero.
    #[arg(long, conflicts_with = "limit", value_parser = super::args::at_least::<1>)]
    grid_stride: Option<usize>,
    /// Keep N (>= 1) starts of the full grid, chosen by a fixed seed (with
    /// --global: every n-th of its starts).
    #[arg(long, value_parser = super::args::at_least::<1>)]
    limit: Option<usize>,
    /// Methods, comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "cosem")]
    method: Vec<MethodArg>,
    /// Degrees of freedom.
    #[arg(long, value_enum, default_value = "6")]
    dof: DofArg,
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
    /// With --global: the largest offset (m) the scene map's frame is moved by.
    #[arg(long, default_value = "50", value_parser = super::args::positive)]
    radius: f64,
    /// Label noise on every scan: none, network[:SEVERITY] (a segmentation
    /// network's class-dependent, spatially coherent errors) or iid:P.
    #[arg(long, default_value = "none")]
    label_noise: LabelNoise,
    /// Seed of the label noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Prior-free protocol instead of the grid: the scene map is moved by a
    /// known heading (36 around the circle) and offset (10 seeded, up to
    /// 50 m) and matched with no prior.
    #[arg(long)]
    global: bool,
}

fn starts(a: &Args) -> Vec<Start> {
    match (a.limit, a.grid_stride, a.grid) {
        (Some(n), _, _) => sample(n, 0xC05E),
        (None, Some(k), _) => grid(k),
        (None, None, GridArg::Paper) => grid(1),
        (None, None, GridArg::Corners) => corners(),
    }
}

fn progress_bar(len: usize) -> ProgressBar {
    let bar = ProgressBar::new(len as u64);
    let style = ProgressStyle::with_template("{bar:40} {pos}/{len} matches, {elapsed} elapsed, eta {eta}");
    bar.set_style(style.unwrap_or_else(|_| ProgressStyle::default_bar()));
    bar
}

/// Checks the output paths can be written before the run.
fn check_outputs(a: &Args) -> Result<(), Error> {
    let mut inputs: Vec<&std::path::Path> = a.negatives.iter().map(|p| p.data.as_path()).collect();
    inputs.extend(a.data.as_deref());
    inputs.extend(a.source.classes.as_deref());
    let outputs: Vec<&std::path::Path> = [&a.json, &a.plot].into_iter().flatten().map(|p| p.as_path()).collect();
    Ok(cosem_host::paths::check_outputs(&outputs, &inputs)?)
}

/// The settings with the verdict's threshold of the arguments.
fn verdict(a: &Args, s: MatchSettings) -> MatchSettings {
    MatchSettings { min_agreement: a.min_agreement.unwrap_or(s.min_agreement), ..s }
}

/// The pair the arguments name (clap requires them without --negatives).
fn spec(a: &Args) -> Result<PairSpec, Error> {
    let (Some(data), Some(ra), Some(rb)) = (&a.data, a.a, a.b) else {
        return Err("--data, --a and --b are required".into());
    };
    Ok(PairSpec::new(data, ra, rb, a.voxel).with_noise(a.label_noise, a.seed).with_source(a.source.options()))
}

fn negatives(a: &Args, pool: &rayon::ThreadPool) -> Result<(), Error> {
    let spec = PairSpec::places(a.voxel).with_noise(a.label_noise, a.seed).with_source(a.source.options());
    let s = verdict(a, settings(a.method.first().copied().unwrap_or(MethodArg::Cosem), a.dof));
    let n = a.negatives.len();
    let bar = progress_bar(n * (n - 1) * (2 + a.random_priors));
    let tick = || bar.inc(1);
    let report = pool.install(|| run_negatives(&a.negatives, &spec, s, a.random_priors, &tick))?;
    bar.finish_and_clear();
    print!("{report}");
    if let Some(path) = &a.json {
        cosem_host::paths::write_file(path, serde_json::to_string_pretty(&report)?)
            .map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

pub fn run(a: Args) -> Result<(), Error> {
    check_outputs(&a)?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.threads.unwrap_or(0)).build()?;
    if !a.negatives.is_empty() {
        return negatives(&a, &pool);
    }
    let spec = spec(&a)?;
    let mut pair = Pair::load(&spec)?;
    if a.label_noise != LabelNoise::None {
        println!(
            "label noise {:?} (seed {}): {:.1}% of labelled points changed",
            a.label_noise,
            a.seed,
            100.0 * pair.noise.rate()
        );
    }
    if a.through_encoding {
        pair.through_encoding()?;
        println!("maps passed through the wire encoding");
    }
    let maps = MapsInfo { a_voxels: pair.map_a.len(), b_voxels: pair.map_b.len(), overlap: pair.overlap() };
    let t0 = Instant::now();
    let (pa, pb) = (prepare(&pair.map_a, DEFAULT_LEVELS)?, prepare(&pair.map_b, DEFAULT_LEVELS)?);
    let prep_ms = t0.elapsed().as_secs_f64() * 1e3 / 2.0;
    println!(
        "maps: A {} voxels, B {} voxels at {} m, overlap {:.1}% under the ground truth; preparation {prep_ms:.1} ms per map",
        maps.a_voxels,
        maps.b_voxels,
        a.voxel,
        100.0 * maps.overlap,
    );
    let (mode, results) = if a.global {
        ("global", pool.install(|| global(&a, &pair))?)
    } else {
        let starts = starts(&a);
        println!("{} starts x {} method(s) on {} thread(s)", starts.len(), a.method.len(), pool.current_num_threads());
        let bar = progress_bar(starts.len() * a.method.len());
        let mut results = Vec::new();
        for m in &a.method {
            let s = verdict(&a, settings(*m, a.dof));
            let tick = || bar.inc(1);
            results.extend(pool.install(|| run_grid(s.method.name(), s, (&pa, &pb), &pair.gt, &starts, &tick))?);
        }
        bar.finish_and_clear();
        ("grid", results)
    };
    let report = EvalReport::new(mode, maps, a.voxel, a.dof.count(), prep_ms, &pair.gt, results);
    print_report(&a, &report);
    write_outputs(&a, &report)
}

/// `--global`: 36 headings x 10 seeded offsets up to 50 m, no prior.
fn global(a: &Args, pair: &Pair) -> Result<Vec<Outcome>, Error> {
    let method = a.method.first().copied().unwrap_or(MethodArg::Cosem);
    let s = verdict(a, settings(method, a.dof));
    let starts = global_starts(a.radius, a.limit);
    println!(
        "prior-free: {} starts (of 36 headings x 10 offsets up to {} m) on {} thread(s)",
        starts.len(),
        a.radius,
        rayon::current_num_threads()
    );
    let bar = progress_bar(starts.len());
    let spec = spec(a)?;
    let tick = || bar.inc(1);
    let frames = &pair.frames_b;
    let out =
        run_global(s.method.name(), s, &pair.map_a, frames, (spec.config, &spec.filter), &pair.gt, &starts, &tick);
    bar.finish_and_clear();
    Ok(out?)
}

fn print_report(a: &Args, report: &EvalReport) {
    if a.verbose {
        report.results.iter().for_each(|o| println!("{o}"));
    }
    for (name, m) in &report.methods {
        print!("{}", m.text(name, report.mode, a.voxel));
    }
}

fn write_outputs(a: &Args, report: &EvalReport) -> Result<(), Error> {
    let write = |path: &PathBuf, text: String| {
        cosem_host::paths::write_file(path, text).map_err(|e| format!("{}: {e}", path.display()))
    };
    if let Some(path) = &a.json {
        write(path, serde_json::to_string_pretty(report)?)?;
    }
    if let Some(path) = &a.plot {
        let spec = spec(a)?;
        let (name, ra, rb) = (spec.name(), spec.a, spec.b);
        write(path, report.plot(&format!("{name} A={ra} B={rb}, {} starts, {} m voxels", report.starts, a.voxel)))?;
    }
    Ok(())
}
