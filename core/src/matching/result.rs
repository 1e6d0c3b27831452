//! What a match returns.

use super::pyramid::MAX_LEVELS;
use crate::wire::report::MatchReport;
use nalgebra::{Isometry3, Matrix6};

/// Verdict of a match, as the conventions spell it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MatchStatus {
    /// The finest level converged, the maps overlap, the geometry constrains
    /// every degree of freedom.
    Converged,
    /// The iteration budget ran out before the finest level converged.
    NotConverged,
    /// The geometry leaves a direction unconstrained (e.g. a flat road alone).
    Degenerate,
    /// The maps do not overlap enough under the result to trust it.
    NoOverlap,
}

impl MatchStatus {
    /// The conventions' status string.
    pub fn as_str(self) -> &'static str {
        match self {
            MatchStatus::Converged => "Converged",
            MatchStatus::NotConverged => "NotConverged",
            MatchStatus::Degenerate => "Degenerate",
            MatchStatus::NoOverlap => "NoOverlap",
        }
    }

    /// The status as one byte on the wire: 0 Converged, 1 NotConverged,
    /// 2 Degenerate, 3 NoOverlap.
    pub fn code(self) -> u8 {
        self as u8
    }

    /// The status of a wire byte, if valid.
    pub fn from_code(code: u8) -> Option<Self> {
        [MatchStatus::Converged, MatchStatus::NotConverged, MatchStatus::Degenerate, MatchStatus::NoOverlap]
            .get(usize::from(code))
            .copied()
    }
}

/// The estimate `T_model_scene` and what backs it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MatchResult {
    /// `T_model_scene`: maps scene coordinates into the model frame.
    pub transform: Isometry3<f32>,
    /// Verdict.
    pub status: MatchStatus,
    /// EM iterations used, all levels together.
    pub iterations: u32,
    /// Iterations per level (index 0 is the finest).
    pub iterations_per_level: [u8; MAX_LEVELS],
    /// Scene voxels with a model voxel within one voxel size at the end
    /// (counted on the subset of `MatchSettings::max_agreement_entries`,
    /// scaled to the whole scene).
    pub inliers: u32,
    /// The conventions' overlap under the result (on that subset).
    pub overlap: f32,
    /// Root mean square distance of the inlier pairs (m).
    pub rmse: f32,
    /// Of the scene's standing voxels (not ground) in places the model saw,
    /// the fraction with a model voxel of the same class group (see
    /// `footprint::GROUP_BITS`) within one voxel: how well what both maps
    /// saw agrees, whatever their overlap.
    pub agreement: f32,
    /// Fraction of the scene's standing voxels in places the model saw.
    pub coverage: f32,
    /// 6x6 information matrix, order (tx, ty, tz, rx, ry, rz), for a left
    /// perturbation in the model frame: `sum w J^T J / s^2` at the solution,
    /// with `s^2` the weighted mean squared residual.
    pub information: Matrix6<f32>,
    /// Smallest eigenvalue of `information`.
    pub min_eigenvalue: f32,
    /// Smallest eigenvalue of the information normalised to unit weight and
    /// unit lever arm (dimensionless, 0 = unconstrained direction).
    pub degeneracy: f32,
}

impl MatchResult {
    /// The match as robot `a`'s estimate of robot `b` (its map the scene),
    /// as robots share it.
    pub fn estimate(&self, a: u8, b: u8) -> crate::wire::share::Estimate {
        let info: [[f32; 6]; 6] = core::array::from_fn(|r| core::array::from_fn(|c| self.information[(r, c)]));
        crate::wire::share::Estimate::new(
            a,
            b,
            self.status.code(),
            crate::geometry::rows(&self.transform),
            &info,
            self.agreement,
        )
    }

    /// The result as robot `robot_id` reports it over a line: plain numbers
    /// ([`MatchReport`]).
    pub fn report(&self, robot_id: u8) -> MatchReport {
        MatchReport {
            robot_id,
            status: self.status.code(),
            transform: crate::geometry::rows(&self.transform),
            iterations: self.iterations.min(u32::from(u16::MAX)) as u16,
            inliers: self.inliers,
            overlap: self.overlap,
            rmse: self.rmse,
        }
    }

    /// `NoOverlap` at the identity with nothing behind it: what a match
    /// that found no basis for an answer reports.
    pub fn no_overlap() -> Self {
        MatchResult {
            transform: Isometry3::identity(),
            status: MatchStatus::NoOverlap,
            iterations: 0,
            iterations_per_level: [0; MAX_LEVELS],
            inliers: 0,
            overlap: 0.0,
            rmse: 0.0,
            agreement: 0.0,
            coverage: 0.0,
            information: Matrix6::zeros(),
            min_eigenvalue: 0.0,
            degeneracy: 0.0,
        }
    }

    /// `NotConverged` at `at`, with nothing behind it: a placement a work
    /// budget did not pay for ([`super::Work`]), neither refined nor judged.
    pub fn not_judged(at: Isometry3<f32>) -> Self {
        MatchResult { transform: at, status: MatchStatus::NotConverged, ..Self::no_overlap() }
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for MatchResult {
    fn format(&self, f: defmt::Formatter<'_>) {
        let t = self.transform.translation.vector;
        let (roll, pitch, yaw) = self.transform.rotation.euler_angles();
        defmt::write!(
            f,
            "{} t=({=f32},{=f32},{=f32}) m rpy=({=f32},{=f32},{=f32}) deg, {=u32} iterations, {=u32} inliers, overlap {=f32}, rmse {=f32} m, degeneracy {=f32}",
            self.status,
            t.x,
            t.y,
            t.z,
            roll.to_degrees(),
            pitch.to_degrees(),
            yaw.to_degrees(),
            self.iterations,
            self.inliers,
            self.overlap,
            self.rmse,
            self.degeneracy
        )
    }
}
