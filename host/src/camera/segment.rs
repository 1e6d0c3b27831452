//! Camera segmentation with a network in ONNX, in pure Rust (`tract-onnx`,
//! feature `segment`): the paper's camera pipeline. A colour image in, the
//! network's class scores at the image's own size out, as the PNG of
//! Cityscapes training ids (255 void) or the probability map that
//! [`crate::camera::label`] reads.
//!
//! The network's contract (e.g. `../shared/models/PROVENANCE.md`): one input
//! `float32 [1, 3, H, W]`, RGB, `(pixel / 255 - mean) / std` with ImageNet's
//! mean and deviation; one output `float32 [1, C, H, W]` of raw scores,
//! channels 0-18 the Cityscapes training ids, any further one void.

use crate::camera::seg_files::Fit;
use crate::camera::seg_files::{npy_bytes, ProbabilityMap, SegImage};
pub use crate::camera::seg_files::{read_rgb_png, write_rgb_png, RgbImage};
use crate::knobs::Knob;
use std::path::{Path, PathBuf};
use tract_onnx::prelude::*;

/// ImageNet's channel means and deviations (R, G, B), as torchvision's.
const MEAN: [f32; 3] = [0.485, 0.456, 0.406];
const STD: [f32; 3] = [0.229, 0.224, 0.225];
/// Cityscapes training ids: channels beyond are void.
const CITYSCAPES_CLASSES: usize = 19;

/// The ONNX opsets tract-onnx is tested against (its own words: 9 to 18).
pub const SUPPORTED_OPSETS: std::ops::RangeInclusive<i64> = 9..=18;
/// The id a void pixel gets in the PNG (what `cosem label` ignores).
pub const VOID_ID: u8 = 255;

