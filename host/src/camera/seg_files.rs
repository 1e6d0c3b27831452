//! Segmentation files: images of class ids (PNG) and per-pixel class
//! probabilities (NumPy `.npy`), read and written; what `cosem label`
//! reads and `cosem segment` and `cosem synth` write.

/// Why a segmentation image or probability map could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// Reading the file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Not an image (or map) of the kind expected; what is wrong.
    #[error("{path}: {what}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

impl crate::error::LayerError for ImageError {}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ImageError + '_ {
    move |source| ImageError::Io { path: path.to_path_buf(), source }
}
use crate::knobs::Knob;
use cosem_core::camera::SegClasses;
use std::path::{Path, PathBuf};

/// A segmentation image: one class id per pixel, row by row.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SegImage {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// Class ids, `width * height`, row by row.
    pub ids: Vec<u8>,
}

impl SegImage {
    /// The id at column `u`, row `v`.
    pub fn at(&self, u: u32, v: u32) -> Option<u8> {
        self.ids.get(v as usize * self.width as usize + u as usize).copied()
    }
}

/// Reads an 8-bit single-channel PNG (grayscale or palette) of class ids.
#[cfg(feature = "png")]
pub fn read_seg_png(path: &Path) -> Result<SegImage, ImageError> {
    let format = |what: String| ImageError::Format { path: path.to_path_buf(), what };
    let file = std::fs::File::open(path).map_err(io(path))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    // Palette indices are the ids: no expansion to RGB.
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(|e| format(format!("not a readable PNG ({e})")))?;
    let file_bytes = std::fs::metadata(path).map_err(io(path))?.len();
    crate::limits::image_pixels(reader.info().width, reader.info().height, file_bytes).map_err(format)?;
    let (color, depth) = reader.output_color_type();
    if !matches!(color, png::ColorType::Grayscale | png::ColorType::Indexed) || depth != png::BitDepth::Eight {
        return Err(format(format!(
            "expected an 8-bit single-channel (grayscale or palette) PNG of class ids, found {color:?} {depth:?}"
        )));
    }
    let size = reader.output_buffer_size().ok_or_else(|| format("image too large".into()))?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(|e| format(format!("corrupt PNG data ({e})")))?;
    let (w, h) = (info.width, info.height);
    let mut ids = Vec::with_capacity(w as usize * h as usize);
    for row in buf.chunks(info.line_size).take(h as usize) {
        ids.extend_from_slice(row.get(..w as usize).ok_or_else(|| format("short image row".into()))?);
    }
    if ids.len() != w as usize * h as usize {
        return Err(format("truncated image".into()));
    }
    Ok(SegImage { width: w, height: h, ids })
}

/// Without the `png` feature: segmentation images cannot be read.
#[cfg(not(feature = "png"))]
pub fn read_seg_png(path: &Path) -> Result<SegImage, ImageError> {
    Err(ImageError::Format { path: path.to_path_buf(), what: "PNG support is off (cosem-host's `png` feature)".into() })
}

/// Without the `png` feature: segmentation images cannot be written.
#[cfg(not(feature = "png"))]
pub fn write_seg_png(_path: &Path, _image: &SegImage) -> std::io::Result<()> {
    Err(std::io::Error::other("PNG support is off (cosem-host's `png` feature)"))
}

/// Writes an 8-bit grayscale PNG of class ids.
#[cfg(feature = "png")]
pub fn write_seg_png(path: &Path, image: &SegImage) -> std::io::Result<()> {
    write_png(path, (image.width, image.height), png::ColorType::Grayscale, &image.ids)
}

/// Writes an 8-bit PNG of `size` pixels in `color` (samples row by row).
#[cfg(feature = "png")]
pub fn write_png(path: &Path, (width, height): (u32, u32), color: png::ColorType, data: &[u8]) -> std::io::Result<()> {
    let mut file = crate::paths::Output::create(path)?;
    let mut enc = png::Encoder::new(&mut file, width, height);
    enc.set_color(color);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut w = enc.write_header().map_err(std::io::Error::other)?;
    w.write_image_data(data).map_err(std::io::Error::other)?;
    w.finish().map_err(std::io::Error::other)?;
    file.commit()
}

