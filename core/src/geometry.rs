//! Rigid transforms, in one form everywhere: nalgebra's [`Isometry3`].
//! `T_a_b` maps coordinates in frame b into frame a: `p_a = R * p_b + t`.
//!
//! The core matches in `f32`; hosts keep poses in `f64` (ground truth,
//! error measures) and cast at the matcher. This module holds what every
//! command, file and test must agree on (`docs/conventions.md`):
//! the pose syntax `x,y,z,roll,pitch,yaw` (metres, degrees,
//! `R = Rz(yaw) * Ry(pitch) * Rx(roll)`), the 16-number row-major JSON form,
//! the 12-number form messages carry, and the error measures `e_t`, `e_r`.

pub use nalgebra::{Isometry3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Builds `T = Translation(x, y, z) * Rz(yaw) * Ry(pitch) * Rx(roll)` (metres,
/// radians) in `f32`, as the matcher uses it.
pub fn from_xyz_rpy(x: f32, y: f32, z: f32, roll: f32, pitch: f32, yaw: f32) -> Isometry3<f32> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::from_euler_angles(roll, pitch, yaw))
}

/// The conventions' pose `x,y,z,roll,pitch,yaw` in metres and degrees.
pub fn pose_deg(x: f64, y: f64, z: f64, roll: f64, pitch: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(roll.to_radians(), pitch.to_radians(), yaw.to_radians()),
    )
}

/// `[x, y, z, roll, pitch, yaw]` (metres, degrees) of a transform.
pub fn xyz_rpy_deg(t: &Isometry3<f64>) -> [f64; 6] {
    let (roll, pitch, yaw) = t.rotation.euler_angles();
    let v = t.translation.vector;
    [v.x, v.y, v.z, roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()]
}

/// Why a pose string is not one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PoseError {
    /// Not six comma-separated numbers (how many there were).
    Count(usize),
    /// The number at this position (0-based) does not parse.
    NotANumber(usize),
    /// The number at this position is NaN or infinite.
    NonFinite(usize),
    /// The number at this position is out of range: a translation beyond
    /// [`MAX_POSE_METRES`], an angle beyond [`MAX_POSE_DEGREES`].
    OutOfRange(usize),
}

/// The largest translation a pose may have (m): 1,000 km, far beyond any
/// robot's map (and past where `f32` keeps centimetres).
pub const MAX_POSE_METRES: f64 = 1.0e6;

/// The largest angle a pose may have (degrees, either sign).
pub const MAX_POSE_DEGREES: f64 = 360.0;

impl core::fmt::Display for PoseError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        const NAMES: [&str; 6] = ["x", "y", "z", "roll", "pitch", "yaw"];
        let name = |i: &usize| NAMES.get(*i).copied().unwrap_or("?");
        match self {
            PoseError::Count(n) => write!(f, "expected 6 numbers x,y,z,roll,pitch,yaw, found {n}"),
            PoseError::NotANumber(i) => write!(f, "{} is not a number", name(i)),
            PoseError::NonFinite(i) => write!(f, "{} is not finite", name(i)),
            PoseError::OutOfRange(i) if *i < 3 => {
                write!(f, "{} is beyond {MAX_POSE_METRES:e} m", name(i))
            }
            PoseError::OutOfRange(i) => write!(f, "{} is beyond {MAX_POSE_DEGREES} degrees", name(i)),
        }
    }
}

impl core::error::Error for PoseError {}

/// Parses the conventions' pose syntax `x,y,z,roll,pitch,yaw` (metres,
/// degrees); spaces around the numbers are allowed.
pub fn parse_pose(s: &str) -> Result<Isometry3<f64>, PoseError> {
    let mut v = [0.0f64; 6];
    let mut n = 0;
    for (i, part) in s.split(',').enumerate() {
        if let Some(slot) = v.get_mut(i) {
            let x: f64 = part.trim().parse().map_err(|_| PoseError::NotANumber(i))?;
            if !x.is_finite() {
                return Err(PoseError::NonFinite(i));
            }
            if x.abs() > if i < 3 { MAX_POSE_METRES } else { MAX_POSE_DEGREES } {
                return Err(PoseError::OutOfRange(i));
            }
            *slot = x;
        }
        n = i + 1;
    }
    if n != 6 {
        return Err(PoseError::Count(n));
    }
    Ok(pose_deg(v[0], v[1], v[2], v[3], v[4], v[5]))
}

/// The 16 numbers of a transform's 4x4 matrix, row by row (the conventions'
/// JSON form).
pub fn row_major(t: &Isometry3<f64>) -> [f64; 16] {
    let m = t.to_homogeneous();
    let mut out = [0.0; 16];
    for (i, o) in out.iter_mut().enumerate() {
        *o = m[(i / 4, i % 4)];
    }
    out
}

/// The top three rows of `t`'s 4x4 matrix, row by row (how transforms
/// travel in messages).
pub fn rows(t: &Isometry3<f32>) -> [f32; 12] {
    let m = t.to_homogeneous();
    let mut out = [0.0; 12];
    for (i, o) in out.iter_mut().enumerate() {
        *o = m[(i / 4, i % 4)];
    }
    out
}

/// The isometry of a matrix's top three rows (the rotation re-orthonormalised
/// through a quaternion).
pub fn from_rows(r: &[f32; 12]) -> Isometry3<f32> {
    let m = nalgebra::Matrix3::new(r[0], r[1], r[2], r[4], r[5], r[6], r[8], r[9], r[10]);
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
    Isometry3::from_parts(Translation3::new(r[3], r[7], r[11]), rot)
}

