//! `cosem bench`: benchmarks that print numbers (the measuring is in
//! `cosem_host::evaluation::bench`).

use super::Error;
use cosem_host::evaluation::bench;
use cosem_host::evaluation::pair::{Pair, PairSpec};
use cosem_host::paths::TempDir;
use cosem_host::sources::kitti::FrameRange;
use std::path::{Path, PathBuf};

#[derive(clap::Subcommand, Debug)]
pub enum What {
    /// Points fused per second into a local map (single thread).
    Map(MapArgs),
    /// Encode and decode throughput of the compact voxel encoding.
    Wire(MapArgs),
    /// Two maps exchanged over a simulated 115200-baud line, clean and lossy.
    Link(LinkArgs),
    /// Prior-free global alignment: landmarks, correspondence search, refinement (single thread).
    Global(GlobalArgs),
    /// Camera labels on a synthetic street: points labelled per second, agreement with the ground
    /// truth (perfect, corrupted, probabilities), matching success with camera against true labels.
    Label(LabelArgs),
    /// Camera segmentation with a network (ONNX, feature `segment`): milliseconds per image on one core
    /// and on all.
    Segment(SegmentArgs),
    /// Robots that keep driving: `cosem session` on the built-in town with
    /// drift (1%, 0.5 deg/100 m) over seeds, 2 and 3 robots, true and
    /// network-like labels, and a slip: wrong Converged, availability,
    /// first fix, update bytes, tracking cost.
    Session(SessionArgs),
}

#[derive(clap::Args, Debug)]
pub struct SessionArgs {
    /// Seeds of the towns (and of drift and label noise).
    #[arg(long, default_value = "1,2,3,4,5", value_delimiter = ',')]
    seeds: Vec<u64>,
    /// Sessions run at once (each on one thread; default: the cores).
    #[arg(long, value_parser = super::args::threads)]
    threads: Option<usize>,
    /// Scans per robot of each town (default: the town's, 280; fewer for a
    /// quick look, without the second meeting).
    #[arg(long, value_parser = super::args::frames_count)]
    frames: Option<usize>,
}

#[derive(clap::Args, Debug)]
pub struct SegmentArgs {
    /// The network (ONNX); default `$COSEM_DATA/../models/espnetv2-cityscapes-s2.0-512x1024.onnx`.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Colour images NNNNNN.png; default `$COSEM_DATA/kitti00/image_2`.
    #[arg(long)]
    images: Option<PathBuf>,
    /// Frames.
    #[arg(long, default_value = "0:4")]
    frames: FrameRange,
    /// How an image meets the network (see `cosem segment`).
    #[arg(long, default_value = "tile", value_parser = super::args::fit)]
    fit: cosem_host::camera::seg_files::Fit,
}

#[derive(clap::Args, Debug)]
pub struct LabelArgs {
    /// Frames of the synthetic sequence (robot A the first half, B the rest; at least 4).
    #[arg(long, default_value_t = 10, value_parser = super::args::frames_count)]
    frames: usize,
    /// Seeds of the synthetic sequences.
    #[arg(long, default_value = "5", value_delimiter = ',')]
    seeds: Vec<u64>,
    /// Keep every K-th value of the paper's grid of starts on each axis.
    #[arg(long, default_value_t = 2, value_parser = super::args::at_least::<1>)]
    grid_stride: usize,
    /// Also a real SemanticKITTI-layout sequence (labelled scans splatted into camera 2 as segmentation).
    #[arg(long)]
    data: Option<PathBuf>,
    /// Robot A's frames of --data.
    #[arg(long, default_value = "0:5")]
    a: FrameRange,
    /// Robot B's frames of --data.
    #[arg(long, default_value = "5:10")]
    b: FrameRange,
}

/// Two robots' frames of one sequence.
#[derive(clap::Args, Debug)]
pub struct PairArgs {
    /// The scans (a SemanticKITTI folder, a .mcap recording, PCD/PLY scans
    /// with poses.txt); default `$COSEM_DATA/kitti00`, else a synthetic one.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Robot A's frames (the model).
    #[arg(long, default_value = "0:5")]
    a: FrameRange,
    /// Robot B's frames (the scene).
    #[arg(long, default_value = "5:10")]
    b: FrameRange,
    #[command(flatten)]
    source: super::args::SourceArgs,
}

impl PairArgs {
    /// Loads the pair at `voxel`, points within `max_range` of their
    /// sensor (the guard removes a synthetic folder).
    fn load(&self, voxel: f32, max_range: Option<f32>) -> Result<(Pair, PathBuf, Option<TempDir>), Error> {
        let (dir, tmp) = data(self.data.clone(), self.b.end)?;
        let mut spec = PairSpec::new(&dir, self.a, self.b, voxel).with_source(self.source.options());
        spec.filter.max_range = max_range;
        Ok((Pair::load(&spec)?, dir, tmp))
    }
}

