//! Layer 6 (a team of robots, beside matching): every robot placed in one frame from the
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
//! Which matches to keep is decided first, by [`consistent_set`]: one
//! false match, accepted, would bend every pose after it, so the matches
//! are checked against each other around cycles (`T_ab T_bc T_ca` close to
//! the identity, `T_ab T_ba` too), with tolerances from their information
//! matrices, and the largest set whose cycles all close is kept.

use nalgebra::{Isometry3, Matrix6, SMatrix, SVector, Translation3, UnitQuaternion, Vector3, Vector6};

/// Most robots in a team.
pub const MAX_ROBOTS: usize = 8;
const DIM: usize = 6 * MAX_ROBOTS;
/// The pose graph's normal equations, row by row (an array, built in
/// place: a board's stack holds one).
type Normal = [[f64; DIM]; DIM];

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

/// The matches a team is placed from: a slice, or any list that hands them
/// out one at a time (a robot's table of estimates, read in place: a
/// board's stack could not hold 56 of them as `f64`).
pub trait Matches {
    /// How many.
    fn count(&self) -> usize;
    /// Match `i` (`None` past the end).
    fn get(&self, i: usize) -> Option<RelativePose>;
}

impl Matches for [RelativePose] {
    fn count(&self) -> usize {
        self.len()
    }
    fn get(&self, i: usize) -> Option<RelativePose> {
        <[RelativePose]>::get(self, i).copied()
    }
}

impl<const N: usize> Matches for [RelativePose; N] {
    fn count(&self) -> usize {
        N
    }
    fn get(&self, i: usize) -> Option<RelativePose> {
        self.as_slice().get(i).copied()
    }
}

/// The matches of `list` in order.
fn each<L: Matches + ?Sized>(list: &L) -> impl Iterator<Item = (usize, RelativePose)> + '_ {
    (0..list.count()).filter_map(|i| list.get(i).map(|m| (i, m)))
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

/// The team's size and every match checked: robots inside the team, two
/// different ones, finite numbers.
fn check<L: Matches + ?Sized>(robots: usize, matches: &L) -> Result<(), TeamError> {
    if robots > MAX_ROBOTS {
        return Err(TeamError::TooManyRobots);
    }
    for (index, m) in each(matches) {
        let (a, b) = (usize::from(m.a), usize::from(m.b));
        if a >= robots || b >= robots || a == b {
            return Err(TeamError::BadMatch { index });
        }
        if !finite_iso(&m.transform) || m.information.iter().any(|v| !v.is_finite()) {
            return Err(TeamError::NonFinite { index });
        }
    }
    Ok(())
}

