//! Stage 7 (a team of robots): every robot placed in one frame from the
//! pairwise matches that were kept.
//!
//! Each kept match is a [`RelativePose`]: robot `a`'s estimate of `T_a_b`
//! with its information matrix (the matcher's, of a perturbation applied on
//! the left, in `a`'s frame: `T_a_b = [R(w), v] * estimate`, order `(v,
//! w)`). [`solve`] finds the poses that agree best with all of them, a
//! small pose graph solved by Gauss-Newton: each connected group of robots
//! is placed in the frame of its lowest index (robot 0's group is the
//! team's frame), with the covariance of each pose from the inverse of the
//! normal equations. Fixed capacity ([`MAX_ROBOTS`]), no allocation; the
//! normal equations are one dense `48 x 48` matrix of `f64` (18 KiB).
//!
//! Which matches to keep (consistency around cycles) is decided before:
//! this module trusts what it is given.

use nalgebra::{Isometry3, Matrix6, SMatrix, SVector, Translation3, UnitQuaternion, Vector3, Vector6};

/// Most robots in a team.
pub const MAX_ROBOTS: usize = 8;
const DIM: usize = 6 * MAX_ROBOTS;

/// One kept match: robot `a`'s estimate of `T_a_b` (robot `b`'s frame in
/// robot `a`'s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelativePose {
    /// The robot whose map was the model.
    pub a: u8,
    /// The robot whose map was the scene.
    pub b: u8,
    /// `T_a_b`.
    pub transform: Isometry3<f64>,
    /// Information of the estimate (left perturbation in `a`'s frame,
    /// translation first).
    pub information: Matrix6<f64>,
}

/// Where a robot ends up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// The robot whose frame the pose is in: the lowest index of the group
    /// connected to this robot (0 for robot 0's group).
    pub anchor: u8,
    /// `T_anchor_robot`.
    pub pose: Isometry3<f64>,
    /// Covariance of the pose (left perturbation in the anchor's frame,
    /// translation first); zero for the anchor itself.
    pub covariance: Matrix6<f64>,
}

/// The solved team.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TeamSolution {
    /// One per robot (`None` beyond the team's size).
    pub placements: [Option<Placement>; MAX_ROBOTS],
    /// Gauss-Newton iterations run.
    pub iterations: u32,
}

/// Why a team could not be solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TeamError {
    /// More robots than [`MAX_ROBOTS`].
    TooManyRobots,
    /// Match `index` names a robot outside the team, or the same robot twice.
    BadMatch {
        /// Its position in the list.
        index: usize,
    },
    /// Match `index` holds a NaN or an infinity.
    NonFinite {
        /// Its position in the list.
        index: usize,
    },
    /// The information of a group does not fix its poses (a match without
    /// information, or one that constrains nothing).
    Singular,
}

impl core::fmt::Display for TeamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TeamError::TooManyRobots => write!(f, "more than {MAX_ROBOTS} robots"),
            TeamError::BadMatch { index } => {
                write!(f, "match {index} names a robot outside the team or one robot twice")
            }
            TeamError::NonFinite { index } => write!(f, "match {index} holds a non-finite number"),
            TeamError::Singular => f.write_str("the matches do not fix every pose of a group (information singular)"),
        }
    }
}

impl core::error::Error for TeamError {}

/// `[R(w), v] * t`: the matcher's perturbation, applied on the left.
fn retract(d: &Vector6<f64>, t: &Isometry3<f64>) -> Isometry3<f64> {
    let rot = UnitQuaternion::from_scaled_axis(Vector3::new(d[3], d[4], d[5]));
    let mut out = Isometry3::from_parts(Translation3::new(d[0], d[1], d[2]), rot) * t;
    out.rotation.renormalize();
    out
}

/// The perturbation `d` with `retract(d, identity) = t`.
fn local(t: &Isometry3<f64>) -> Vector6<f64> {
    let w = t.rotation.scaled_axis();
    Vector6::new(t.translation.x, t.translation.y, t.translation.z, w.x, w.y, w.z)
}

/// How far the poses are from match `m`: the perturbation that takes its
/// estimate to `X_a^-1 X_b`.
fn residual(m: &RelativePose, xa: &Isometry3<f64>, xb: &Isometry3<f64>) -> Vector6<f64> {
    local(&(xa.inverse() * xb * m.transform.inverse()))
}

fn finite_iso(t: &Isometry3<f64>) -> bool {
    t.translation.vector.iter().chain(t.rotation.coords.iter()).all(|v| v.is_finite())
}

