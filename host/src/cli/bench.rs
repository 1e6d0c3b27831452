//! `cosem bench map`: insertion throughput and memory, printed as numbers.

use super::{data_root, Error};
use cosem_core::classes::{Class, MovingObjects};
use cosem_core::map::{MapConfig, BYTES_PER_VOXEL};
use cosem_host::kitti::{FrameRange, Sequence};
use cosem_host::mapping::{new_map, PointFilter};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Subcommand, Debug)]
pub enum What {
    /// Points fused per second into a local map (single thread).
    Map(MapArgs),
    /// Encode and decode throughput of the compact voxel encoding.
    Wire(MapArgs),
    /// Two maps exchanged over a simulated 115200-baud line, clean and lossy.
    Link(LinkArgs),
    /// Prior-free global alignment of two maps: landmark extraction,
    /// correspondence search, refinement (single thread).
    Global(GlobalArgs),
    /// Camera labels on a synthetic street: points labelled per second,
    /// agreement with the ground truth (perfect, corrupted, probabilities),
    /// and matching success with camera labels against ground-truth labels.
    Label(LabelArgs),
}

#[derive(clap::Args, Debug)]
pub struct LabelArgs {
    /// Frames of the synthetic sequence (robot A the first half, B the rest).
    #[arg(long, default_value_t = 10)]
    frames: usize,
    /// Seeds of the synthetic sequences.
    #[arg(long, default_value = "5", value_delimiter = ',')]
    seeds: Vec<u64>,
    /// Keep every K-th value of the paper's grid of starts on each axis.
    #[arg(long, default_value_t = 2)]
    grid_stride: usize,
    /// Also a real SemanticKITTI-layout sequence, whose labelled scans are
    /// splatted into camera 2 as stand-in segmentation images.
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
    /// SemanticKITTI-layout folder; default `$COSEM_DATA/kitti00`, else a
    /// synthetic sequence.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Robot A's frames (the model).
    #[arg(long, default_value = "0:5")]
    a: FrameRange,
    /// Robot B's frames (the scene).
    #[arg(long, default_value = "5:10")]
    b: FrameRange,
}

#[derive(clap::Args, Debug)]
pub struct GlobalArgs {
    #[command(flatten)]
    pair: PairArgs,
    /// Voxel size (m).
    #[arg(long, default_value_t = 0.2)]
    voxel: f32,
    /// Repetitions (the median is reported).
    #[arg(long, default_value_t = 5)]
    repeat: usize,
}

#[derive(clap::Args, Debug)]
pub struct LinkArgs {
    #[command(flatten)]
    pair: PairArgs,
    /// Byte error rates to simulate (each byte flipped, dropped or duplicated).
    #[arg(long, default_value = "0,0.001,0.01", value_delimiter = ',')]
    error_rates: Vec<f64>,
    /// Line speed (baud, 8N1).
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
}

#[derive(clap::Args, Debug)]
pub struct MapArgs {
    /// SemanticKITTI-layout folder; default `$COSEM_DATA/kitti00`, else a
    /// synthetic sequence.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Frames START:END[:STRIDE].
    #[arg(long, default_value = "0:10")]
    frames: FrameRange,
    /// Voxel size (m).
    #[arg(long, default_value_t = 0.2)]
    voxel: f32,
    /// Repetitions (the median is reported).
    #[arg(long, default_value_t = 5)]
    repeat: usize,
}

pub fn run(w: What) -> Result<(), Error> {
    match w {
        What::Map(a) => bench_map(a),
        What::Wire(a) => bench_wire(a),
        What::Link(a) => bench_link(a),
        What::Global(a) => bench_global(a),
        What::Label(a) => bench_label(a),
    }
}

