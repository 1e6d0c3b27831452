//! The measurements behind `cosem bench`: each function runs one benchmark
//! and returns its figures (the command prints them). Times are medians of
//! repeated single-threaded runs.

use crate::error::Error;
use crate::evaluation::eval::{grid, STRICT};
use crate::evaluation::pair::{Pair, PairSpec};
use crate::evaluation::stats::median;
use crate::knobs::Knob;
use crate::lines::exchange::simulate_exchange;
use crate::maps::mapping::{new_map, HostMap, PointFilter};
use crate::matching::align::{prepare, DEFAULT_LEVELS};
use crate::paths::TempDir;
use crate::sources::kitti::{Frame, FrameRange, Sequence};
use cosem_core::classes::Class;
use cosem_core::geometry::errors_of;
use cosem_core::map::MapConfig;
use cosem_core::matching::{MatchResult, MatchSettings};
use cosem_core::sim::{Mix, SimConfig};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Seconds of `f`'s median run over `repeat` runs (at least one), and the
/// last run's value.
pub fn timed<T>(repeat: usize, mut f: impl FnMut() -> Result<T, Error>) -> Result<(f64, T), Error> {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        last = Some(f()?);
        times.push(t.elapsed().as_secs_f64());
    }
    let value = last.ok_or_else(|| Error::Invalid("no run".into()))?;
    Ok((median(&times).unwrap_or(0.0), value))
}

/// Figures of `cosem bench map`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MapFigures {
    /// Points read.
    pub points: usize,
    /// Points with a class, fused.
    pub fused: usize,
    /// Voxels of the map.
    pub voxels: usize,
    /// Median seconds to insert the labelled points.
    pub insert_s: f64,
    /// Median seconds to classify and insert every point read.
    pub classify_insert_s: f64,
    /// Seconds to coarsen by 5, and the coarse map's voxels.
    pub coarsen: (f64, usize),
    /// Bytes of the map file.
    pub file_bytes: usize,
}

/// Insertion throughput and sizes over `frames`.
pub fn map(frames: &[Frame], voxel: f32, repeat: usize) -> Result<MapFigures, Error> {
    let filter = PointFilter::default();
    let labelled: Vec<([f32; 3], Class)> = frames
        .iter()
        .flat_map(|f| f.points.iter().zip(&f.ranges).zip(&f.labels).map(|((p, r), l)| (*p, *r, *l)))
        .filter_map(|(p, r, l)| filter.keep(r, l).flatten().map(|c| (p, c)))
        .collect();
    let config = MapConfig::with_resolution(voxel);
    let mut map = new_map(labelled.len(), config)?;
    let (insert_s, _) = timed(repeat, || {
        map.clear();
        for (p, c) in &labelled {
            map.insert_point(*p, *c).map_err(|e| Error::Invalid(e.to_string()))?;
        }
        Ok(())
    })?;
    let (classify_insert_s, _) = timed(repeat, || {
        map.clear();
        crate::maps::mapping::fuse_frames(&mut map, frames, &filter)?;
        Ok(())
    })?;
    let mut coarse = new_map(map.len(), config)?;
    let t = Instant::now();
    map.coarsen_into(5, &mut coarse).map_err(|e| Error::Invalid(format!("{e:?}")))?;
    let coarsen = (t.elapsed().as_secs_f64(), coarse.len());
    Ok(MapFigures {
        points: frames.iter().map(|f| f.points.len()).sum(),
        fused: labelled.len(),
        voxels: map.len(),
        insert_s,
        classify_insert_s,
        coarsen,
        file_bytes: crate::maps::cmap::encode(&map, None, None).len(),
    })
}

/// Figures of `cosem bench wire`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct WireFigures {
    /// Voxels encoded.
    pub voxels: usize,
    /// Bytes of encoding, and in how many chunks.
    pub bytes: (usize, usize),
    /// Median seconds to encode and to decode.
    pub encode_s: f64,
    /// Median seconds to decode.
    pub decode_s: f64,
}

