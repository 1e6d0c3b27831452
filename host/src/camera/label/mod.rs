//! LiDAR labels from camera segmentation (`cosem label`): each scan's points
//! are projected into the segmentation image of one camera and take the
//! class of their pixel (core: [`cosem_core::camera`]). The result is a
//! SemanticKITTI-layout folder, so the rest of the tool chain is unchanged.
//!
//! Segmentation images are 8-bit single-channel PNGs (grayscale or palette:
//! the stored value is the class id), one per scan and named like it
//! (`000042.png`). With probabilities, `000042.npy` holds the network's
//! per-pixel class probabilities (NumPy `.npy`, `<f4` or `|u1` scaled to
//! 255, shape `(H, W, C)` or `(C, H, W)`); each point's probabilities are
//! then turned into label evidence, written beside the labels as
//! `evidence/000042.bin` (four `u16` label slots per point, see
//! [`cosem_core::map::LabelDistribution::raw`]), which mapping fuses
//! instead of a hard label.

use crate::knobs::Knob;
use crate::sources::kitti::{KittiError, Sequence};
use cosem_core::camera::{evidence_from_probabilities, Camera, DepthGrid, Projection, SegClasses};
use cosem_core::classes::{Class, MovingObjects, NUM_CLASSES};
use cosem_core::map::{SensorModel, LABEL_SLOTS};
use std::path::{Path, PathBuf};

mod calibration;

use calibration::{camera_for, check_ids, check_size};
pub use calibration::{camera_of, parse_image_size};

