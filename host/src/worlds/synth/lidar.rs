//! The simulated 64-beam spinning LiDAR: its beams and one revolution's
//! scan cast through a scene.

use super::scene::{Scene, Sectors};
use super::SynthConfig;
use crate::rng::Rng;
use cosem_core::classes::Class;
use cosem_core::geometry::{Isometry3, Vector3};

/// Mount height of the LiDAR above the road (KITTI's).
pub const SENSOR_HEIGHT: f64 = 1.73;

/// Velodyne HDL-64E elevation angles (degrees): 32 upper beams at 1/3 degree
/// from +2 down, 32 lower beams at 1/2 degree from -8.83 down.
pub fn beam_elevations() -> Vec<f64> {
    let mut e: Vec<f64> = (0..32).map(|i| 2.0 - i as f64 / 3.0).collect();
    e.extend((0..32).map(|i| -8.83 - i as f64 * 0.5));
    e
}

/// One simulated scan: points in the sensor frame and raw SemanticKITTI labels.
pub struct SynthScan {
    /// x, y, z, intensity.
    pub points: Vec<[f32; 4]>,
    /// Raw label per point.
    pub labels: Vec<u32>,
}

/// Casts every beam of one revolution from `pose` through the scene.
pub(crate) fn scan(scene: &Scene, pose: &Isometry3<f64>, cfg: &SynthConfig, rng: &mut Rng) -> SynthScan {
    let t = pose.translation.vector;
    let o = [t.x, t.y, t.z];
    let rot = pose.rotation.to_rotation_matrix().into_inner();
    let sectors = Sectors::new(scene, o, cfg.max_range);
    let elevations = beam_elevations();
    let columns = (360.0 / cfg.azimuth_step_deg).round() as usize;
    let mut points = Vec::with_capacity(columns * elevations.len());
    let mut labels = Vec::with_capacity(columns * elevations.len());
    for col in 0..columns {
        let az_local = (col as f64 * cfg.azimuth_step_deg).to_radians();
        for &el in &elevations {
            let el = el.to_radians();
            let local = Vector3::new(el.cos() * az_local.cos(), el.cos() * az_local.sin(), el.sin());
            let w = rot * local;
            let Some((best, mut class)) = sectors.cast(scene, [w[0], w[1], w[2]]) else { continue };
            if best > cfg.max_range || best < 2.0 {
                continue;
            }
            let range = best + cfg.range_noise * rng.gaussian();
            if cfg.label_noise > 0.0 && rng.chance(cfg.label_noise) {
                class = Class::ALL[rng.below(Class::ALL.len() as u64) as usize];
            }
            let p = local * range;
            let intensity = 0.2 + 0.6 * (class.index() as f64 / 19.0);
            points.push([p[0] as f32, p[1] as f32, p[2] as f32, intensity as f32]);
            labels.push(u32::from(class.semantic_kitti_id()));
        }
    }
    SynthScan { points, labels }
}
