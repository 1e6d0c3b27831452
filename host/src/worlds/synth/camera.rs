//! Camera 2 of a synthetic sequence: its calibration, the segmentation a
//! perfect network would give, that image corrupted as a real network's,
//! and per-pixel class probabilities.

use super::scene::{Scene, Sectors};
use super::{BORDER_JITTER_PX, IMAGE_SIZE, WRONG_BLOBS};
use crate::camera::label::{ProbabilityMap, SegImage};
use crate::rng::Rng;
use cosem_core::camera::SegClasses;
use cosem_core::classes::Class;
use cosem_core::geometry::{Isometry3, Matrix4, Vector3};

/// KITTI sequence 00's camera projections, and an exactly orthonormal
/// velodyne-to-camera transform close to KITTI's.
pub(super) const CALIB_P: &str = "P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P1: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.861448000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P2: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 4.538225000000e+01 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 -1.130887000000e-01 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 3.779761000000e-03
P3: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.372877000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 2.369057000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 4.915215000000e-03
";

/// The synthetic velodyne-to-camera transform: camera x = -velodyne y,
/// camera y = -velodyne z, camera z = velodyne x, plus KITTI's offset.
pub fn synthetic_tr() -> Isometry3<f64> {
    let m = Matrix4::new(
        0.0, -1.0, 0.0, -0.012, //
        0.0, 0.0, -1.0, -0.054, //
        1.0, 0.0, 0.0, -0.292, //
        0.0, 0.0, 0.0, 1.0,
    );
    cosem_core::geometry::rigid_from_matrix(&m).unwrap_or_else(Isometry3::identity)
}

/// Camera `k`'s 3x4 projection from [`CALIB_P`].
fn projection(k: usize) -> nalgebra::Matrix3x4<f64> {
    let line = CALIB_P.lines().nth(k).unwrap_or_default();
    let v: Vec<f64> = line.split_whitespace().skip(1).filter_map(|t| t.parse().ok()).collect();
    nalgebra::Matrix3x4::from_row_slice(&v)
}

/// Renders what a perfect segmentation network gives for camera 2 on the
/// vehicle at LiDAR pose `velodyne` (world frame): the class of the first
/// surface along each pixel's ray; the sky where there is none.
pub(crate) fn render(scene: &Scene, velodyne: &Isometry3<f64>, classes: SegClasses) -> SegImage {
    let p2 = projection(2);
    let k = p2.fixed_view::<3, 3>(0, 0).into_owned();
    let kinv = k.try_inverse().unwrap_or_else(nalgebra::Matrix3::identity);
    let centre = -(kinv * p2.column(3));
    let cam_to_world = velodyne * synthetic_tr().inverse();
    let o = cam_to_world * nalgebra::Point3::new(centre.x, centre.y, centre.z);
    let rot = cam_to_world.rotation.to_rotation_matrix().into_inner();
    let sectors = Sectors::new(scene, [o.x, o.y, o.z], 500.0);
    let (w, h) = IMAGE_SIZE;
    let mut ids = Vec::with_capacity(w as usize * h as usize);
    for v in 0..h {
        for u in 0..w {
            let d = (rot * (kinv * Vector3::new(f64::from(u), f64::from(v), 1.0))).normalize();
            let class = sectors.cast(scene, [d.x, d.y, d.z]).filter(|(t, _)| *t <= 500.0).map(|(_, c)| c);
            ids.push(classes.id(class));
        }
    }
    SegImage { width: w, height: h, ids }
}

/// The class a segmentation network confuses `c` with.
fn confusable(c: Class) -> Class {
    match c {
        Class::Road | Class::Parking => Class::Sidewalk,
        Class::Sidewalk | Class::OtherGround => Class::Road,
        Class::Terrain => Class::Vegetation,
        Class::Vegetation => Class::Terrain,
        Class::Building => Class::Fence,
        Class::Fence => Class::Building,
        Class::Pole | Class::Trunk => Class::TrafficSign,
        Class::TrafficSign => Class::Pole,
        Class::Car => Class::Truck,
        Class::Truck | Class::OtherVehicle => Class::Car,
        Class::Person => Class::Bicyclist,
        Class::Bicyclist | Class::Motorcyclist | Class::Bicycle | Class::Motorcycle => Class::Person,
    }
}

