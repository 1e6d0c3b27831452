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
    /// Number of frames, 1 to 100,000 (default 10; with --town, per
    /// robot, default 280).
    #[arg(long, value_parser = super::args::frames_count)]
    frames: Option<usize>,
    /// Seed of scene, trajectory and noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Range noise, standard deviation (m), 0 to 10.
    #[arg(long, default_value_t = SynthConfig::default().range_noise, value_parser = super::args::within::<0, 10>)]
    range_noise: f64,
    /// Fraction of points given a wrong random label, 0 to 1.
    #[arg(long, default_value_t = 0.0, value_parser = super::args::probability)]
    label_noise: f64,
    /// Distance driven per frame (m), 0 to 50 (default 0.8; with --town 1).
    #[arg(long, value_parser = super::args::within::<0, 50>)]
    step: Option<f64>,
    /// A town instead of a street: a grid of blocks and a route per robot
    /// (robot_0/, robot_1/, ...: a SemanticKITTI-layout folder each, poses in
    /// the town's world frame). Robots 0 and 1 start at opposite corners,
    /// meet, part and meet again.
    #[arg(long)]
    town: bool,
    /// With --town: its robots, 2 or 3.
    #[arg(long, requires = "town", value_parser = clap::value_parser!(u8).range(2..=3))]
    robots: Option<u8>,
    /// With --town: blocks on a side, 1 to 8.
    #[arg(long, requires = "town", value_parser = clap::value_parser!(u8).range(1..=8))]
    blocks: Option<u8>,
    /// Render camera 2's segmentation image per frame into seg_2/, with
    /// these ids: cityscapes (a Cityscapes-trained network's 19 training
    /// ids), semantickitti (learning-map ids, 0 unlabeled), or none.
    #[arg(long, default_value = "cityscapes", value_parser = super::args::seg)]
    seg: SegChoice,
    /// Corrupt the images as a real network would: displaced class
    /// borders, blobs of a confusable wrong class (a town's images always
    /// are).
    #[arg(long)]
    seg_corrupt: bool,
    /// Also write per-pixel class probabilities (seg_2/NNNNNN.npy).
    #[arg(long)]
    seg_probabilities: bool,
}

pub fn run(a: Args) -> Result<(), Error> {
    if a.town {
        return town(a);
    }
    let frames = a.frames.unwrap_or(10);
    if frames == 0 {
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
        frames,
        seed: a.seed,
        range_noise: a.range_noise,
        label_noise: a.label_noise,
        step: a.step.unwrap_or(SynthConfig::default().step),
        ..SynthConfig::default()
    };
    let t0 = std::time::Instant::now();
    let seq = write_sequence(&a.out, &cfg).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let points: usize = seq.scans.iter().map(|s| s.points.len()).sum();
    println!(
        "{}: {} frames, {} points ({:.0} per scan), seed {}, in {:.2} s",
        a.out.display(),
        frames,
        points,
        points as f64 / frames as f64,
        a.seed,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

/// `cosem synth --town`.
fn town(a: Args) -> Result<(), Error> {
    use cosem_host::worlds::town::{write_town, TownConfig};
    if a.label_noise > 0.0 {
        return Err("--label-noise: a town's scans keep exact labels (give a session --label-noise instead)".into());
    }
    let d = TownConfig::default();
    let seg = match a.seg {
        Some(classes) => Some(SegRender { classes, corrupt: true, probabilities: a.seg_probabilities }),
        None if a.seg_corrupt || a.seg_probabilities => {
            return Err("--seg-corrupt and --seg-probabilities need --seg cityscapes|semantickitti".into())
        }
        None => None,
    };
    let cfg = TownConfig {
        blocks: a.blocks.map_or(d.blocks, usize::from),
        robots: a.robots.map_or(d.robots, usize::from),
        frames: a.frames.unwrap_or(d.frames),
        step: a.step.unwrap_or(d.step),
        seed: a.seed,
        range_noise: a.range_noise,
        seg,
        ..d
    };
    if cfg.step <= 0.0 {
        return Err("--step: a town's robots drive, more than 0 m a frame".into());
    }
    let t0 = std::time::Instant::now();
    let town = write_town(&a.out, &cfg).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let points: usize = town.robots.iter().flat_map(|r| &r.scans).map(|s| s.points.len()).sum();
    println!(
        "{}: a town of {} blocks, {} robots of {} frames ({} points), seed {}, in {:.2} s",
        a.out.display(),
        cfg.blocks,
        cfg.robots,
        cfg.frames,
        points,
        a.seed,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::Args;
    use cosem_host::worlds::town::TownConfig;

    /// The help states the town's defaults as `TownConfig` has them (it
    /// once said 120 frames 4 m apart, after the town had changed).
    #[test]
    fn the_help_states_the_towns_defaults() {
        let d = TownConfig::default();
        let mut cmd = <Args as clap::Args>::augment_args(clap::Command::new("synth"));
        let help = cmd.render_long_help().to_string();
        for said in [format!("with --town, per robot, default {})", d.frames), format!("with --town {})", d.step)] {
            assert!(help.contains(&said), "the help does not say {said:?}: {help}");
        }
    }
}