/// Encode and decode throughput of the compact encoding in link-sized chunks.
pub fn wire(map: &HostMap, repeat: usize) -> Result<WireFigures, Error> {
    let (encode_s, chunks) = timed(repeat, || Ok(crate::maps::cmap::encode_chunks(map, 240)))?;
    let (decode_s, out) = timed(repeat, || {
        let mut out = new_map(map.len(), *map.config())?;
        let mut model = Box::new(cosem_core::wire::CodecModel::new());
        let mut d = cosem_core::wire::MapDecoder::new(map.len(), &mut model);
        for c in &chunks {
            d.decode_chunk(&mut model, c, &mut out).map_err(|e| Error::Invalid(e.to_string()))?;
        }
        Ok(out)
    })?;
    if out.len() != map.len() {
        return Err(Error::Invalid("decoded map lost voxels".into()));
    }
    Ok(WireFigures { voxels: map.len(), bytes: (chunks.iter().map(Vec::len).sum(), chunks.len()), encode_s, decode_s })
}

/// Figures of one simulated exchange (`cosem bench link`).
#[derive(Clone, Debug)]
pub struct LinkFigures {
    /// Byte error rate.
    pub rate: f64,
    /// Shares of the damage: bit flips, substituted, dropped, duplicated.
    pub mix: [f64; 4],
    /// Simulated seconds until A's map, then B's, was through (`None`: never).
    pub through_s: [Option<f64>; 2],
    /// Simulated seconds until both ends were over (closing included).
    pub over_s: f64,
    /// Bytes each side sent.
    pub bytes: [u64; 2],
    /// Bytes of each side's map stream (header and encoded voxels).
    pub stream_bytes: [u64; 2],
    /// Retransmissions of each side.
    pub retransmissions: [u32; 2],
    /// Both maps arrived whole (digest checked) and both ends ended well.
    pub delivered: bool,
}

/// Both maps of `pair` exchanged over a simulated line of `baud` with byte
/// error `rate` damaging bytes as `mix` says (seeded by `seed`), full
/// duplex (both at once) or half (one after the other), in simulated time.
pub fn link(
    pair: &Pair,
    (rate, mix, half_duplex): (f64, Mix, bool),
    baud: u32,
    seed: u64,
) -> Result<LinkFigures, Error> {
    let line = SimConfig { error_rate: rate, mix, half_duplex, ..SimConfig::clean(baud, seed) };
    let x = simulate_exchange(&pair.map_a, &pair.map_b, line)?;
    let [a, b] = x.stats;
    Ok(LinkFigures {
        rate,
        mix: [mix.bit, mix.byte, mix.drop, mix.dup],
        through_s: x.through_s,
        over_s: x.over_s,
        bytes: [a.bytes_sent, b.bytes_sent],
        stream_bytes: [a.chunk_bytes_sent, b.chunk_bytes_sent],
        retransmissions: [a.retransmissions, b.retransmissions],
        delivered: x.delivered,
    })
}

/// The most data per byte of line a retransmission scheme gets, with
/// `overhead` bytes a frame, at byte error rate `p`, when the receiver
/// repairs a frame whose only damage is one error of a kind that is a
/// fraction `repairable` of all errors: max over frame lengths L of
/// (L - h) / L * ((1 - p)^L + L p r (1 - p)^(L - 1)). With `repairable` 0,
/// the bound of any scheme without forward error correction.
pub fn goodput_bound(p: f64, overhead: usize, repairable: f64) -> f64 {
    let h = overhead as f64;
    (overhead + 1..4096)
        .map(|l| {
            let n = l as f64;
            let arrive = (1.0 - p).powi(l as i32) + n * p * repairable * (1.0 - p).powi(l as i32 - 1);
            (n - h) / n * arrive
        })
        .fold(0.0, f64::max)
}

/// The capacity of a line that substitutes a fraction `p` of its bytes
/// (a 256-ary symmetric channel), as a fraction of its raw rate:
/// `(8 - H(p) - p log2 255) / 8`. Drops and duplicates cost more, and no
/// simple closed form bounds them: this is the floor of what any code
/// could do at this error rate.
pub fn capacity_bound(p: f64) -> f64 {
    if p <= 0.0 {
        return 1.0;
    }
    let p = p.min(1.0);
    let h = if p >= 1.0 { 0.0 } else { -p * p.log2() - (1.0 - p) * (1.0 - p).log2() };
    ((8.0 - h - p * 255f64.log2()) / 8.0).max(0.0)
}

/// The simulator's flips garble a whole byte (not repairable); its
/// duplicated bytes are: a third of its errors.
pub const SIM_REPAIRABLE: f64 = 1.0 / 3.0;

