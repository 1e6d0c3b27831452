//! Odometry drift with a known truth: a robot's own poses as its odometry
//! would give them. A seeded model, applied to any source's poses: a scale
//! error of the distance driven (its sign drawn per robot) and a heading
//! random walk whose variance grows with the distance driven; and, to test
//! that a fix stops agreeing, a sudden slip.

use crate::rng::Rng;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// Drift of a robot's odometry (`--drift S,H`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Drift {
    /// Scale error of the distance driven, as a fraction (0.01: 1%); each
    /// robot's sign is drawn from its seed.
    pub scale: f64,
    /// Heading random walk: its standard deviation after 100 m driven
    /// (degrees); the variance grows as `heading^2` per 100 m.
    pub heading_deg: f64,
}

impl Drift {
    /// No drift.
    pub const NONE: Drift = Drift { scale: 0.0, heading_deg: 0.0 };
}

/// `S,H`: scale `S` (a fraction, or a percentage with `%`, at most 50%)
/// and heading `H` (degrees per 100 m, at most 90).
impl std::str::FromStr for Drift {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || {
            format!("`{s}`: expected S,H: a scale error S (0.01 or 1%, at most 50%) and a heading walk H (degrees per 100 m, 0 to 90)")
        };
        let (scale, heading) = s.split_once(',').ok_or_else(bad)?;
        let scale = scale.trim();
        let scale = match scale.strip_suffix('%') {
            Some(p) => p.trim().parse::<f64>().map(|v| v / 100.0),
            None => scale.parse::<f64>(),
        }
        .map_err(|_| bad())?;
        let heading_deg = heading.trim().parse::<f64>().map_err(|_| bad())?;
        if !(0.0..=0.5).contains(&scale) || !(0.0..=90.0).contains(&heading_deg) {
            return Err(bad());
        }
        Ok(Drift { scale, heading_deg })
    }
}

impl std::fmt::Display for Drift {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}%,{}", self.scale * 100.0, self.heading_deg)
    }
}

/// A sudden jump of a robot's odometry: 2 m sideways and 10 degrees of
/// heading, the slip.
pub fn slip() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.0, 2.0, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 10f64.to_radians()),
    )
}

/// A robot's odometry: `truth` (its true poses in its anchor frame, the
/// first the identity) as drifted odometry gives them, re-anchored at the
/// first. Each step's motion is scaled by `1 ± scale` (sign drawn from
/// `seed`), and turned by a heading step of variance `heading^2 * d / 100`
/// (d: the step's length, m); `slip_at`: the pose index from which the
/// odometry has slipped by [`slip`].
pub fn drifted(truth: &[Isometry3<f64>], drift: Drift, seed: u64, slip_at: Option<usize>) -> Vec<Isometry3<f64>> {
    let mut rng = Rng::new(seed ^ 0xD41F_7000);
    let sign = if rng.chance(0.5) { 1.0 } else { -1.0 };
    let scale = 1.0 + sign * drift.scale;
    let mut out: Vec<Isometry3<f64>> = Vec::with_capacity(truth.len());
    for (k, pose) in truth.iter().enumerate() {
        let Some(prev_true) = k.checked_sub(1).and_then(|p| truth.get(p)) else {
            out.push(Isometry3::identity());
            continue;
        };
        let step = prev_true.inverse() * pose;
        let d = step.translation.vector.norm();
        let sigma = drift.heading_deg.to_radians() * (d / 100.0).sqrt();
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), sigma * rng.gaussian());
        let moved = Isometry3::from_parts(Translation3::from(step.translation.vector * scale), step.rotation);
        let prev = out.last().copied().unwrap_or_else(Isometry3::identity);
        let mut next = prev * Isometry3::from_parts(Translation3::identity(), turn) * moved;
        if slip_at == Some(k) {
            next = prev * slip() * Isometry3::from_parts(Translation3::identity(), turn) * moved;
        }
        out.push(next);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn straight(n: usize, step: f64) -> Vec<Isometry3<f64>> {
        (0..n).map(|i| Isometry3::translation(step * i as f64, 0.0, 0.0)).collect()
    }

    #[test]
    fn no_drift_is_the_truth_and_drift_grows_with_distance() {
        let truth = straight(201, 1.0);
        let same = drifted(&truth, Drift::NONE, 1, None);
        assert!(same.iter().zip(&truth).all(|(a, b)| (a.translation.vector - b.translation.vector).norm() < 1e-9));
        // 1% scale: 2 m after 200 m, either way.
        let scaled = drifted(&truth, Drift { scale: 0.01, heading_deg: 0.0 }, 1, None);
        let end = scaled.last().unwrap().translation.vector;
        assert!((end.x.abs() - 200.0).abs() > 1.99 && (end.x.abs() - 200.0).abs() < 2.01, "{end}");
        // The heading walk: over seeds, the heading after 200 m spreads as
        // H * sqrt(2).
        let h = Drift { scale: 0.0, heading_deg: 0.5 };
        let yaws: Vec<f64> = (0..400)
            .map(|s| drifted(&truth, h, s, None).last().unwrap().rotation.euler_angles().2.to_degrees())
            .collect();
        let sd = (yaws.iter().map(|y| y * y).sum::<f64>() / yaws.len() as f64).sqrt();
        assert!((sd - 0.5 * 2f64.sqrt()).abs() < 0.1, "heading sd {sd}");
        // A slip jumps the odometry from its pose on.
        let slipped = drifted(&truth, Drift::NONE, 1, Some(100));
        assert!((slipped[99].translation.vector - truth[99].translation.vector).norm() < 1e-9);
        assert!((slipped[100].translation.vector - truth[100].translation.vector).norm() > 1.9);
    }

    #[test]
    fn drift_is_parsed_with_its_bounds() {
        assert_eq!("1%,0.5".parse::<Drift>(), Ok(Drift { scale: 0.01, heading_deg: 0.5 }));
        assert_eq!("0.02,1".parse::<Drift>(), Ok(Drift { scale: 0.02, heading_deg: 1.0 }));
        for bad in ["1%", "x,1", "60%,1", "1%,-1", "1%,nan", "1%,100"] {
            assert!(bad.parse::<Drift>().is_err(), "{bad}");
        }
    }
}