/// Why segmentation failed; every variant names its file.
#[derive(Debug, thiserror::Error)]
pub enum SegmentError {
    /// Reading or writing failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The network could not be loaded or run.
    #[error("{path}: {what}")]
    Model {
        /// The model file.
        path: PathBuf,
        /// What went wrong.
        what: String,
    },
    /// The network's inputs or outputs are not the contract's.
    #[error(
        "{path}: {what} (expected one input float32 [1, 3, H, W] and one output float32 [1, C, H, W], C at least 19)"
    )]
    Contract {
        /// The model file.
        path: PathBuf,
        /// What does not fit, with the shapes found.
        what: String,
    },
    /// The model declares an ONNX opset the runtime does not support.
    #[error(
        "{path}: declares ONNX opset {opset}; the runtime (tract-onnx) supports opsets {} to {}: export the \
         network with one of those", SUPPORTED_OPSETS.start(), SUPPORTED_OPSETS.end()
    )]
    Opset {
        /// The model file.
        path: PathBuf,
        /// The opset it declares (0: none of the default domain).
        opset: i64,
    },
    /// The network scored an image with a number that is not finite (NaN
    /// or infinite weights): no label can be read from it.
    #[error("{image}: the network {model} gave the score {value} (output value {at}): not a finite number")]
    NonFinite {
        /// The image.
        image: PathBuf,
        /// The model file.
        model: PathBuf,
        /// Where in the network's output.
        at: usize,
        /// The value.
        value: f32,
    },
    /// An image that is not an 8-bit RGB(A) or grey PNG.
    #[error("{path}: {what}")]
    Image {
        /// The image.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

impl crate::error::LayerError for SegmentError {}

/// Resampling from `src` to `dst` samples with a triangle (bilinear)
/// filter, widened by the ratio when shrinking (so no sample is skipped):
/// per output sample, the first source sample and the weights (summing to 1).
fn taps(src: usize, dst: usize) -> Vec<(usize, Vec<f32>)> {
    let ratio = src as f32 / dst as f32;
    let support = ratio.max(1.0);
    (0..dst)
        .map(|i| {
            let centre = (i as f32 + 0.5) * ratio;
            let lo = (centre - support).floor().max(0.0) as usize;
            let hi = ((centre + support).ceil() as usize).min(src);
            let mut w: Vec<f32> =
                (lo..hi).map(|j| (1.0 - ((j as f32 + 0.5 - centre) / support).abs()).max(0.0)).collect();
            let sum: f32 = w.iter().sum();
            if sum > 0.0 {
                w.iter_mut().for_each(|x| *x /= sum);
            }
            (lo, w)
        })
        .collect()
}

/// Resizes `planes` planes of `sw` x `sh` values (plane-major) to `dw` x `dh`.
fn resize_planes(values: &[f32], planes: usize, (sw, sh): (usize, usize), (dw, dh): (usize, usize)) -> Vec<f32> {
    let (tx, ty) = (taps(sw, dw), taps(sh, dh));
    let mut out = vec![0f32; planes * dw * dh];
    let mut rows = vec![0f32; sh * dw];
    for p in 0..planes {
        let plane = &values[p * sw * sh..(p + 1) * sw * sh];
        for (y, row) in rows.chunks_exact_mut(dw).enumerate() {
            let src = &plane[y * sw..(y + 1) * sw];
            for (o, (lo, w)) in row.iter_mut().zip(&tx) {
                *o = w.iter().zip(&src[*lo..]).map(|(a, b)| a * b).sum();
            }
        }
        let dst = &mut out[p * dw * dh..(p + 1) * dw * dh];
        for (y, (lo, w)) in ty.iter().enumerate() {
            let row = &mut dst[y * dw..(y + 1) * dw];
            for (k, wk) in w.iter().enumerate() {
                let src = &rows[(lo + k) * dw..(lo + k + 1) * dw];
                row.iter_mut().zip(src).for_each(|(o, s)| *o += wk * s);
            }
        }
    }
    out
}

/// Class scores of every pixel of an image: `channels` planes of `width` x
/// `height` (plane-major).
#[derive(Clone, Debug, PartialEq)]
pub struct Scores {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// Planes: the network's output channels.
    pub channels: usize,
    /// `channels * width * height` raw scores.
    pub values: Vec<f32>,
}

impl Scores {
    /// The best class per pixel: a Cityscapes training id, [`VOID_ID`] where
    /// a void channel wins.
    pub fn labels(&self) -> SegImage {
        let n = self.width as usize * self.height as usize;
        let ids = (0..n)
            .map(|i| {
                let mut best = (0usize, f32::NEG_INFINITY);
                for c in 0..self.channels {
                    let v = self.values[c * n + i];
                    if v > best.1 {
                        best = (c, v);
                    }
                }
                if best.0 < CITYSCAPES_CLASSES {
                    best.0 as u8
                } else {
                    VOID_ID
                }
            })
            .collect();
        SegImage { width: self.width, height: self.height, ids }
    }

    /// Per-pixel probabilities (softmax over the channels, void last), pixel-major.
    pub fn probabilities(&self) -> ProbabilityMap {
        let n = self.width as usize * self.height as usize;
        let c = self.channels;
        let mut values = vec![0f32; n * c];
        for (i, px) in values.chunks_exact_mut(c).enumerate() {
            let top = (0..c).map(|k| self.values[k * n + i]).fold(f32::NEG_INFINITY, f32::max);
            let mut sum = 0.0;
            for (k, p) in px.iter_mut().enumerate() {
                *p = (self.values[k * n + i] - top).exp();
                sum += *p;
            }
            px.iter_mut().for_each(|p| *p /= sum);
        }
        ProbabilityMap { width: self.width, height: self.height, channels: c, values }
    }
}

/// A segmentation network loaded and optimised, checked against the
/// contract.
pub struct Network {
    plan: std::sync::Arc<TypedSimplePlan>,
    path: PathBuf,
    /// Input height and width (pixels).
    pub input: (usize, usize),
    /// Output channels.
    pub channels: usize,
}

fn shape_of(fact: &TypedFact) -> String {
    format!("{:?} {:?}", fact.datum_type, fact.shape)
}

impl Network {
    /// Loads `path` (ONNX), checks its input and output against the
    /// contract and optimises it.
    pub fn load(path: &Path) -> Result<Network, SegmentError> {
        let model_err = |e: TractError| SegmentError::Model { path: path.to_path_buf(), what: format!("{e:#}") };
        let contract = |what: String| SegmentError::Contract { path: path.to_path_buf(), what };
        let bytes = std::fs::read(path).map_err(|source| SegmentError::Io { path: path.to_path_buf(), source })?;
        let onnx = tract_onnx::onnx();
        let proto = onnx.proto_model_for_read(&mut bytes.as_slice()).map_err(model_err)?;
        let opset = proto.opset_import.iter().find(|o| o.domain.is_empty() || o.domain == "ai.onnx").map(|o| o.version);
        match opset {
            Some(v) if SUPPORTED_OPSETS.contains(&v) => {}
            v => return Err(SegmentError::Opset { path: path.to_path_buf(), opset: v.unwrap_or(0) }),
        }
        let model = onnx.model_for_proto_model(&proto).map_err(model_err)?;
        let typed = model.into_typed().map_err(model_err)?;
        if typed.inputs.len() != 1 || typed.outputs.len() != 1 {
            return Err(contract(format!("{} inputs and {} outputs", typed.inputs.len(), typed.outputs.len())));
        }
        let input = typed.input_fact(0).map_err(model_err)?.clone();
        let output = typed.output_fact(0).map_err(model_err)?.clone();
        let dims = |f: &TypedFact| f.shape.as_concrete().map(<[usize]>::to_vec);
        let (Some(i), Some(o)) = (dims(&input), dims(&output)) else {
            return Err(contract(format!("input {}, output {}: not static", shape_of(&input), shape_of(&output))));
        };
        let fits = input.datum_type == f32::datum_type()
            && output.datum_type == f32::datum_type()
            && matches!(i[..], [1, 3, h, w] if h > 0 && w > 0)
            && matches!(o[..], [1, c, _, _] if c >= CITYSCAPES_CLASSES)
            && i.get(2..) == o.get(2..);
        if !fits {
            return Err(contract(format!("input {}, output {}", shape_of(&input), shape_of(&output))));
        }
        crate::limits::network_pixels(i[2], i[3]).map_err(contract)?;
        let plan = typed.into_optimized().and_then(|m| m.into_runnable()).map_err(model_err)?;
        Ok(Network { plan, path: path.to_path_buf(), input: (i[2], i[3]), channels: o[1] })
    }

    /// The network's scores for one input of its size, normalised RGB
    /// planes (`3 * H * W`).
    pub fn infer(&self, input: &[f32]) -> Result<Vec<f32>, SegmentError> {
        let err = |e: TractError| SegmentError::Model { path: self.path.clone(), what: format!("{e:#}") };
        let (h, w) = self.input;
        let tensor = Tensor::from_shape(&[1, 3, h, w], input).map_err(err)?;
        let out = self.plan.run(tvec!(tensor.into())).map_err(err)?;
        let first = out.first().ok_or_else(|| err(TractError::msg("no output")))?;
        let scores = first.try_as_plain_ram().and_then(|v| v.as_slice::<f32>().map(<[f32]>::to_vec)).map_err(err)?;
        if let Some(k) = scores.iter().position(|v| !v.is_finite()) {
            return Err(SegmentError::NonFinite {
                image: PathBuf::new(),
                model: self.path.clone(),
                at: k,
                value: scores[k],
            });
        }
        Ok(scores)
    }

    /// The normalised input planes for an image of exactly the input's size
    /// given as 0-255 RGB planes.
    fn normalise(planes: &mut [f32], n: usize) {
        for (c, plane) in planes.chunks_exact_mut(n).enumerate().take(3) {
            plane.iter_mut().for_each(|v| *v = (*v / 255.0 - MEAN[c]) / STD[c]);
        }
    }

    /// The network's input for `image` stretched whole to its size.
    pub fn squashed_input(&self, image: &RgbImage) -> Vec<f32> {
        let (h, w) = self.input;
        let mut planes = resize_planes(&rgb_planes(image), 3, (image.width as usize, image.height as usize), (w, h));
        Self::normalise(&mut planes, w * h);
        planes
    }

    /// The scores of `image` squashed to the network (`out`, the network's
    /// output) stretched back to the image's size.
    pub fn back_to_image(&self, out: &[f32], image: &RgbImage) -> Scores {
        let (h, w) = self.input;
        let values = resize_planes(out, self.channels, (w, h), (image.width as usize, image.height as usize));
        Scores { width: image.width, height: image.height, channels: self.channels, values }
    }

    /// Scores for `image` at its own size, brought to the network by `fit`.
    pub fn scores(&self, image: &RgbImage, fit: Fit) -> Result<Scores, SegmentError> {
        match fit {
            Fit::Squash => Ok(self.back_to_image(&self.infer(&self.squashed_input(image))?, image)),
            Fit::Tile { scale } => self.tiled(image, scale),
        }
    }

    /// Scores of `image` scaled by `scale`, grown to at least the input's
    /// size (edges repeated) and covered by overlapping tiles (scores
    /// averaged), back at the image's size.
    fn tiled(&self, image: &RgbImage, scale: f32) -> Result<Scores, SegmentError> {
        let (iw, ih) = (image.width as usize, image.height as usize);
        let (h, w) = self.input;
        let c = self.channels;
        let (sw, sh) = (((iw as f32 * scale).round() as usize).max(1), ((ih as f32 * scale).round() as usize).max(1));
        let scaled = resize_planes(&rgb_planes(image), 3, (iw, ih), (sw, sh));
        let (pw, ph) = (sw.max(w), sh.max(h));
        let padded = pad_edges(&scaled, 3, (sw, sh), (pw, ph));
        let mut sum = vec![0f32; c * pw * ph];
        let mut count = vec![0u16; pw * ph];
        for y0 in tile_starts(ph, h) {
            for x0 in tile_starts(pw, w) {
                let mut input = crop(&padded, 3, pw, (x0, y0), (w, h));
                Self::normalise(&mut input, w * h);
                let out = self.infer(&input)?;
                add_tile(&mut sum, &mut count, &out, c, pw, (x0, y0), (w, h));
            }
        }
        for (k, v) in sum.iter_mut().enumerate() {
            *v /= f32::from(count[k % (pw * ph)].max(1));
        }
        let kept = crop(&sum, c, pw, (0, 0), (sw, sh));
        let values = resize_planes(&kept, c, (sw, sh), (iw, ih));
        Ok(Scores { width: image.width, height: image.height, channels: c, values })
    }
}

/// What `cosem segment` does.
#[derive(Clone, Debug)]
pub struct SegmentOptions {
    /// The network (ONNX).
    pub model: PathBuf,
    /// Colour images, `NNNNNN.png` (KITTI's `image_2/`).
    pub images: PathBuf,
    /// Output folder: `NNNNNN.png` of training ids, and with
    /// `probabilities` `NNNNNN.npy` probability maps.
    pub out: PathBuf,
    /// Frames to segment (checked against the images there before any is
    /// segmented); default: every PNG in `images`.
    pub frames: Option<crate::sources::kitti::FrameRange>,
    /// Also write probability maps (`|u1`, H x W x C, void last).
    pub probabilities: bool,
    /// How images are brought to the network's size.
    pub fit: Fit,
    /// Images segmented at once (each on one core).
    pub threads: usize,
    /// Also write `NNNNNN.overlay.png`: the image with each pixel's class
    /// colour (cosem's class table) laid over it, half and half.
    pub overlay: bool,
    /// Also write, per image, the network's input (`NNNNNN.input.npy`,
    /// float32 [1, 3, H, W]) and its labels at its own size
    /// (`NNNNNN.labels.npy`, uint8 [H, W]) here: to check the inference
    /// against another runtime (squash only: one input per image).
    pub check: Option<PathBuf>,
}

/// What a segmentation run did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SegmentSummary {
    /// Images segmented.
    pub images: usize,
    /// The network's input (height, width).
    pub input: (usize, usize),
    /// Its output channels.
    pub channels: usize,
    /// Seconds loading and optimising the network.
    pub load_s: f64,
    /// Seconds for all images, wall time.
    pub wall_s: f64,
    /// Milliseconds per image, wall time over the images (with `threads`
    /// images at once).
    pub ms_per_image: f64,
    /// Threads.
    pub threads: usize,
}

