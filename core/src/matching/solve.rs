//! M-step: one damped Gauss-Newton step of the weighted least squares on
//! SE(3) (or its 4-DoF subgroup), applied on the left in the model frame.

use super::settings::Dof;
use nalgebra::{Isometry3, Matrix4, Matrix6, Translation3, UnitQuaternion, Vector3, Vector4, Vector6};

/// Indices of (tx, ty, tz, rz) in the 6-vector.
const FOUR: [usize; 4] = [0, 1, 2, 5];

/// Solves `(H + lambda I) delta = -g`. `None` when the system is singular.
pub(crate) fn step(h: &Matrix6<f32>, g: &Vector6<f32>, dof: Dof) -> Option<Vector6<f32>> {
    let scale = h.diagonal().iter().fold(0.0f32, |a, v| a.max(*v));
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let lambda = 1e-6 * scale;
    let delta = match dof {
        Dof::Six => {
            let a = h + Matrix6::identity() * lambda;
            a.cholesky()?.solve(&(-g))
        }
        Dof::Four => {
            let mut a = Matrix4::zeros();
            let mut b = Vector4::zeros();
            for (i, &ii) in FOUR.iter().enumerate() {
                b[i] = -g[ii];
                for (j, &jj) in FOUR.iter().enumerate() {
                    a[(i, j)] = h[(ii, jj)];
                }
                a[(i, i)] += lambda;
            }
            let x = a.cholesky()?.solve(&b);
            let mut d = Vector6::zeros();
            for (i, &ii) in FOUR.iter().enumerate() {
                d[ii] = x[i];
            }
            d
        }
    };
    delta.iter().all(|v| v.is_finite()).then_some(delta)
}

/// The step of [`step`] confined to the directions the pairs constrain:
/// `H` normalised as [`normalised_min_eigenvalue`] does (rotations by the
/// lever arm, per unit weight), solved over its eigenvectors whose
/// eigenvalue is at least `threshold` (a pseudo-inverse); the others, the
/// directions a street seen along its length leaves free, are not moved.
/// Tracking from a fix uses it: there the fix holds what the maps do not.
/// `None` when no direction is constrained or the inputs are not finite.
pub(crate) fn step_held(
    h: &Matrix6<f32>,
    g: &Vector6<f32>,
    sum_w: f32,
    lever: f32,
    dof: Dof,
    threshold: f32,
) -> Option<Vector6<f32>> {
    if !(sum_w > 0.0 && lever > 0.0 && sum_w.is_finite() && lever.is_finite()) {
        return None;
    }
    // Roll and pitch, not solved for in 4 DoF: their rows and columns zero,
    // their eigenvalues 0, never solved over.
    let unsolved = |i: usize| matches!(dof, Dof::Four) && !FOUR.contains(&i);
    let mut n = normalised(h, sum_w, lever);
    for i in (0..6).filter(|&i| unsolved(i)) {
        n.row_mut(i).fill(0.0);
        n.column_mut(i).fill(0.0);
    }
    let b = Vector6::from_fn(|i, _| if unsolved(i) { 0.0 } else { -g[i] * lever_scale(i, lever) / sum_w });
    let eig = nalgebra::SymmetricEigen::new(n);
    let mut x = Vector6::zeros();
    let mut any = false;
    for (k, &lambda) in eig.eigenvalues.iter().enumerate() {
        if lambda >= threshold && lambda > 0.0 && lambda.is_finite() {
            let v = eig.eigenvectors.column(k);
            x += v * (v.dot(&b) / lambda);
            any = true;
        }
    }
    let delta = Vector6::from_fn(|i, _| if unsolved(i) { 0.0 } else { x[i] * lever_scale(i, lever) });
    (any && delta.iter().all(|v| v.is_finite())).then_some(delta)
}

/// What a coordinate of a step is scaled by to make it dimensionless:
/// translations 1, rotations `1 / lever` (a rotation as the metres it moves
/// a point `lever` away).
fn lever_scale(i: usize, lever: f32) -> f32 {
    if i < 3 {
        1.0
    } else {
        1.0 / lever
    }
}

/// `h` normalised ([`lever_scale`] on both sides, then per unit of the
/// total weight `sum_w`): dimensionless, its eigenvalues comparable with
/// the verdict's degeneracy threshold.
fn normalised(h: &Matrix6<f32>, sum_w: f32, lever: f32) -> Matrix6<f32> {
    Matrix6::from_fn(|a, b| h[(a, b)] * lever_scale(a, lever) * lever_scale(b, lever) / sum_w)
}

/// `Exp(delta) * t`: translation part first three, rotation vector last three.
pub(crate) fn apply(delta: &Vector6<f32>, t: &Isometry3<f32>) -> Isometry3<f32> {
    let rot = UnitQuaternion::from_scaled_axis(Vector3::new(delta[3], delta[4], delta[5]));
    let d = Isometry3::from_parts(Translation3::new(delta[0], delta[1], delta[2]), rot);
    let mut out = d * t;
    out.rotation.renormalize();
    out
}

/// Smallest eigenvalue of the information restricted to the estimated
/// degrees of freedom, after scaling rotations by the lever arm `lever` and
/// dividing by the total weight: dimensionless, 0 for an unconstrained
/// direction, about 1/3 for a well-spread cloud of points.
pub(crate) fn normalised_min_eigenvalue(h: &Matrix6<f32>, sum_w: f32, lever: f32, dof: Dof) -> f32 {
    if !(sum_w > 0.0 && lever > 0.0) {
        return 0.0;
    }
    let n = normalised(h, sum_w, lever);
    let ev = match dof {
        Dof::Six => nalgebra::SymmetricEigen::new(n).eigenvalues.iter().fold(f32::INFINITY, |a, v| a.min(*v)),
        Dof::Four => {
            let mut m = Matrix4::zeros();
            for (i, &ii) in FOUR.iter().enumerate() {
                for (j, &jj) in FOUR.iter().enumerate() {
                    m[(i, j)] = n[(ii, jj)];
                }
            }
            nalgebra::SymmetricEigen::new(m).eigenvalues.iter().fold(f32::INFINITY, |a, v| a.min(*v))
        }
    };
    if ev.is_finite() {
        ev.max(0.0)
    } else {
        0.0
    }
}

/// Smallest eigenvalue of a symmetric 6x6 matrix.
pub(crate) fn min_eigenvalue(m: &Matrix6<f32>) -> f32 {
    nalgebra::SymmetricEigen::new(*m).eigenvalues.iter().fold(f32::INFINITY, |a, v| a.min(*v))
}