/// A realistic network's errors on a perfect image: borders displaced by a
/// smooth random field (bilinear over a 24-pixel grid, up to
/// [`BORDER_JITTER_PX`]) plus a pixel of noise, then [`WRONG_BLOBS`] blobs
/// of a confusable wrong class on surfaces.
pub fn corrupt(image: &SegImage, classes: SegClasses, rng: &mut Rng) -> SegImage {
    let (w, h) = (image.width as usize, image.height as usize);
    const STEP: usize = 24;
    let (gw, gh) = (w / STEP + 2, h / STEP + 2);
    let field: Vec<[f64; 2]> = (0..gw * gh)
        .map(|_| [rng.range(-BORDER_JITTER_PX, BORDER_JITTER_PX), rng.range(-BORDER_JITTER_PX, BORDER_JITTER_PX)])
        .collect();
    let mut out = vec![0u8; w * h];
    for v in 0..h {
        for u in 0..w {
            let (fx, fy) = (u as f64 / STEP as f64, v as f64 / STEP as f64);
            let (gx, gy) = (fx.floor() as usize, fy.floor() as usize);
            let (ax, ay) = (fx - gx as f64, fy - gy as f64);
            let at = |x: usize, y: usize, k: usize| field[(y.min(gh - 1)) * gw + x.min(gw - 1)][k];
            let lerp = |k: usize| {
                (1.0 - ay) * ((1.0 - ax) * at(gx, gy, k) + ax * at(gx + 1, gy, k))
                    + ay * ((1.0 - ax) * at(gx, gy + 1, k) + ax * at(gx + 1, gy + 1, k))
            };
            let du = lerp(0) + rng.below(3) as f64 - 1.0;
            let dv = lerp(1) + rng.below(3) as f64 - 1.0;
            let su = (u as f64 + du).round().clamp(0.0, (w - 1) as f64) as usize;
            let sv = (v as f64 + dv).round().clamp(0.0, (h - 1) as f64) as usize;
            out[v * w + u] = image.ids[sv * w + su];
        }
    }
    for _ in 0..WRONG_BLOBS {
        let (cu, cv) = (rng.below(w as u64) as usize, rng.below(h as u64) as usize);
        let (rx, ry) = (rng.range(6.0, 40.0), rng.range(4.0, 25.0));
        let Ok(Some(c)) = classes.class(out[cv * w + cu]) else { continue };
        let wrong = classes.id(Some(confusable(c)));
        let (u0, u1) = ((cu as f64 - rx).max(0.0) as usize, ((cu as f64 + rx) as usize).min(w - 1));
        let (v0, v1) = ((cv as f64 - ry).max(0.0) as usize, ((cv as f64 + ry) as usize).min(h - 1));
        for v in v0..=v1 {
            for u in u0..=u1 {
                let (x, y) = ((u as f64 - cu as f64) / rx, (v as f64 - cv as f64) / ry);
                let px = &mut out[v * w + u];
                if x * x + y * y <= 1.0 && matches!(classes.class(*px), Ok(Some(_))) {
                    *px = wrong;
                }
            }
        }
    }
    SegImage { width: image.width, height: image.height, ids: out }
}

/// Per-pixel class probabilities from an image: each id's share of a 5x5
/// window (plus a little mass on every id), so borders are uncertain.
pub fn probabilities_of(image: &SegImage, classes: SegClasses) -> ProbabilityMap {
    let (w, h) = (image.width as usize, image.height as usize);
    let channels = classes.channels();
    let floor = 0.05f32;
    let mut values = vec![0.0f32; w * h * channels];
    for v in 0..h {
        for u in 0..w {
            let px = &mut values[(v * w + u) * channels..(v * w + u + 1) * channels];
            let mut n = 0.0f32;
            for y in v.saturating_sub(2)..=(v + 2).min(h - 1) {
                for x in u.saturating_sub(2)..=(u + 2).min(w - 1) {
                    if let Some(p) = px.get_mut(usize::from(image.ids[y * w + x])) {
                        *p += 1.0;
                        n += 1.0;
                    }
                }
            }
            let total = n + floor * channels as f32;
            for p in px.iter_mut() {
                *p = (*p + floor) / total;
            }
        }
    }
    ProbabilityMap { width: image.width, height: image.height, channels, values }
}