/// Places every robot of a team of `robots` from the kept `matches` (see
/// the module documentation). Deterministic.
pub fn solve(robots: usize, matches: &[RelativePose], max_iterations: u32) -> Result<TeamSolution, TeamError> {
    if robots > MAX_ROBOTS {
        return Err(TeamError::TooManyRobots);
    }
    for (index, m) in matches.iter().enumerate() {
        let (a, b) = (usize::from(m.a), usize::from(m.b));
        if a >= robots || b >= robots || a == b {
            return Err(TeamError::BadMatch { index });
        }
        if !finite_iso(&m.transform) || m.information.iter().any(|v| !v.is_finite()) {
            return Err(TeamError::NonFinite { index });
        }
    }
    // Groups: each robot's anchor is the lowest index it is connected to.
    let mut anchor: [usize; MAX_ROBOTS] = core::array::from_fn(|i| i);
    loop {
        let mut changed = false;
        for m in matches {
            let (a, b) = (usize::from(m.a), usize::from(m.b));
            let low = anchor[a].min(anchor[b]);
            changed |= anchor[a] != low || anchor[b] != low;
            anchor[a] = low;
            anchor[b] = low;
        }
        if !changed {
            break;
        }
    }
    // First poses along a spanning tree from each anchor.
    let mut pose: [Option<Isometry3<f64>>; MAX_ROBOTS] = [None; MAX_ROBOTS];
    for (i, p) in pose.iter_mut().enumerate().take(robots) {
        if anchor[i] == i {
            *p = Some(Isometry3::identity());
        }
    }
    loop {
        let mut grew = false;
        for m in matches {
            let (a, b) = (usize::from(m.a), usize::from(m.b));
            match (pose[a], pose[b]) {
                (Some(xa), None) => pose[b] = Some(xa * m.transform),
                (None, Some(xb)) => pose[a] = Some(xb * m.transform.inverse()),
                _ => continue,
            }
            grew = true;
        }
        if !grew {
            break;
        }
    }
    let mut x: [Isometry3<f64>; MAX_ROBOTS] = core::array::from_fn(|i| pose[i].unwrap_or_else(Isometry3::identity));
    let free = |i: usize| i < robots && anchor[i] != i;
    let mut iterations = 0;
    let mut h = SMatrix::<f64, DIM, DIM>::zeros();
    for _ in 0..max_iterations.max(1) {
        iterations += 1;
        h = SMatrix::<f64, DIM, DIM>::zeros();
        let mut g = SVector::<f64, DIM>::zeros();
        for m in matches {
            let (a, b) = (usize::from(m.a), usize::from(m.b));
            let r = residual(m, &x[a], &x[b]);
            // Numeric Jacobians of the residual in each free pose.
            let mut j = [SMatrix::<f64, 6, 6>::zeros(); 2];
            for (side, &k) in [a, b].iter().enumerate() {
                if !free(k) {
                    continue;
                }
                for c in 0..6 {
                    let e = 1e-6;
                    let mut d = Vector6::zeros();
                    d[c] = e;
                    let (mut xp, mut xm) = (x, x);
                    xp[k] = retract(&d, &x[k]);
                    xm[k] = retract(&(-d), &x[k]);
                    let col = (residual(m, &xp[a], &xp[b]) - residual(m, &xm[a], &xm[b])) / (2.0 * e);
                    j[side].set_column(c, &col);
                }
            }
            for (s1, &k1) in [a, b].iter().enumerate() {
                if !free(k1) {
                    continue;
                }
                let jt_l = j[s1].transpose() * m.information;
                let mut gk = g.fixed_rows_mut::<6>(6 * k1);
                gk += jt_l * r;
                for (s2, &k2) in [a, b].iter().enumerate() {
                    if free(k2) {
                        let mut block = h.fixed_view_mut::<6, 6>(6 * k1, 6 * k2);
                        block += jt_l * j[s2];
                    }
                }
            }
        }
        // Anchors and robots beyond the team do not move.
        for i in 0..MAX_ROBOTS {
            if !free(i) {
                for c in 0..6 {
                    h[(6 * i + c, 6 * i + c)] = 1.0;
                }
            }
        }
        let chol = nalgebra::Cholesky::new(h).ok_or(TeamError::Singular)?;
        let delta = -chol.solve(&g);
        for (i, xi) in x.iter_mut().enumerate() {
            if free(i) {
                *xi = retract(&delta.fixed_rows::<6>(6 * i).into_owned(), xi);
            }
        }
        if delta.amax() < 1e-10 {
            break;
        }
    }
    let inverse = nalgebra::Cholesky::new(h).ok_or(TeamError::Singular)?.inverse();
    let mut placements = [None; MAX_ROBOTS];
    for (i, p) in placements.iter_mut().enumerate().take(robots) {
        let covariance = if free(i) { inverse.fixed_view::<6, 6>(6 * i, 6 * i).into_owned() } else { Matrix6::zeros() };
        *p = Some(Placement { anchor: anchor[i] as u8, pose: x[i], covariance });
    }
    Ok(TeamSolution { placements, iterations })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose_deg;

    fn truth() -> [Isometry3<f64>; 5] {
        [
            Isometry3::identity(),
            pose_deg(6.0, 1.0, 0.1, 1.0, -0.5, 20.0),
            pose_deg(12.0, -2.0, 0.0, 0.0, 1.0, -35.0),
            pose_deg(3.0, 9.0, -0.2, -1.0, 0.0, 150.0),
            pose_deg(40.0, 40.0, 0.0, 0.0, 0.0, 90.0),
        ]
    }

    /// A match from the truth, disturbed by `noise` (a left perturbation).
    fn measured(t: &[Isometry3<f64>], a: u8, b: u8, noise: [f64; 6], sigma: f64) -> RelativePose {
        let truth = t[usize::from(a)].inverse() * t[usize::from(b)];
        let d = Vector6::from_column_slice(&noise);
        RelativePose { a, b, transform: retract(&d, &truth), information: Matrix6::identity() / (sigma * sigma) }
    }

    fn errors(p: &Placement, truth: &Isometry3<f64>) -> (f64, f64) {
        let d = p.pose.inverse() * truth;
        (d.translation.vector.norm(), d.rotation.angle())
    }

    #[test]
    fn exact_matches_give_the_true_poses_and_groups_keep_their_own_frame() {
        let t = truth();
        let m = [
            measured(&t, 0, 1, [0.0; 6], 0.05),
            measured(&t, 1, 2, [0.0; 6], 0.05),
            measured(&t, 2, 0, [0.0; 6], 0.05),
            measured(&t, 4, 3, [0.0; 6], 0.05),
        ];
        let s = solve(6, &m, 20).unwrap();
        for (i, truth) in t.iter().enumerate().take(3) {
            let p = s.placements[i].unwrap();
            assert_eq!(p.anchor, 0);
            let (et, er) = errors(&p, truth);
            assert!(et < 1e-9 && er < 1e-9, "robot {i}: {et} m, {er} rad");
        }
        // Robots 3 and 4 are a group of their own, in robot 3's frame.
        let p4 = s.placements[4].unwrap();
        assert_eq!(p4.anchor, 3);
        let (et, er) = errors(&p4, &(t[3].inverse() * t[4]));
        assert!(et < 1e-9 && er < 1e-9);
        // Robot 5 has no match: alone, its own anchor.
        assert_eq!(s.placements[5].map(|p| p.anchor), Some(5));
        assert_eq!(s.placements[6], None);
    }

    #[test]
    fn noisy_matches_average_and_more_matches_mean_less_uncertainty() {
        let t = truth();
        let s = 0.05;
        let m = [
            measured(&t, 0, 1, [0.04, -0.03, 0.01, 0.002, -0.001, 0.004], s),
            measured(&t, 1, 0, [-0.05, 0.02, 0.0, -0.001, 0.002, -0.003], s),
            measured(&t, 1, 2, [0.03, 0.05, -0.02, 0.0, 0.001, 0.002], s),
            measured(&t, 2, 0, [-0.02, 0.01, 0.03, 0.001, 0.0, -0.004], s),
            measured(&t, 0, 3, [0.05, 0.0, 0.01, 0.0, -0.002, 0.001], s),
        ];
        let sol = solve(4, &m, 20).unwrap();
        for (i, truth) in t.iter().enumerate().take(4) {
            let (et, er) = errors(&sol.placements[i].unwrap(), truth);
            assert!(et < 0.2 && er < 0.02, "robot {i}: {et} m, {er} rad");
        }
        // Robot 1 has three matches, robot 3 one: robot 1 is surer.
        let trace = |i: usize| sol.placements[i].unwrap().covariance.trace();
        assert!(trace(1) < trace(3), "{} {}", trace(1), trace(3));
        assert!(sol.placements[0].unwrap().covariance == Matrix6::zeros());
        // Robot 3 hangs on its one match from robot 0, whose perturbation is
        // in robot 0's frame: its covariance is that match's, exactly.
        let c3 = sol.placements[3].unwrap().covariance;
        assert!((c3 - Matrix6::identity() * s * s).amax() < 1e-9, "{c3}");
    }

    #[test]
    fn bad_matches_are_typed_errors() {
        let t = truth();
        let m = measured(&t, 0, 1, [0.0; 6], 0.05);
        assert_eq!(solve(9, &[m], 5), Err(TeamError::TooManyRobots));
        assert_eq!(solve(2, &[m, RelativePose { b: 0, ..m }], 5), Err(TeamError::BadMatch { index: 1 }));
        assert_eq!(solve(1, &[m], 5), Err(TeamError::BadMatch { index: 0 }));
        let mut nan = m;
        nan.information[(2, 2)] = f64::NAN;
        assert_eq!(solve(2, &[nan], 5), Err(TeamError::NonFinite { index: 0 }));
        let zero = RelativePose { information: Matrix6::zeros(), ..m };
        assert_eq!(solve(2, &[zero], 5), Err(TeamError::Singular));
    }
}
