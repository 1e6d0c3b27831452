//! A synthetic town for robots that keep driving (`cosem synth --town`):
//! a grid of blocks (streets with junctions, one loop around the town and
//! others through it, parked cars, trees and bushes, poles and signs,
//! buildings), and a route per robot along its streets, on the right lane.
//! With the defaults two robots start at opposite corners, out of sight of
//! each other, drive the outer loop in opposite directions, meet at a
//! corner, part, and meet again at the opposite corner; a third starts at
//! a third corner and crosses the town's middle street.
//!
//! Each robot gets a SemanticKITTI-layout folder (`robot_<i>/`): its scans
//! (the simulated 64-beam LiDAR of [`super::synth`]), camera 2's
//! segmentation, and its true poses in the town's one world frame
//! (`poses.txt` is not re-anchored), with `world.txt` naming the town, so
//! that tools know the robots share a world.

use super::synth::{
    render, scan, write_folder, Object, Road, Scene, SegRender, Shape, SynthConfig, Synthesised, SENSOR_HEIGHT,
};
use crate::rng::Rng;
use cosem_core::camera::SegClasses;
use cosem_core::geometry::{Isometry3, Translation3, UnitQuaternion};
use std::io::Write;
use std::path::Path;

/// What town to build, and how its robots drive.
#[derive(Clone, Debug)]
pub struct TownConfig {
    /// Blocks on a side (the streets: one more each way).
    pub blocks: usize,
    /// Distance between two parallel streets (m).
    pub block: f64,
    /// Robots (2 or 3).
    pub robots: usize,
    /// Scans per robot.
    pub frames: usize,
    /// Distance driven between two scans (m).
    pub step: f64,
    /// Seed of the town, the scans' noise and the images' errors.
    pub seed: u64,
    /// Range noise of the LiDAR (m).
    pub range_noise: f64,
    /// Horizontal angle between two firings (degrees).
    pub azimuth_step_deg: f64,
    /// Farthest return (m).
    pub max_range: f64,
    /// Camera segmentation to render (`None`: none).
    pub seg: Option<SegRender>,
}

impl Default for TownConfig {
    /// Two blocks of 40 m a side, two robots, 280 scans 1 m apart each
    /// (280 m: two meetings of robots 0 and 1), the LiDAR at 0.6 degrees
    /// to 40 m, camera segmentation as a real network gives it
    /// (Cityscapes ids, corrupted).
    fn default() -> Self {
        TownConfig {
            blocks: 2,
            block: 40.0,
            robots: 2,
            frames: 280,
            step: 1.0,
            seed: 1,
            range_noise: 0.02,
            azimuth_step_deg: 0.6,
            max_range: 40.0,
            seg: Some(SegRender { classes: SegClasses::Cityscapes, corrupt: true, probabilities: false }),
        }
    }
}

/// The largest town: blocks on a side.
pub const MAX_BLOCKS: usize = 8;

/// The first line of the town's PROVENANCE.md.
const PROVENANCE_TITLE: &str = "# Synthetic town made by `cosem synth` (a town)";

/// Road margin beyond the outer streets (m): the town's edge.
const EDGE: f64 = 30.0;

/// The town's objects and roads: each street generated along x in its own
/// frame (clear of its junctions), turned into place.
fn town_scene(cfg: &TownConfig, rng: &mut Rng) -> Scene {
    let n = cfg.blocks;
    let span = n as f64 * cfg.block;
    let lines: Vec<f64> = (0..=n).map(|k| k as f64 * cfg.block).collect();
    let mut objects = Vec::new();
    let mut roads = Vec::new();
    for along_x in [true, false] {
        for &at in &lines {
            let street = Scene::town_street(rng, -EDGE, span + EDGE, lines.clone());
            objects.extend(street.into_iter().map(|o| place(o, along_x, at)));
            roads.push(Road { along_x, at, from: -EDGE, to: span + EDGE });
        }
    }
    Scene::town(objects, roads)
}

/// An object of a street along x (centre line y = 0) placed on the street
/// along x at y = `at`, or along y at x = `at` (turned by 90 degrees).
fn place(o: Object, along_x: bool, at: f64) -> Object {
    let p = |x: f64, y: f64| if along_x { [x, y + at] } else { [at - y, x] };
    let shape = match o.shape {
        Shape::Box { min, max } => {
            let (a, b) = (p(min[0], min[1]), p(max[0], max[1]));
            Shape::Box { min: [a[0].min(b[0]), a[1].min(b[1]), min[2]], max: [a[0].max(b[0]), a[1].max(b[1]), max[2]] }
        }
        Shape::Cylinder { c, r, z0, z1 } => Shape::Cylinder { c: p(c[0], c[1]), r, z0, z1 },
        Shape::Sphere { c, r } => {
            let q = p(c[0], c[1]);
            Shape::Sphere { c: [q[0], q[1], c[2]], r }
        }
    };
    Object::new(shape, o.class)
}

