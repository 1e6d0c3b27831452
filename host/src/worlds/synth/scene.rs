//! The procedural street (or a town): its objects and roads, generated
//! from a seed, and the first surface along a ray through it.

use crate::rng::Rng;
use cosem_core::classes::Class;

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

    /// The highest point of the object.
    fn top(&self) -> f64 {
        match self.shape {
            Shape::Box { max, .. } => max[2],
            Shape::Cylinder { z1, .. } => z1,
            Shape::Sphere { c, r } => c[2] + r,
        }
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

    pub(super) fn generate(rng: &mut Rng, x_min: f64, x_max: f64) -> Scene {
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

/// The scene's objects binned by azimuth around one viewpoint, so that each
/// ray tests few of them.
pub(super) struct Sectors {
    origin: [f64; 3],
    /// Per sector, its objects nearest first: the least horizontal
    /// distance from the origin to each (its bounding circle's), and its
    /// index.
    lists: Vec<Vec<(f64, u32)>>,
    width: f64,
    /// The highest any object reaches: a ray rising above it hits nothing
    /// farther.
    top: f64,
}

impl Sectors {
    const COUNT: usize = 720;

    pub(super) fn new(scene: &Scene, origin: [f64; 3], max_range: f64) -> Sectors {
        let width = std::f64::consts::TAU / Self::COUNT as f64;
        let mut lists: Vec<Vec<(f64, u32)>> = vec![Vec::new(); Self::COUNT];
        for (i, ob) in scene.objects.iter().enumerate() {
            let (c, r) = ob.bound;
            let (dx, dy) = (c[0] - origin[0], c[1] - origin[1]);
            let d = dx.hypot(dy);
            let near = (d - r).max(0.0);
            if d - r > max_range {
                continue;
            }
            if d <= r + 0.5 {
                for s in lists.iter_mut() {
                    s.push((near, i as u32));
                }
                continue;
            }
            let az = dy.atan2(dx);
            let half = (r / d).asin() + width;
            let first = ((az - half) / width).floor() as i64;
            let last = ((az + half) / width).ceil() as i64;
            for s in first..=last {
                lists[s.rem_euclid(Self::COUNT as i64) as usize].push((near, i as u32));
            }
        }
        for list in &mut lists {
            list.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        }
        let top = scene.objects.iter().map(Object::top).fold(f64::NEG_INFINITY, f64::max);
        Sectors { origin, lists, width, top }
    }

    /// The first surface along unit direction `d` (world frame) from the
    /// origin: distance and class (of equally near objects, the first
    /// made; an object only when nearer than the ground).
    ///
    /// The sector's objects are tried nearest first, and none after one
    /// whose least distance is beyond the nearest hit so far: a ray
    /// travels at least as far as it moves horizontally. The same answers
    /// as trying all of them, faster where the ground or a near wall stops
    /// the ray; and none once a rising ray has climbed above every object
    /// (a camera image's sky).
    pub(super) fn cast(&self, scene: &Scene, d: [f64; 3]) -> Option<(f64, Class)> {
        let o = self.origin;
        let az = d[1].atan2(d[0]);
        let sector = ((az / self.width).floor() as i64).rem_euclid(Self::COUNT as i64) as usize;
        let mut best = f64::INFINITY;
        let mut class = None;
        // The object hit at `best`, if the nearest hit is one.
        let mut hit: Option<u32> = None;
        // How fast a rising ray climbs per metre it moves horizontally.
        let climb = if d[2] > 0.0 { d[2] / d[0].hypot(d[1]).max(1e-12) } else { 0.0 };
        if d[2] < -1e-9 {
            let t = -o[2] / d[2];
            if t < best {
                best = t;
                class = Some(scene.ground_class(o[0] + t * d[0], o[1] + t * d[1]));
            }
        }
        for &(near, i) in &self.lists[sector] {
            if near > best || o[2] + near * climb > self.top {
                break;
            }
            let ob = &scene.objects[i as usize];
            if let Some(t) = ob.hit(&o, &d) {
                if t < best || (t == best && hit.is_some_and(|h| i < h)) {
                    best = t;
                    class = Some(ob.class);
                    hit = Some(i);
                }
            }
        }
        class.map(|c| (best, c))
    }
}