/// Many seeded exchanges at one error rate, summarised.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LinkSummary {
    /// Version of these fields (2: `mix` and `capacity` added).
    pub schema: u32,
    /// Byte error rate.
    pub rate: f64,
    /// Shares of the damage: bit flips, substituted, dropped, duplicated.
    pub mix: [f64; 4],
    /// Runs that delivered both maps, and runs.
    pub delivered: (usize, usize),
    /// Median seconds until both maps were through, and until both ends
    /// were over (delivered runs).
    pub median_s: (f64, f64),
    /// Slowest delivered run: both maps through (s).
    pub worst_s: f64,
    /// Median goodput: map bytes over line bytes in the time each map took.
    pub goodput: f64,
    /// [`goodput_bound`] with this protocol's frame overhead, without and
    /// with the deframer's repair of the simulator's duplicated bytes.
    pub bound: [f64; 2],
    /// [`capacity_bound`] at this error rate.
    pub capacity: f64,
    /// Median retransmissions per run (both sides).
    pub retransmissions: f64,
    /// Stream bytes of A's and B's map.
    pub stream_bytes: [u64; 2],
}

impl LinkSummary {
    /// Summarises `runs` (one error rate) on a line of `baud`.
    pub fn of(runs: &[LinkFigures], baud: u32) -> Self {
        let line_bytes_per_s = f64::from(baud) / 10.0;
        let ok: Vec<&LinkFigures> = runs.iter().filter(|r| r.delivered).collect();
        let median = |v: Vec<f64>| crate::evaluation::stats::quantile(&v, 0.5).unwrap_or(f64::NAN);
        let both = |r: &LinkFigures| r.through_s[0].unwrap_or(f64::NAN).max(r.through_s[1].unwrap_or(f64::NAN));
        let goodput: Vec<f64> = ok
            .iter()
            .flat_map(|r| {
                (0..2).filter_map(move |d| r.through_s[d].map(|t| r.stream_bytes[d] as f64 / (t * line_bytes_per_s)))
            })
            .collect();
        LinkSummary {
            schema: 2,
            rate: runs.first().map(|r| r.rate).unwrap_or(0.0),
            mix: runs.first().map(|r| r.mix).unwrap_or([0.0; 4]),
            delivered: (ok.len(), runs.len()),
            median_s: (median(ok.iter().map(|r| both(r)).collect()), median(ok.iter().map(|r| r.over_s).collect())),
            worst_s: ok.iter().map(|r| both(r)).fold(0.0, f64::max),
            goodput: median(goodput),
            bound: {
                let (p, h) = (runs.first().map(|r| r.rate).unwrap_or(0.0), cosem_core::wire::message::DATA_OVERHEAD);
                [goodput_bound(p, h, 0.0), goodput_bound(p, h, SIM_REPAIRABLE)]
            },
            capacity: capacity_bound(runs.first().map(|r| r.rate).unwrap_or(0.0)),
            retransmissions: median(
                runs.iter().map(|r| f64::from(r.retransmissions[0] + r.retransmissions[1])).collect(),
            ),
            stream_bytes: runs.first().map(|r| r.stream_bytes).unwrap_or([0, 0]),
        }
    }
}

impl std::fmt::Display for LinkSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "  byte errors {:>4.1}% (bit {}, byte {}, drop {}, dup {}): {}/{} delivered whole; both maps through in {:.2} s median ({:.2} s worst), ends over {:.2} s; goodput {:.0}% of the line (capacity bound {:.0}%; without FEC at most {:.0}%, with one-error repair {:.0}%); {:.0} retransmissions; {} + {} map bytes",
            self.rate * 100.0,
            self.mix[0],
            self.mix[1],
            self.mix[2],
            self.mix[3],
            self.delivered.0,
            self.delivered.1,
            self.median_s.0,
            self.worst_s,
            self.median_s.1,
            self.goodput * 100.0,
            self.capacity * 100.0,
            self.bound[0] * 100.0,
            self.bound[1] * 100.0,
            self.retransmissions,
            self.stream_bytes[0],
            self.stream_bytes[1],
        )
    }
}

/// Figures of `cosem bench global`.
#[derive(Clone, Debug)]
pub struct GlobalFigures {
    /// What the coarse search found (its best candidate only, as the
    /// prior-free alignment first asks).
    pub outcome: Option<cosem_core::matching::search::GlobalSearchOutcome>,
    /// The refined result.
    pub result: MatchResult,
    /// Its errors against the truth (m, degrees).
    pub errors: (f64, f64),
    /// Median seconds: coarse search over every heading and offset, then
    /// the whole prior-free alignment (search and refinement).
    pub seconds: [f64; 2],
}