/// Anything wrong with labelling a sequence.
#[derive(Debug, thiserror::Error)]
pub enum LabelError {
    /// A segmentation image or probability map.
    #[error(transparent)]
    Image(#[from] crate::camera::seg_files::ImageError),
    /// Reading the LiDAR sequence.
    #[error(transparent)]
    Kitti(#[from] KittiError),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A scan has no segmentation image.
    #[error("{path}: missing segmentation image for frame {frame}")]
    MissingImage {
        /// The expected image.
        path: PathBuf,
        /// The frame.
        frame: usize,
    },
    /// Not a PNG we can read as class ids.
    #[error("{path}: {what}")]
    Format {
        /// The image.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// An image of another size than the others (or than asked for).
    #[error("{path}: image is {got_w}x{got_h}, expected {want_w}x{want_h}")]
    ImageSize {
        /// The image.
        path: PathBuf,
        /// Its width.
        got_w: u32,
        /// Its height.
        got_h: u32,
        /// The expected width.
        want_w: u32,
        /// The expected height.
        want_h: u32,
    },
    /// A pixel value with no class in the class set.
    #[error("{path}: pixel ({u}, {v}) has class id {id}, not a {classes} id")]
    UnknownClass {
        /// The image.
        path: PathBuf,
        /// Column.
        u: u32,
        /// Row.
        v: u32,
        /// The value.
        id: u8,
        /// The class set's name.
        classes: &'static str,
    },
    /// A bad probability vector.
    #[error("{path}: pixel ({u}, {v}): {what}")]
    Probability {
        /// The probability file.
        path: PathBuf,
        /// Column.
        u: u32,
        /// Row.
        v: u32,
        /// What is wrong.
        what: String,
    },
    /// The calibration cannot make a camera.
    #[error("{path}: camera {camera}: {what}")]
    Camera {
        /// calib.txt.
        path: PathBuf,
        /// The camera.
        camera: u8,
        /// What is wrong.
        what: String,
    },
}

impl crate::error::LayerError for LabelError {}

pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> LabelError + '_ {
    move |source| LabelError::Io { path: path.to_path_buf(), source }
}

pub use crate::camera::seg_files::{
    read_probabilities, read_probabilities_of, read_seg_png, write_probabilities, write_seg_png, ProbabilityMap,
    SegImage, VoidChannel,
};

/// `cosem label --model NET --images DIR`: the images segmented first
/// ([`label_from_images`], feature `segment`; without it an
/// error saying how to build it), then labelled. Returns the counts, the
/// images segmented and the milliseconds per image.
pub fn label_with_model(
    o: &LabelOptions,
    model: &Path,
    images: &Path,
    fit: crate::camera::seg_files::Fit,
) -> Result<(LabelStats, usize, f64), crate::error::Error> {
    #[cfg(feature = "segment")]
    {
        let (stats, s) = label_from_images(o, model, images, fit)?;
        Ok((stats, s.images, s.ms_per_image))
    }
    #[cfg(not(feature = "segment"))]
    {
        let _ = (o, model, images, fit);
        Err(crate::error::Error::Invalid(format!(
            "{} needs the `segment` feature (tract-onnx): cargo build --release --features segment",
            Knob::Model
        )))
    }
}

/// `cosem label --model NET --images DIR`: the images segmented (as `cosem
/// segment` would, on every core) into a new folder beside `o.out`, the
/// scans labelled from it (`o.seg` is set to it), and the segmentation kept
/// in OUT/seg_<camera>/ (a sequence folder's place for it, as `cosem synth`
/// writes it); removed when labelling fails.
#[cfg(feature = "segment")]
pub fn label_from_images(
    o: &LabelOptions,
    model: &Path,
    images: &Path,
    fit: crate::camera::seg_files::Fit,
) -> Result<(LabelStats, crate::camera::segment::SegmentSummary), crate::error::Error> {
    if o.frames.len() > 1 {
        return Err(crate::error::Error::Invalid(format!("{} labels one frame range at a time", Knob::Model)));
    }
    check_out(o, &[(Knob::Data.name(), &o.data), (Knob::Images.name(), images), (Knob::Model.name(), model)])?;
    let io = |source| crate::error::Error::Io { path: o.out.clone(), source };
    let dir = crate::paths::OutputDir::create(&o.out).map_err(io)?;
    let seg = dir.path().join(format!("seg_{}", o.camera));
    let opts = crate::camera::segment::SegmentOptions {
        model: model.to_path_buf(),
        images: images.to_path_buf(),
        out: seg.clone(),
        frames: o.frames.first().copied(),
        probabilities: o.probabilities,
        fit,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        check: None,
        overlay: false,
    };
    let summary = crate::camera::segment::segment_into(&opts, &|| {})?;
    // A network run here gives its void channel last.
    let void_channel = if o.probabilities { VoidChannel::Last } else { o.void_channel };
    let labelling = LabelOptions { seg, void_channel, out: dir.path().to_path_buf(), ..o.clone() };
    let stats = label_into(&labelling, &o.out.join(format!("seg_{}", o.camera)))?;
    dir.commit().map_err(io)?;
    Ok((stats, summary))
}

/// What `cosem label` does.
#[derive(Clone, Debug)]
pub struct LabelOptions {
    /// The LiDAR sequence (SemanticKITTI layout; labels not needed).
    pub data: PathBuf,
    /// Segmentation images (and probability maps), named like the scans.
    pub seg: PathBuf,
    /// Camera index in calib.txt (`P<camera>`).
    pub camera: u8,
    /// What the images' ids mean.
    pub classes: SegClasses,
    /// Use the `.npy` probability maps instead of the PNGs' hard ids.
    pub probabilities: bool,
    /// Expected image size; default: the first image's.
    pub image_size: Option<(u32, u32)>,
    /// Leave points hidden from the camera by nearer points unlabelled
    /// ([`DepthGrid`]).
    pub occlusion: bool,
    /// Frames to label, range after range, each checked against the
    /// scans in `velodyne/`; none: every scan there.
    pub frames: Vec<crate::sources::kitti::FrameRange>,
    /// The output folder.
    pub out: PathBuf,
    /// Copy the scans into the output instead of linking them (relative
    /// symbolic links by default).
    pub copy_scans: bool,
    /// A void channel in the probability maps.
    pub void_channel: VoidChannel,
    /// Scale the camera's projection to segmentation images of another
    /// size than the camera's (a network's output size).
    pub scale_to_images: bool,
}

/// Counts of one labelling run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LabelStats {
    /// Frames labelled.
    pub frames: usize,
    /// Points read.
    pub points: usize,
    /// Points projecting into the image and seen by the camera.
    pub in_view: usize,
    /// Points projecting into the image but hidden from the camera behind
    /// nearer points of the scan (left unlabelled).
    pub occluded: usize,
    /// In-view points given a class of the table.
    pub labelled: usize,
    /// In-view points whose existing (ground-truth) label has a class, when
    /// the input had labels.
    pub compared: usize,
    /// Of those, points whose new class equals the existing one.
    pub agreeing: usize,
    /// The camera's image size the projection was scaled from, when the
    /// segmentation is of another size (`--scale-to-images`).
    pub scaled_from: Option<(u32, u32)>,
    /// Of those, points whose new class equals the existing one as the
    /// class set can say it (Cityscapes has no trunk: a trunk seen as
    /// vegetation agrees here).
    pub agreeing_in_set: usize,
    /// Seconds spent projecting and labelling (reading and writing excluded).
    pub label_seconds: f64,
    /// Compared points by (truth, new class): row `t` (a class index, the
    /// truth as the class set can say it), column `c` (a class index, or
    /// [`NUM_CLASSES`] for none); empty until a point is compared.
    pub confusion: Vec<u64>,
}

/// How one class fared against the truth (see [`LabelStats::per_class`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ClassAgreement {
    /// The class.
    pub class: &'static str,
    /// Compared points whose truth is this class.
    pub truth_points: u64,
    /// Compared points labelled this class.
    pub labelled_points: u64,
    /// Of the truth's points, the share labelled this class.
    pub recall: Option<f64>,
    /// Of the points labelled this class, the share whose truth it is.
    pub precision: Option<f64>,
    /// What the truth's points were labelled instead, most first (at most
    /// three, each a share of the truth's points; "none": left unlabelled).
    pub confused_with: Vec<(&'static str, f64)>,
}

impl LabelStats {
    /// The figures in words, as `cosem label` prints them (`wall`: seconds
    /// in all, reading and writing included).
    pub fn text(&self, opts: &LabelOptions, wall: f64) -> String {
        let rate = self.points as f64 / self.label_seconds.max(1e-9);
        let pct = |n: usize, d: usize| 100.0 * n as f64 / d.max(1) as f64;
        let mut out = format!(
            "{}: {} frames, {} points; {} in camera {}'s view ({:.1}%; {} more hidden behind nearer points), {} labelled ({:.1}% of those)\n",
            opts.out.display(),
            self.frames,
            self.points,
            self.in_view,
            opts.camera,
            pct(self.in_view, self.points),
            self.occluded,
            self.labelled,
            pct(self.labelled, self.in_view)
        );
        out += &match self.agreement() {
            Some(g) => format!(
                "agreement with the input's labels: {:.2}% of {} in-view labelled points ({:.2}% as {} ids can say them)\n",
                100.0 * g,
                self.compared,
                100.0 * self.agreement_in_set().unwrap_or(0.0),
                opts.classes.name()
            ),
            None => "(the input has no labels to compare with)\n".into(),
        };
        let classes = self.per_class();
        if !classes.is_empty() {
            out += "  class            truth   recall  precision  mostly confused with\n";
        }
        for k in &classes {
            let pct = |v: Option<f64>| v.map_or("     -".into(), |v| format!("{:5.1}%", 100.0 * v));
            let conf: Vec<String> = k.confused_with.iter().map(|(c, f)| format!("{c} {:.0}%", 100.0 * f)).collect();
            out += &format!(
                "  {:<14} {:>7}   {}     {}  {}\n",
                k.class,
                k.truth_points,
                pct(k.recall),
                pct(k.precision),
                conf.join(", ")
            );
        }
        if let Some((w, h)) = self.scaled_from {
            out += &format!("the camera's projection was scaled from its {w}x{h} images to the segmentation's size\n");
        }
        out + &format!("{:.1} M points labelled per second ({wall:.2} s in all with reading and writing)\n", rate / 1e6)
    }

