//! `cosem segment`: camera images through a segmentation network (ONNX, in
//! pure Rust) into what `cosem label --seg` reads.

use super::Error;
use cosem_host::sources::kitti::FrameRange;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The network (ONNX): one input float32 [1, 3, H, W] (RGB, ImageNet
    /// normalisation), one output float32 [1, C, H, W] of scores, channels
    /// 0-18 the Cityscapes training ids, any further one void.
    #[arg(long)]
    model: PathBuf,
    /// Colour images NNNNNN.png (KITTI's image_2/).
    #[arg(long)]
    images: PathBuf,
    /// Output folder: NNNNNN.png of training ids (255 void) at each image's
    /// own size; with --probabilities also NNNNNN.npy.
    #[arg(long, value_name = "OUT")]
    out: PathBuf,
    /// Frames START:END[:STRIDE]; default: every image.
    #[arg(long)]
    frames: Option<FrameRange>,
    /// Also write per-pixel probabilities (.npy, |u1, HxWxC, void last:
    /// `cosem label --probabilities --void-channel last`).
    #[arg(long)]
    probabilities: bool,
    /// Images segmented at once, one per core, 1 to 4 x the cores
    /// (default: all cores).
    #[arg(long, value_parser = super::args::threads)]
    threads: Option<usize>,
    /// How an image meets the network's input: tile (at its own scale,
    /// covered by overlapping tiles: the better labels), tile:SCALE (scaled
    /// first, aspect kept) or squash (the whole image stretched to it: one
    /// inference, half the time).
    #[arg(long, default_value = "tile", value_parser = super::args::fit)]
    fit: cosem_host::camera::seg_files::Fit,
    /// Also write each image's network input and labels at the network's
    /// size as .npy here (to check against another runtime; squash only).
    #[arg(long, value_name = "OUT")]
    check_dir: Option<PathBuf>,
    /// Also write NNNNNN.overlay.png: the image with its class colours laid over it.
    #[arg(long)]
    overlay: bool,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

#[cfg(feature = "segment")]
pub fn run(a: Args) -> Result<(), Error> {
    use cosem_host::camera::seg_files::Fit;
    use cosem_host::camera::segment::{segment_folder, SegmentOptions};
    let fit = a.fit;
    if a.check_dir.is_some() && fit != Fit::Squash {
        return Err("--check-dir: only with --fit squash (one network input per image)".into());
    }
    let threads = a.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let opts = SegmentOptions {
        model: a.model,
        images: a.images,
        out: a.out,
        frames: a.frames,
        probabilities: a.probabilities,
        fit,
        threads,
        check: a.check_dir,
        overlay: a.overlay,
    };
    let bar = indicatif::ProgressBar::new(opts.frames.map_or(0, |r| r.len()) as u64);
    let style = indicatif::ProgressStyle::with_template("{bar:40} {pos} images, {elapsed} elapsed, eta {eta}");
    bar.set_style(style.unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()));
    let s = segment_folder(&opts, &|| bar.inc(1))?;
    bar.finish_and_clear();
    if a.json {
        return super::print_json(&s);
    }
    println!(
        "segmented {} images into {} ({} threads, fit {}): {:.0} ms per image, network {}x{} with {} channels loaded in {:.1} s",
        s.images,
        opts.out.display(),
        s.threads,
        a.fit,
        s.ms_per_image,
        s.input.1,
        s.input.0,
        s.channels,
        s.load_s
    );
    Ok(())
}

#[cfg(not(feature = "segment"))]
pub fn run(_: Args) -> Result<(), Error> {
    Err("this cosem was built without the `segment` feature (tract-onnx): \
         cargo build --release --features segment (or cargo install --path host --features segment)"
        .into())
}