/// Prior-free alignment of `pair`, stage by stage (maps prepared first).
pub fn global(pair: &Pair, repeat: usize) -> Result<GlobalFigures, Error> {
    use cosem_core::matching::search::{search_global, GlobalSearch};
    let (pa, pb) = (prepare(&pair.map_a, DEFAULT_LEVELS)?, prepare(&pair.map_b, DEFAULT_LEVELS)?);
    let no_footprint = || Error::Invalid("a map has no footprint".into());
    let (fa, fb) = (pa.footprint().ok_or_else(no_footprint)?, pb.footprint().ok_or_else(no_footprint)?);
    let first = GlobalSearch { candidates: 1, ..GlobalSearch::default() };
    let (t_search, outcome) = timed(repeat, || Ok(search_global(fa, fb, &first, true)))?;
    let (t_all, (result, _)) =
        timed(repeat, || Ok(crate::matching::align::align(MatchSettings::default(), None, (&pa, &pb))?))?;
    Ok(GlobalFigures { outcome, result, errors: errors_of(&result.transform, &pair.gt), seconds: [t_search, t_all] })
}

/// Strict success of matching ranges `a` and `b` of `dir` (0.2 m maps)
/// from the paper's grid thinned by `stride`, and robot A's voxels.
pub fn strict_success(dir: &Path, a: FrameRange, b: FrameRange, stride: usize) -> Result<(f64, usize), Error> {
    let pair = Pair::load(&PairSpec::new(dir, a, b, 0.2))?;
    let (pa, pb) = (prepare(&pair.map_a, DEFAULT_LEVELS)?, prepare(&pair.map_b, DEFAULT_LEVELS)?);
    let starts = grid(stride);
    let mut ok = 0;
    for s in &starts {
        let prior = s.apply(&pair.gt).cast::<f32>();
        let (r, _) = crate::matching::align::align(MatchSettings::default(), Some(&prior), (&pa, &pb))?;
        let (et, er) = errors_of(&r.transform, &pair.gt);
        ok += usize::from(STRICT.met(r.status, et, er));
    }
    Ok((ok as f64 / starts.len().max(1) as f64, pair.map_a.len()))
}

/// Where real data lives: `COSEM_DATA`, else `../shared/data` (relative to
/// the repository root, where the commands are run from).
pub fn data_root() -> PathBuf {
    std::env::var_os("COSEM_DATA").map_or_else(|| PathBuf::from("../shared/data"), PathBuf::from)
}

/// The most frames a benchmark synthesises when it has no data.
pub const MAX_SYNTHETIC_FRAMES: usize = 1000;

/// The sequence to benchmark on: `given`, else `kitti00` under
/// [`data_root`], else a fresh synthetic one of `frames` frames (removed
/// when the returned guard drops: its presence says it is synthetic).
pub fn data_dir(given: Option<PathBuf>, frames: usize) -> Result<(PathBuf, Option<TempDir>), Error> {
    if let Some(d) = given {
        return Ok((d, None));
    }
    let kitti = data_root().join("kitti00");
    if kitti.join("poses.txt").exists() {
        return Ok((kitti, None));
    }
    if frames > MAX_SYNTHETIC_FRAMES {
        return Err(Error::Invalid(format!(
            "frames up to {frames}: no {} and no kitti00 under {}, and a synthetic sequence has at most \
             {MAX_SYNTHETIC_FRAMES} frames here",
            Knob::Data,
            data_root().display()
        )));
    }
    let tmp = TempDir::new("cosem-bench");
    let cfg = crate::worlds::synth::SynthConfig { frames, ..Default::default() };
    crate::worlds::synth::write_sequence(&tmp.0, &cfg).map_err(|source| Error::Io { path: tmp.0.clone(), source })?;
    Ok((tmp.0.clone(), Some(tmp)))
}

/// The frames of a range of a source of scans (a folder, a recording, a
/// folder of PCD/PLY scans).
pub fn frames(
    dir: &Path,
    range: FrameRange,
    options: &crate::sources::source::SourceOptions,
) -> Result<Vec<Frame>, Error> {
    Ok(crate::sources::source::Source::open(dir, options)?.load(Some(range))?.0)
}

