//! Layer 3 (above [`crate::map`], whose label evidence it makes): labels for LiDAR points from a
//! camera's semantic segmentation (the
//! paper's section IV-A): a segmentation network labels each image, and each
//! LiDAR point takes the class of the pixel it projects to through the
//! camera-LiDAR calibration.
//!
//! - [`Camera`]: a 3x4 projection matrix (KITTI's `P2`) after the
//!   LiDAR-to-camera extrinsic (`Tr`), and the image size. Points behind the
//!   camera or outside the image have no pixel ([`Projection`]).
//! - [`SegClasses`]: what the pixel values of a segmentation image mean:
//!   Cityscapes' 19 training ids (the paper's Deeplab) or SemanticKITTI's
//!   learning-map ids, and how each maps to the class table.
//! - [`evidence_from_probabilities`]: a per-pixel class probability vector,
//!   when the network gives one, turned into label evidence that
//!   [`crate::map::LocalMap::insert_point_evidence`] fuses into a voxel's
//!   label distribution by Bayes' rule, like a hard label but weighted by the
//!   network's confidence.

use crate::classes::{Class, NUM_CLASSES};
use crate::map::{LabelDistribution, SensorModel, SCORE_UNITS_PER_NAT};

/// Points nearer than this to the camera plane (m) are treated as behind it.
pub const MIN_DEPTH: f32 = 0.1;

/// A calibrated camera seeing the LiDAR's points.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Camera {
    /// `P * Tr`, row by row: LiDAR point to homogeneous pixel.
    m: [[f32; 4]; 3],
    width: u32,
    height: u32,
}

/// Where a point lands in the image.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Projection {
    /// In view: column `u`, row `v` (pixel centres at integer coordinates,
    /// as in KITTI's calibration) and the depth in front of the camera (m).
    Pixel {
        /// Column, `0..width`.
        u: u32,
        /// Row, `0..height`.
        v: u32,
        /// Depth along the optical axis (m).
        depth: f32,
    },
    /// Behind the camera (or nearer than [`MIN_DEPTH`]).
    Behind,
    /// In front of the camera but outside the image.
    Outside,
}

/// Why a camera could not be made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CameraError {
    /// A matrix entry is NaN or infinite.
    NonFinite,
    /// The image has no pixel.
    EmptyImage,
    /// The projection's third row is zero: it cannot give a depth.
    Degenerate,
}

impl core::fmt::Display for CameraError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            CameraError::NonFinite => "non-finite number in the projection or extrinsic",
            CameraError::EmptyImage => "image width or height is zero",
            CameraError::Degenerate => "the projection's third row is zero",
        })
    }
}

impl core::error::Error for CameraError {}

impl Camera {
    /// A camera from its 3x4 `projection` (row by row, e.g. KITTI's `P2`),
    /// the 3x4 rigid `lidar_to_camera` extrinsic (row by row, KITTI's `Tr`:
    /// LiDAR coordinates to the rectified camera frame) and the image size.
    pub fn new(
        projection: &[f32; 12],
        lidar_to_camera: &[f32; 12],
        width: u32,
        height: u32,
    ) -> Result<Camera, CameraError> {
        if !projection.iter().chain(lidar_to_camera.iter()).all(|v| v.is_finite()) {
            return Err(CameraError::NonFinite);
        }
        if width == 0 || height == 0 {
            return Err(CameraError::EmptyImage);
        }
        if projection[8..12].iter().all(|v| *v == 0.0) {
            return Err(CameraError::Degenerate);
        }
        // m = P * [Tr; 0 0 0 1]
        let mut m = [[0.0f32; 4]; 3];
        for (r, row) in m.iter_mut().enumerate() {
            for (c, out) in row.iter_mut().enumerate() {
                let mut s = if c == 3 { projection[r * 4 + 3] } else { 0.0 };
                for k in 0..3 {
                    s += projection[r * 4 + k] * lidar_to_camera[k * 4 + c];
                }
                *out = s;
            }
        }
        if !m.iter().flatten().all(|v| v.is_finite()) {
            return Err(CameraError::NonFinite);
        }
        Ok(Camera { m, width, height })
    }