/// The data folder: given, else kitti00, else a fresh synthetic sequence.
fn data_dir(given: Option<PathBuf>, frames: usize) -> Result<(PathBuf, Option<TempDir>), Error> {
    if let Some(d) = given {
        return Ok((d, None));
    }
    let kitti = data_root().join("kitti00");
    if kitti.join("poses.txt").exists() {
        return Ok((kitti, None));
    }
    let tmp = std::env::temp_dir().join(format!("cosem-bench-{}", std::process::id()));
    let cfg = cosem_host::synth::SynthConfig { frames, ..Default::default() };
    cosem_host::synth::write_sequence(&tmp, &cfg)?;
    println!("(no kitti00 under {}: using a synthetic sequence)", data_root().display());
    Ok((tmp.clone(), Some(TempDir(tmp))))
}

fn bench_wire(a: MapArgs) -> Result<(), Error> {
    let (dir, _tmp) = data_dir(a.data, a.frames.end)?;
    let seq = Sequence::open(&dir)?;
    let frames = seq.load_range(a.frames)?;
    let (map, _) =
        cosem_host::mapping::build_map(&frames, MapConfig::with_resolution(a.voxel), &PointFilter::default())?;
    let repeat = a.repeat.max(1);
    let mut enc = Vec::new();
    let mut dec = Vec::new();
    let mut chunks = Vec::new();
    for _ in 0..repeat {
        let t = Instant::now();
        chunks = cosem_host::cmap::encode_chunks(&map, 240);
        enc.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let mut out = new_map(map.len(), *map.config())?;
        let mut d = cosem_core::wire::MapDecoder::new(map.len());
        for c in &chunks {
            d.decode_chunk(c, &mut out)?;
        }
        dec.push(t.elapsed().as_secs_f64());
        if out.len() != map.len() {
            return Err("decoded map lost voxels".into());
        }
    }
    let bytes: usize = chunks.iter().map(Vec::len).sum();
    let (te, td) = (median(enc), median(dec));
    println!(
        "bench wire: {} voxels at {} m from {} frames {} of {}",
        map.len(),
        a.voxel,
        frames.len(),
        a.frames,
        dir.display()
    );
    println!(
        "  encoding             {bytes} bytes in {} chunks of <= 240 bytes: {:.2} bytes/voxel",
        chunks.len(),
        bytes as f64 / map.len() as f64
    );
    println!(
        "  encode               {:.1} M voxels/s ({:.1} MB/s of output, {:.2} ms)",
        map.len() as f64 / te / 1e6,
        bytes as f64 / te / 1e6,
        te * 1e3
    );
    println!(
        "  decode               {:.1} M voxels/s ({:.1} MB/s of input, {:.2} ms)",
        map.len() as f64 / td / 1e6,
        bytes as f64 / td / 1e6,
        td * 1e3
    );
    println!("  (median of {repeat} runs, single thread, chunk size as on the link)");
    Ok(())
}