/// One row of `cosem bench label`.
#[derive(Clone, Debug)]
pub struct LabelRow {
    /// The sequence.
    pub seq: String,
    /// Where its labels came from.
    pub labels: &'static str,
    /// Labelling figures (camera rows).
    pub figures: Option<crate::camera::label::LabelStats>,
    /// Strict success over the grid.
    pub strict: f64,
    /// Robot A's voxels.
    pub voxels: usize,
}

fn label_options(
    data: PathBuf,
    seg: PathBuf,
    probabilities: bool,
    frames: Vec<FrameRange>,
    out: PathBuf,
) -> crate::camera::label::LabelOptions {
    crate::camera::label::LabelOptions {
        data,
        seg,
        camera: 2,
        classes: cosem_core::camera::SegClasses::Cityscapes,
        probabilities,
        occlusion: true,
        image_size: None,
        frames,
        out,
        copy_scans: false,
        void_channel: crate::camera::label::VoidChannel::None,
        scale_to_images: false,
    }
}

/// A synthetic street of `frames` frames (A the first half, B the rest)
/// labelled four ways: LiDAR ground truth, camera 2 perfect, corrupted, and
/// corrupted with probabilities; each matched over the grid (`stride`).
pub fn label_synthetic(seed: u64, frames: usize, stride: usize, tmp: &Path) -> Result<Vec<LabelRow>, Error> {
    use crate::worlds::synth::{write_sequence, SegRender, SynthConfig, SEG_DIR};
    let half = frames / 2;
    let (ra, rb) = (FrameRange { start: 0, end: half, stride: 1 }, FrameRange { start: half, end: frames, stride: 1 });
    let cs = cosem_core::camera::SegClasses::Cityscapes;
    let variants: [(&'static str, Option<SegRender>); 4] = [
        ("ground truth (LiDAR)", None),
        ("camera, perfect", Some(SegRender { classes: cs, corrupt: false, probabilities: false })),
        ("camera, corrupted", Some(SegRender { classes: cs, corrupt: true, probabilities: false })),
        ("camera, corrupted, probs", Some(SegRender { classes: cs, corrupt: true, probabilities: true })),
    ];
    let mut rows = Vec::new();
    for (k, (name, seg)) in variants.into_iter().enumerate() {
        let src = tmp.join(format!("s{seed}-{k}"));
        let cfg = SynthConfig { frames, seed, seg, ..SynthConfig::default() };
        write_sequence(&src, &cfg).map_err(|source| Error::Io { path: src.clone(), source })?;
        let (dir, figures) = match seg {
            None => (src.clone(), None),
            Some(r) => {
                let out = tmp.join(format!("l{seed}-{k}"));
                let opts = label_options(src.clone(), src.join(SEG_DIR), r.probabilities, Vec::new(), out.clone());
                (out, Some(crate::camera::label::label_sequence(&opts)?))
            }
        };
        let (strict, voxels) = strict_success(&dir, ra, rb, stride)?;
        rows.push(LabelRow { seq: format!("synth {seed}"), labels: name, figures, strict, voxels });
    }
    Ok(rows)
}

/// Real scans have no camera images here: each scan's labelled points are
/// splatted into camera 2 as a stand-in for a network's output (perfect,
/// then corrupted), labelled back and matched over the grid.
pub fn label_real(
    data: &Path,
    a: FrameRange,
    b: FrameRange,
    stride: usize,
    tmp: &Path,
) -> Result<Vec<LabelRow>, Error> {
    use crate::camera::label::{camera_of, label_sequence, splat_segmentation, write_seg_png};
    let cs = cosem_core::camera::SegClasses::Cityscapes;
    let seq = Sequence::open(data)?;
    let all = seq.scan_frames()?;
    let mut frames = a.select(&all, data)?;
    frames.extend(b.select(&all, data)?);
    let name = data.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let (strict, voxels) = strict_success(data, a, b, stride)?;
    let mut rows = vec![LabelRow { seq: name.clone(), labels: "ground truth (LiDAR)", figures: None, strict, voxels }];
    let mut rng = crate::rng::Rng::new(1);
    for (k, corrupt) in [false, true].into_iter().enumerate() {
        let seg = tmp.join(format!("real-seg-{k}"));
        std::fs::create_dir_all(&seg).map_err(|source| Error::Io { path: seg.clone(), source })?;
        for &f in &frames {
            let scan = seq.read_scan(f)?;
            let path = seg.join(format!("{f:06}.png"));
            let cam = camera_of(&seq, 2, crate::worlds::synth::IMAGE_SIZE, &path)?;
            let im = splat_segmentation(&cam, &scan.points, &scan.labels, cs);
            let im = if corrupt { crate::worlds::synth::corrupt(&im, cs, &mut rng) } else { im };
            write_seg_png(&path, &im).map_err(|source| Error::Io { path: path.clone(), source })?;
        }
        let out = tmp.join(format!("real-out-{k}"));
        let s = label_sequence(&label_options(data.to_path_buf(), seg, false, vec![a, b], out.clone()))?;
        let (strict, voxels) = strict_success(&out, a, b, stride)?;
        let labels = if corrupt { "splatted camera, corrupted" } else { "splatted camera" };
        rows.push(LabelRow { seq: name.clone(), labels, figures: Some(s), strict, voxels });
    }
    Ok(rows)
}

impl std::fmt::Display for MapFigures {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let per_point = self.insert_s / self.fused.max(1) as f64;
        let bpv = cosem_core::map::BYTES_PER_VOXEL;
        writeln!(f, "  points read          {}", self.points)?;
        writeln!(f, "  points fused         {}", self.fused)?;
        writeln!(f, "  voxels               {}", self.voxels)?;
        writeln!(
            f,
            "  insert               {:.1} M points/s ({:.1} ns/point, {:.2} ms per 120k-point scan)",
            1e-6 / per_point,
            per_point * 1e9,
            per_point * 120_000.0 * 1e3
        )?;
        let all = self.points as f64 / self.classify_insert_s / 1e6;
        writeln!(f, "  classify + insert    {all:.1} M points/s over all {} points read", self.points)?;
        writeln!(f, "  coarsen x5           {:.2} ms -> {} voxels", self.coarsen.0 * 1e3, self.coarsen.1)?;
        writeln!(f, "  memory per voxel     {bpv} bytes (24 voxel + 8 index, load factor <= 0.5)")?;
        let file = self.file_bytes as f64 / self.voxels.max(1) as f64;
        writeln!(f, "  file per voxel       {file:.2} bytes ({} bytes)", self.file_bytes)
    }
}

