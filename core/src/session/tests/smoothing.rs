//! The smoother's tests: the pose a fix's rounds report, against answers
//! that scatter or wander about a truth that moves as slowly as odometry
//! drifts, and answers that jump (a slip).

use super::super::smoother::{pair_drift_deg, Smoother, GATE_M, HEADING_DRIFT_DEG, INFO_SCALE, PAIR_DRIFT_FLOOR_DEG};
use super::Lcg;
use crate::geometry::{from_xyz_rpy, Isometry3};
use nalgebra::{Matrix6, Vector6};

/// EM's information for an answer whose heading, scaled by
/// [`INFO_SCALE`], has a standard deviation of `yaw_deg`.
fn information(yaw_deg: f32) -> Matrix6<f32> {
    let yaw = (yaw_deg / INFO_SCALE).to_radians();
    let (t, r) = (0.01f32, 0.001f32);
    Matrix6::from_diagonal(&Vector6::new(
        1.0 / (t * t),
        1.0 / (t * t),
        1.0 / (t * t),
        1.0 / (r * r),
        1.0 / (r * r),
        1.0 / (yaw * yaw),
    ))
}

/// Heading (degrees) and distance (m) between two poses at `at`.
fn apart(a: &Isometry3<f32>, b: &Isometry3<f32>, at: [f32; 3]) -> (f32, f32) {
    let p = nalgebra::Point3::from(at);
    ((a * b.inverse()).rotation.angle().to_degrees(), (a * p - b * p).norm())
}

/// The truth after `round` rounds: 60 m and 30 degrees off, its heading
/// moving by `deg_per_round`.
fn truth(round: usize, deg_per_round: f32) -> Isometry3<f32> {
    from_xyz_rpy(60.0, 20.0, 0.0, 0.0, 0.0, (30.0 + deg_per_round * round as f32).to_radians())
}

/// The robot's place after `round` rounds of 2 m.
fn place(round: usize) -> [f32; 3] {
    [70.0 + 2.0 * round as f32, 10.0, 0.0]
}

/// A pose `yaw_deg` and (`dx`, `dy`) off `pose`, turned about `at` (where
/// an answer's error is: about what the maps share, not an origin a lever
/// arm away).
fn off_at(pose: &Isometry3<f32>, at: [f32; 3], dx: f32, dy: f32, yaw_deg: f32) -> Isometry3<f32> {
    let to = from_xyz_rpy(at[0], at[1], at[2], 0.0, 0.0, 0.0);
    to * from_xyz_rpy(dx, dy, 0.0, 0.0, 0.0, yaw_deg.to_radians()) * to.inverse() * pose
}

/// Answers scattered about a still truth (0.5 degrees and 0.25 m, as a
/// tracked answer's error is taken to be): the poses reported are closer to
/// it than the answers, at the root mean square by half.
#[test]
fn smoothing_reports_scattered_answers_closer_to_the_truth() {
    let mut rng = Lcg(3);
    let mut noise = || 2.0 * rng.unit() - 1.0;
    let (mut smoother, mut raw, mut smoothed) = (None::<Smoother>, 0.0, 0.0);
    for round in 0..40 {
        let t = truth(round, 0.0);
        let at = place(round);
        let answer = off_at(&t, at, 0.25 * noise(), 0.25 * noise(), 0.5 * noise());
        let reported = match smoother.as_mut() {
            Some(s) => s.update(answer, &information(0.5), at, None),
            None => *smoother.insert(Smoother::start(answer, &information(0.5), at)).transform(),
        };
        if round >= 5 {
            raw += apart(&answer, &t, at).0.powi(2);
            smoothed += apart(&reported, &t, at).0.powi(2);
        }
    }
    assert!(smoothed < 0.25 * raw, "heading, squared: {smoothed} smoothed against {raw}");
}

