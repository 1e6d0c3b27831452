//! Synthetic SemanticKITTI sequences: a procedural street scene seen by a
//! simulated 64-beam spinning LiDAR driving through it.
//!
//! The scene is a straight street along x (road, parked cars, sidewalks with
//! poles and traffic signs, a terrain strip with trees, building facades of
//! varied setback and height with gaps, fences and bushes) crossed by side
//! streets. Everything is seeded: the same seed gives the same bytes. This is
//! the project's built-in data: demos and tests run on it without any dataset.

use crate::camera::label::{ProbabilityMap, SegImage};
use crate::rng::Rng;
use cosem_core::camera::SegClasses;
use cosem_core::classes::Class;
use cosem_core::geometry::{Isometry3, Matrix4, Translation3, UnitQuaternion, Vector3};
use std::io::Write;
use std::path::Path;

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

/// Mount height of the LiDAR above the road (KITTI's).
pub const SENSOR_HEIGHT: f64 = 1.73;
const ROAD_HALF: f64 = 5.0;
const SIDEWALK_WIDTH: f64 = 2.5;
const CURB: f64 = 0.15;

#[derive(Clone, Copy, Debug)]
pub(crate) enum Shape {
    /// Axis-aligned box.
    Box {
        min: [f64; 3],
        max: [f64; 3],
    },
    /// Vertical cylinder.
    Cylinder {
        c: [f64; 2],
        r: f64,
        z0: f64,
        z1: f64,
    },
    Sphere {
        c: [f64; 3],
        r: f64,
    },
}

#[derive(Clone, Copy, Debug)]
pub(crate) struct Object {
    pub(crate) shape: Shape,
    pub(crate) class: Class,
    /// Bounding circle in xy: centre and radius.
    bound: ([f64; 2], f64),
}

impl Object {
    pub(crate) fn new(shape: Shape, class: Class) -> Self {
        let bound = match shape {
            Shape::Box { min, max } => {
                let c = [(min[0] + max[0]) / 2.0, (min[1] + max[1]) / 2.0];
                (c, ((max[0] - min[0]).hypot(max[1] - min[1])) / 2.0)
            }
            Shape::Cylinder { c, r, .. } => (c, r),
            Shape::Sphere { c, r } => ([c[0], c[1]], r),
        };
        Object { shape, class, bound }
    }

    /// Distance along the ray to the first hit, if any.
    fn hit(&self, o: &[f64; 3], d: &[f64; 3]) -> Option<f64> {
        match self.shape {
            Shape::Box { min, max } => {
                let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
                for a in 0..3 {
                    if d[a].abs() < 1e-12 {
                        if o[a] < min[a] || o[a] > max[a] {
                            return None;
                        }
                    } else {
                        let inv = 1.0 / d[a];
                        let (mut ta, mut tb) = ((min[a] - o[a]) * inv, (max[a] - o[a]) * inv);
                        if ta > tb {
                            std::mem::swap(&mut ta, &mut tb);
                        }
                        t0 = t0.max(ta);
                        t1 = t1.min(tb);
                        if t0 > t1 {
                            return None;
                        }
                    }
                }
                (t0 > 1e-6).then_some(t0)
            }
            Shape::Cylinder { c, r, z0, z1 } => {
                let (ox, oy) = (o[0] - c[0], o[1] - c[1]);
                let a = d[0] * d[0] + d[1] * d[1];
                if a < 1e-12 {
                    return None;
                }
                let b = ox * d[0] + oy * d[1];
                let cc = ox * ox + oy * oy - r * r;
                let disc = b * b - a * cc;
                if disc < 0.0 {
                    return None;
                }
                let t = (-b - disc.sqrt()) / a;
                let z = o[2] + t * d[2];
                (t > 1e-6 && z >= z0 && z <= z1).then_some(t)
            }
            Shape::Sphere { c, r } => {
                let oc = [o[0] - c[0], o[1] - c[1], o[2] - c[2]];
                let b = oc[0] * d[0] + oc[1] * d[1] + oc[2] * d[2];
                let cc = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - r * r;
                let disc = b * b - cc;
                if disc < 0.0 {
                    return None;
                }
                let t = -b - disc.sqrt();
                (t > 1e-6).then_some(t)
            }
        }
    }
}