/// The images to segment: `(frame name, path)`, in order.
fn image_list(o: &SegmentOptions) -> Result<Vec<(String, PathBuf)>, SegmentError> {
    let io = |source| SegmentError::Io { path: o.images.clone(), source };
    if let Some(range) = &o.frames {
        let mut numbered = Vec::new();
        for entry in std::fs::read_dir(&o.images).map_err(io)? {
            let name = entry.map_err(io)?.file_name();
            let name = name.to_string_lossy();
            if let Some(Ok(n)) = name.strip_suffix(".png").map(str::parse::<usize>) {
                numbered.push(n);
            }
        }
        numbered.sort_unstable();
        let frames = range.select(&numbered, &o.images).map_err(|e| SegmentError::Image {
            path: o.images.clone(),
            what: {
                let e = e.to_string();
                format!("{} {}", Knob::Frames, e.strip_prefix("frames ").unwrap_or(&e))
            },
        })?;
        return Ok(frames.iter().map(|f| (format!("{f:06}"), o.images.join(format!("{f:06}.png")))).collect());
    }
    let mut list = Vec::new();
    let mut other = None;
    for entry in std::fs::read_dir(&o.images).map_err(io)? {
        let path = entry.map_err(io)?.path();
        if path.extension().is_some_and(|e| e == "png") {
            match path.file_stem().and_then(|s| s.to_str()).map(|s| (s, s.parse::<usize>())) {
                Some((stem, Ok(n))) => list.push((n, stem.to_string(), path.clone())),
                _ => other = Some(path.clone()),
            }
        }
    }
    if let (Some(other), false) = (other, list.is_empty()) {
        return Err(SegmentError::Image {
            path: o.images.clone(),
            what: format!(
                "mixes numbered images (NNNNNN.png) with {}: name every image by its frame number",
                other.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
            ),
        });
    }
    // Ordered by frame number, not by text (9 before 10).
    list.sort();
    if list.is_empty() {
        return Err(SegmentError::Image {
            path: o.images.clone(),
            what: "no numbered .png images (NNNNNN.png) in this folder".into(),
        });
    }
    Ok(list.into_iter().map(|(_, stem, path)| (stem, path)).collect())
}