/// The folder to run on ([`bench::data_dir`]), saying when it is synthetic.
fn data(given: Option<PathBuf>, frames: usize) -> Result<(PathBuf, Option<TempDir>), Error> {
    let (dir, tmp) = bench::data_dir(given, frames)?;
    if tmp.is_some() {
        println!("(no kitti00 under {}: using a synthetic sequence)", bench::data_root().display());
    }
    Ok((dir, tmp))
}

#[derive(clap::Args, Debug)]
pub struct GlobalArgs {
    #[command(flatten)]
    pair: PairArgs,
    /// Voxel size (m).
    #[arg(long, default_value_t = super::args::HOST.voxel, value_parser = super::args::voxel)]
    voxel: f32,
    /// Repetitions (the median is reported), 1 to 1,000.
    #[arg(long, default_value_t = 5, value_parser = super::args::repeat)]
    repeat: usize,
}

#[derive(clap::Args, Debug)]
pub struct LinkArgs {
    #[command(flatten)]
    pair: PairArgs,
    /// Byte error rates to simulate, each damaged byte as --mix says.
    #[arg(long, default_value = "0,0.01,0.05,0.1,0.2", value_delimiter = ',', value_parser = super::args::probability)]
    error_rates: Vec<f64>,
    /// Shares of the damage: bit=S,byte=S,drop=S,dup=S (default substituted, dropped, duplicated alike).
    #[arg(long, value_parser = cosem_host::lines::relay::parse_mix, default_value = "byte=1,drop=1,dup=1")]
    mix: cosem_host::lines::relay::Mix,
    /// Line speed (baud, 8N1).
    #[arg(long, default_value_t = 115_200, value_parser = super::args::baud)]
    baud: u32,
    /// Voxel size (m); the default makes a robot's map.
    #[arg(long, default_value_t = super::args::ROBOT.voxel, value_parser = super::args::voxel)]
    voxel: f32,
    /// Keep points within this range of their sensor (m).
    #[arg(long, default_value_t = super::args::ROBOT_CROP, value_parser = super::args::crop)]
    max_range: f32,
    /// Seeded runs per error rate, 1 to 10,000.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    seeds: u64,
    /// One medium for both directions: the maps go one after the other, in bursts that take turns.
    #[arg(long)]
    half_duplex: bool,
}

#[derive(clap::Args, Debug)]
pub struct MapArgs {
    /// The scans (a SemanticKITTI folder, a .mcap recording, PCD/PLY scans
    /// with poses.txt); default `$COSEM_DATA/kitti00`, else a synthetic one.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Frames START:END[:STRIDE].
    #[arg(long, default_value = "0:10")]
    frames: FrameRange,
    #[command(flatten)]
    source: super::args::SourceArgs,
    /// Voxel size (m).
    #[arg(long, default_value_t = super::args::HOST.voxel, value_parser = super::args::voxel)]
    voxel: f32,
    /// Repetitions (the median is reported), 1 to 1,000.
    #[arg(long, default_value_t = 5, value_parser = super::args::repeat)]
    repeat: usize,
}

pub fn run(w: What, json: Option<&Path>) -> Result<(), Error> {
    if let Some(out) = json {
        let inputs: Vec<(&str, &Path)> = match &w {
            What::Map(a) | What::Wire(a) => named([("--data", &a.data), ("--classes", &a.source.classes)]),
            What::Link(a) => named([("--data", &a.pair.data), ("--classes", &a.pair.source.classes)]),
            What::Global(a) => named([("--data", &a.pair.data), ("--classes", &a.pair.source.classes)]),
            What::Label(a) => named([("--data", &a.data), ("--data", &None)]),
            What::Segment(a) => named([("--model", &a.model), ("--images", &a.images)]),
            What::Session(_) => Vec::new(),
        };
        cosem_host::paths::check_output("--json", out, &inputs)?;
    }
    match w {
        What::Map(a) => bench_map(a, json),
        What::Wire(a) => bench_wire(a, json),
        What::Link(a) => bench_link(a, json),
        What::Global(a) => bench_global(a),
        What::Label(a) => bench_label(a, json),
        What::Segment(a) => bench_segment(a, json),
        What::Session(a) => bench_session(a, json),
    }
}