/// A straight road of a town: its centre line along x (at `y = at`) or
/// along y (at `x = at`), from `from` to `to`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Road {
    /// Along x (else along y).
    pub(crate) along_x: bool,
    /// The centre line's other coordinate.
    pub(crate) at: f64,
    /// Where it starts and ends along its axis.
    pub(crate) from: f64,
    pub(crate) to: f64,
}

impl Road {
    fn holds(&self, x: f64, y: f64) -> bool {
        let (along, across) = if self.along_x { (x, y) } else { (y, x) };
        (across - self.at).abs() < ROAD_HALF && along >= self.from - ROAD_HALF && along <= self.to + ROAD_HALF
    }
}

/// The procedural street (or, with `roads`, a town).
pub(crate) struct Scene {
    pub(crate) objects: Vec<Object>,
    /// x centres of the cross streets.
    cross: Vec<f64>,
    /// A town's roads (empty: the one street along x and its cross streets).
    pub(crate) roads: Vec<Road>,
    /// No building reaches across a cross street (a town's, whose streets
    /// robots drive).
    keep_cross_clear: bool,
}

impl Scene {
    fn in_cross_street(&self, x: f64, margin: f64) -> bool {
        self.cross.iter().any(|c| (x - c).abs() < ROAD_HALF + margin)
    }

    /// Whether `[a, b]` reaches into a cross street (with `margin`).
    fn spans_cross_street(&self, a: f64, b: f64, margin: f64) -> bool {
        self.cross.iter().any(|c| a < c + ROAD_HALF + margin && b > c - ROAD_HALF - margin)
    }

    /// Class of the ground at (x, y).
    fn ground_class(&self, x: f64, y: f64) -> Class {
        let road = if self.roads.is_empty() {
            y.abs() < ROAD_HALF || self.in_cross_street(x, 0.0)
        } else {
            self.roads.iter().any(|r| r.holds(x, y))
        };
        if road {
            Class::Road
        } else {
            Class::Terrain
        }
    }

    /// One street along x from `x_min` to `x_max` with cross streets at
    /// `cross`, in its own frame (the centre line on y = 0), its objects
    /// kept clear of the cross streets: a town's street, placed by the
    /// caller.
    pub(crate) fn town_street(rng: &mut Rng, x_min: f64, x_max: f64, cross: Vec<f64>) -> Vec<Object> {
        let mut scene = Scene { objects: Vec::new(), cross, roads: Vec::new(), keep_cross_clear: true };
        scene.both_sides(rng, x_min, x_max);
        scene.objects
    }

    /// Both sides of the street from `x_min` to `x_max`: sidewalks,
    /// buildings, trees, poles, parked cars.
    fn both_sides(&mut self, rng: &mut Rng, x_min: f64, x_max: f64) {
        for side in [-1.0f64, 1.0] {
            self.sidewalks(side, x_min, x_max);
            self.buildings(rng, side, x_min, x_max);
            self.trees(rng, side, x_min, x_max);
            self.poles(rng, side, x_min, x_max);
            self.cars(rng, side, x_min, x_max);
        }
    }

    /// A town: its objects and roads.
    pub(crate) fn town(objects: Vec<Object>, roads: Vec<Road>) -> Scene {
        Scene { objects, cross: Vec::new(), roads, keep_cross_clear: true }
    }

    fn generate(rng: &mut Rng, x_min: f64, x_max: f64) -> Scene {
        let mut cross = Vec::new();
        let mut x = x_min + rng.range(20.0, 50.0);
        while x < x_max {
            cross.push(x);
            x += rng.range(60.0, 120.0);
        }
        let mut scene = Scene { objects: Vec::new(), cross, roads: Vec::new(), keep_cross_clear: false };
        scene.both_sides(rng, x_min, x_max);
        scene
    }

    fn add(&mut self, shape: Shape, class: Class) {
        self.objects.push(Object::new(shape, class));
    }

    /// Sidewalk slabs on one side, cut at cross streets.
    fn sidewalks(&mut self, side: f64, x_min: f64, x_max: f64) {
        let scene = self;
        let mut edges = vec![x_min];
        for c in &scene.cross {
            edges.push(c - ROAD_HALF);
            edges.push(c + ROAD_HALF);
        }
        edges.push(x_max);
        for pair in edges.chunks(2) {
            if let [a, b] = *pair {
                if b > a {
                    let (y0, y1) = (side * ROAD_HALF, side * (ROAD_HALF + SIDEWALK_WIDTH));
                    scene.add(Shape::Box { min: [a, y0.min(y1), 0.0], max: [b, y0.max(y1), CURB] }, Class::Sidewalk);
                }
            }
        }
    }