/// Each robot's anchor: the lowest index it is connected to by `matches`.
#[inline(always)]
fn anchors<L: Matches + ?Sized>(matches: &L) -> [usize; MAX_ROBOTS] {
    let mut anchor: [usize; MAX_ROBOTS] = core::array::from_fn(|i| i);
    loop {
        let mut changed = false;
        for (_, m) in each(matches) {
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
    anchor
}

/// First poses along a spanning tree from each anchor.
#[inline(always)]
fn first_poses<L: Matches + ?Sized>(
    robots: usize,
    matches: &L,
    anchor: &[usize; MAX_ROBOTS],
) -> [Option<Isometry3<f64>>; MAX_ROBOTS] {
    let mut pose: [Option<Isometry3<f64>>; MAX_ROBOTS] = [None; MAX_ROBOTS];
    for (i, p) in pose.iter_mut().enumerate().take(robots) {
        if anchor[i] == i {
            *p = Some(Isometry3::identity());
        }
    }
    loop {
        let mut grew = false;
        for (_, m) in each(matches) {
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
    pose
}

/// Places every robot of a team of `robots` from the kept `matches` (see
/// the module documentation). Deterministic. Never inlined: its normal
/// equations (18 KiB) are on the stack only while it runs.
#[inline(never)]
pub fn solve<L: Matches + ?Sized>(robots: usize, matches: &L, max_iterations: u32) -> Result<TeamSolution, TeamError> {
    check(robots, matches)?;
    let anchor = anchors(matches);
    let pose = first_poses(robots, matches, &anchor);
    let mut x: [Isometry3<f64>; MAX_ROBOTS] = core::array::from_fn(|i| pose[i].unwrap_or_else(Isometry3::identity));
    let movable: [bool; MAX_ROBOTS] = core::array::from_fn(|i| i < robots && anchor[i] != i);
    let free = |i: usize| movable[i];
    let mut iterations = 0;
    // The normal equations, factored in place (the one big matrix: a
    // robot's stack holds it once).
    let mut h = [[0.0f64; DIM]; DIM];
    for _ in 0..max_iterations.max(1) {
        iterations += 1;
        h = [[0.0f64; DIM]; DIM];
        let mut g = SVector::<f64, DIM>::zeros();
        for (_, m) in each(matches) {
            add_match(&mut h, &mut g, &m, &x, &movable);
        }
        // Anchors and robots beyond the team do not move.
        for i in 0..MAX_ROBOTS {
            if !free(i) {
                for c in 0..6 {
                    h[6 * i + c][6 * i + c] = 1.0;
                }
            }
        }
        cholesky_in_place(&mut h).ok_or(TeamError::Singular)?;
        cholesky_solve(&h, &mut g);
        let delta = -g;
        for (i, xi) in x.iter_mut().enumerate() {
            if free(i) {
                *xi = retract(&delta.fixed_rows::<6>(6 * i).into_owned(), xi);
            }
        }
        if delta.amax() < 1e-10 {
            break;
        }
    }
    // Each pose's covariance: its diagonal block of the inverse, one column
    // at a time from the last factor.
    let mut placements = [None; MAX_ROBOTS];
    for (i, p) in placements.iter_mut().enumerate().take(robots) {
        let mut covariance = Matrix6::zeros();
        if free(i) {
            for c in 0..6 {
                let mut col = SVector::<f64, DIM>::zeros();
                col[6 * i + c] = 1.0;
                cholesky_solve(&h, &mut col);
                covariance.set_column(c, &col.fixed_rows::<6>(6 * i));
            }
        }
        *p = Some(Placement { anchor: anchor[i] as u8, pose: x[i], covariance });
    }
    Ok(TeamSolution { placements, iterations })
}

/// Adds match `m`'s terms to the normal equations `h`, `g` at the poses
/// `x` (numeric Jacobians in each pose that may move). Not inlined, like
/// the factorisation: `solve`'s frame holds the one big matrix, no more.
#[inline(never)]
fn add_match(
    h: &mut Normal,
    g: &mut SVector<f64, DIM>,
    m: &RelativePose,
    x: &[Isometry3<f64>; MAX_ROBOTS],
    free: &[bool; MAX_ROBOTS],
) {
    let (a, b) = (usize::from(m.a), usize::from(m.b));
    let (Some(&xa), Some(&xb)) = (x.get(a), x.get(b)) else { return };
    let free = |k: usize| free.get(k).copied().unwrap_or(false);
    let r = residual(m, &xa, &xb);
    let mut j = [SMatrix::<f64, 6, 6>::zeros(); 2];
    for (side, &k) in [a, b].iter().enumerate() {
        if !free(k) {
            continue;
        }
        let xk = if k == a { xa } else { xb };
        for c in 0..6 {
            let e = 1e-6;
            let mut d = Vector6::zeros();
            d[c] = e;
            let moved = |d: &Vector6<f64>| {
                let moved = retract(d, &xk);
                if k == a {
                    residual(m, &moved, &xb)
                } else {
                    residual(m, &xa, &moved)
                }
            };
            let col = (moved(&d) - moved(&(-d))) / (2.0 * e);
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
                let block = jt_l * j[s2];
                for (r, row) in h.iter_mut().skip(6 * k1).take(6).enumerate() {
                    for (c, v) in row.iter_mut().skip(6 * k2).take(6).enumerate() {
                        *v += block[(r, c)];
                    }
                }
            }
        }
    }
}

/// Factors the symmetric positive definite `h` in place: its lower
/// triangle becomes `L` with `h = L L^T` (the upper triangle is left as
/// is). `None` when `h` is not positive definite.
#[inline(never)]
fn cholesky_in_place(h: &mut Normal) -> Option<()> {
    for j in 0..DIM {
        let (upper, lower) = h.split_at_mut(j + 1);
        let row_j = upper.last_mut()?;
        let (left, rest) = row_j.split_at_mut(j);
        let diag = rest.first_mut()?;
        let d = *diag - dot(left, left);
        if !(d > 0.0 && d.is_finite()) {
            return None;
        }
        let d = libm::sqrt(d);
        *diag = d;
        for row_i in lower.iter_mut() {
            let (left_i, rest_i) = row_i.split_at_mut(j);
            if let Some(v) = rest_i.first_mut() {
                *v = (*v - dot(left_i, left)) / d;
            }
        }
    }
    Some(())
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).fold(0.0, |s, (x, y)| s + x * y)
}

/// Solves `L L^T x = v` in place, `L` the lower triangle of `l` (from
/// [`cholesky_in_place`]).
#[inline(never)]
fn cholesky_solve(l: &Normal, v: &mut SVector<f64, DIM>) {
    let v = v.as_mut_slice();
    for (i, row) in l.iter().enumerate() {
        let (done, rest) = v.split_at_mut(i);
        if let Some(x) = rest.first_mut() {
            *x = (*x - dot(&row[..i], done)) / row[i];
        }
    }
    for i in (0..DIM).rev() {
        let (head, done) = v.split_at_mut(i + 1);
        let below = l.iter().skip(i + 1).map(|row| row[i]);
        let s = below.zip(done.iter()).fold(0.0, |s, (a, b)| s + a * b);
        if let Some(x) = head.last_mut() {
            *x = (*x - s) / l[i][i];
        }
    }
}

/// Tolerance floor added to every match's own covariance: the matcher's
/// information counts thousands of voxel pairs as independent and is far
/// surer than its errors on real pairs (a few centimetres, a tenth of a
/// degree). Standard deviations: 0.1 m per axis, 0.3 degrees per axis.
pub const FLOOR_SIGMA: (f64, f64) = (0.1, 0.3 * core::f64::consts::PI / 180.0);
/// A cycle closes when its squared Mahalanobis distance (6 degrees of
/// freedom) is under this: the chi-square quantile at 0.999.
pub const CYCLE_CHI2: f64 = 22.46;
/// Most branches the search of the largest consistent set explores; past
/// it, the best set found so far is kept (and [`Consistency::exhaustive`]
/// says so).
pub const MAX_BRANCHES: u32 = 200_000;

/// The SE(3) adjoint of `t` for left perturbations, translation first.
fn adjoint(t: &Isometry3<f64>) -> Matrix6<f64> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let p = t.translation.vector;
    let px = nalgebra::Matrix3::new(0.0, -p.z, p.y, p.z, 0.0, -p.x, -p.y, p.x, 0.0);
    let mut a = Matrix6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&(px * r));
    a.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    a
}