/// The inputs given, by their arguments.
fn named<'a, const N: usize>(args: [(&'static str, &'a Option<PathBuf>); N]) -> Vec<(&'static str, &'a Path)> {
    args.into_iter().filter_map(|(n, p)| Some((n, p.as_deref()?))).collect()
}

/// Milliseconds per image on one core, then on all.
fn bench_segment(a: SegmentArgs, json: Option<&Path>) -> Result<(), Error> {
    let root = bench::data_root();
    let model = a.model.unwrap_or_else(|| root.join("../models/espnetv2-cityscapes-s2.0-512x1024.onnx"));
    let images = a.images.unwrap_or_else(|| root.join("kitti00/image_2"));
    let figures = bench::segment(&model, &images, a.frames, a.fit)?;
    figures.iter().for_each(|f| println!("{f}"));
    save(json, &figures)
}

/// Writes `figures` as JSON to `path`, if given.
fn save(path: Option<&Path>, figures: &impl serde::Serialize) -> Result<(), Error> {
    let Some(path) = path else { return Ok(()) };
    Ok(cosem_host::paths::write_file(path, serde_json::to_string_pretty(figures)?)?)
}

fn bench_map(a: MapArgs, json: Option<&Path>) -> Result<(), Error> {
    let (dir, _tmp) = data(a.data, a.frames.end)?;
    let frames = bench::frames(&dir, a.frames, &a.source.options())?;
    println!("bench map: {} frames {} of {}, {} m voxels", frames.len(), a.frames, dir.display(), a.voxel);
    let figures = bench::map(&frames, a.voxel, a.repeat)?;
    print!("{figures}");
    println!("  (median of {} runs, single thread)", a.repeat.max(1));
    save(json, &figures)
}

fn bench_wire(a: MapArgs, json: Option<&Path>) -> Result<(), Error> {
    let (dir, _tmp) = data(a.data, a.frames.end)?;
    let frames = bench::frames(&dir, a.frames, &a.source.options())?;
    let config = cosem_core::map::MapConfig::with_resolution(a.voxel);
    let (map, _) =
        cosem_host::maps::mapping::build_map(&frames, config, &cosem_host::maps::mapping::PointFilter::default())?;
    let (n, range, d) = (frames.len(), a.frames, dir.display());
    println!("bench wire: {} voxels at {} m from {n} frames {range} of {d}", map.len(), a.voxel);
    let figures = bench::wire(&map, a.repeat)?;
    print!("{figures}");
    println!("  (median of {} runs, single thread, chunk size as on the link)", a.repeat.max(1));
    save(json, &figures)
}

fn bench_link(a: LinkArgs, json: Option<&Path>) -> Result<(), Error> {
    let (pair, dir, _tmp) = a.pair.load(a.voxel, Some(a.max_range))?;
    let (na, nb, ra, rb) = (pair.map_a.len(), pair.map_b.len(), a.pair.a, a.pair.b);
    let (d, voxel, range, baud, seeds) = (dir.display(), a.voxel, a.max_range, a.baud, a.seeds);
    println!("bench link: A {na} voxels ({ra}), B {nb} voxels ({rb}) of {d} at {voxel} m within {range} m; both ways at once, {baud} baud (8N1), simulated time, {seeds} seeds");
    let mut summaries = Vec::new();
    for &rate in &a.error_rates {
        let runs = (1..=seeds.max(1))
            .map(|s| bench::link(&pair, (rate, a.mix, a.half_duplex), baud, s))
            .collect::<Result<Vec<_>, _>>()?;
        println!("{}", bench::LinkSummary::of(&runs, baud));
        summaries.push(bench::LinkSummary::of(&runs, baud));
    }
    println!("  goodput: map bytes per direction over the line's bytes in the time until that map was through; capacity: a line substituting that share of bytes (8 - H(p) - p log2 255 bits a byte), the floor for drops and duplicates;\n  without FEC: the best of retransmission alone with this frame overhead, max over L of (L-h)/L (1-p)^L; one-error repair: as cosem's frames were before forward error correction");
    save(json, &summaries)
}

fn bench_global(a: GlobalArgs) -> Result<(), Error> {
    let (pair, dir, _tmp) = a.pair.load(a.voxel, None)?;
    let (na, nb, pa, pb) = (pair.map_a.len(), pair.map_b.len(), a.pair.a, a.pair.b);
    println!("bench global: A {na} voxels ({pa}), B {nb} voxels ({pb}) at {} m of {}", a.voxel, dir.display());
    print!("{}", bench::global(&pair, a.repeat)?);
    println!("  (median of {} runs, single thread; maps prepared beforehand)", a.repeat.max(1));
    Ok(())
}