    /// Buildings on one side, with bushes and fences in some gaps.
    fn buildings(&mut self, rng: &mut Rng, side: f64, x_min: f64, x_max: f64) {
        let scene = self;
        let mut x = x_min;
        while x < x_max {
            let len = rng.range(8.0, 30.0);
            let gap = rng.range(1.0, 9.0);
            let clear = if scene.keep_cross_clear {
                !scene.spans_cross_street(x, x + len + gap, 3.0)
            } else {
                !scene.in_cross_street(x, 3.0) && !scene.in_cross_street(x + len, 3.0)
            };
            if clear {
                let front = ROAD_HALF + SIDEWALK_WIDTH + rng.range(1.5, 7.0);
                let depth = rng.range(8.0, 15.0);
                let height = rng.range(5.0, 18.0);
                let (y0, y1) = (side * front, side * (front + depth));
                scene
                    .add(Shape::Box { min: [x, y0.min(y1), 0.0], max: [x + len, y0.max(y1), height] }, Class::Building);
                if rng.chance(0.4) {
                    // Bushes along the facade.
                    let yb = side * (front - 0.6);
                    let h = rng.range(0.6, 1.5);
                    scene.add(
                        Shape::Box {
                            min: [x + 1.0, yb.min(yb - side * 0.8), 0.0],
                            max: [x + len - 1.0, yb.max(yb - side * 0.8), h],
                        },
                        Class::Vegetation,
                    );
                }
                if gap > 3.0 && rng.chance(0.5) {
                    let yf = side * (front + 0.5);
                    scene.add(
                        Shape::Box {
                            min: [x + len, yf.min(yf + side * 0.08), 0.0],
                            max: [x + len + gap, yf.max(yf + side * 0.08), rng.range(1.0, 2.0)],
                        },
                        Class::Fence,
                    );
                }
            }
            x += len + gap;
        }
    }

    /// Trees on the terrain strip behind the sidewalk.
    fn trees(&mut self, rng: &mut Rng, side: f64, x_min: f64, x_max: f64) {
        let scene = self;
        let mut x = x_min + rng.range(0.0, 10.0);
        while x < x_max {
            if !scene.in_cross_street(x, 2.0) && rng.chance(0.7) {
                let y = side * (ROAD_HALF + SIDEWALK_WIDTH + rng.range(0.6, 1.4));
                let r = rng.range(0.12, 0.3);
                let h = rng.range(1.8, 3.5);
                scene.add(Shape::Cylinder { c: [x, y], r, z0: 0.0, z1: h }, Class::Trunk);
                let cr = rng.range(1.5, 3.0);
                scene.add(Shape::Sphere { c: [x, y, h + 0.7 * cr], r: cr }, Class::Vegetation);
            }
            x += rng.range(7.0, 20.0);
        }
    }

    /// Poles at the curb, some carrying a traffic sign.
    fn poles(&mut self, rng: &mut Rng, side: f64, x_min: f64, x_max: f64) {
        let scene = self;
        let mut x = x_min + rng.range(0.0, 15.0);
        while x < x_max {
            if !scene.in_cross_street(x, 0.5) {
                let y = side * (ROAD_HALF + 0.4);
                let h = rng.range(4.5, 9.0);
                scene.add(Shape::Cylinder { c: [x, y], r: rng.range(0.08, 0.15), z0: 0.0, z1: h }, Class::Pole);
                if rng.chance(0.35) {
                    let z = rng.range(2.0, 3.0);
                    let (w, t) = (rng.range(0.5, 0.9), 0.05);
                    let xs = x - side * 0.2;
                    scene.add(
                        Shape::Box { min: [xs - t, y - w / 2.0, z], max: [xs + t, y + w / 2.0, z + w] },
                        Class::TrafficSign,
                    );
                }
            }
            x += rng.range(12.0, 35.0);
        }
    }