/// Segments one image into the output folder (and the check folder).
fn segment_one(net: &Network, o: &SegmentOptions, name: &str, path: &Path) -> Result<(), SegmentError> {
    segment_image(net, o, name, path).map_err(|e| match e {
        SegmentError::NonFinite { model, at, value, .. } => {
            SegmentError::NonFinite { image: path.to_path_buf(), model, at, value }
        }
        e => e,
    })
}

fn segment_image(net: &Network, o: &SegmentOptions, name: &str, path: &Path) -> Result<(), SegmentError> {
    let io = |p: PathBuf| move |source| SegmentError::Io { path: p, source };
    let image = read_rgb_png(path).map_err(|e| match e {
        crate::camera::seg_files::ImageError::Io { path, source } => SegmentError::Io { path, source },
        crate::camera::seg_files::ImageError::Format { path, what } => SegmentError::Image { path, what },
    })?;
    let scores = match &o.check {
        // The one inference of a squashed image serves the check too.
        Some(dir) => {
            let input = net.squashed_input(&image);
            let out = net.infer(&input)?;
            let (h, w) = net.input;
            let at_network = Scores { width: w as u32, height: h as u32, channels: net.channels, values: out };
            let bytes: Vec<u8> = input.iter().flat_map(|v| v.to_le_bytes()).collect();
            let file = dir.join(format!("{name}.input.npy"));
            crate::paths::write_file(&file, npy_bytes("<f4", &[1, 3, h, w], &bytes)).map_err(io(file.clone()))?;
            let file = dir.join(format!("{name}.labels.npy"));
            let labels = npy_bytes("|u1", &[h, w], &at_network.labels().ids);
            crate::paths::write_file(&file, labels).map_err(io(file.clone()))?;
            net.back_to_image(&at_network.values, &image)
        }
        None => net.scores(&image, o.fit)?,
    };
    let labels = scores.labels();
    let file = o.out.join(format!("{name}.png"));
    crate::camera::seg_files::write_seg_png(&file, &labels).map_err(io(file.clone()))?;
    if o.overlay {
        let file = o.out.join(format!("{name}.overlay.png"));
        write_rgb_png(&file, &overlay(&image, &labels)).map_err(io(file.clone()))?;
    }
    if o.probabilities {
        let file = o.out.join(format!("{name}.npy"));
        crate::camera::seg_files::write_probabilities(&file, &scores.probabilities()).map_err(io(file.clone()))?;
    }
    Ok(())
}