/// An 8-bit colour image, RGB row by row.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// `width * height * 3` bytes.
    pub rgb: Vec<u8>,
}

/// Reads an 8-bit PNG (RGB, RGBA, grey, palette) as RGB.
#[cfg(feature = "png")]
pub fn read_rgb_png(path: &Path) -> Result<RgbImage, ImageError> {
    let bad = |what: String| ImageError::Format { path: path.to_path_buf(), what };
    let file = std::fs::File::open(path).map_err(io(path))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| bad(format!("not a readable PNG ({e})")))?;
    let file_bytes = std::fs::metadata(path).map_err(io(path))?.len();
    crate::limits::image_pixels(reader.info().width, reader.info().height, file_bytes).map_err(bad)?;
    let size = reader.output_buffer_size().ok_or_else(|| bad("image too large".into()))?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(|e| bad(format!("corrupt PNG data ({e})")))?;
    let (w, h) = (info.width as usize, info.height as usize);
    let per = match info.color_type {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        other => return Err(bad(format!("unsupported colour type {other:?}"))),
    };
    if w == 0 || h == 0 {
        return Err(bad("empty image".into()));
    }
    let mut rgb = Vec::with_capacity(w * h * 3);
    for row in buf.chunks(info.line_size).take(h) {
        let row = row.get(..w * per).ok_or_else(|| bad("short image row".into()))?;
        for px in row.chunks_exact(per) {
            match per {
                1 | 2 => rgb.extend([px[0]; 3]),
                _ => rgb.extend_from_slice(&px[..3]),
            }
        }
    }
    if rgb.len() != w * h * 3 {
        return Err(bad("truncated image".into()));
    }
    Ok(RgbImage { width: info.width, height: info.height, rgb })
}

/// Writes an 8-bit RGB PNG.
#[cfg(feature = "png")]
pub fn write_rgb_png(path: &Path, image: &RgbImage) -> std::io::Result<()> {
    write_png(path, (image.width, image.height), png::ColorType::Rgb, &image.rgb)
}

/// How an image is brought to the network's input size. The default,
/// tiles at the image's own scale, labelled KITTI's camera points better
/// than squashing (77.3% / 85.4% right against 77.2% / 83.6% on kitti00 /
/// kitti07, as Cityscapes can say them) at twice the inferences.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fit {
    /// The whole image stretched to the input (a KITTI image: 1.36x taller,
    /// 0.83x narrower than it is): one inference.
    Squash,
    /// The image scaled keeping its aspect, then covered by overlapping
    /// tiles of the input's size (scores averaged where tiles overlap).
    Tile {
        /// Scale of the image before tiling (1: as it is, two tiles for a
        /// KITTI image; 1.6: KITTI's focal length then about Cityscapes'
        /// at 1024x512, four tiles).
        scale: f32,
    },
}

impl Default for Fit {
    fn default() -> Self {
        Fit::Tile { scale: 1.0 }
    }
}

impl std::str::FromStr for Fit {
    type Err = String;
    /// `squash`, `tile` (scale 1) or `tile:SCALE`.
    fn from_str(s: &str) -> Result<Self, String> {
        match s.split_once(':') {
            None if s == "squash" => Ok(Fit::Squash),
            None if s == "tile" => Ok(Fit::Tile { scale: 1.0 }),
            Some(("tile", v)) => match v.parse::<f32>() {
                Ok(scale) if scale.is_finite() && (0.1..=8.0).contains(&scale) => Ok(Fit::Tile { scale }),
                _ => Err(format!("tile scale {v:?}: a number from 0.1 to 8")),
            },
            _ => Err(format!("{s:?}: squash, tile or tile:SCALE")),
        }
    }
}