    /// Parked cars in the parking lane at the road's edge.
    fn cars(&mut self, rng: &mut Rng, side: f64, x_min: f64, x_max: f64) {
        let scene = self;
        let mut x = x_min + rng.range(0.0, 6.0);
        while x < x_max {
            let len = rng.range(3.8, 4.9);
            let clear = if scene.keep_cross_clear {
                !scene.spans_cross_street(x, x + len, 1.0)
            } else {
                !scene.in_cross_street(x, 1.0) && !scene.in_cross_street(x + len, 1.0)
            };
            if clear && rng.chance(0.55) {
                let yc = side * (ROAD_HALF - 1.1);
                let w = rng.range(1.7, 1.95) / 2.0;
                let h = rng.range(1.35, 1.7);
                scene.add(Shape::Box { min: [x, yc - w, 0.2], max: [x + len, yc + w, h * 0.6] }, Class::Car);
                scene.add(
                    Shape::Box {
                        min: [x + len * 0.25, yc - w * 0.85, h * 0.6],
                        max: [x + len * 0.8, yc + w * 0.85, h],
                    },
                    Class::Car,
                );
            }
            x += len + rng.range(0.8, 10.0);
        }
    }
}

/// Velodyne HDL-64E elevation angles (degrees): 32 upper beams at 1/3 degree
/// from +2 down, 32 lower beams at 1/2 degree from -8.83 down.
pub fn beam_elevations() -> Vec<f64> {
    let mut e: Vec<f64> = (0..32).map(|i| 2.0 - i as f64 / 3.0).collect();
    e.extend((0..32).map(|i| -8.83 - i as f64 * 0.5));
    e
}

/// The vehicle's LiDAR pose at frame `i` (world frame).
fn sensor_pose(i: usize, step: f64, wobble: f64) -> Isometry3<f64> {
    let x = i as f64 * step;
    let y = -1.6 + 0.35 * (x / 14.0 + wobble).sin();
    let dy = 0.35 / 14.0 * (x / 14.0 + wobble).cos();
    let yaw = dy.atan();
    Isometry3::from_parts(Translation3::new(x, y, SENSOR_HEIGHT), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw))
}

/// KITTI sequence 00's camera projections, and an exactly orthonormal
/// velodyne-to-camera transform close to KITTI's.
const CALIB_P: &str = "P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
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

/// One simulated scan: points in the sensor frame and raw SemanticKITTI labels.
pub struct SynthScan {
    /// x, y, z, intensity.
    pub points: Vec<[f32; 4]>,
    /// Raw label per point.
    pub labels: Vec<u32>,
}

/// The scene's objects binned by azimuth around one viewpoint, so that each
/// ray tests few of them.
struct Sectors {
    origin: [f64; 3],
    lists: Vec<Vec<u32>>,
    width: f64,
}

impl Sectors {
    const COUNT: usize = 720;

    fn new(scene: &Scene, origin: [f64; 3], max_range: f64) -> Sectors {
        let width = std::f64::consts::TAU / Self::COUNT as f64;
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); Self::COUNT];
        for (i, ob) in scene.objects.iter().enumerate() {
            let (c, r) = ob.bound;
            let (dx, dy) = (c[0] - origin[0], c[1] - origin[1]);
            let d = dx.hypot(dy);
            if d - r > max_range {
                continue;
            }
            if d <= r + 0.5 {
                for s in lists.iter_mut() {
                    s.push(i as u32);
                }
                continue;
            }
            let az = dy.atan2(dx);
            let half = (r / d).asin() + width;
            let first = ((az - half) / width).floor() as i64;
            let last = ((az + half) / width).ceil() as i64;
            for s in first..=last {
                lists[s.rem_euclid(Self::COUNT as i64) as usize].push(i as u32);
            }
        }
        Sectors { origin, lists, width }
    }

    /// The first surface along unit direction `d` (world frame) from the
    /// origin: distance and class.
    fn cast(&self, scene: &Scene, d: [f64; 3]) -> Option<(f64, Class)> {
        let o = self.origin;
        let az = d[1].atan2(d[0]);
        let sector = ((az / self.width).floor() as i64).rem_euclid(Self::COUNT as i64) as usize;
        let mut best = f64::INFINITY;
        let mut class = None;
        if d[2] < -1e-9 {
            let t = -o[2] / d[2];
            if t < best {
                best = t;
                class = Some(scene.ground_class(o[0] + t * d[0], o[1] + t * d[1]));
            }
        }
        for &i in &self.lists[sector] {
            let ob = &scene.objects[i as usize];
            if let Some(t) = ob.hit(&o, &d) {
                if t < best {
                    best = t;
                    class = Some(ob.class);
                }
            }
        }
        class.map(|c| (best, c))
    }
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
