//! Synthetic SemanticKITTI sequences: a procedural street scene seen by a
//! simulated 64-beam spinning LiDAR driving through it.
//!
//! The scene is a straight street along x (road, parked cars, sidewalks with
//! poles and traffic signs, a terrain strip with trees, building facades of
//! varied setback and height with gaps, fences and bushes) crossed by side
//! streets. Everything is seeded: the same seed gives the same bytes. This is
//! the project's built-in data: demos and tests run on it without any dataset.

use crate::camera::label::SegImage;
use crate::rng::Rng;
use cosem_core::camera::SegClasses;
use cosem_core::geometry::{Isometry3, Translation3, UnitQuaternion};
use std::io::Write;
use std::path::Path;

mod camera;
mod lidar;
mod scene;

pub(crate) use camera::render;
use camera::CALIB_P;
pub use camera::{corrupt, probabilities_of, synthetic_tr};
pub(crate) use lidar::scan;
pub use lidar::{beam_elevations, SynthScan, SENSOR_HEIGHT};
pub(crate) use scene::{Object, Road, Scene, Shape};

/// What to synthesise.
#[derive(Clone, Debug)]
pub struct SynthConfig {
    /// Number of frames.
    pub frames: usize,
    /// Seed of the scene, the trajectory and the noise.
    pub seed: u64,
    /// Standard deviation of the range noise (m).
    pub range_noise: f64,
    /// Fraction of points given a wrong random label.
    pub label_noise: f64,
    /// Distance driven per frame (m); KITTI drives about 0.7-0.8 m per scan.
    pub step: f64,
    /// Horizontal angle between two firings (degrees).
    pub azimuth_step_deg: f64,
    /// Farthest return (m).
    pub max_range: f64,
    /// Segmentation images to render for camera 2 (`None`: none).
    pub seg: Option<SegRender>,
}

/// Segmentation images of camera 2, as a network would give them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SegRender {
    /// The ids written.
    pub classes: SegClasses,
    /// Corrupt the perfect image realistically: class borders displaced by a
    /// smooth random field of up to [`BORDER_JITTER_PX`] pixels plus one
    /// pixel of noise, and [`WRONG_BLOBS`] elliptic blobs of a confusable
    /// wrong class.
    pub corrupt: bool,
    /// Also write per-pixel class probabilities (`.npy`): each pixel's
    /// class shares in a 5x5 window, so borders are uncertain.
    pub probabilities: bool,
}

/// Folder of the rendered segmentation images in a synthetic sequence.
pub const SEG_DIR: &str = "seg_2";

/// Size of the rendered segmentation images (KITTI sequence 00's camera 2).
pub const IMAGE_SIZE: (u32, u32) = (1241, 376);
/// Largest border displacement of a corrupted image (pixels).
pub const BORDER_JITTER_PX: f64 = 4.0;
/// Wrong-class blobs per corrupted image.
pub const WRONG_BLOBS: usize = 12;

impl Default for SynthConfig {
    fn default() -> Self {
        SynthConfig {
            frames: 10,
            seed: 1,
            range_noise: 0.02,
            label_noise: 0.0,
            step: 0.8,
            azimuth_step_deg: 0.2,
            max_range: 80.0,
            seg: None,
        }
    }
}

/// The vehicle's LiDAR pose at frame `i` (world frame).
fn sensor_pose(i: usize, step: f64, wobble: f64) -> Isometry3<f64> {
    let x = i as f64 * step;
    let y = -1.6 + 0.35 * (x / 14.0 + wobble).sin();
    let dy = 0.35 / 14.0 * (x / 14.0 + wobble).cos();
    let yaw = dy.atan();
    Isometry3::from_parts(Translation3::new(x, y, SENSOR_HEIGHT), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw))
}

/// A synthesised sequence held in memory.
pub struct Synthesised {
    /// LiDAR poses: relative to the first scan's (a street), or in the
    /// world frame (a town's robot).
    pub poses: Vec<Isometry3<f64>>,
    /// The scans.
    pub scans: Vec<SynthScan>,
    /// Camera 2's segmentation image per scan, when asked for.
    pub seg: Vec<SegImage>,
}

/// Synthesises a sequence in memory.
pub fn synthesise(cfg: &SynthConfig) -> Synthesised {
    let mut rng = Rng::new(cfg.seed);
    let length = cfg.frames as f64 * cfg.step;
    let scene = Scene::generate(&mut rng, -cfg.max_range - 10.0, length + cfg.max_range + 10.0);
    let wobble = rng.range(0.0, std::f64::consts::TAU);
    let world: Vec<Isometry3<f64>> = (0..cfg.frames).map(|i| sensor_pose(i, cfg.step, wobble)).collect();
    let first_inv = world.first().map(Isometry3::inverse).unwrap_or_else(Isometry3::identity);
    let mut scans = Vec::with_capacity(cfg.frames);
    for pose in &world {
        scans.push(scan(&scene, pose, cfg, &mut rng));
    }
    // Images draw from their own seeded stream: the scans stay the same bytes.
    let mut seg_rng = Rng::new(cfg.seed ^ 0x005E_C011_A6E5);
    let seg = match cfg.seg {
        Some(r) => world
            .iter()
            .map(|pose| {
                let perfect = render(&scene, pose, r.classes);
                if r.corrupt {
                    corrupt(&perfect, r.classes, &mut seg_rng)
                } else {
                    perfect
                }
            })
            .collect(),
        None => Vec::new(),
    };
    Synthesised { poses: world.iter().map(|p| first_inv * p).collect(), scans, seg }
}