    /// Image width (pixels).
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height (pixels).
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Projects a LiDAR point (LiDAR frame, m). Non-finite points are
    /// [`Projection::Behind`]: they have no pixel.
    pub fn project(&self, p: [f32; 3]) -> Projection {
        let row = |r: &[f32; 4]| r[0] * p[0] + r[1] * p[1] + r[2] * p[2] + r[3];
        let (x, y, w) = (row(&self.m[0]), row(&self.m[1]), row(&self.m[2]));
        if !(w.is_finite() && w > MIN_DEPTH) {
            return Projection::Behind;
        }
        let (u, v) = (libm::floorf(x / w + 0.5), libm::floorf(y / w + 0.5));
        // NaN fails both comparisons.
        if u >= 0.0 && v >= 0.0 && u < self.width as f32 && v < self.height as f32 {
            Projection::Pixel { u: u as u32, v: v as u32, depth: w }
        } else {
            Projection::Outside
        }
    }
}

/// Side of a [`DepthGrid`] cell (pixels): about one LiDAR beam spacing
/// at KITTI's focal length (0.4 degrees x 718 pixels per radian = 5 pixels).
pub const DEPTH_CELL_PX: u32 = 4;

/// The camera and the LiDAR see from different places, so a point the LiDAR
/// sees past an object's edge can lie behind that object in the image and
/// would take its class. A depth grid of the scan's own points, projected,
/// finds them: a point is occluded when a point of the scan in a
/// neighbouring cell is nearer by more than a margin. Its buffer (one `f32`
/// per cell of [`DEPTH_CELL_PX`] pixels) is the caller's.
pub struct DepthGrid<'a> {
    width: u32,
    height: u32,
    depth: &'a mut [f32],
}

impl<'a> DepthGrid<'a> {
    /// Cells needed for a camera's image.
    pub fn cells(camera: &Camera) -> usize {
        (camera.width.div_ceil(DEPTH_CELL_PX) * camera.height.div_ceil(DEPTH_CELL_PX)) as usize
    }

    /// An empty grid for `camera` in `buffer` (at least [`DepthGrid::cells`]
    /// long; `None` if shorter).
    pub fn new(camera: &Camera, buffer: &'a mut [f32]) -> Option<DepthGrid<'a>> {
        let n = Self::cells(camera);
        let depth = buffer.get_mut(..n)?;
        depth.iter_mut().for_each(|d| *d = f32::INFINITY);
        Some(DepthGrid {
            width: camera.width.div_ceil(DEPTH_CELL_PX),
            height: camera.height.div_ceil(DEPTH_CELL_PX),
            depth,
        })
    }

    /// Records a projected point.
    pub fn insert(&mut self, u: u32, v: u32, depth: f32) {
        let (i, j) = (u / DEPTH_CELL_PX, v / DEPTH_CELL_PX);
        if let Some(d) = self.depth.get_mut((j * self.width + i) as usize) {
            *d = d.min(depth);
        }
    }

    /// Whether a point at pixel (`u`, `v`) and `depth` lies behind another
    /// point of the grid within one cell: nearer by more than a fifth of its
    /// depth (and 0.5 m). Ground seen at a grazing angle gets nearer by less
    /// than that from one cell to the next, so it does not hide itself.
    pub fn occluded(&self, u: u32, v: u32, depth: f32) -> bool {
        let (i, j) = ((u / DEPTH_CELL_PX) as i64, (v / DEPTH_CELL_PX) as i64);
        let margin = 0.5f32.max(0.2 * depth);
        for dj in -1..=1i64 {
            for di in -1..=1i64 {
                let (x, y) = (i + di, j + dj);
                if x < 0 || y < 0 || x >= i64::from(self.width) || y >= i64::from(self.height) {
                    continue;
                }
                if self.depth.get((y * i64::from(self.width) + x) as usize).is_some_and(|d| *d < depth - margin) {
                    return true;
                }
            }
        }
        false
    }
}

/// What the pixel values of a segmentation image (and the channels of a
/// probability map) mean.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SegClasses {
    /// Cityscapes' 19 training ids (0 road ... 18 bicycle; 255 ignored), as
    /// a network trained on Cityscapes gives them (the paper's Deeplab).
    #[default]
    Cityscapes,
    /// SemanticKITTI's learning-map ids: 0 unlabeled, 1 car ... 19
    /// traffic-sign (the class table's index plus one).
    SemanticKitti,
}

