//! A match result as it travels: plain numbers, no type from the layers
//! above (the matcher builds one with `MatchResult::report`).

use super::message::MessageError;
use crate::geometry::{from_rows, Isometry3};
use serde::{Deserialize, Serialize};

/// A match result a robot reports.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MatchReport {
    /// Reporting robot.
    pub robot_id: u8,
    /// Status code: 0 Converged, 1 NotConverged, 2 Degenerate, 3 NoOverlap
    /// (`MatchStatus::code`).
    pub status: u8,
    /// `T_model_scene`, the top three rows of the 4x4 matrix, row by row.
    pub transform: [f32; 12],
    /// EM iterations.
    pub iterations: u16,
    /// Inlier voxels.
    pub inliers: u32,
    /// Overlap (0..1).
    pub overlap: f32,
    /// RMSE (m).
    pub rmse: f32,
}

impl MatchReport {
    /// `T_model_scene`.
    pub fn transform(&self) -> Isometry3<f32> {
        from_rows(&self.transform)
    }

    /// Whether every number is finite (what came over a line may not be).
    pub fn check(&self) -> Result<(), MessageError> {
        let finite = self.transform.iter().chain([&self.overlap, &self.rmse]).all(|v| v.is_finite());
        if finite {
            Ok(())
        } else {
            Err(MessageError::NonFinite)
        }
    }
}

/// A report with every field set: part of the golden feed bytes.
pub const GOLDEN_MATCH: MatchReport = MatchReport {
    robot_id: 0,
    status: 0,
    transform: [1.0, 0.0, 0.0, 2.5, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0],
    iterations: 17,
    inliers: 1234,
    overlap: 0.75,
    rmse: 0.125,
};