/// A transform with the covariance of its left perturbation.
#[derive(Clone, Copy, Debug)]
struct Uncertain {
    t: Isometry3<f64>,
    cov: Matrix6<f64>,
}

impl Uncertain {
    fn of(m: &RelativePose) -> Option<Self> {
        let (st, sr) = FLOOR_SIGMA;
        let floor = Matrix6::from_diagonal(&Vector6::new(st * st, st * st, st * st, sr * sr, sr * sr, sr * sr));
        let own = m.information.try_inverse().filter(|c| c.iter().all(|v| v.is_finite()))?;
        Some(Uncertain { t: m.transform, cov: 0.5 * (own + own.transpose()) + floor })
    }

    /// `self * other`.
    fn then(&self, other: &Uncertain) -> Uncertain {
        let ad = adjoint(&self.t);
        Uncertain { t: self.t * other.t, cov: self.cov + ad * other.cov * ad.transpose() }
    }

    fn inverse(&self) -> Uncertain {
        let inv = self.t.inverse();
        let ad = adjoint(&inv);
        Uncertain { t: inv, cov: ad * self.cov * ad.transpose() }
    }
}

/// Which matches [`consistent_set`] kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Consistency {
    /// Bit `i` set: match `i` is kept.
    pub kept: u64,
    /// Whether the search went through every set (else it stopped at
    /// [`MAX_BRANCHES`] with what it had found).
    pub exhaustive: bool,
}

/// The largest set of `matches` (at most 64) whose cycles all close: each
/// match, added to a set, is checked against the path that the set already
/// has between its two robots (each fundamental cycle once), with the
/// covariances of the path and the match (their own plus [`FLOOR_SIGMA`])
/// and [`CYCLE_CHI2`]. A match between robots the set does not connect yet
/// is always consistent with it. When several sets are equally large, only
/// the matches they all hold are kept: two robots whose two estimates
/// disagree, with no cycle to tell which is right, keep neither (never a
/// guess). Branch and bound over the matches; a match whose information
/// cannot be inverted is never kept. Deterministic. Never inlined (its
/// table of covariances is on the stack only while it runs).
#[inline(never)]
pub fn consistent_set<L: Matches + ?Sized>(robots: usize, matches: &L) -> Result<Consistency, TeamError> {
    if robots > MAX_ROBOTS {
        return Err(TeamError::TooManyRobots);
    }
    if matches.count() > 64 {
        return Err(TeamError::BadMatch { index: 64 });
    }
    check(robots, matches)?;
    // Each match's covariance (floor included), packed: a board's stack
    // holds 64 of them.
    let mut edges = [None; 64];
    for (i, m) in each(matches) {
        if let Some(e) = edges.get_mut(i) {
            *e = Uncertain::of(&m).map(|u| pack(&u.cov));
        }
    }
    let mut search = Search { matches, edges: &edges, best: 0, best_count: 0, branches: 0 };
    search.run(0, 0, 0);
    Ok(Consistency { kept: search.best, exhaustive: search.branches <= MAX_BRANCHES })
}