/// Whether a file name is one `cosem segment` writes (into the output
/// folder, or with `check` into the check folder).
fn segment_file(name: &str, check: bool) -> bool {
    let suffixes: &[&str] = if check { &[".input.npy", ".labels.npy"] } else { &[".overlay.png", ".png", ".npy"] };
    suffixes.iter().any(|s| name.strip_suffix(s).is_some_and(|stem| !stem.is_empty() && !stem.contains('.')))
}

/// Refuses an existing folder that holds anything `cosem segment` does not
/// write (it is replaced whole).
fn refuse_foreign(arg: &str, dir: &Path, check: bool) -> Result<(), SegmentError> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(()) };
    for name in entries.flatten().map(|e| e.file_name().to_string_lossy().into_owned()) {
        if !segment_file(&name, check) {
            return Err(SegmentError::Image {
                path: dir.to_path_buf(),
                what: format!(
                    "{arg}: holds {name}, which is not an earlier `cosem segment` output: the folder is replaced \
                     whole, choose a new or empty folder"
                ),
            });
        }
    }
    Ok(())
}

/// Segments every image of `o` with the network, `o.threads` at once;
/// `tick` after each image (a progress bar). The output folders (`out`,
/// `check`) are written whole and swapped into place: new or empty
/// folders, or earlier outputs of this command; never an input, inside
/// one or holding one (an image linked into the output included).
pub fn segment_folder(o: &SegmentOptions, tick: &(dyn Fn() + Sync)) -> Result<SegmentSummary, SegmentError> {
    fn refuse(path: &Path) -> impl Fn(crate::error::Error) -> SegmentError + '_ {
        move |e| SegmentError::Image { path: path.to_path_buf(), what: e.to_string() }
    }
    let inputs: [(&str, &Path); 2] = [(Knob::Images.name(), &o.images), (Knob::Model.name(), &o.model)];
    let mut outputs: Vec<(&str, &Path)> = vec![(Knob::Out.name(), &o.out)];
    outputs.extend(o.check.as_deref().map(|c| (Knob::CheckDir.name(), c)));
    crate::paths::check_outputs_apart(&outputs).map_err(refuse(&o.out))?;
    for (arg, dir) in &outputs {
        crate::paths::check_output(arg, dir, &inputs).map_err(refuse(dir))?;
        refuse_foreign(arg, dir, *arg == Knob::CheckDir.name())?;
    }
    let list = image_list(o)?;
    for (_, image) in &list {
        for (arg, dir) in &outputs {
            crate::paths::check_output(arg, dir, &[(Knob::Images.name(), image)]).map_err(refuse(dir))?;
        }
    }
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| SegmentError::Io { path, source }
    };
    let out = crate::paths::OutputDir::create(&o.out).map_err(io(&o.out))?;
    let check = o.check.as_deref().map(|c| crate::paths::OutputDir::create(c).map_err(io(c))).transpose()?;
    let run = SegmentOptions {
        out: out.path().to_path_buf(),
        check: check.as_ref().map(|c| c.path().to_path_buf()),
        ..o.clone()
    };
    let summary = segment_list(&run, &list, tick)?;
    out.commit().map_err(io(&o.out))?;
    if let (Some(c), Some(path)) = (check, &o.check) {
        c.commit().map_err(io(path))?;
    }
    Ok(summary)
}