impl std::fmt::Display for WireFigures {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (bytes, chunks) = self.bytes;
        let per_voxel = bytes as f64 / self.voxels.max(1) as f64;
        writeln!(
            f,
            "  encoding             {bytes} bytes in {chunks} chunks of <= 240 bytes: {per_voxel:.2} bytes/voxel"
        )?;
        for (name, s, what) in [("encode", self.encode_s, "output"), ("decode", self.decode_s, "input")] {
            let (v, mb) = (self.voxels as f64 / s / 1e6, bytes as f64 / s / 1e6);
            writeln!(f, "  {name}               {v:.1} M voxels/s ({mb:.1} MB/s of {what}, {:.2} ms)", s * 1e3)?;
        }
        Ok(())
    }
}

impl std::fmt::Display for GlobalFigures {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.outcome {
            Some(o) => {
                writeln!(f, "  coarse search        best score {}, {} nodes scored", o.scores().0, o.evaluations)?
            }
            None => writeln!(f, "  coarse search        no footprint")?,
        }
        let [ts, tall] = self.seconds;
        let (e_t, e_r) = self.errors;
        let r = &self.result;
        writeln!(f, "  result               {} (e_t {e_t:.3} m, e_r {e_r:.3} deg)", r.status.as_str())?;
        writeln!(
            f,
            "  agreement            {:.3} (coverage {:.3}, overlap {:.3})",
            r.agreement, r.coverage, r.overlap
        )?;
        writeln!(f, "  coarse search        {:.2} ms", ts * 1e3)?;
        writeln!(f, "  prior-free in all    {:.2} ms (search and refinement)", tall * 1e3)
    }
}

/// One row of `cosem bench label` as JSON (`--json`).
#[derive(Clone, Debug, serde::Serialize)]
pub struct LabelFigures {
    /// The sequence.
    pub seq: String,
    /// Where its labels came from.
    pub labels: &'static str,
    /// Points projected and looked up per second (camera rows).
    pub points_per_s: Option<f64>,
    /// Share of the camera's points whose class is the truth's (camera rows).
    pub agreement: Option<f64>,
    /// The same, as Cityscapes' classes can say it.
    pub agreement_in_set: Option<f64>,
    /// Robot A's voxels.
    pub voxels: usize,
    /// Strict success over the grid.
    pub strict: f64,
}