    /// Agreement with the existing labels over in-view points, if compared.
    pub fn agreement(&self) -> Option<f64> {
        (self.compared > 0).then(|| self.agreeing as f64 / self.compared as f64)
    }

    /// Agreement within what the class set can say, if compared.
    pub fn agreement_in_set(&self) -> Option<f64> {
        (self.compared > 0).then(|| self.agreeing_in_set as f64 / self.compared as f64)
    }

    /// Per class (those the truth or the new labels hold): recall,
    /// precision and the top confusions, from [`LabelStats::confusion`].
    pub fn per_class(&self) -> Vec<ClassAgreement> {
        let cols = NUM_CLASSES + 1;
        if self.confusion.len() != NUM_CLASSES * cols {
            return Vec::new();
        }
        let at = |t: usize, c: usize| self.confusion[t * cols + c];
        let name = |c: usize| Class::from_index(c as u8).map_or("none", Class::name);
        (0..NUM_CLASSES)
            .filter_map(|k| {
                let truth: u64 = (0..cols).map(|c| at(k, c)).sum();
                let labelled: u64 = (0..NUM_CLASSES).map(|t| at(t, k)).sum();
                if truth == 0 && labelled == 0 {
                    return None;
                }
                let share = |n: u64, d: u64| (d > 0).then(|| n as f64 / d as f64);
                let mut others: Vec<(usize, u64)> =
                    (0..cols).filter(|&c| c != k && at(k, c) > 0).map(|c| (c, at(k, c))).collect();
                others.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
                Some(ClassAgreement {
                    class: name(k),
                    truth_points: truth,
                    labelled_points: labelled,
                    recall: share(at(k, k), truth),
                    precision: share(at(k, k), labelled),
                    confused_with: others.iter().take(3).map(|&(c, n)| (name(c), n as f64 / truth as f64)).collect(),
                })
            })
            .collect()
    }
}

/// Puts `from` at `to`: a relative symbolic link (so that the output and
/// input folders can be moved or copied together), or a copy when `copy`
/// is asked or no link can be made.
fn copy_or_link(from: &Path, to: &Path, copy: bool) -> Result<(), LabelError> {
    let abs = std::fs::canonicalize(from).map_err(io(from))?;
    #[cfg(unix)]
    if !copy {
        let dir = to.parent().map(crate::paths::resolved).unwrap_or_default();
        if std::os::unix::fs::symlink(relative_to(&abs, &dir), to).is_ok() {
            return Ok(());
        }
    }
    crate::paths::copy_file(&abs, to).map_err(io(to))
}

/// `target` (absolute) as a path relative to the folder `base` (absolute).
fn relative_to(target: &Path, base: &Path) -> PathBuf {
    let t: Vec<_> = target.components().collect();
    let b: Vec<_> = base.components().collect();
    let common = t.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut rel = PathBuf::new();
    for _ in common..b.len() {
        rel.push("..");
    }
    for c in &t[common..] {
        rel.push(c);
    }
    rel
}

/// First line of the PROVENANCE.md `cosem label` writes: an output folder
/// with it may be replaced by a new run.
const PROVENANCE_TITLE: &str = "# Labels from camera segmentation (`cosem label`)";

/// Refuses an output folder that is, lies inside or holds an input (any
/// spelling: [`crate::paths::check_output`]), and an existing folder that
/// is neither empty nor a `cosem label` output.
pub(crate) fn check_out(o: &LabelOptions, inputs: &[(&str, &Path)]) -> Result<(), crate::error::Error> {
    crate::paths::check_output(Knob::Out.name(), &o.out, inputs)?;
    let out = &o.out;
    let ours = std::fs::read_to_string(out.join("PROVENANCE.md")).is_ok_and(|t| t.starts_with(PROVENANCE_TITLE));
    let empty = std::fs::read_dir(out).map(|mut d| d.next().is_none()).unwrap_or(true);
    if out.exists() && !(ours || empty) {
        return Err(LabelError::Format {
            path: o.out.clone(),
            what: format!("exists and is not an earlier `cosem label` output: choose another {}", Knob::Out),
        }
        .into());
    }
    Ok(())
}

/// Labels a sequence from its segmentation images and writes a
/// SemanticKITTI-layout folder at `out`: links to the scans, copies of
/// calib.txt, poses.txt, times.txt and world.txt, the new labels (and, with
/// probabilities, the evidence). Written into a new folder beside `out`,
/// then swapped into place ([`crate::paths::OutputDir`]): an input is never
/// touched, a failed run leaves nothing behind, and `out` may only be a
/// new or empty folder or an earlier output.
pub fn label_sequence(o: &LabelOptions) -> Result<LabelStats, crate::error::Error> {
    check_out(o, &[(Knob::Data.name(), &o.data), (Knob::Seg.name(), &o.seg)])?;
    let dir = crate::paths::OutputDir::create(&o.out).map_err(io(&o.out))?;
    let run = LabelOptions { out: dir.path().to_path_buf(), ..o.clone() };
    let stats = label_into(&run, &o.seg)?;
    dir.commit().map_err(io(&o.out))?;
    Ok(stats)
}

/// Labels `o.data` into the folder `o.out` (a new temporary one); `seg`
/// is how the segmentation is named in the provenance.
pub(crate) fn label_into(o: &LabelOptions, seg: &Path) -> Result<LabelStats, LabelError> {
    let seq = Sequence::open(&o.data)?;
    let all = seq.scan_frames()?;
    let frames = if o.frames.is_empty() {
        all
    } else {
        let mut chosen = Vec::new();
        for r in &o.frames {
            chosen.extend(r.select(&all, &o.data.join("velodyne"))?);
        }
        chosen
    };
    if frames.is_empty() {
        return Err(LabelError::Format {
            path: o.data.join("velodyne"),
            what: "no scans (NNNNNN.bin) to label".into(),
        });
    }
    prepare_output(o, seg)?;
    let mut stats = LabelStats::default();
    let mut camera: Option<(Camera, (u32, u32))> = None;
    let mut depth_buffer: Vec<f32> = Vec::new();
    for &frame in &frames {
        // Existing labels, if any, are compared with the new ones.
        let (points, truth) = if seq.label_path(frame).exists() {
            let scan = seq.read_scan(frame)?;
            (scan.points, Some(scan.labels))
        } else {
            (seq.read_points(frame)?, None)
        };
        let (seg, image_path) = read_segmentation(o, frame)?;
        let size = seg.size();
        if camera.is_none() {
            let (cam, scaled) = camera_for(o, &seq, size, &image_path, frame)?;
            stats.scaled_from = scaled;
            camera = Some((cam, size));
        }
        let Some((cam, want)) = &camera else { continue };
        check_size(&image_path, size, *want)?;
        let t = std::time::Instant::now();
        let projected: Vec<Projection> = points.iter().map(|p| cam.project([p[0], p[1], p[2]])).collect();
        let grid = if o.occlusion {
            depth_buffer.resize(DepthGrid::cells(cam), 0.0);
            let mut g = DepthGrid::new(cam, &mut depth_buffer);
            for pr in &projected {
                if let (Some(g), Projection::Pixel { u, v, depth }) = (g.as_mut(), pr) {
                    g.insert(*u, *v, *depth);
                }
            }
            g
        } else {
            None
        };
        let frame_labels =
            FrameLabels { o, seg: &seg, image: &image_path, grid: grid.as_ref(), truth: truth.as_deref() };
        let (labels, evidence) = frame_labels.label(&projected, &mut stats)?;
        stats.label_seconds += t.elapsed().as_secs_f64();
        stats.points += points.len();
        stats.frames += 1;
        write_frame(o, &seq, frame, &labels, &evidence)?;
    }
    Ok(stats)
}

/// The output folder's layout and what it copies from the input.
fn prepare_output(o: &LabelOptions, seg: &Path) -> Result<(), LabelError> {
    for d in ["velodyne", "labels"] {
        let p = o.out.join(d);
        std::fs::create_dir_all(&p).map_err(io(&p))?;
    }
    if o.probabilities {
        let p = o.out.join("evidence");
        std::fs::create_dir_all(&p).map_err(io(&p))?;
    }
    // world.txt: the labelled scans stay in their world (a town's robots).
    for f in ["calib.txt", "poses.txt", "times.txt", "world.txt"] {
        let from = o.data.join(f);
        if from.exists() {
            let to = o.out.join(f);
            crate::paths::copy_file(&from, &to).map_err(io(&to))?;
        }
    }
    let prov = format!(
        "{PROVENANCE_TITLE}\n\nscans, poses, calibration: {}\nsegmentation: {} (camera {}, {} ids{})\n\n\
         Each LiDAR point takes the class of the pixel it projects to (P{} after Tr); points behind the camera or \
         outside the image are unlabeled (0). See the source folder's PROVENANCE.md for the data's origin and licence.\n",
        o.data.display(),
        seg.display(),
        o.camera,
        o.classes.name(),
        if o.probabilities { ", per-pixel probabilities" } else { "" },
        o.camera
    );
    crate::paths::write_file(o.out.join("PROVENANCE.md"), prov).map_err(io(&o.out))
}

/// One frame's segmentation: hard class ids, or per-pixel probabilities.
enum Segmentation {
    Ids(SegImage),
    Probabilities(ProbabilityMap),
}

impl Segmentation {
    fn size(&self) -> (u32, u32) {
        match self {
            Segmentation::Ids(im) => (im.width, im.height),
            Segmentation::Probabilities(p) => (p.width, p.height),
        }
    }
}

/// Reads frame `frame`'s segmentation (checked whole) and names its file.
fn read_segmentation(o: &LabelOptions, frame: usize) -> Result<(Segmentation, PathBuf), LabelError> {
    let path = o.seg.join(format!("{frame:06}.{}", if o.probabilities { "npy" } else { "png" }));
    if !path.exists() {
        return Err(LabelError::MissingImage { path, frame });
    }
    let seg = if o.probabilities {
        Segmentation::Probabilities(read_probabilities_of(&path, o.classes, o.void_channel)?)
    } else {
        let im = read_seg_png(&path)?;
        check_ids(&path, &im, o.classes)?;
        Segmentation::Ids(im)
    };
    Ok((seg, path))
}

/// What labels one frame's points.
struct FrameLabels<'a> {
    o: &'a LabelOptions,
    seg: &'a Segmentation,
    image: &'a Path,
    grid: Option<&'a DepthGrid<'a>>,
    /// The input's labels, to compare with.
    truth: Option<&'a [u32]>,
}