impl std::fmt::Display for Fit {
    /// As it is read: `squash`, `tile` or `tile:SCALE`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Fit::Squash => f.write_str("squash"),
            Fit::Tile { scale } if *scale == 1.0 => f.write_str("tile"),
            Fit::Tile { scale } => write!(f, "tile:{scale}"),
        }
    }
}

/// Per-pixel class probabilities: `channels` values per pixel, row by row.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbabilityMap {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// Values per pixel.
    pub channels: usize,
    /// `width * height * channels` values, pixel-major (HWC).
    pub values: Vec<f32>,
}

impl ProbabilityMap {
    /// The probabilities of pixel (`u`, `v`).
    pub fn at(&self, u: u32, v: u32) -> Option<&[f32]> {
        let i = (v as usize * self.width as usize + u as usize) * self.channels;
        self.values.get(i..i + self.channels)
    }
}

/// A `.npy` file's header: its dtype, its shape and where its data start.
fn npy_header(bytes: &[u8]) -> Result<(String, Vec<usize>, usize), String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a NumPy .npy file (bad magic at byte 0)".into());
    }
    let (header_len, start) = match bytes[6] {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        2 | 3 if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        v => return Err(format!("unsupported .npy version {v} at byte 6")),
    };
    let header = bytes
        .get(start..start + header_len)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| format!("header of {header_len} bytes at byte {start} is truncated or not text"))?;
    let field = |name: &str| -> Option<&str> {
        let at = header.find(&format!("'{name}':"))? + name.len() + 3;
        Some(header[at..].trim_start())
    };
    let descr = field("descr")
        .and_then(|s| s.strip_prefix('\'')?.split('\'').next())
        .ok_or_else(|| "header has no 'descr'".to_string())?;
    if field("fortran_order").is_some_and(|s| s.starts_with("True")) {
        return Err("Fortran-ordered arrays are not supported".into());
    }
    let shape: Vec<usize> = field("shape")
        .and_then(|s| s.strip_prefix('(')?.split(')').next())
        .map(|s| s.split(',').map(str::trim).filter(|t| !t.is_empty()).map(str::parse).collect::<Result<_, _>>())
        .and_then(Result::ok)
        .ok_or_else(|| "header has no readable 'shape'".to_string())?;
    Ok((descr.to_owned(), shape, start + header_len))
}

/// Reads a NumPy `.npy` probability map (`<f4`, or `|u1` read as value/255)
/// of shape `(H, W, C)` or `(C, H, W)` with `C = channels`.
pub fn read_probabilities(path: &Path, channels: usize) -> Result<ProbabilityMap, ImageError> {
    let format = |what: String| ImageError::Format { path: path.to_path_buf(), what };
    let bytes = std::fs::read(path).map_err(io(path))?;
    let (descr, shape, data_at) = npy_header(&bytes).map_err(format)?;
    let [a, b, c] = shape[..] else {
        return Err(format(format!("shape {shape:?}: expected three dimensions (H, W, C) or (C, H, W)")));
    };
    let (height, width, chw) = if c == channels {
        (a, b, false)
    } else if a == channels {
        (b, c, true)
    } else if a == channels + 1 || c == channels + 1 {
        return Err(format(format!(
            "shape {shape:?}: {} channels, the class set has {channels}: a network's void (ignore) channel as well? \
             say which with {} last (or first)",
            channels + 1,
            Knob::VoidChannel
        )));
    } else {
        return Err(format(format!("shape {shape:?}: no dimension of {channels} class channels")));
    };
    if height == 0 || width == 0 {
        return Err(format(format!("shape {shape:?}: an image of {height}x{width} pixels, none to label")));
    }
    let data = bytes.get(data_at..).unwrap_or(&[]);
    let n = height
        .checked_mul(width)
        .and_then(|v| v.checked_mul(channels))
        .filter(|n| n.checked_mul(4).is_some())
        .ok_or_else(|| format(format!("shape {shape:?} is too large")))?;
    let raw: Vec<f32> = match descr.as_str() {
        "<f4" => {
            if data.len() != 4 * n {
                return Err(format(format!(
                    "{} data bytes for shape {shape:?} of <f4, expected {}",
                    data.len(),
                    4 * n
                )));
            }
            data.chunks_exact(4).map(|q| f32::from_le_bytes([q[0], q[1], q[2], q[3]])).collect()
        }
        "|u1" => {
            if data.len() != n {
                return Err(format(format!("{} data bytes for shape {shape:?} of |u1, expected {n}", data.len())));
            }
            data.iter().map(|&v| f32::from(v) / 255.0).collect()
        }
        d => return Err(format(format!("dtype {d}: expected <f4 or |u1"))),
    };
    let values = if chw {
        let mut out = vec![0.0f32; n];
        for k in 0..channels {
            for p in 0..height * width {
                out[p * channels + k] = raw[k * height * width + p];
            }
        }
        out
    } else {
        raw
    };
    Ok(ProbabilityMap { width: width as u32, height: height as u32, channels, values })
}

