//! `cosem eval`: the paper's robustness protocol over a grid of starts, or
//! the prior-free protocol (`--global`).

use super::args::settings;
use super::Error;
use cosem_core::matching::{Alignment, Dof, MatchSettings, Method};
use cosem_host::evaluation::eval::{
    corners, evaluate, global_starts, grid, run_negatives, sample, EvalReport, MapsInfo, Place, Protocol, Start,
};
use cosem_host::evaluation::pair::{Pair, PairSpec};
use cosem_host::maps::noise::LabelNoise;
use cosem_host::sources::kitti::FrameRange;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;

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
    /// EM iterations, the verdict's thresholds (to measure other operating
    /// points), the prior-free search's budget.
    #[command(flatten)]
    tuning: super::args::Tuning,
    /// Random priors per negative pair.
    #[arg(long, default_value_t = 3)]
    random_priors: usize,
    /// Voxel size (m).
    #[arg(long, default_value_t = super::args::HOST.voxel, value_parser = super::args::voxel)]
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
    /// Methods, comma-separated: cosem, cosem-hard, geometric.
    #[arg(long, value_delimiter = ',', default_value = "cosem", value_parser = super::args::method)]
    method: Vec<Method>,
    /// Degrees of freedom: 6, or 4 (x, y, z, yaw).
    #[arg(long, default_value = "6", value_parser = super::args::dof)]
    dof: Dof,
    /// Worker threads (each match itself runs on one), 1 to 4 x the
    /// cores; default: all cores.
    #[arg(long, value_parser = super::args::threads)]
    threads: Option<usize>,
    /// Write the summary and every start's result as JSON to this file.
    #[arg(long, value_name = "OUT")]
    json: Option<PathBuf>,
    /// Write box plots of e_t and e_r per method to this SVG file.
    #[arg(long, value_name = "OUT")]
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
    /// Unlabelled points (id 0; a camera's labels leave so the points
    /// outside its view): drop, or geometry (voxels of an unknown class).
    #[arg(long, default_value = "drop", value_parser = super::args::named::<cosem_host::maps::mapping::Unlabeled>())]
    unlabeled: cosem_host::maps::mapping::Unlabeled,
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
    let mut inputs: Vec<(&str, &std::path::Path)> =
        a.negatives.iter().map(|p| ("--negatives", p.data.as_path())).collect();
    inputs.extend(a.data.as_deref().map(|p| ("--data", p)));
    inputs.extend(a.source.classes.as_deref().map(|p| ("--classes", p)));
    let outputs: Vec<(&str, &std::path::Path)> =
        [("--json", &a.json), ("--plot", &a.plot)].into_iter().filter_map(|(n, p)| Some((n, p.as_deref()?))).collect();
    Ok(cosem_host::paths::check_outputs(&outputs, &inputs)?)
}

/// A method's alignment, tuned as the arguments say.
fn verdict(a: &Args, s: MatchSettings) -> Alignment {
    a.tuning.apply(Alignment::from(s))
}

/// The alignment of the first method (negatives and the prior-free protocol run one).
fn first_method(a: &Args) -> Alignment {
    verdict(a, settings(a.method.first().copied().unwrap_or_default(), a.dof))
}

/// The pair the arguments name (clap requires them without --negatives).
fn spec(a: &Args) -> Result<PairSpec, Error> {
    let (Some(data), Some(ra), Some(rb)) = (&a.data, a.a, a.b) else { return Err("--data, --a and --b".into()) };
    Ok(PairSpec::new(data, ra, rb, a.voxel)
        .with_noise(a.label_noise, a.seed)
        .with_source(a.source.options())
        .with_unlabeled(a.unlabeled))
}

fn negatives(a: &Args, pool: &rayon::ThreadPool) -> Result<(), Error> {
    let spec = PairSpec::places(a.voxel)
        .with_noise(a.label_noise, a.seed)
        .with_source(a.source.options())
        .with_unlabeled(a.unlabeled);
    let s = first_method(a);
    let n = a.negatives.len();
    let bar = progress_bar(n * (n - 1) * (2 + a.random_priors));
    let tick = || bar.inc(1);
    let report = pool.install(|| run_negatives(&a.negatives, &spec, s, a.random_priors, &tick))?;
    bar.finish_and_clear();
    print!("{report}");
    if let Some(path) = &a.json {
        write(path, serde_json::to_string_pretty(&report)?)?;
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
        let (noise, seed, rate) = (a.label_noise, a.seed, 100.0 * pair.noise.rate());
        println!("label noise {noise:?} (seed {seed}): {rate:.1}% of labelled points changed");
    }
    if a.through_encoding {
        pair.through_encoding()?;
        println!("maps passed through the wire encoding");
    }
    let protocol = if a.global {
        let s = first_method(&a);
        let starts = global_starts(a.radius, a.limit);
        let (n, r, threads) = (starts.len(), a.radius, pool.current_num_threads());
        println!("prior-free: {n} starts (of 36 headings x 10 offsets up to {r} m) on {threads} thread(s)");
        Protocol::Global { starts, settings: s }
    } else {
        let starts = starts(&a);
        println!("{} starts x {} method(s) on {} thread(s)", starts.len(), a.method.len(), pool.current_num_threads());
        Protocol::Grid { starts, methods: a.method.iter().map(|m| verdict(&a, settings(*m, a.dof))).collect() }
    };
    let bar = progress_bar(protocol.matches());
    let prepared = |maps: &MapsInfo, prep_ms: f64| {
        let (na, nb, overlap) = (maps.a_voxels, maps.b_voxels, 100.0 * maps.overlap);
        println!(
            "maps: A {na} voxels, B {nb} voxels at {} m, overlap {overlap:.1}% under the ground truth; preparation {prep_ms:.1} ms per map",
            a.voxel
        );
    };
    let tick = || bar.inc(1);
    let report = pool.install(|| evaluate(&pair, &spec, &protocol, prepared, &tick))?;
    bar.finish_and_clear();
    print_report(&a, &report);
    write_outputs(&a, &report)
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

fn write(path: &std::path::Path, text: String) -> Result<(), Error> {
    Ok(cosem_host::paths::write_file(path, text).map_err(|e| format!("{}: {e}", path.display()))?)
}
