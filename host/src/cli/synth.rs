//! `cosem synth`: a synthetic sequence in SemanticKITTI layout.

use super::args::SegChoice;
use super::Error;
use cosem_host::worlds::synth::{write_sequence, SegRender, SynthConfig};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder.
    #[arg(long, value_name = "OUT")]
    out: PathBuf,
    /// Number of frames, 1 to 100,000.
    #[arg(long, default_value_t = 10, value_parser = super::args::frames_count)]
    frames: usize,
    /// Seed of scene, trajectory and noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Range noise, standard deviation (m), 0 to 10.
    #[arg(long, default_value_t = SynthConfig::default().range_noise, value_parser = super::args::within::<0, 10>)]
    range_noise: f64,
    /// Fraction of points given a wrong random label, 0 to 1.
    #[arg(long, default_value_t = 0.0, value_parser = super::args::probability)]
    label_noise: f64,
    /// Distance driven per frame (m), 0 to 50.
    #[arg(long, default_value_t = SynthConfig::default().step, value_parser = super::args::within::<0, 50>)]
    step: f64,
    /// Render camera 2's segmentation image per frame into seg_2/, with
    /// these ids: cityscapes (a Cityscapes-trained network's 19 training
    /// ids), semantickitti (learning-map ids, 0 unlabeled), or none.
    #[arg(long, default_value = "cityscapes", value_parser = super::args::seg)]
    seg: SegChoice,
    /// Corrupt the images as a real network would: displaced class
    /// borders, blobs of a confusable wrong class.
    #[arg(long)]
    seg_corrupt: bool,
    /// Also write per-pixel class probabilities (seg_2/NNNNNN.npy).
    #[arg(long)]
    seg_probabilities: bool,
}

pub fn run(a: Args) -> Result<(), Error> {
    if a.frames == 0 {
        return Err("--frames must be at least 1".into());
    }
    if !((0.0..=1.0).contains(&a.label_noise) && a.range_noise >= 0.0 && a.range_noise.is_finite()) {
        return Err("--label-noise must be in [0, 1] and --range-noise a finite number >= 0".into());
    }
    if a.seg.is_none() && (a.seg_corrupt || a.seg_probabilities) {
        return Err("--seg-corrupt and --seg-probabilities need --seg cityscapes|semantickitti".into());
    }
    let seg = a.seg.map(|classes| SegRender { classes, corrupt: a.seg_corrupt, probabilities: a.seg_probabilities });
    let cfg = SynthConfig {
        seg,
        frames: a.frames,
        seed: a.seed,
        range_noise: a.range_noise,
        label_noise: a.label_noise,
        step: a.step,
        ..SynthConfig::default()
    };
    let t0 = std::time::Instant::now();
    let seq = write_sequence(&a.out, &cfg).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let points: usize = seq.scans.iter().map(|s| s.points.len()).sum();
    println!(
        "{}: {} frames, {} points ({:.0} per scan), seed {}, in {:.2} s",
        a.out.display(),
        a.frames,
        points,
        points as f64 / a.frames as f64,
        a.seed,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