fn bench_label(a: LabelArgs, json: Option<&Path>) -> Result<(), Error> {
    if a.frames < 4 {
        return Err(format!("--frames {}: at least 4 (two robots of two frames)", a.frames).into());
    }
    let tmp = TempDir::new("cosem-bench-label");
    let starts = cosem_host::evaluation::eval::grid(a.grid_stride).len();
    println!("bench label: camera 2, Cityscapes ids; strict success over {starts} starts of the paper's grid");
    println!(
        "  {:<8} {:<26} {:>8} {:>10} {:>8} {:>11} {:>8}",
        "seq", "labels", "M pts/s", "agreement", "in set", "A voxels", "strict"
    );
    let mut rows = Vec::new();
    for &seed in &a.seeds {
        rows.extend(bench::label_synthetic(seed, a.frames, a.grid_stride, &tmp.0)?);
    }
    if let Some(data) = &a.data {
        rows.extend(bench::label_real(data, a.a, a.b, a.grid_stride, &tmp.0)?);
    }
    rows.iter().for_each(|r| println!("{r}"));
    println!("  (M pts/s: projection and lookup of every point of a scan, single thread; agreement over the");
    println!("   points camera 2 sees; 'in set': as Cityscapes ids can say it, trunks being vegetation there)");
    save(json, &rows.iter().map(bench::LabelRow::figures).collect::<Vec<_>>())
}

fn bench_session(a: SessionArgs, json: Option<&Path>) -> Result<(), Error> {
    use cosem_host::evaluation::session::bench::{bench_session, BENCH_DRIFT, BENCH_SLIP};
    if a.seeds.is_empty() || a.seeds.len() > 100 {
        return Err(format!("--seeds: 1 to 100 seeds, not {}", a.seeds.len()).into());
    }
    let tmp = TempDir::new("cosem-bench-session");
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.threads.unwrap_or(0)).build()?;
    println!(
        "bench session: the built-in town, seeds {:?}, drift {BENCH_DRIFT}, slip of robot {} at round {}; {} sessions at once",
        a.seeds,
        BENCH_SLIP.0,
        BENCH_SLIP.1,
        pool.current_num_threads()
    );
    let t0 = std::time::Instant::now();
    let cases = pool.install(|| bench_session(&tmp.0, &a.seeds, a.frames))?;
    let opt = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
    println!(
        "  {:<7} {:<8} {:<5} {:<8} {:>6} {:>6} {:>6} {:>6} {:>7} {:>7} {:>6} {:>6} {:>22} {:>12} {:>8} {:>9} {:>5}",
        "robots",
        "labels",
        "slip",
        "mode",
        "rounds",
        "wrong",
        "@origin",
        "local",
        "avail",
        "min",
        "meets",
        "fix",
        "update p50/p95/max",
        "held p50/p95",
        "B/round",
        "cost",
        "slip"
    );
    for c in &cases {
        let upd = c.update_bytes_ratio.map_or("-".into(), |[p, q, m]| format!("{p:.3}/{q:.3}/{m:.3}"));
        let held = c.update_deferred.map_or("-".into(), |[p, q, _]| format!("{p:.0}/{q:.0}"));
        println!(
            "  {:<7} {:<8} {:<5} {:<8} {:>6} {:>6} {:>6} {:>6} {:>7} {:>7} {:>6} {:>6} {:>22} {:>12} {:>8} {:>9} {:>5}",
            c.case.robots,
            c.case.labels,
            c.case.slip,
            if c.case.one_shot { "one-shot" } else { "tracked" },
            c.rounds,
            c.wrong_converged,
            c.wrong_at_origin,
            c.wrong_converged_local,
            opt(c.availability),
            opt(c.availability_min),
            c.meetings,
            c.first_fix_rounds.map_or("-".into(), |v| v.to_string()),
            upd,
            held,
            c.bytes_per_round.map_or("-".into(), |b| format!("{b:.0}")),
            opt(c.tracking_cost_ratio),
            c.slip_caught_rounds.map_or("-".into(), |v| v.to_string()),
        );
    }
    println!(
        "  (wrong: Converged and e_t at the meeting place or e_r over the strict thresholds; @origin: with e_t at the odometry origins;\n   local: against the truth as the maps hold it about the closest pair of scans (each robot's frame averaged over its scans within the crop);\n   held: voxels an update held back for later rounds (its budget); B/round: bytes a robot received from a peer in a round, median; cost: a tracking round's median time /\n   a from-scratch match's, single thread; one-shot: whole maps every round, matched prior-free; {:.0} s in all)",
        t0.elapsed().as_secs_f64()
    );
    save(json, &cases)
}