/// Largest departure from a rigid transform a 4x4 matrix read from a file
/// may show (entries of `R^T R - I`, `det R - 1`, the bottom row): text files
/// print about seven digits.
pub const RIGID_TOLERANCE: f64 = 1e-3;

/// The isometry of a 4x4 matrix, if it is rigid to [`RIGID_TOLERANCE`] and
/// finite (a rotation, a translation, bottom row `0 0 0 1`); `None` for
/// anything else (a zero matrix, a scale, a shear, a NaN).
pub fn rigid_from_matrix(m: &Matrix4<f64>) -> Option<Isometry3<f64>> {
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let r = m.fixed_view::<3, 3>(0, 0).into_owned();
    let off = (r.transpose() * r - nalgebra::Matrix3::identity()).amax();
    let bottom = (m[(3, 0)].abs()).max(m[(3, 1)].abs()).max(m[(3, 2)].abs()).max((m[(3, 3)] - 1.0).abs());
    if off > RIGID_TOLERANCE || (r.determinant() - 1.0).abs() > RIGID_TOLERANCE || bottom > RIGID_TOLERANCE {
        return None;
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Some(Isometry3::from_parts(Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]), rot))
}

/// Translation error (m) and rotation error (degrees) of an estimate
/// against the truth: `dT = T_est * inv(T_gt)`, `e_t = |t(dT)|`, `e_r` the
/// angle of `R(dT)`. The angle is atan2 of the antisymmetric part and the
/// trace: exact near zero, where acos of the trace alone turns an `f32`
/// rotation's departure from orthonormality into hundredths of a degree.
pub fn pose_errors(est: &Isometry3<f64>, gt: &Isometry3<f64>) -> (f64, f64) {
    let d = est * gt.inverse();
    let et = d.translation.vector.norm();
    let r = d.rotation.to_rotation_matrix().into_inner();
    let cos = (r.trace() - 1.0) / 2.0;
    let sin = Vector3::new(r[(2, 1)] - r[(1, 2)], r[(0, 2)] - r[(2, 0)], r[(1, 0)] - r[(0, 1)]).norm() / 2.0;
    (et, libm::atan2(sin, cos).to_degrees())
}

/// Errors of an `f32` estimate (as the matcher returns it) against an `f64`
/// truth.
pub fn errors_of(est: &Isometry3<f32>, gt: &Isometry3<f64>) -> (f64, f64) {
    pose_errors(&est.cast::<f64>(), gt)
}

/// Applies `t` to a point given as an array.
pub fn transform_point(t: &Isometry3<f32>, p: [f32; 3]) -> [f32; 3] {
    let q = t * Point3::new(p[0], p[1], p[2]);
    [q.x, q.y, q.z]
}

/// Metres between two places given as arrays.
pub fn distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_round_trip() {
        let t = from_xyz_rpy(3.5, -1.0, 0.2, 0.01, -0.02, 2.5);
        let back = from_rows(&rows(&t));
        assert!((back.translation.vector - t.translation.vector).norm() < 1e-6);
        assert!(back.rotation.angle_to(&t.rotation) < 1e-5);
    }

    #[test]
    fn pose_syntax_round_trips_and_names_errors() {
        let t = parse_pose("1, 2,3,4,5,-150").unwrap();
        for (a, b) in xyz_rpy_deg(&t).iter().zip([1.0, 2.0, 3.0, 4.0, 5.0, -150.0]) {
            assert!((a - b).abs() < 1e-9);
        }
        assert_eq!(parse_pose("1,2,3"), Err(PoseError::Count(3)));
        assert_eq!(parse_pose("1,2,3,4,5,6,7"), Err(PoseError::Count(7)));
        assert_eq!(parse_pose("1,2,x,4,5,6"), Err(PoseError::NotANumber(2)));
        assert_eq!(parse_pose("1,2,3,4,5,nan"), Err(PoseError::NonFinite(5)));
        assert_eq!(parse_pose(""), Err(PoseError::NotANumber(0)));
    }

    #[test]
    fn errors_of_a_known_offset() {
        let gt = pose_deg(1.0, 2.0, 0.5, 1.0, 2.0, 30.0);
        let d = pose_deg(3.0, 4.0, 0.0, 0.0, 0.0, 10.0);
        let (et, er) = pose_errors(&(d * gt), &gt);
        assert!((et - 5.0).abs() < 1e-9 && (er - 10.0).abs() < 1e-9, "{et} {er}");
    }

    #[test]
    fn rigid_matrices_only() {
        let t = pose_deg(1.0, -2.0, 3.0, 10.0, -20.0, 170.0);
        let back = rigid_from_matrix(&t.to_homogeneous()).unwrap();
        assert!(pose_errors(&back, &t).0 < 1e-12 && pose_errors(&back, &t).1 < 1e-9);
        assert!(rigid_from_matrix(&Matrix4::zeros()).is_none());
        assert!(rigid_from_matrix(&(Matrix4::identity() * 2.0)).is_none());
        let mut m = Matrix4::identity();
        m[(0, 0)] = -1.0; // a reflection
        assert!(rigid_from_matrix(&m).is_none());
        m[(0, 0)] = f64::NAN;
        assert!(rigid_from_matrix(&m).is_none());
    }
}