/// The truth's heading moving a tenth of a degree a round (as fast as the
/// assumed drift lets it, two robots of 2 m a round): the poses reported
/// follow it within 0.3 degree (a lag of about two rounds); answers that
/// wander away from a still truth by 0.12 degree a round (a shrinking
/// overlap) are followed as far behind, the poses reported over 0.2
/// degree closer to the truth than the answers from the sixth round on.
#[test]
fn smoothing_follows_the_drift_and_holds_a_wandering_answer() {
    let start = truth(0, 0.1);
    let mut smoother = Smoother::start(start, &information(0.5), place(0));
    for round in 1..30 {
        let t = truth(round, 0.1);
        let reported = smoother.update(t, &information(0.5), place(round), None);
        assert!(apart(&reported, &t, place(round)).0 < 0.3, "round {round}: {reported:?}");
    }
    let mut smoother = Smoother::start(start, &information(0.5), place(0));
    for round in 1..12 {
        let t = truth(round, 0.0);
        let wandered = off_at(&t, place(round), 0.0, 0.0, 0.12 * round as f32);
        let reported = smoother.update(wandered, &information(0.5), place(round), None);
        let (ours, theirs) = (apart(&reported, &t, place(round)).0, apart(&wandered, &t, place(round)).0);
        assert!(round < 6 || ours < theirs - 0.2, "round {round}: {ours} degrees off, the answer {theirs}");
    }
}

/// A slip (2 m and 10 degrees), or an answer whose information cannot be
/// inverted: the answer is reported as it is, and the filter starts again
/// from it.
#[test]
fn a_jump_or_an_unusable_information_starts_the_smoothing_again() {
    let mut smoother = Smoother::start(truth(0, 0.0), &information(0.5), place(0));
    for round in 1..10 {
        smoother.update(truth(round, 0.0), &information(0.5), place(round), None);
    }
    let slipped = from_xyz_rpy(2.0, 0.0, 0.0, 0.0, 0.0, 10f32.to_radians()) * truth(10, 0.0);
    assert_eq!(smoother.update(slipped, &information(0.5), place(10), None), slipped);
    // From the slipped pose on, a slightly different answer is smoothed.
    let next = from_xyz_rpy(0.0, 0.0, 0.0, 0.0, 0.0, 0.3f32.to_radians()) * slipped;
    let smoothed = smoother.update(next, &information(0.5), place(11), None);
    assert!(apart(&smoothed, &next, place(11)).0 > 0.05, "{smoothed:?}");
    // A jump at the place beyond the gate alone, no rotation.
    let shifted = from_xyz_rpy(GATE_M + 0.1, 0.0, 0.0, 0.0, 0.0, 0.0) * next;
    assert_eq!(smoother.update(shifted, &information(0.5), place(12), None), shifted);
    let singular = Matrix6::zeros();
    let again = from_xyz_rpy(0.0, 0.0, 0.0, 0.0, 0.0, 0.2f32.to_radians()) * shifted;
    assert_eq!(smoother.update(again, &singular, place(13), None), again);
    let nan = Matrix6::from_element(f32::NAN);
    assert_eq!(smoother.update(shifted, &nan, place(14), None), shifted);
}

/// The pair's walk figure sets the drift the filter assumes
/// ([`pair_drift_deg`]): with the figure of odometry that walks half a
/// degree per 100 m (0.1 degree) an answer wandering from a still truth is
/// held closer to the truth than with none (the default assumes a degree
/// per 100 m of each robot); with the figure of a heavy walk (0.4 degree)
/// a truth turning 0.2 degree a round is followed closer than with none.
#[test]
fn the_pair_walk_sets_the_drift_the_smoothing_assumes() {
    assert_eq!(pair_drift_deg(None), HEADING_DRIFT_DEG * core::f32::consts::SQRT_2);
    assert_eq!(pair_drift_deg(Some(f32::NAN)), pair_drift_deg(None));
    assert_eq!(pair_drift_deg(Some(0.0)), PAIR_DRIFT_FLOOR_DEG);
    let wander = |walk: Option<f32>| {
        let mut smoother = Smoother::start(truth(0, 0.0), &information(0.5), place(0));
        let mut off = 0.0;
        for round in 1..12 {
            let t = truth(round, 0.0);
            let wandered = off_at(&t, place(round), 0.0, 0.0, 0.1 * round as f32);
            off = apart(&smoother.update(wandered, &information(0.5), place(round), walk), &t, place(round)).0;
        }
        off
    };
    let (measured, assumed) = (wander(Some(0.1)), wander(None));
    assert!(measured < assumed - 0.1, "{measured} degrees off with the figure, {assumed} without");
    let follow = |walk: Option<f32>| {
        let mut smoother = Smoother::start(truth(0, 0.2), &information(0.5), place(0));
        let mut off = 0.0f32;
        for round in 1..20 {
            let t = truth(round, 0.2);
            off = off.max(apart(&smoother.update(t, &information(0.5), place(round), walk), &t, place(round)).0);
        }
        off
    };
    let (measured, assumed) = (follow(Some(0.4)), follow(None));
    assert!(measured < assumed - 0.1, "{measured} degrees behind with the figure, {assumed} without");
}
