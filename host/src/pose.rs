//! The conventions' pose syntax `x,y,z,roll,pitch,yaw` (metres, degrees,
//! `R = Rz(yaw) * Ry(pitch) * Rx(roll)`) and conversions.

use nalgebra::{Matrix4, Rotation3};

/// Parses `x,y,z,roll,pitch,yaw` into a 4x4 transform.
pub fn parse(s: &str) -> Result<Matrix4<f64>, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>().map_err(|_| format!("pose `{s}`: `{t}` is not a number")))
        .collect::<Result<_, _>>()?;
    if v.len() != 6 {
        return Err(format!("pose `{s}`: expected 6 numbers x,y,z,roll,pitch,yaw, found {}", v.len()));
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(format!("pose `{s}`: non-finite number"));
    }
    Ok(from_xyz_rpy_deg(v[0], v[1], v[2], v[3], v[4], v[5]))
}

/// Builds a transform from metres and degrees.
pub fn from_xyz_rpy_deg(x: f64, y: f64, z: f64, roll: f64, pitch: f64, yaw: f64) -> Matrix4<f64> {
    let r = Rotation3::from_euler_angles(roll.to_radians(), pitch.to_radians(), yaw.to_radians());
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
    m[(0, 3)] = x;
    m[(1, 3)] = y;
    m[(2, 3)] = z;
    m
}

/// Decomposes a transform into `[x, y, z, roll, pitch, yaw]` (metres, degrees).
pub fn to_xyz_rpy_deg(m: &Matrix4<f64>) -> [f64; 6] {
    let r = Rotation3::from_matrix_unchecked(m.fixed_view::<3, 3>(0, 0).into_owned());
    let (roll, pitch, yaw) = r.euler_angles();
    [m[(0, 3)], m[(1, 3)], m[(2, 3)], roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()]
}

/// The 16 numbers of a transform, row by row (the conventions' JSON form).
pub fn to_row_major(m: &Matrix4<f64>) -> Vec<f64> {
    (0..4).flat_map(|r| (0..4).map(move |c| m[(r, c)])).collect()
}

/// An isometry of the core from a 4x4 matrix.
pub fn to_isometry(m: &Matrix4<f64>) -> nalgebra::Isometry3<f32> {
    let r = Rotation3::from_matrix_unchecked(m.fixed_view::<3, 3>(0, 0).into_owned().cast::<f32>());
    nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::new(m[(0, 3)] as f32, m[(1, 3)] as f32, m[(2, 3)] as f32),
        nalgebra::UnitQuaternion::from_rotation_matrix(&r),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let m = parse("1,2,3,4,5,-150").unwrap();
        let v = to_xyz_rpy_deg(&m);
        for (a, b) in v.iter().zip([1.0, 2.0, 3.0, 4.0, 5.0, -150.0]) {
            assert!((a - b).abs() < 1e-9, "{v:?}");
        }
        assert!(parse("1,2,3").is_err());
        assert!(parse("1,2,3,4,5,nan").is_err());
    }
}