fn write_3x4(out: &mut impl Write, t: &Isometry3<f64>) -> std::io::Result<()> {
    let m = t.to_homogeneous();
    let v: Vec<String> =
        (0..3).flat_map(|r| (0..4).map(move |c| (r, c))).map(|(r, c)| format!("{:.9e}", m[(r, c)])).collect();
    writeln!(out, "{}", v.join(" "))
}

/// The first line of the PROVENANCE.md `cosem synth` writes: a folder
/// with it may be written over by a new run.
const PROVENANCE_TITLE: &str = "# Synthetic sequence made by `cosem synth`";

/// Refuses a folder that holds anything but an earlier output whose
/// PROVENANCE.md starts with `title` (a user's data would be replaced).
pub(crate) fn refuse_foreign(dir: &Path, title: &str) -> std::io::Result<()> {
    let Ok(mut entries) = std::fs::read_dir(dir) else { return Ok(()) };
    if entries.next().is_none() {
        return Ok(());
    }
    let ours = std::fs::read_to_string(dir.join("PROVENANCE.md")).is_ok_and(|t| t.starts_with(title));
    if ours {
        return Ok(());
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::AlreadyExists,
        "the folder holds files that are not an earlier `cosem synth` output of the same kind: choose a new or empty folder",
    ))
}

/// Synthesises a sequence and writes it in SemanticKITTI layout to `dir`
/// (a new or empty folder, or an earlier synthetic sequence's).
pub fn write_sequence(dir: &Path, cfg: &SynthConfig) -> std::io::Result<Synthesised> {
    refuse_foreign(dir, PROVENANCE_TITLE)?;
    // Written whole into a temporary folder, then swapped into place.
    let out = crate::paths::OutputDir::create(dir)?;
    let seq = write_into(out.path(), cfg)?;
    out.commit()?;
    Ok(seq)
}

fn write_into(dir: &Path, cfg: &SynthConfig) -> std::io::Result<Synthesised> {
    let seq = synthesise(cfg);
    let mut prov = Vec::new();
    writeln!(
        prov,
        "{PROVENANCE_TITLE}\n\nframes: {}\nseed: {}\nrange noise (m): {}\nlabel noise: {}\nstep (m/frame): {}\n\n\
         A procedural street seen by a simulated 64-beam LiDAR; labels are exact \
         SemanticKITTI ids (before label noise). Generated data, no third-party content.",
        cfg.frames, cfg.seed, cfg.range_noise, cfg.label_noise, cfg.step
    )?;
    write_folder(dir, &seq, cfg.seg, prov)?;
    Ok(seq)
}

/// Writes scans in SemanticKITTI layout into `dir`: velodyne/, labels/,
/// poses.txt (camera poses from `seq.poses`, in whatever frame they are),
/// times.txt (10 Hz), calib.txt, PROVENANCE.md (`prov`, then what the
/// segmentation is) and the segmentation images.
pub(crate) fn write_folder(
    dir: &Path,
    seq: &Synthesised,
    seg: Option<SegRender>,
    mut prov: Vec<u8>,
) -> std::io::Result<()> {
    std::fs::create_dir_all(dir.join("velodyne"))?;
    std::fs::create_dir_all(dir.join("labels"))?;
    let tr = synthetic_tr();
    let tr_inv = tr.inverse();
    let mut poses = Vec::new();
    let mut times = Vec::new();
    for (i, (pose, s)) in seq.poses.iter().zip(&seq.scans).enumerate() {
        let mut bin = Vec::with_capacity(s.points.len() * 16);
        for p in &s.points {
            for v in p {
                bin.extend_from_slice(&v.to_le_bytes());
            }
        }
        crate::paths::write_file(dir.join("velodyne").join(format!("{i:06}.bin")), bin)?;
        let lab: Vec<u8> = s.labels.iter().flat_map(|l| l.to_le_bytes()).collect();
        crate::paths::write_file(dir.join("labels").join(format!("{i:06}.label")), lab)?;
        write_3x4(&mut poses, &(tr * pose * tr_inv))?;
        writeln!(times, "{:.6e}", i as f64 * 0.1)?;
    }
    crate::paths::write_file(dir.join("poses.txt"), poses)?;
    crate::paths::write_file(dir.join("times.txt"), times)?;
    let mut calib = CALIB_P.as_bytes().to_vec();
    calib.extend_from_slice(b"Tr: ");
    write_3x4(&mut calib, &tr)?;
    crate::paths::write_file(dir.join("calib.txt"), calib)?;
    if let Some(r) = seg {
        writeln!(
            prov,
            "\n{SEG_DIR}/: camera 2's segmentation per scan ({}x{} PNG of {} ids{}{}), rendered by ray casting \
             through P2 and Tr.",
            IMAGE_SIZE.0,
            IMAGE_SIZE.1,
            r.classes.name(),
            if r.corrupt { ", corrupted: displaced borders and wrong-class blobs" } else { ", as a perfect network" },
            if r.probabilities { "; NNNNNN.npy: per-pixel class probabilities" } else { "" }
        )?;
    }
    crate::paths::write_file(dir.join("PROVENANCE.md"), prov)?;
    if let Some(r) = seg {
        let seg_dir = dir.join(SEG_DIR);
        std::fs::create_dir_all(&seg_dir)?;
        for (i, im) in seq.seg.iter().enumerate() {
            crate::camera::label::write_seg_png(&seg_dir.join(format!("{i:06}.png")), im)?;
            if r.probabilities {
                let p = probabilities_of(im, r.classes);
                crate::camera::label::write_probabilities(&seg_dir.join(format!("{i:06}.npy")), &p)?;
            }
        }
    }
    Ok(())
}
