//! An estimate as ROS 2 publishes a pose with its uncertainty
//! (`geometry_msgs/PoseWithCovariance`).
//!
//! The conventions differ. cosem's information matrix
//! ([`cosem_core::matching::MatchResult::information`]) is over a *left
//! perturbation in the model frame*: `T' = Exp(xi) * T`, `xi = (rho,
//! phi)`, translation first. ROS's covariance is on the pose in the parent
//! frame (`header.frame_id`, here the model's odometry frame): the
//! position's error in that frame, then a small rotation about its fixed
//! x, y and z axes (`R' = Exp(dtheta) * R`). To first order
//! `dp = rho - [p]x phi` and `dtheta = phi`, so the covariance published
//! is `J * inv(information) * J^T` with `J = [[I, -[p]x], [0, I]]`.
//!
//! Directions the maps do not constrain (a 4-DoF match's roll and pitch, a
//! street seen along its length) have no finite variance: the information
//! is inverted on the directions whose eigenvalue is at least
//! [`RELATIVE_FLOOR`] of the largest, and each other direction gets the
//! variance [`UNCONSTRAINED`] (m² or rad²), which ROS tools read as "not
//! known". An information matrix with no finite, positive direction gives
//! no pose.

use crate::sources::ros_msgs::{Pose, PoseWithCovariance, Quaternion, Vector3};
use nalgebra::{Isometry3, Matrix3, Matrix6, SymmetricEigen};

/// Directions whose information is under this fraction of the largest
/// are left unconstrained.
pub const RELATIVE_FLOOR: f64 = 1e-9;
/// The variance published along a direction the maps do not constrain.
pub const UNCONSTRAINED: f64 = 1e6;

fn skew(p: &nalgebra::Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -p.z, p.y, p.z, 0.0, -p.x, -p.y, p.x, 0.0)
}

/// The covariance of a left perturbation in the model frame with
/// `information` (order tx, ty, tz, rx, ry, rz), unconstrained directions
/// at [`UNCONSTRAINED`]; `None` when no direction is constrained or the
/// matrix is not finite.
pub fn covariance_of(information: &Matrix6<f64>) -> Option<Matrix6<f64>> {
    if !information.iter().all(|v| v.is_finite()) {
        return None;
    }
    let sym = (information + information.transpose()) * 0.5;
    let eig = SymmetricEigen::new(sym);
    let largest = eig.eigenvalues.max();
    if !(largest > 0.0 && largest.is_finite()) {
        return None;
    }
    let inverse = eig.eigenvalues.map(|l| if l >= RELATIVE_FLOOR * largest { 1.0 / l } else { UNCONSTRAINED });
    let v = eig.eigenvectors;
    Some(v * Matrix6::from_diagonal(&inverse) * v.transpose())
}

/// `J`: a left perturbation in the parent frame to ROS's (position,
/// fixed-axis rotation) of the pose `t`.
pub fn ros_jacobian(t: &Isometry3<f64>) -> Matrix6<f64> {
    let mut j = Matrix6::identity();
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&t.translation.vector)));
    j
}

/// `t` (`T_parent_child`) with the covariance ROS expects of the
/// estimate whose information is `information`; `None` when the
/// information constrains nothing ([`covariance_of`]).
pub fn pose_with_covariance(t: &Isometry3<f64>, information: &Matrix6<f64>) -> Option<PoseWithCovariance> {
    let j = ros_jacobian(t);
    let c = j * covariance_of(information)? * j.transpose();
    let mut covariance = [[0.0; 6]; 6];
    for (r, row) in covariance.iter_mut().enumerate() {
        for (k, v) in row.iter_mut().enumerate() {
            *v = c[(r, k)];
        }
    }
    let (p, q) = (t.translation.vector, t.rotation.quaternion());
    Some(PoseWithCovariance {
        pose: Pose {
            position: Vector3 { x: p.x, y: p.y, z: p.z },
            orientation: Quaternion { x: q.i, y: q.j, z: q.k, w: q.w },
        },
        covariance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector6};

    fn exp(xi: &Vector6<f64>) -> Isometry3<f64> {
        // First order is all the test needs; the rotation exact.
        let phi = nalgebra::Vector3::new(xi[3], xi[4], xi[5]);
        let r = UnitQuaternion::from_scaled_axis(phi);
        Isometry3::from_parts(Translation3::new(xi[0], xi[1], xi[2]), r)
    }

    /// ROS's deltas of a pose moved by a small left perturbation are `J`
    /// times the perturbation.
    #[test]
    fn the_jacobian_maps_a_left_perturbation_to_ros_deltas() {
        let t = Isometry3::from_parts(
            Translation3::new(12.0, -30.0, 2.5),
            UnitQuaternion::from_euler_angles(0.02, -0.01, 2.1),
        );
        let j = ros_jacobian(&t);
        for k in 0..6 {
            let mut xi = Vector6::zeros();
            xi[k] = 1e-6;
            let moved = exp(&xi) * t;
            let dp = moved.translation.vector - t.translation.vector;
            let dtheta = (moved.rotation * t.rotation.inverse()).scaled_axis();
            let got = Vector6::new(dp.x, dp.y, dp.z, dtheta.x, dtheta.y, dtheta.z);
            let want = j * xi;
            assert!((got - want).norm() < 1e-9, "direction {k}: {got} against {want}");
        }
    }

    #[test]
    fn a_full_rank_information_is_inverted() {
        let a = Matrix6::from_fn(|r, c| ((r * 7 + c * 3) % 5) as f64 * 0.1 + if r == c { 4.0 } else { 0.0 });
        let info = a * a.transpose();
        let cov = covariance_of(&info).unwrap();
        assert!((cov * info - Matrix6::identity()).norm() < 1e-9);
    }

    /// A 4-DoF match constrains no roll or pitch: those get the variance
    /// of an unknown, the rest the inverse of what is known.
    #[test]
    fn unconstrained_directions_are_published_as_unknown() {
        let mut info = Matrix6::zeros();
        for (k, v) in [(0, 400.0), (1, 100.0), (2, 900.0), (5, 2500.0)] {
            info[(k, k)] = v;
        }
        let cov = covariance_of(&info).unwrap();
        for (k, v) in
            [(0, 1.0 / 400.0), (1, 0.01), (2, 1.0 / 900.0), (3, UNCONSTRAINED), (4, UNCONSTRAINED), (5, 1.0 / 2500.0)]
        {
            assert!((cov[(k, k)] - v).abs() < 1e-9 * v.max(1.0), "variance {k}: {}", cov[(k, k)]);
        }
        assert!(covariance_of(&Matrix6::zeros()).is_none());
        assert!(covariance_of(&Matrix6::from_element(f64::NAN)).is_none());
    }

    #[test]
    fn a_pose_at_the_origin_keeps_its_covariance() {
        let info = Matrix6::from_diagonal(&Vector6::new(1.0, 4.0, 9.0, 16.0, 25.0, 36.0));
        let p = pose_with_covariance(&Isometry3::identity(), &info).unwrap();
        assert!((p.covariance[1][1] - 0.25).abs() < 1e-12);
        assert!((p.covariance[5][5] - 1.0 / 36.0).abs() < 1e-12);
        assert_eq!(p.pose.orientation.w, 1.0);
    }
}