fn bench_link(a: LinkArgs) -> Result<(), Error> {
    let p = &a.pair;
    use cosem_core::link::sim::{SimConfig, SimLine};
    use cosem_core::link::{Endpoint, LinkConfig, Progress};
    let (dir, _tmp) = data_dir(p.data.clone(), p.b.end)?;
    let seq = Sequence::open(&dir)?;
    let config = MapConfig::default();
    let (ma, _) = cosem_host::mapping::build_map(&seq.load_range(p.a)?, config, &PointFilter::default())?;
    let (mb, _) = cosem_host::mapping::build_map(&seq.load_range(p.b)?, config, &PointFilter::default())?;
    println!(
        "bench link: A {} voxels ({}), B {} voxels ({}) of {}, both ways at once, {} baud (8N1), simulated time",
        ma.len(),
        p.a,
        mb.len(),
        p.b,
        dir.display(),
        a.baud
    );
    for &rate in &a.error_rates {
        let line = Box::new(std::cell::RefCell::new(SimLine::<65536>::new(SimConfig {
            seed: 1,
            error_rate: rate,
            stall_chance: 0.0,
            bytes_per_ms: f64::from(a.baud) / 10.0 / 1000.0,
            half_duplex: false,
        })));
        let (mut p0, mut p1) = SimLine::ports(&line);
        let (mut s0, mut s1) = (vec![0u32; ma.len()], vec![0u32; mb.len()]);
        let (mut st0, mut st1) = (new_map(mb.len(), config)?, new_map(ma.len(), config)?);
        let lc = LinkConfig::default();
        let mut e0 = Endpoint::new(lc, 0, 1, 0, Some((&ma, &mut s0)), Some(&mut st0))?;
        let mut e1 = Endpoint::new(lc, 1, 2, 0, Some((&mb, &mut s1)), Some(&mut st1))?;
        let (mut r0, mut r1) = (Ok(Progress::Busy), Ok(Progress::Busy));
        let (mut t0, mut t1) = (None, None);
        let mut now = 0u64;
        while (r0 == Ok(Progress::Busy) || r1 == Ok(Progress::Busy)) && now < 3_600_000 {
            line.borrow_mut().tick(now);
            if r0 == Ok(Progress::Busy) {
                r0 = e0.step(&mut p0, now);
            }
            if r1 == Ok(Progress::Busy) {
                r1 = e1.step(&mut p1, now);
            }
            // When each map was through (before the linger).
            if t0.is_none() && e1.received() {
                t0 = Some(now);
            }
            if t1.is_none() && e0.received() {
                t1 = Some(now);
            }
            now += 1;
        }
        let (x, y) = (e0.stats(), e1.stats());
        let secs = |t: Option<u64>| t.map(|v| format!("{:.1} s", v as f64 / 1e3)).unwrap_or_else(|| "never".into());
        println!(
            "  byte errors {:>5.1}%: A->B {} ({} bytes), B->A {} ({} bytes); {} + {} retransmissions; {}",
            rate * 100.0,
            secs(t0),
            x.bytes_sent,
            secs(t1),
            y.bytes_sent,
            x.retransmissions,
            y.retransmissions,
            match (r0, r1) {
                (Ok(_), Ok(_)) => "both maps identical to the sent ones (digest checked)".to_string(),
                (a, b) => format!("failed: {a:?} / {b:?}"),
            }
        );
    }
    Ok(())
}

fn bench_global(a: GlobalArgs) -> Result<(), Error> {
    let p = &a.pair;
    use cosem_core::matching::global::{align_landmarks, refine, GlobalSettings};
    use cosem_core::matching::{MatchSettings, Matcher};
    use cosem_host::align::{errors, prepare, to_matrix, DEFAULT_LEVELS};
    let (dir, _tmp) = data_dir(p.data.clone(), p.b.end)?;
    let seq = Sequence::open(&dir)?;
    let config = MapConfig::with_resolution(a.voxel);
    let filter = PointFilter::default();
    let (ma, _) = cosem_host::mapping::build_map(&seq.load_range(p.a)?, config, &filter)?;
    let (mb, _) = cosem_host::mapping::build_map(&seq.load_range(p.b)?, config, &filter)?;
    let gt = seq.relative_pose(p.a.start, p.b.start)?;
    let (pa, pb) = (prepare(&ma, DEFAULT_LEVELS)?, prepare(&mb, DEFAULT_LEVELS)?);
    let matcher = Matcher::new(MatchSettings::default());
    let settings = GlobalSettings::default();
    let mut scratch = vec![0u32; ma.len().max(mb.len())];
    let (mut t_extract, mut t_search, mut t_refine) = (Vec::new(), Vec::new(), Vec::new());
    let mut last = None;
    for _ in 0..a.repeat.max(1) {
        let t = Instant::now();
        let (mut la, mut lb) = (heapless::Vec::new(), heapless::Vec::new());
        cosem_core::matching::landmarks::extract(&ma, &mut scratch, &mut la)?;
        cosem_core::matching::landmarks::extract(&mb, &mut scratch, &mut lb)?;
        t_extract.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let outcome = align_landmarks(&la, &lb, &settings);
        t_search.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let r = refine(&matcher, &pa, &pb, outcome.as_ref())?;
        t_refine.push(t.elapsed().as_secs_f64());
        last = Some((la.len(), lb.len(), outcome, r));
    }
    let Some((na, nb, outcome, r)) = last else { return Err("no run".into()) };
    let (te, ts, tr) = (median(t_extract), median(t_search), median(t_refine));
    println!(
        "bench global: A {} voxels ({}), B {} voxels ({}) at {} m of {}",
        ma.len(),
        p.a,
        mb.len(),
        p.b,
        a.voxel,
        dir.display()
    );
    println!("  landmarks            {na} / {nb}");
    match &outcome {
        Some(o) => println!(
            "  correspondences      {} candidates, {} agree (runner-up {}): {}",
            o.candidates,
            o.agreeing,
            o.runner_up,
            if o.unique { "unique" } else { "not unique" }
        ),
        None => println!("  correspondences      too few agree"),
    }
    let (e_t, e_r) = errors(&to_matrix(&r.transform), &gt);
    println!("  result               {} (e_t {e_t:.3} m, e_r {e_r:.3} deg)", r.status.as_str());
    println!("  extract landmarks    {:.2} ms (both maps)", te * 1e3);
    println!("  correspondences      {:.2} ms", ts * 1e3);
    println!("  refine (matcher)     {:.2} ms", tr * 1e3);
    println!("  global alignment     {:.2} ms in all", (te + ts + tr) * 1e3);
    println!("  (median of {} runs, single thread; maps prepared beforehand)", a.repeat.max(1));
    Ok(())
}