impl FrameLabels<'_> {
    /// Each projected point's SemanticKITTI id (0: unlabelled) and, with
    /// probabilities, its label evidence; counts into `stats`.
    fn label(&self, projected: &[Projection], stats: &mut LabelStats) -> Result<(Vec<u32>, Vec<u8>), LabelError> {
        let mut labels = vec![0u32; projected.len()];
        let mut evidence: Vec<u8> = Vec::new();
        for (i, pr) in projected.iter().enumerate() {
            let mut slots = [0u16; LABEL_SLOTS];
            let class = match *pr {
                Projection::Pixel { u, v, depth } if self.grid.is_some_and(|g| g.occluded(u, v, depth)) => {
                    stats.occluded += 1;
                    None
                }
                Projection::Pixel { u, v, .. } => {
                    stats.in_view += 1;
                    let c = self.class_at(u, v, &mut slots)?;
                    stats.labelled += usize::from(c.is_some());
                    self.compare(i, c, stats);
                    c
                }
                _ => None,
            };
            if let Some(c) = class {
                labels[i] = u32::from(c.semantic_kitti_id());
            }
            if self.o.probabilities {
                for s in slots {
                    evidence.extend_from_slice(&s.to_le_bytes());
                }
            }
        }
        Ok((labels, evidence))
    }

    /// The class at pixel (`u`, `v`), its evidence into `slots`.
    fn class_at(&self, u: u32, v: u32, slots: &mut [u16; LABEL_SLOTS]) -> Result<Option<Class>, LabelError> {
        Ok(match self.seg {
            Segmentation::Ids(im) => im.at(u, v).and_then(|id| self.o.classes.class(id).ok().flatten()),
            Segmentation::Probabilities(pm) => {
                let pv = pm.at(u, v).unwrap_or(&[]);
                let d = evidence_from_probabilities(self.o.classes, pv, &SensorModel::default()).map_err(|e| {
                    LabelError::Probability { path: self.image.to_path_buf(), u, v, what: e.to_string() }
                })?;
                if let Some(d) = d {
                    *slots = d.raw();
                }
                d.and_then(|d| d.argmax())
            }
        })
    }

    /// Counts point `i`'s new class `c` against the input's label.
    fn compare(&self, i: usize, c: Option<Class>, stats: &mut LabelStats) {
        let gt =
            self.truth.and_then(|t| t.get(i)).and_then(|l| Class::from_semantic_kitti(*l, MovingObjects::AsStatic));
        if let Some(gt) = gt {
            stats.compared += 1;
            stats.agreeing += usize::from(c == Some(gt));
            let said = self.o.classes.class(self.o.classes.id(Some(gt))).ok().flatten();
            stats.agreeing_in_set += usize::from(c.is_some() && c == said);
            let cols = NUM_CLASSES + 1;
            if stats.confusion.is_empty() {
                stats.confusion = vec![0; NUM_CLASSES * cols];
            }
            let row = usize::from(said.unwrap_or(gt).index());
            let col = c.map_or(NUM_CLASSES, |c| usize::from(c.index()));
            if let Some(n) = stats.confusion.get_mut(row * cols + col) {
                *n += 1;
            }
        }
    }
}