/// Robot `i`'s junctions, in blocks (repeated as long as it drives).
fn route_nodes(i: usize, n: usize) -> Vec<(usize, usize)> {
    let ring_ccw = [(0, 0), (n, 0), (n, n), (0, n)];
    let mid = n / 2;
    match i {
        0 => ring_ccw.to_vec(),
        1 => vec![(n, n), (n, 0), (0, 0), (0, n)],
        _ => vec![(0, n), (0, mid), (n, mid), (n, n), (mid, n), (mid, 0), (0, 0)],
    }
}

/// Robot `i`'s sensor poses, `step` apart along its route on the right
/// lane, corners rounded.
fn route(i: usize, cfg: &TownConfig) -> Vec<Isometry3<f64>> {
    let nodes = route_nodes(i, cfg.blocks);
    let at = |k: usize| {
        let (x, y) = nodes[k % nodes.len()];
        [x as f64 * cfg.block, y as f64 * cfg.block]
    };
    // A dense centre line: straight legs, corners cut by a quadratic curve.
    let corner = 8.0f64.min(cfg.block / 3.0);
    let mut line: Vec<[f64; 2]> = Vec::new();
    let need = cfg.frames as f64 * cfg.step + cfg.block + corner;
    let (mut k, mut length) = (0usize, 0.0f64);
    while length < need {
        let (a, b, c) = (at(k), at(k + 1), at(k + 2));
        let dir = |p: [f64; 2], q: [f64; 2]| {
            let d = [q[0] - p[0], q[1] - p[1]];
            let l = d[0].hypot(d[1]).max(1e-9);
            [d[0] / l, d[1] / l]
        };
        let (u, v) = (dir(a, b), dir(b, c));
        let leg = (b[0] - a[0]).hypot(b[1] - a[1]);
        let start = if k == 0 { 0.0 } else { corner };
        let mut s = start;
        while s < leg - corner {
            line.push([a[0] + u[0] * s, a[1] + u[1] * s]);
            s += 0.25;
        }
        let (p0, p2) = ([b[0] - u[0] * corner, b[1] - u[1] * corner], [b[0] + v[0] * corner, b[1] + v[1] * corner]);
        for t in 0..16 {
            let t = f64::from(t) / 16.0;
            let w = [(1.0 - t) * (1.0 - t), 2.0 * t * (1.0 - t), t * t];
            line.push([w[0] * p0[0] + w[1] * b[0] + w[2] * p2[0], w[0] * p0[1] + w[1] * b[1] + w[2] * p2[1]]);
        }
        length += leg;
        k += 1;
    }
    resample(&line, cfg.step, cfg.frames)
}

/// Poses every `step` metres along the right lane of a dense centre line
/// (1.6 m right of it), heading along it.
fn resample(centre: &[[f64; 2]], step: f64, frames: usize) -> Vec<Isometry3<f64>> {
    let lane: Vec<[f64; 2]> = (0..centre.len())
        .map(|k| {
            let (a, b) = (centre[k.saturating_sub(1)], centre[(k + 1).min(centre.len() - 1)]);
            let yaw = (b[1] - a[1]).atan2(b[0] - a[0]);
            [centre[k][0] + 1.6 * yaw.sin(), centre[k][1] - 1.6 * yaw.cos()]
        })
        .collect();
    let mut out = Vec::with_capacity(frames);
    let (mut travelled, mut next) = (0.0f64, 0.0f64);
    for w in lane.windows(2) {
        let (a, b) = (w[0], w[1]);
        let d = (b[0] - a[0]).hypot(b[1] - a[1]);
        while next <= travelled + d && out.len() < frames {
            let t = if d > 0.0 { (next - travelled) / d } else { 0.0 };
            let (x, y) = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]));
            let yaw = (b[1] - a[1]).atan2(b[0] - a[0]);
            out.push(Isometry3::from_parts(
                Translation3::new(x, y, SENSOR_HEIGHT),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            ));
            next += step;
        }
        travelled += d;
    }
    out
}

/// A town built in memory: each robot's scans, images and world poses.
pub struct Town {
    /// Robot i's scans, segmentation and poses (in the town's world frame).
    pub robots: Vec<Synthesised>,
}