/// Strict success of matching ranges `a` and `b` of `dir` over the grid of
/// starts, and robot A's map size.
fn strict_success(dir: &std::path::Path, a: FrameRange, b: FrameRange, stride: usize) -> Result<(f64, usize), Error> {
    use cosem_core::matching::{MatchSettings, MatchStatus, Matcher};
    use cosem_host::align::{errors, grid, prepare, to_matrix, DEFAULT_LEVELS};
    let seq = Sequence::open(dir)?;
    let filter = PointFilter::default();
    let (ma, _) = cosem_host::mapping::build_map(&seq.load_range(a)?, MapConfig::default(), &filter)?;
    let (mb, _) = cosem_host::mapping::build_map(&seq.load_range(b)?, MapConfig::default(), &filter)?;
    let gt = seq.relative_pose(a.start, b.start)?;
    let (pa, pb) = (prepare(&ma, DEFAULT_LEVELS)?, prepare(&mb, DEFAULT_LEVELS)?);
    let matcher = Matcher::new(MatchSettings::default());
    let starts = grid(stride);
    let mut ok = 0;
    for s in &starts {
        let r = matcher.align(&pa, &pb, &cosem_host::pose::to_isometry(&s.apply(&gt)))?;
        let (et, er) = errors(&to_matrix(&r.transform), &gt);
        ok += usize::from(r.status == MatchStatus::Converged && et < 0.5 && er < 1.0);
    }
    Ok((ok as f64 / starts.len().max(1) as f64, ma.len()))
}

/// One row of `cosem bench label`.
fn label_row(seed: &str, name: &str, figures: Option<&cosem_host::label::LabelStats>, rate: f64, voxels: usize) {
    let pct = |v: Option<f64>| v.map(|v| format!("{:.2}%", 100.0 * v)).unwrap_or_else(|| "-".into());
    println!(
        "  {:<8} {:<26} {:>8} {:>10} {:>8} {:>11} {:>7.1}%",
        seed,
        name,
        figures.map(|s| format!("{:.1}", s.points as f64 / s.label_seconds.max(1e-9) / 1e6)).unwrap_or("-".into()),
        pct(figures.and_then(|s| s.agreement())),
        pct(figures.and_then(|s| s.agreement_in_set())),
        voxels,
        100.0 * rate
    );
}

