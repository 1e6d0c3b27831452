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