/// Builds the town and drives its robots through it.
pub fn build(cfg: &TownConfig) -> Town {
    let mut rng = Rng::new(cfg.seed);
    let scene = town_scene(cfg, &mut rng);
    let lidar = SynthConfig {
        frames: cfg.frames,
        seed: cfg.seed,
        range_noise: cfg.range_noise,
        step: cfg.step,
        azimuth_step_deg: cfg.azimuth_step_deg,
        max_range: cfg.max_range,
        ..SynthConfig::default()
    };
    let robots = (0..cfg.robots)
        .map(|i| {
            let poses = route(i, cfg);
            let mut noise = Rng::new(cfg.seed ^ (0x7_0A11 + i as u64));
            let scans = poses.iter().map(|p| scan(&scene, p, &lidar, &mut noise)).collect();
            let mut seg_rng = Rng::new(cfg.seed ^ (0x005E_C011_A6E5 + i as u64));
            let seg = cfg
                .seg
                .map(|r| {
                    poses
                        .iter()
                        .map(|p| {
                            let perfect = render(&scene, p, r.classes);
                            if r.corrupt {
                                super::synth::corrupt(&perfect, r.classes, &mut seg_rng)
                            } else {
                                perfect
                            }
                        })
                        .collect()
                })
                .unwrap_or_default();
            Synthesised { poses, scans, seg }
        })
        .collect();
    Town { robots }
}

/// The line of `world.txt` every robot folder of this town holds.
fn world_line(cfg: &TownConfig) -> String {
    format!("cosem town: seed {}, {} blocks of {} m", cfg.seed, cfg.blocks, cfg.block)
}

/// Builds the town and writes it into `dir` (a new or empty folder, or an
/// earlier town's): `robot_<i>/` per robot, and a PROVENANCE.md.
pub fn write_town(dir: &Path, cfg: &TownConfig) -> std::io::Result<Town> {
    super::synth::refuse_foreign(dir, PROVENANCE_TITLE)?;
    let out = crate::paths::OutputDir::create(dir)?;
    let town = build(cfg);
    for (i, robot) in town.robots.iter().enumerate() {
        let folder = out.path().join(format!("robot_{i}"));
        let mut prov = Vec::new();
        writeln!(
            prov,
            "# Robot {i} of a synthetic town made by `cosem synth`\n\n{}\nframes: {}\nstep (m/frame): {}\n\n\
             Poses are in the town's world frame (not re-anchored at the first scan); world.txt names the town. \
             Generated data, no third-party content.",
            world_line(cfg),
            cfg.frames,
            cfg.step
        )?;
        write_folder(&folder, robot, cfg.seg, prov)?;
        crate::paths::write_file(folder.join("world.txt"), format!("{}\n", world_line(cfg)).into_bytes())?;
    }
    let mut prov = Vec::new();
    writeln!(
        prov,
        "{PROVENANCE_TITLE}\n\n{}\nrobots: {}\nframes per robot: {}\nstep (m/frame): {}\n\n\
         robot_<i>/: a SemanticKITTI-layout folder per robot (scans of a simulated 64-beam LiDAR, \
         camera 2's segmentation, true poses in the town's world frame). Generated data, no third-party content.",
        world_line(cfg),
        cfg.robots,
        cfg.frames,
        cfg.step
    )?;
    crate::paths::write_file(out.path().join("PROVENANCE.md"), prov)?;
    out.commit()?;
    Ok(town)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Robots 0 and 1 start out of sight of each other (opposite corners),
    /// pass within a few metres of each other twice in 480 m, and are far
    /// apart between.
    #[test]
    fn robots_meet_part_and_meet_again() {
        let cfg = TownConfig::default();
        let (a, b) = (route(0, &cfg), route(1, &cfg));
        assert_eq!((a.len(), b.len()), (cfg.frames, cfg.frames));
        let d: Vec<f64> = a.iter().zip(&b).map(|(p, q)| (p.translation.vector - q.translation.vector).norm()).collect();
        assert!(d[0] > 100.0, "start {}", d[0]);
        let close: Vec<usize> = (0..d.len()).filter(|&k| d[k] < 10.0).collect();
        assert!(!close.is_empty(), "{d:?}");
        let meetings = 1 + close.windows(2).filter(|w| w[1] > w[0] + 5).count();
        assert!(meetings >= 2, "{meetings} meetings: {close:?}");
        assert!(d.iter().any(|&x| x > 100.0) && d[d.len() / 2] > 60.0, "{d:?}");
        // Steps are `step` apart.
        for w in a.windows(2) {
            let s = (w[1].translation.vector - w[0].translation.vector).norm();
            assert!((s - cfg.step).abs() < 0.1, "{s}");
        }
    }
}