/// [`segment_folder`] into a folder of the caller's (a new one, no checks
/// against inputs beyond the images').
pub(crate) fn segment_into(o: &SegmentOptions, tick: &(dyn Fn() + Sync)) -> Result<SegmentSummary, SegmentError> {
    let list = image_list(o)?;
    std::fs::create_dir_all(&o.out).map_err(|source| SegmentError::Io { path: o.out.clone(), source })?;
    segment_list(o, &list, tick)
}

fn segment_list(
    o: &SegmentOptions,
    list: &[(String, PathBuf)],
    tick: &(dyn Fn() + Sync),
) -> Result<SegmentSummary, SegmentError> {
    let t = std::time::Instant::now();
    let net = Network::load(&o.model)?;
    let load_s = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let threads = o.threads.max(1);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build();
    let pool = pool.map_err(|e| SegmentError::Model { path: o.model.clone(), what: e.to_string() })?;
    use rayon::prelude::*;
    pool.install(|| {
        list.par_iter().try_for_each(|(name, path)| {
            segment_one(&net, o, name, path)?;
            tick();
            Ok::<(), SegmentError>(())
        })
    })?;
    let wall_s = t.elapsed().as_secs_f64();
    Ok(SegmentSummary {
        images: list.len(),
        input: net.input,
        channels: net.channels,
        load_s,
        wall_s,
        ms_per_image: 1000.0 * wall_s / list.len() as f64,
        threads,
    })
}

