//! `cosem label`: LiDAR labels from camera segmentation images.

use super::Error;
use cosem_host::camera::label::{label_sequence, label_with_model, parse_image_size, LabelOptions};
use cosem_host::reports::report::LabelJson;
use cosem_host::sources::kitti::FrameRange;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// SemanticKITTI-layout folder (velodyne/, poses.txt, calib.txt; labels/
    /// optional: when present, the new labels are compared with them).
    #[arg(long)]
    data: PathBuf,
    /// Segmentation images: 8-bit PNGs of class ids named like the scans
    /// (000042.png), or with --probabilities NumPy maps (000042.npy).
    #[arg(long, required_unless_present = "model", conflicts_with = "model")]
    seg: Option<PathBuf>,
    /// Segment the camera's images with this network (ONNX, as `cosem
    /// segment`; feature `segment`) into OUT/seg_<camera>/ first, then label
    /// from them.
    #[arg(long, requires = "images")]
    model: Option<PathBuf>,
    /// With --model: the camera's colour images (KITTI's image_2/).
    #[arg(long, requires = "model")]
    images: Option<PathBuf>,
    /// With --model: how an image meets the network (see `cosem segment`).
    #[arg(long, default_value = "tile", value_parser = super::args::fit)]
    fit: cosem_host::camera::seg_files::Fit,
    /// Camera whose projection `P<camera>` in calib.txt the images are from.
    #[arg(long, default_value_t = 2)]
    camera: u8,
    /// What the image ids mean: cityscapes (19 training ids, 255 ignored) or
    /// semantickitti (learning-map ids, 0 unlabeled).
    #[arg(long, default_value = "cityscapes")]
    classes: cosem_core::camera::SegClasses,
    /// Read per-pixel class probabilities (.npy, <f4 or |u1, HxWxC or CxHxW)
    /// and write their evidence beside the labels (evidence/), which mapping
    /// fuses instead of the hard labels.
    #[arg(long)]
    probabilities: bool,
    /// Label points the camera cannot see (behind nearer points of the scan,
    /// seen by the LiDAR from its other viewpoint) too; by default they stay
    /// unlabelled.
    #[arg(long)]
    keep_occluded: bool,
    /// The camera's image size WIDTHxHEIGHT; default: its images'
    /// (image_<camera>/ beside the scans), else about twice the principal
    /// point. Segmentation of another size is refused unless
    /// --scale-to-images.
    #[arg(long)]
    image_size: Option<String>,
    /// Segmentation of another size than the camera's images (a network's
    /// output, e.g. 1024x512): scale the projection to it.
    #[arg(long)]
    scale_to_images: bool,
    /// With --probabilities: the maps hold a void (ignore) channel beyond
    /// the class set's, first or last (most Cityscapes networks: 19
    /// classes and void last); its probability counts as no class.
    #[arg(long, default_value = "none", value_parser = super::args::named::<cosem_host::camera::seg_files::VoidChannel>())]
    void_channel: cosem_host::camera::label::VoidChannel,
    /// Frames START:END[:STRIDE]; default: every scan in velodyne/.
    #[arg(long)]
    frames: Option<FrameRange>,
    /// Output folder (SemanticKITTI layout: links to the scans, copies of
    /// calib, poses and times, the new labels).
    #[arg(long, value_name = "OUT")]
    out: PathBuf,
    /// Copy the scans into the output folder instead of linking them
    /// (relative symbolic links: the two folders may move together).
    #[arg(long)]
    copy_scans: bool,
    /// Print JSON.
    #[arg(long)]
    pub(super) json: bool,
}

pub fn run(a: Args) -> Result<(), Error> {
    let opts = LabelOptions {
        data: a.data.clone(),
        seg: a.seg.clone().unwrap_or_default(),
        camera: a.camera,
        classes: a.classes,
        probabilities: a.probabilities,
        occlusion: !a.keep_occluded,
        image_size: a.image_size.as_deref().map(parse_image_size).transpose()?,
        frames: a.frames.into_iter().collect(),
        out: a.out.clone(),
        copy_scans: a.copy_scans,
        void_channel: a.void_channel,
        scale_to_images: a.scale_to_images,
    };
    let t = std::time::Instant::now();
    let s = match (&a.seg, &a.model, &a.images) {
        (Some(_), _, _) => label_sequence(&opts)?,
        (None, Some(model), Some(images)) => {
            let (s, n, ms) = label_with_model(&opts, model, images, a.fit)?;
            let kept = a.out.join(format!("seg_{}", a.camera));
            eprintln!("segmented {n} images ({ms:.0} ms per image), kept in {}", kept.display());
            s
        }
        _ => return Err("give --seg, or --model with --images".into()),
    };
    let wall = t.elapsed().as_secs_f64();
    if a.json {
        return super::print_json(&LabelJson::of(&s, &opts, wall));
    }
    print!("{}", s.text(&opts, wall));
    Ok(())
}