/// A pixel value that no class of the [`SegClasses`] has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UnknownId(pub u8);

impl core::fmt::Display for UnknownId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "class id {} is not in the segmentation's class set", self.0)
    }
}

impl core::error::Error for UnknownId {}

/// Cityscapes training id to the class table. Cityscapes has no trunk
/// (trunks are vegetation there), no parking or other-ground (road,
/// sidewalk, terrain), one rider class (taken as bicyclist), and classes
/// the table lacks: a free-standing wall is taken as fence (SemanticKITTI's
/// fence includes small walls), a traffic light as traffic-sign, bus and
/// train as other-vehicle (as the conventions send bus and on-rails), sky
/// as no class.
const CITYSCAPES: [Option<Class>; 19] = [
    Some(Class::Road),
    Some(Class::Sidewalk),
    Some(Class::Building),
    Some(Class::Fence), // wall
    Some(Class::Fence),
    Some(Class::Pole),
    Some(Class::TrafficSign), // traffic light
    Some(Class::TrafficSign),
    Some(Class::Vegetation),
    Some(Class::Terrain),
    None, // sky
    Some(Class::Person),
    Some(Class::Bicyclist), // rider
    Some(Class::Car),
    Some(Class::Truck),
    Some(Class::OtherVehicle), // bus
    Some(Class::OtherVehicle), // train
    Some(Class::Motorcycle),
    Some(Class::Bicycle),
];

/// Cityscapes' "ignore" id.
pub const CITYSCAPES_IGNORE: u8 = 255;
/// Cityscapes' sky id: what a perfect network sees where no surface is.
pub const CITYSCAPES_SKY: u8 = 10;

impl SegClasses {
    /// The class of a pixel value; `Ok(None)` for values that carry no class
    /// of the table (Cityscapes sky and ignore, SemanticKITTI unlabeled).
    pub fn class(self, id: u8) -> Result<Option<Class>, UnknownId> {
        match self {
            SegClasses::Cityscapes => match CITYSCAPES.get(usize::from(id)) {
                Some(c) => Ok(*c),
                None if id == CITYSCAPES_IGNORE => Ok(None),
                None => Err(UnknownId(id)),
            },
            SegClasses::SemanticKitti => match id {
                0 => Ok(None),
                _ => Class::from_index(id - 1).map(Some).ok_or(UnknownId(id)),
            },
        }
    }

    /// The pixel value a perfect network of this class set gives a surface
    /// of `class` (`None`: no surface, e.g. the sky).
    pub fn id(self, class: Option<Class>) -> u8 {
        match self {
            SegClasses::Cityscapes => match class {
                None => CITYSCAPES_SKY,
                Some(c) => match c {
                    Class::Road | Class::Parking => 0,
                    Class::Sidewalk => 1,
                    Class::Building => 2,
                    Class::Fence => 4,
                    Class::Pole => 5,
                    Class::TrafficSign => 7,
                    Class::Vegetation | Class::Trunk => 8,
                    Class::Terrain | Class::OtherGround => 9,
                    Class::Person => 11,
                    Class::Bicyclist | Class::Motorcyclist => 12,
                    Class::Car => 13,
                    Class::Truck => 14,
                    Class::OtherVehicle => 15,
                    Class::Motorcycle => 17,
                    Class::Bicycle => 18,
                },
            },
            SegClasses::SemanticKitti => class.map(|c| c.index() + 1).unwrap_or(0),
        }
    }