/// `image` with each pixel's class colour laid over it, half and half
/// (void pixels left as they are).
pub fn overlay(image: &RgbImage, labels: &SegImage) -> RgbImage {
    use cosem_core::camera::SegClasses;
    let mut rgb = image.rgb.clone();
    for (px, &id) in rgb.chunks_exact_mut(3).zip(&labels.ids) {
        if let Ok(Some(class)) = SegClasses::Cityscapes.class(id) {
            for (p, c) in px.iter_mut().zip(class.color()) {
                *p = ((u16::from(*p) + u16::from(c)) / 2) as u8;
            }
        }
    }
    RgbImage { rgb, ..*image }
}

/// RGB bytes as three planes of 0-255 values.
fn rgb_planes(image: &RgbImage) -> Vec<f32> {
    let n = image.width as usize * image.height as usize;
    let mut planes = vec![0f32; 3 * n];
    for (i, px) in image.rgb.chunks_exact(3).enumerate() {
        for c in 0..3 {
            planes[c * n + i] = f32::from(px[c]);
        }
    }
    planes
}

/// Planes of `sw` x `sh` grown to `pw` x `ph`, the last row and column repeated.
fn pad_edges(values: &[f32], planes: usize, (sw, sh): (usize, usize), (pw, ph): (usize, usize)) -> Vec<f32> {
    let mut out = vec![0f32; planes * pw * ph];
    for p in 0..planes {
        for y in 0..ph {
            let sy = y.min(sh - 1);
            for x in 0..pw {
                out[p * pw * ph + y * pw + x] = values[p * sw * sh + sy * sw + x.min(sw - 1)];
            }
        }
    }
    out
}