struct Search<'a, L: Matches + ?Sized> {
    matches: &'a L,
    edges: &'a [Option<[f64; 21]>; 64],
    best: u64,
    best_count: u32,
    branches: u32,
}

/// The upper triangle of a symmetric 6x6 matrix, row by row.
fn pack(m: &Matrix6<f64>) -> [f64; 21] {
    let mut out = [0.0; 21];
    let mut k = 0;
    for r in 0..6 {
        for c in r..6 {
            out[k] = m[(r, c)];
            k += 1;
        }
    }
    out
}

/// The symmetric matrix [`pack`] packed.
fn unpack(p: &[f64; 21]) -> Matrix6<f64> {
    let mut m = Matrix6::zeros();
    let mut k = 0;
    for r in 0..6 {
        for c in r..6 {
            m[(r, c)] = p[k];
            m[(c, r)] = p[k];
            k += 1;
        }
    }
    m
}

impl<L: Matches + ?Sized> Search<'_, L> {
    /// Match `i` with its covariance, when it has one.
    fn edge(&self, i: usize) -> Option<(RelativePose, Uncertain)> {
        let cov = unpack(self.edges.get(i)?.as_ref()?);
        let m = self.matches.get(i)?;
        Some((m, Uncertain { t: m.transform, cov }))
    }

    fn run(&mut self, next: usize, kept: u64, count: u32) {
        self.branches += 1;
        let left = self.matches.count().saturating_sub(next) as u32;
        if count + left < self.best_count || self.branches > MAX_BRANCHES {
            return;
        }
        if next >= self.matches.count() {
            // Equally large sets: only what they all keep is sure.
            if count > self.best_count || self.best_count == 0 {
                (self.best, self.best_count) = (kept, count);
            } else if count == self.best_count {
                self.best &= kept;
            }
            return;
        }
        if self.fits(kept, next) {
            self.run(next + 1, kept | 1 << next, count + 1);
        }
        self.run(next + 1, kept, count);
    }

    /// Whether match `i` closes every cycle it makes with the set `kept`.
    // Not inlined: the search recurses once per match, and each level's
    // frame would hold this one's path table.
    #[inline(never)]
    fn fits(&self, kept: u64, i: usize) -> bool {
        let Some((m, e)) = self.edge(i) else { return false };
        let Some(path) = self.path(kept, usize::from(m.a), usize::from(m.b)) else { return true };
        // The cycle path^-1 * match: the identity when they agree.
        let cycle = path.inverse().then(&e);
        let r = local(&cycle.t);
        cycle.cov.try_inverse().is_some_and(|info| (r.transpose() * info * r)[(0, 0)] < CYCLE_CHI2)
    }

    /// `T_from_to` along the matches of `kept` (breadth first, so the path
    /// is the same for the same set), with its covariance; `None` when
    /// `kept` does not connect them.
    fn path(&self, kept: u64, from: usize, to: usize) -> Option<Uncertain> {
        let mut reach: [Option<Uncertain>; MAX_ROBOTS] = [None; MAX_ROBOTS];
        let start = Uncertain { t: Isometry3::identity(), cov: Matrix6::zeros() };
        *reach.get_mut(from)? = Some(start);
        loop {
            let mut grew = false;
            for i in (0..self.matches.count()).filter(|i| kept & (1 << i) != 0) {
                let Some((m, e)) = self.edge(i) else { continue };
                let (a, b) = (usize::from(m.a), usize::from(m.b));
                match (reach[a], reach[b]) {
                    (Some(xa), None) => reach[b] = Some(xa.then(&e)),
                    (None, Some(xb)) => reach[a] = Some(xb.then(&e.inverse())),
                    _ => continue,
                }
                grew = true;
            }
            if reach[to].is_some() || !grew {
                return reach[to];
            }
        }
    }
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

    /// Both directions of every pair of a chain of robots, one of them false.
    fn team_with_a_false_match(t: &[Isometry3<f64>], pairs: &[(u8, u8)], false_one: usize) -> [RelativePose; 16] {
        let mut out = [measured(t, 0, 1, [0.0; 6], 0.05); 16];
        let mut k = 0;
        for &(a, b) in pairs {
            for (x, y) in [(a, b), (b, a)] {
                let noise = [0.02 * (k % 3) as f64, -0.01, 0.015, 0.001, -0.001 * (k % 2) as f64, 0.002];
                out[k] = measured(t, x, y, noise, 0.01);
                if k == false_one {
                    // 5 m and 20 degrees off.
                    out[k].transform = pose_deg(5.0, 0.0, 0.0, 0.0, 0.0, 20.0) * out[k].transform;
                }
                k += 1;
            }
        }
        out
    }

    #[test]
    fn a_false_match_on_cycles_is_left_out_and_the_team_placed_without_it() {
        let t = truth();
        let pairs = [(0, 1), (1, 2), (2, 0), (2, 3), (3, 0)];
        for false_one in [0, 3, 7] {
            let m = team_with_a_false_match(&t, &pairs, false_one);
            let m = &m[..2 * pairs.len()];
            let c = consistent_set(4, m).unwrap();
            assert!(c.exhaustive);
            assert_eq!(c.kept, ((1u64 << m.len()) - 1) & !(1 << false_one), "false match {false_one}");
            let mut kept = [m[0]; 16];
            let n = m.iter().enumerate().filter(|(i, _)| c.kept & (1 << i) != 0).fold(0, |n, (_, x)| {
                kept[n] = *x;
                n + 1
            });
            let s = solve(4, &kept[..n], 20).unwrap();
            for (i, truth) in t.iter().enumerate().take(4) {
                let (et, er) = errors(&s.placements[i].unwrap(), truth);
                assert!(et < 0.1 && er < 0.01, "robot {i}: {et} m, {er} rad");
            }
        }
        // With no cycle, nothing tells a false match apart: it is kept
        // (the robot it places is then wrong; the team reports it as such).
        let m = team_with_a_false_match(&t, &[(0, 1)], 0);
        assert_eq!(consistent_set(2, &m[..1]).unwrap().kept, 1);
        // Both directions of one pair disagree, and nothing says which is
        // right: neither is kept.
        let c = consistent_set(2, &m[..2]).unwrap();
        assert_eq!(c.kept, 0);
    }

    #[test]
    fn a_false_match_in_both_directions_on_two_cycles_is_left_out() {
        let t = truth();
        // Five robots; the pair 1-2 lies on the cycles 0-1-2 and 1-2-3.
        let pairs = [(0u8, 1u8), (1, 2), (2, 0), (2, 3), (3, 1), (3, 4), (4, 0)];
        let mut m = [measured(&t, 0, 1, [0.0; 6], 0.01); 14];
        for (k, &(a, b)) in pairs.iter().enumerate() {
            m[2 * k] = measured(&t, a, b, [0.02, -0.01, 0.0, 0.001, 0.0, -0.001], 0.01);
            m[2 * k + 1] = measured(&t, b, a, [-0.01, 0.02, 0.01, 0.0, 0.001, 0.001], 0.01);
        }
        // Both directions of 1-2 wrong the same way (they agree with each other).
        let wrong = pose_deg(5.0, 0.0, 0.0, 0.0, 0.0, 20.0);
        m[2].transform = wrong * m[2].transform;
        m[3].transform = m[2].transform.inverse();
        let c = consistent_set(5, &m).unwrap();
        assert!(c.exhaustive);
        assert_eq!(c.kept, 0x3FFF & !0b1100, "{:b}", c.kept);
    }

    #[test]
    fn true_matches_with_realistic_errors_are_all_kept() {
        let t = truth();
        // Errors of a few centimetres and a tenth of a degree, information
        // far surer than that (as the matcher's is).
        let mut m = [measured(&t, 0, 1, [0.0; 6], 0.001); 8];
        let pairs = [(0u8, 1u8), (1, 0), (1, 2), (2, 1), (2, 0), (0, 2), (0, 3), (3, 0)];
        for (k, &(a, b)) in pairs.iter().enumerate() {
            let e = if k % 2 == 0 { 1.0 } else { -1.0 };
            m[k] = measured(&t, a, b, [0.04 * e, 0.03, -0.02 * e, 0.0015 * e, -0.001, 0.002 * e], 0.001);
        }
        let c = consistent_set(4, &m).unwrap();
        assert_eq!(c.kept, 0xFF);
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