impl LabelRow {
    /// The row's figures for JSON.
    pub fn figures(&self) -> LabelFigures {
        let s = self.figures.as_ref();
        LabelFigures {
            seq: self.seq.clone(),
            labels: self.labels,
            points_per_s: s.map(|s| s.points as f64 / s.label_seconds.max(1e-9)),
            agreement: s.and_then(|s| s.agreement()),
            agreement_in_set: s.and_then(|s| s.agreement_in_set()),
            voxels: self.voxels,
            strict: self.strict,
        }
    }
}

impl std::fmt::Display for LabelRow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pct = |v: Option<f64>| v.map(|v| format!("{:.2}%", 100.0 * v)).unwrap_or_else(|| "-".into());
        let s = self.figures.as_ref();
        let rate = s.map(|s| format!("{:.1}", s.points as f64 / s.label_seconds.max(1e-9) / 1e6));
        write!(
            f,
            "  {:<8} {:<26} {:>8} {:>10} {:>8} {:>11} {:>7.1}%",
            self.seq,
            self.labels,
            rate.unwrap_or_else(|| "-".into()),
            pct(s.and_then(|s| s.agreement())),
            pct(s.and_then(|s| s.agreement_in_set())),
            self.voxels,
            100.0 * self.strict
        )
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_capacity_of_a_substituting_line() {
        // The figure: 5% substituted bytes leave about 91%.
        assert!((super::capacity_bound(0.05) - 0.914).abs() < 0.001);
        assert_eq!(super::capacity_bound(0.0), 1.0);
        assert!(super::capacity_bound(0.2) > 0.6 && super::capacity_bound(0.2) < super::capacity_bound(0.1));
        // Every value equally likely: nothing gets through.
        assert!(super::capacity_bound(255.0 / 256.0) < 1e-9);
    }
}

/// `cosem bench segment`: one network run over the same images on one
/// core, then on all (the second after a first that warmed the caches).
#[derive(Clone, Debug, serde::Serialize)]
pub struct SegmentFigures {
    /// The images.
    pub images_dir: PathBuf,
    /// How they met the network.
    pub fit: String,
    /// Images segmented.
    pub images: usize,
    /// The network's input (height, width).
    pub input: (usize, usize),
    /// Images at once.
    pub threads: usize,
    /// Milliseconds per image, wall time.
    pub ms_per_image: f64,
}

impl std::fmt::Display for SegmentFigures {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "bench segment: {} images of {} ({} fit), network {}x{}: {} thread(s): {:.0} ms per image ({:.2} images/s)",
            self.images,
            self.images_dir.display(),
            self.fit,
            self.input.1,
            self.input.0,
            self.threads,
            self.ms_per_image,
            1000.0 / self.ms_per_image
        )
    }
}

/// Segments `frames` of `images` with `model` on one core, then on all
/// (feature `segment`; without it an error saying how to build it).
pub fn segment(
    model: &Path,
    images: &Path,
    frames: FrameRange,
    fit: crate::camera::seg_files::Fit,
) -> Result<Vec<SegmentFigures>, Error> {
    #[cfg(feature = "segment")]
    {
        use crate::camera::segment::{segment_folder, SegmentOptions};
        let tmp = TempDir::new("cosem-bench-segment");
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let mut figures = Vec::new();
        for threads in [1, cores] {
            let opts = SegmentOptions {
                model: model.to_path_buf(),
                images: images.to_path_buf(),
                out: tmp.0.join(format!("t{threads}")),
                frames: Some(frames),
                probabilities: false,
                fit,
                threads,
                check: None,
                overlay: false,
            };
            let s = segment_folder(&opts, &|| {})?;
            figures.push(SegmentFigures {
                images_dir: images.to_path_buf(),
                fit: fit.to_string(),
                images: s.images,
                input: s.input,
                threads,
                ms_per_image: s.ms_per_image,
            });
        }
        Ok(figures)
    }
    #[cfg(not(feature = "segment"))]
    {
        let _ = (model, images, frames, fit);
        Err(Error::Invalid(
            "bench segment needs the `segment` feature (tract-onnx): cargo build --release --features segment".into(),
        ))
    }
}