/// Where tiles of `tile` start to cover `len` (the first at 0, the last
/// ending at `len`, evenly spaced, overlapping).
fn tile_starts(len: usize, tile: usize) -> Vec<usize> {
    if len <= tile {
        return vec![0];
    }
    let n = len.div_ceil(tile);
    (0..n).map(|k| ((len - tile) * k).div_ceil(n - 1)).collect()
}

/// The `w` x `h` window at `(x0, y0)` of planes `stride` wide.
fn crop(values: &[f32], planes: usize, stride: usize, (x0, y0): (usize, usize), (w, h): (usize, usize)) -> Vec<f32> {
    let rows = values.len() / planes / stride;
    let mut out = Vec::with_capacity(planes * w * h);
    for p in 0..planes {
        for y in y0..y0 + h {
            let at = p * stride * rows + y * stride + x0;
            out.extend_from_slice(&values[at..at + w]);
        }
    }
    out
}

/// Adds a tile's scores into the sums at `(x0, y0)`.
fn add_tile(
    sum: &mut [f32],
    count: &mut [u16],
    tile: &[f32],
    planes: usize,
    stride: usize,
    (x0, y0): (usize, usize),
    (w, h): (usize, usize),
) {
    let n = count.len();
    for p in 0..planes {
        for y in 0..h {
            let dst = p * n + (y0 + y) * stride + x0;
            let src = p * w * h + y * w;
            sum[dst..dst + w].iter_mut().zip(&tile[src..src + w]).for_each(|(s, t)| *s += t);
        }
    }
    for y in 0..h {
        let at = (y0 + y) * stride + x0;
        count[at..at + w].iter_mut().for_each(|c| *c += 1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resizing_keeps_constants_and_means() {
        let plane = vec![7.0f32; 40 * 30];
        for (dw, dh) in [(40, 30), (17, 11), (100, 64)] {
            let out = resize_planes(&plane, 1, (40, 30), (dw, dh));
            assert!(out.iter().all(|v| (v - 7.0).abs() < 1e-4), "{dw}x{dh}");
        }
        // A ramp shrunk by two keeps its mean.
        let ramp: Vec<f32> = (0..64).map(|i| i as f32).collect();
        let half = resize_planes(&ramp, 1, (64, 1), (32, 1));
        let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
        assert!((mean(&half) - mean(&ramp)).abs() < 0.5);
    }

    #[test]
    fn tiles_cover_with_overlap() {
        assert_eq!(tile_starts(512, 512), vec![0]);
        assert_eq!(tile_starts(602, 512), vec![0, 90]);
        assert_eq!(tile_starts(1986, 1024), vec![0, 962]);
        assert_eq!(tile_starts(3000, 1024), vec![0, 988, 1976]);
    }

    #[test]
    fn fits_parse_and_bad_ones_are_named() {
        assert_eq!("squash".parse(), Ok(Fit::Squash));
        assert_eq!("tile".parse(), Ok(Fit::Tile { scale: 1.0 }));
        assert_eq!(Fit::default(), Fit::Tile { scale: 1.0 });
        assert_eq!("tile:2".parse(), Ok(Fit::Tile { scale: 2.0 }));
        assert!("tile:nan".parse::<Fit>().is_err());
        assert!("pad".parse::<Fit>().is_err());
    }

    #[test]
    fn labels_take_the_best_channel_and_void_is_255() {
        // Two pixels, 20 channels: the first's best is 3, the second's the void.
        let mut values = vec![0f32; 20 * 2];
        values[3 * 2] = 5.0;
        values[19 * 2 + 1] = 5.0;
        let s = Scores { width: 2, height: 1, channels: 20, values };
        assert_eq!(s.labels().ids, vec![3, VOID_ID]);
        let p = s.probabilities();
        assert!((p.values[..20].iter().sum::<f32>() - 1.0).abs() < 1e-5);
        assert!(p.values[3] > 0.8);
    }
}