fn label_options(
    data: PathBuf,
    seg: PathBuf,
    probabilities: bool,
    frames: Option<Vec<usize>>,
    out: PathBuf,
) -> cosem_host::label::LabelOptions {
    cosem_host::label::LabelOptions {
        data,
        seg,
        camera: 2,
        classes: cosem_core::camera::SegClasses::Cityscapes,
        probabilities,
        occlusion: true,
        image_size: None,
        frames,
        out,
    }
}

fn bench_label(a: LabelArgs) -> Result<(), Error> {
    use cosem_core::camera::SegClasses;
    use cosem_host::label::label_sequence;
    use cosem_host::synth::{write_sequence, SegRender, SynthConfig, SEG_DIR};
    if a.frames < 4 {
        return Err("--frames must be at least 4".into());
    }
    let tmp = TempDir(std::env::temp_dir().join(format!("cosem-bench-label-{}", std::process::id())));
    let half = a.frames / 2;
    let (ra, rb) =
        (FrameRange { start: 0, end: half, stride: 1 }, FrameRange { start: half, end: a.frames, stride: 1 });
    println!(
        "bench label: camera 2, Cityscapes ids; strict success over {} starts of the paper's grid",
        cosem_host::align::grid(a.grid_stride).len()
    );
    println!(
        "  {:<8} {:<26} {:>8} {:>10} {:>8} {:>11} {:>8}",
        "seq", "labels", "M pts/s", "agreement", "in set", "A voxels", "strict"
    );
    for &seed in &a.seeds {
        let cs = SegClasses::Cityscapes;
        let variants: [(&str, Option<SegRender>); 4] = [
            ("ground truth (LiDAR)", None),
            ("camera, perfect", Some(SegRender { classes: cs, corrupt: false, probabilities: false })),
            ("camera, corrupted", Some(SegRender { classes: cs, corrupt: true, probabilities: false })),
            ("camera, corrupted, probs", Some(SegRender { classes: cs, corrupt: true, probabilities: true })),
        ];
        for (k, (name, seg)) in variants.into_iter().enumerate() {
            let src = tmp.0.join(format!("s{seed}-{k}"));
            let cfg = SynthConfig { frames: a.frames, seed, seg, ..SynthConfig::default() };
            write_sequence(&src, &cfg)?;
            let (dir, figures) = match seg {
                None => (src.clone(), None),
                Some(r) => {
                    let out = tmp.0.join(format!("l{seed}-{k}"));
                    let opts = label_options(src.clone(), src.join(SEG_DIR), r.probabilities, None, out.clone());
                    (out, Some(label_sequence(&opts)?))
                }
            };
            let (rate, voxels) = strict_success(&dir, ra, rb, a.grid_stride)?;
            label_row(&format!("synth {seed}"), name, figures.as_ref(), rate, voxels);
        }
    }
    if let Some(data) = &a.data {
        // Real scans have no camera images here: splat their labelled points
        // into camera 2 as a stand-in for a network's output.
        let seq = Sequence::open(data)?;
        let frames: Vec<usize> = a.a.frames().chain(a.b.frames()).collect();
        let name = data.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let (rate, voxels) = strict_success(data, a.a, a.b, a.grid_stride)?;
        label_row(&name, "ground truth (LiDAR)", None, rate, voxels);
        let mut rng = cosem_host::rng::Rng::new(1);
        for (k, corrupt) in [false, true].into_iter().enumerate() {
            let seg = tmp.0.join(format!("real-seg-{k}"));
            std::fs::create_dir_all(&seg)?;
            for &f in &frames {
                let scan = seq.read_scan(f)?;
                let path = seg.join(format!("{f:06}.png"));
                let cam = cosem_host::label::camera_of(&seq, 2, cosem_host::synth::IMAGE_SIZE, &path)?;
                let im =
                    cosem_host::label::splat_segmentation(&cam, &scan.points, &scan.labels, SegClasses::Cityscapes);
                let im = if corrupt { cosem_host::synth::corrupt(&im, SegClasses::Cityscapes, &mut rng) } else { im };
                cosem_host::label::write_seg_png(&path, &im)?;
            }
            let out = tmp.0.join(format!("real-out-{k}"));
            let s = label_sequence(&label_options(data.clone(), seg, false, Some(frames.clone()), out.clone()))?;
            let (rate, voxels) = strict_success(&out, a.a, a.b, a.grid_stride)?;
            let label = if corrupt { "splatted camera, corrupted" } else { "splatted camera" };
            label_row(&name, label, Some(&s), rate, voxels);
        }
    }
    println!("  (M pts/s: projection and lookup of every point of a scan, single thread; agreement over the");
    println!("   points camera 2 sees; 'in set': as Cityscapes ids can say it, trunks being vegetation there)");
    Ok(())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn bench_map(a: MapArgs) -> Result<(), Error> {
    let (dir, _tmp) = data_dir(a.data, a.frames.end)?;
    let seq = Sequence::open(&dir)?;
    let frames = seq.load_range(a.frames)?;
    let filter = PointFilter { max_range: None, moving: MovingObjects::Skip };
    let labelled: Vec<([f32; 3], Class)> = frames
        .iter()
        .flat_map(|f| f.points.iter().zip(&f.ranges).zip(&f.labels).map(|((p, r), l)| (*p, *r, *l)))
        .filter_map(|(p, r, l)| filter.keep(r, l).map(|c| (p, c)))
        .collect();
    let raw_points: usize = frames.iter().map(|f| f.points.len()).sum();
    let config = MapConfig::with_resolution(a.voxel);
    let mut map = new_map(labelled.len(), config)?;
    let repeat = a.repeat.max(1);
    let mut insert_times = Vec::new();
    let mut full_times = Vec::new();
    for _ in 0..repeat {
        map.clear();
        let t = Instant::now();
        for (p, c) in &labelled {
            map.insert_point(*p, *c)?;
        }
        insert_times.push(t.elapsed().as_secs_f64());
        map.clear();
        // Raw labels through the class map and range filter, then fused.
        let t = Instant::now();
        for f in &frames {
            for ((p, &r), &l) in f.points.iter().zip(&f.ranges).zip(&f.labels) {
                if let Some(c) = filter.keep(r, l) {
                    map.insert_point(*p, c)?;
                }
            }
        }
        full_times.push(t.elapsed().as_secs_f64());
    }
    let ti = median(insert_times);
    let tf = median(full_times);
    let mut coarse = new_map(map.len(), config)?;
    let t = Instant::now();
    map.coarsen_into(5, &mut coarse)?;
    let t_coarse = t.elapsed().as_secs_f64();
    let file_bytes = cosem_host::cmap::encode(&map, None, None).len();
    println!("bench map: {} frames {} of {}", frames.len(), a.frames, dir.display());
    println!("  points read          {raw_points}");
    println!("  points fused         {}", labelled.len());
    println!("  voxels               {} at {} m", map.len(), a.voxel);
    println!(
        "  insert               {:.1} M points/s ({:.1} ns/point, {:.2} ms per 120k-point scan)",
        labelled.len() as f64 / ti / 1e6,
        ti / labelled.len() as f64 * 1e9,
        ti / labelled.len() as f64 * 120_000.0 * 1e3
    );
    println!("  classify + insert    {:.1} M points/s over all {raw_points} points read", raw_points as f64 / tf / 1e6);
    println!("  coarsen x5           {:.2} ms -> {} voxels at {} m", t_coarse * 1e3, coarse.len(), a.voxel * 5.0);
    println!("  memory per voxel     {BYTES_PER_VOXEL} bytes (24 voxel + 8 index, load factor <= 0.5)");
    println!("  file per voxel       {:.2} bytes ({file_bytes} bytes)", file_bytes as f64 / map.len().max(1) as f64);
    println!("  (median of {repeat} runs, single thread)");
    Ok(())
}

/// Removes a temporary folder when dropped.
pub struct TempDir(pub PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
