//! Poses as text, in the conventions' syntax (`x,y,z,roll,pitch,yaw`, m
//! and degrees) and in words, and back from the JSON's row-major numbers.

use cosem_core::geometry::{xyz_rpy_deg, Isometry3};

/// A transform from its 16 row-major numbers (as the JSON holds it).
pub fn from_row_major(m: &[f64; 16]) -> Isometry3<f64> {
    cosem_core::geometry::rigid_from_matrix(&nalgebra::Matrix4::from_row_slice(m)).unwrap_or_else(Isometry3::identity)
}

/// `x,y,z,roll,pitch,yaw` (m, degrees) of a transform, for printing.
pub fn pose_text(t: &Isometry3<f64>) -> String {
    let x = xyz_rpy_deg(t);
    format!("{:.4},{:.4},{:.4},{:.3},{:.3},{:.3}", x[0], x[1], x[2], x[3], x[4], x[5])
}

/// `x ... m, ... yaw ... deg` of a transform, in words.
pub fn pose_words(t: &Isometry3<f64>) -> String {
    let g = xyz_rpy_deg(t);
    format!(
        "x {:.3} m, y {:.3} m, z {:.3} m, roll {:.2}, pitch {:.2}, yaw {:.2} deg",
        g[0], g[1], g[2], g[3], g[4], g[5]
    )
}