/// Writes a frame's scan link, labels and evidence into the output.
fn write_frame(
    o: &LabelOptions,
    seq: &Sequence,
    frame: usize,
    labels: &[u32],
    evidence: &[u8],
) -> Result<(), LabelError> {
    let name = format!("{frame:06}");
    copy_or_link(&seq.scan_path(frame), &o.out.join("velodyne").join(format!("{name}.bin")), o.copy_scans)?;
    let lpath = o.out.join("labels").join(format!("{name}.label"));
    let bytes: Vec<u8> = labels.iter().flat_map(|l| l.to_le_bytes()).collect();
    crate::paths::write_file(&lpath, bytes).map_err(io(&lpath))?;
    if o.probabilities {
        let epath = o.out.join("evidence").join(format!("{name}.bin"));
        crate::paths::write_file(&epath, evidence).map_err(io(&epath))?;
    }
    Ok(())
}

/// A stand-in for a segmentation image where no camera images exist (real
/// LiDAR-only data): the labelled points of a scan splatted into the image
/// through `camera`, nearest first, each over a block of pixels about the
/// beams' spacing (5 x 3), the rest `classes`' "no class" id. Only for
/// benchmarks and tests of the labelling path on real calibration and
/// geometry; it is no network.
pub fn splat_segmentation(camera: &Camera, points: &[[f32; 4]], labels: &[u32], classes: SegClasses) -> SegImage {
    let (w, h) = (camera.width(), camera.height());
    let none = match classes {
        SegClasses::Cityscapes => cosem_core::camera::CITYSCAPES_IGNORE,
        SegClasses::SemanticKitti => 0,
    };
    let mut ids = vec![none; w as usize * h as usize];
    let mut depth = vec![f32::INFINITY; ids.len()];
    for (p, l) in points.iter().zip(labels) {
        let Some(class) = Class::from_semantic_kitti(*l, MovingObjects::AsStatic) else { continue };
        let Projection::Pixel { u, v, depth: d } = camera.project([p[0], p[1], p[2]]) else { continue };
        let id = classes.id(Some(class));
        for y in v.saturating_sub(2)..=(v + 2).min(h - 1) {
            for x in u.saturating_sub(1)..=(u + 1).min(w - 1) {
                let i = y as usize * w as usize + x as usize;
                if d < depth[i] {
                    depth[i] = d;
                    ids[i] = id;
                }
            }
        }
    }
    SegImage { width: w, height: h, ids }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probability_maps_round_trip_and_bad_files_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.npy");
        let map = ProbabilityMap {
            width: 3,
            height: 2,
            channels: 19,
            values: (0..3 * 2 * 19).map(|i| (i % 19) as f32 / 18.0).collect(),
        };
        write_probabilities(&path, &map).unwrap();
        let back = read_probabilities(&path, 19).unwrap();
        assert_eq!((back.width, back.height, back.channels), (3, 2, 19));
        for (a, b) in back.values.iter().zip(&map.values) {
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6);
        }
        assert!(read_probabilities(&path, 20).is_err());
        // Every truncation, and a few corruptions, are errors naming the file.
        let bytes = std::fs::read(&path).unwrap();
        for k in 0..bytes.len() {
            crate::paths::write_file(&path, &bytes[..k]).unwrap();
            let e = read_probabilities(&path, 19).unwrap_err().to_string();
            assert!(e.contains("p.npy"), "{e}");
        }
        let text = String::from_utf8_lossy(&bytes).into_owned();
        for (from, to) in [("(2, 3, 19)", "(99999999999, 99999999999, 19)"), ("|u1", "<i8"), ("False", "True ")] {
            let bad = text.replacen(from, to, 1);
            crate::paths::write_file(&path, bad.as_bytes()).unwrap();
            assert!(read_probabilities(&path, 19).is_err(), "{from} -> {to}");
        }
    }
}