    /// Channels of a probability map: one per id (19 for Cityscapes, 20 for
    /// SemanticKITTI with unlabeled first).
    pub fn channels(self) -> usize {
        match self {
            SegClasses::Cityscapes => CITYSCAPES.len(),
            SegClasses::SemanticKitti => NUM_CLASSES + 1,
        }
    }

    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            SegClasses::Cityscapes => "cityscapes",
            SegClasses::SemanticKitti => "semantickitti",
        }
    }
}

impl core::str::FromStr for SegClasses {
    type Err = UnknownSegClasses;
    /// `cityscapes` or `semantickitti`.
    fn from_str(s: &str) -> Result<Self, UnknownSegClasses> {
        match s {
            "cityscapes" => Ok(SegClasses::Cityscapes),
            "semantickitti" => Ok(SegClasses::SemanticKitti),
            _ => Err(UnknownSegClasses),
        }
    }
}

/// A class-set name that is not one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnknownSegClasses;

impl core::fmt::Display for UnknownSegClasses {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("expected cityscapes or semantickitti")
    }
}

impl core::error::Error for UnknownSegClasses {}

/// Why a probability vector was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ProbabilityError {
    /// Not one value per channel of the class set.
    Channels {
        /// Values given.
        got: u32,
        /// Channels of the class set.
        expected: u32,
    },
    /// A value is NaN, infinite or negative, or all are zero.
    Invalid,
}

impl core::fmt::Display for ProbabilityError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ProbabilityError::Channels { got, expected } => {
                write!(f, "{got} probabilities, expected one per class channel ({expected})")
            }
            ProbabilityError::Invalid => f.write_str("probabilities must be finite, non-negative and not all zero"),
        }
    }
}

impl core::error::Error for ProbabilityError {}

