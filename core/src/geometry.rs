//! Rigid transforms. `T_a_b` maps coordinates in frame b into frame a:
//! `p_a = R * p_b + t`.

pub use nalgebra::{Isometry3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Builds `T = Translation(x, y, z) * Rz(yaw) * Ry(pitch) * Rx(roll)` (metres,
/// radians): the conventions' pose syntax.
pub fn from_xyz_rpy(x: f32, y: f32, z: f32, roll: f32, pitch: f32, yaw: f32) -> Isometry3<f32> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::from_euler_angles(roll, pitch, yaw))
}

/// Applies `t` to a point given as an array.
pub fn transform_point(t: &Isometry3<f32>, p: [f32; 3]) -> [f32; 3] {
    let q = t * Point3::new(p[0], p[1], p[2]);
    [q.x, q.y, q.z]
}

/// The top three rows of `t`'s 4x4 matrix, row by row (how transforms
/// travel in messages).
pub fn rows(t: &Isometry3<f32>) -> [f32; 12] {
    let m = t.to_homogeneous();
    let mut out = [0.0; 12];
    for r in 0..3 {
        for c in 0..4 {
            out[4 * r + c] = m[(r, c)];
        }
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

#[cfg(test)]
mod tests {
    #[test]
    fn rows_round_trip() {
        let t = super::from_xyz_rpy(3.5, -1.0, 0.2, 0.01, -0.02, 2.5);
        let back = super::from_rows(&super::rows(&t));
        assert!((back.translation.vector - t.translation.vector).norm() < 1e-6);
        assert!(back.rotation.angle_to(&t.rotation) < 1e-5);
    }
}