/// Where a probability map holds a void (ignore) channel beyond the class
/// set's channels, as most Cityscapes networks output (19 classes and
/// void).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum VoidChannel {
    /// No void channel.
    #[default]
    None,
    /// The first channel is void.
    First,
    /// The last channel is void.
    Last,
}

impl VoidChannel {
    /// The names it is read from (the command line's, Python's).
    pub const NAMES: &'static [&'static str] = &["none", "first", "last"];
}

impl std::str::FromStr for VoidChannel {
    type Err = String;
    /// Where a void channel is: none, first or last.
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" => Ok(VoidChannel::None),
            "first" => Ok(VoidChannel::First),
            "last" => Ok(VoidChannel::Last),
            _ => Err(format!("`{s}`: expected none, first or last")),
        }
    }
}

/// Reads a probability map of `classes` plus a `void` channel, whose
/// probability joins the channel of no class (Cityscapes' sky,
/// SemanticKITTI's unlabeled): a pixel the network calls void leaves its
/// points unlabelled, as one it calls sky does.
pub fn read_probabilities_of(
    path: &Path,
    classes: SegClasses,
    void: VoidChannel,
) -> Result<ProbabilityMap, ImageError> {
    let n = classes.channels();
    if void == VoidChannel::None {
        return read_probabilities(path, n);
    }
    let with = read_probabilities(path, n + 1)?;
    let (skip, none) = (if void == VoidChannel::First { 0 } else { n }, usize::from(classes.id(None)));
    let mut values = Vec::with_capacity(with.values.len() / (n + 1) * n);
    for px in with.values.chunks_exact(n + 1) {
        let v = px[skip];
        let start = values.len();
        values.extend(px.iter().enumerate().filter(|(k, _)| *k != skip).map(|(_, p)| *p));
        if let Some(slot) = values.get_mut(start + none) {
            *slot += v;
        }
    }
    Ok(ProbabilityMap { width: with.width, height: with.height, channels: n, values })
}

/// Writes a `|u1` `(H, W, C)` `.npy` probability map (values scaled to 255).
pub fn write_probabilities(path: &Path, map: &ProbabilityMap) -> std::io::Result<()> {
    let values: Vec<u8> = map.values.iter().map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect();
    crate::paths::write_file(path, npy_bytes("|u1", &[map.height as usize, map.width as usize, map.channels], &values))
}

/// A `.npy` file (version 1.0) of `shape` (C order) holding `data`, whose
/// dtype is `descr` (e.g. `<f4`, `|u1`).
pub fn npy_bytes(descr: &str, shape: &[usize], data: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
    // As NumPy writes a tuple: a trailing comma only for one dimension.
    let comma = if shape.len() == 1 { "," } else { "" };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({}{comma}), }}", dims.join(", "));
    // Magic (6) + version (2) + length (2) + header + newline, a multiple of 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(data);
    out
}