/// Turns a pixel's class probabilities (one per channel of `classes`, any
/// positive scale) into label evidence for
/// [`crate::map::LocalMap::insert_point_evidence`]. `Ok(None)` when the
/// channels without a class of the table (sky, unlabeled) hold more
/// probability than any class: the point stays unlabelled, as with a hard
/// label.
///
/// Channels mapping to one class add up. The network's probabilities are
/// read as likelihoods of the observation given each class, floored at the
/// sensor model's error rate `(1 - accuracy) / 18`: a network is never
/// surer than the sensor model allows, so a one-hot vector gives about the
/// evidence of one hard label, and a split vector gives split evidence. The
/// four most probable classes are kept, each scored by its log-likelihood
/// ratio against the fifth (the untracked classes' shared baseline).
pub fn evidence_from_probabilities(
    classes: SegClasses,
    probabilities: &[f32],
    model: &SensorModel,
) -> Result<Option<LabelDistribution>, ProbabilityError> {
    let channels = classes.channels();
    if probabilities.len() != channels {
        return Err(ProbabilityError::Channels { got: probabilities.len() as u32, expected: channels as u32 });
    }
    if !probabilities.iter().all(|p| p.is_finite() && *p >= 0.0) {
        return Err(ProbabilityError::Invalid);
    }
    let mut q = [0.0f32; NUM_CLASSES];
    let mut none = 0.0f32;
    let mut total = 0.0f32;
    for (id, &p) in probabilities.iter().enumerate() {
        total += p;
        match classes.class(id as u8) {
            Ok(Some(c)) => {
                if let Some(slot) = q.get_mut(usize::from(c.index())) {
                    *slot += p;
                }
            }
            _ => none += p,
        }
    }
    if !(total.is_finite() && total > 0.0) {
        return Err(ProbabilityError::Invalid);
    }
    let best = q.iter().copied().fold(0.0f32, f32::max);
    if none >= best {
        return Ok(None);
    }
    let floor = if model.is_valid() { (1.0 - model.accuracy) / (NUM_CLASSES as f32 - 1.0) } else { 0.01 };
    let sum: f32 = q.iter().sum();
    for v in q.iter_mut() {
        *v = (*v / sum).max(floor);
    }
    // The five largest, in order (ties to the lower class index).
    let mut order = [0usize; NUM_CLASSES];
    for (i, o) in order.iter_mut().enumerate() {
        *o = i;
    }
    order.sort_unstable_by(|&a, &b| q[b].total_cmp(&q[a]).then(a.cmp(&b)));
    let base = q[order[crate::map::LABEL_SLOTS]];
    let mut d = LabelDistribution::EMPTY;
    for &i in order.iter().take(crate::map::LABEL_SLOTS) {
        let units = libm::roundf(libm::logf(q[i] / base) * SCORE_UNITS_PER_NAT);
        if let (Some(class), true) = (Class::from_index(i as u8), units >= 1.0) {
            d.observe(class, units.min(f32::from(u16::MAX)) as u16);
        }
    }
    Ok(if d.is_empty() { None } else { Some(d) })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// KITTI sequence 00's `P2` and `Tr`.
    const P2: [f32; 12] =
        [718.856, 0.0, 607.1928, 45.38225, 0.0, 718.856, 185.2157, -0.1130887, 0.0, 0.0, 1.0, 0.003779761];
    const TR: [f32; 12] = [
        4.276802e-04,
        -9.999672e-01,
        -8.084492e-03,
        -1.19846e-2,
        -7.210627e-03,
        8.081198e-03,
        -9.999413e-01,
        -5.403984e-02,
        9.999739e-01,
        4.859485e-04,
        -7.206933e-03,
        -2.921968e-01,
    ];

    #[test]
    fn points_project_like_kittis_devkit() {
        let cam = Camera::new(&P2, &TR, 1241, 376).unwrap();
        // 20 m ahead of the LiDAR: near the principal point, a little right
        // of it (camera 2 sits 6 cm left of camera 0).
        match cam.project([20.0, 0.0, 0.0]) {
            Projection::Pixel { u, v, depth } => {
                assert!((608..=612).contains(&u) && (175..=181).contains(&v), "{u} {v}");
                assert!((depth - 19.71).abs() < 0.05, "{depth}");
            }
            p => panic!("{p:?}"),
        }
        // Left of the vehicle at 10 m: smaller u; higher: smaller v.
        let Projection::Pixel { u: ul, v: vh, .. } = cam.project([10.0, 2.0, 1.0]) else { panic!() };
        assert!(ul < 500 && vh < 150, "{ul} {vh}");
        assert_eq!(cam.project([-10.0, 0.0, 0.0]), Projection::Behind);
        assert_eq!(cam.project([0.2, 0.0, 0.0]), Projection::Behind);
        assert_eq!(cam.project([5.0, 30.0, 0.0]), Projection::Outside);
        assert_eq!(cam.project([f32::NAN, 0.0, 0.0]), Projection::Behind);
        assert_eq!(Camera::new(&P2, &TR, 0, 376), Err(CameraError::EmptyImage));
        let mut bad = TR;
        bad[3] = f32::INFINITY;
        assert_eq!(Camera::new(&P2, &bad, 1241, 376), Err(CameraError::NonFinite));
    }

    #[test]
    fn nearer_points_hide_farther_ones_but_ground_does_not_hide_itself() {
        let cam = Camera::new(&P2, &TR, 1241, 376).unwrap();
        let mut buf = std::vec![0.0f32; DepthGrid::cells(&cam)];
        let mut g = DepthGrid::new(&cam, &mut buf).unwrap();
        // A pole at 10 m; a wall 20 m away behind it, and ground points.
        let pole = [10.0, 0.0, 0.0];
        let Projection::Pixel { u, v, depth } = cam.project(pole) else { panic!() };
        g.insert(u, v, depth);
        let Projection::Pixel { u: wu, v: wv, depth: wd } = cam.project([20.0, 0.1, 0.1]) else { panic!() };
        g.insert(wu, wv, wd);
        assert!(g.occluded(wu, wv, wd));
        assert!(!g.occluded(u, v, depth));
        // Ground 18 m and 20 m ahead (1.73 m below the sensor): neighbours, not occluders.
        let mut buf2 = std::vec![0.0f32; DepthGrid::cells(&cam)];
        let mut g = DepthGrid::new(&cam, &mut buf2).unwrap();
        let mut seen = std::vec::Vec::new();
        for x in [18.0, 19.0, 20.0] {
            let Projection::Pixel { u, v, depth } = cam.project([x, 0.0, -1.73]) else { panic!() };
            g.insert(u, v, depth);
            seen.push((u, v, depth));
        }
        for (u, v, d) in seen {
            assert!(!g.occluded(u, v, d));
        }
        assert!(DepthGrid::new(&cam, &mut buf[..10]).is_none());
    }

    #[test]
    fn class_sets_round_trip_where_they_can() {
        for c in Class::ALL {
            let s = SegClasses::SemanticKitti;
            assert_eq!(s.class(s.id(Some(c))), Ok(Some(c)));
            // Cityscapes keeps every class it has.
            let cs = SegClasses::Cityscapes;
            let back = cs.class(cs.id(Some(c))).unwrap().unwrap();
            match c {
                Class::Trunk => assert_eq!(back, Class::Vegetation),
                Class::Parking => assert_eq!(back, Class::Road),
                Class::OtherGround => assert_eq!(back, Class::Terrain),
                Class::Motorcyclist => assert_eq!(back, Class::Bicyclist),
                _ => assert_eq!(back, c),
            }
        }
        assert_eq!(SegClasses::Cityscapes.class(CITYSCAPES_SKY), Ok(None));
        assert_eq!(SegClasses::Cityscapes.class(255), Ok(None));
        assert_eq!(SegClasses::Cityscapes.class(19), Err(UnknownId(19)));
        assert_eq!(SegClasses::SemanticKitti.class(0), Ok(None));
        assert_eq!(SegClasses::SemanticKitti.class(20), Err(UnknownId(20)));
    }

    #[test]
    fn probabilities_become_weighted_evidence() {
        let model = SensorModel::default();
        let cs = SegClasses::Cityscapes;
        let mut p = [0.0f32; 19];
        // One-hot car: about one hard label's evidence (34 units).
        p[13] = 1.0;
        let d = evidence_from_probabilities(cs, &p, &model).unwrap().unwrap();
        assert_eq!(d.argmax(), Some(Class::Car));
        let (_, score) = d.entries().next().unwrap();
        assert!((33..=37).contains(&score), "{score}");
        // Split between pole and traffic sign: less evidence, both kept.
        let mut p = [0.0f32; 19];
        p[5] = 0.55;
        p[7] = 0.45;
        let d = evidence_from_probabilities(cs, &p, &model).unwrap().unwrap();
        assert_eq!(d.argmax(), Some(Class::Pole));
        let probs = d.probabilities();
        assert!(probs[Class::TrafficSign.index() as usize] > 0.3, "{probs:?}");
        // Wall and fence add up to fence.
        let mut p = [0.01f32; 19];
        p[3] = 0.3;
        p[4] = 0.3;
        p[2] = 0.35;
        assert_eq!(evidence_from_probabilities(cs, &p, &model).unwrap().unwrap().argmax(), Some(Class::Fence));
        // Mostly sky: unlabelled.
        let mut p = [0.0f32; 19];
        p[10] = 0.9;
        p[0] = 0.1;
        assert_eq!(evidence_from_probabilities(cs, &p, &model), Ok(None));
        assert_eq!(
            evidence_from_probabilities(cs, &p[..5], &model),
            Err(ProbabilityError::Channels { got: 5, expected: 19 })
        );
        p[0] = f32::NAN;
        assert_eq!(evidence_from_probabilities(cs, &p, &model), Err(ProbabilityError::Invalid));
        assert_eq!(evidence_from_probabilities(cs, &[0.0; 19], &model), Err(ProbabilityError::Invalid));
    }
}
