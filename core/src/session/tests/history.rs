//! The history's tests: fixes that drift explains continue it, look-alikes
//! (a junction turned by 90 degrees, a street slid a block) are contested
//! until their confirmed rounds outweigh it, a slip is not contested, and
//! the bounds grow with the driving.

use super::super::history::{History, HISTORY_DEG, HISTORY_M};
use crate::geometry::{from_xyz_rpy, Isometry3};

/// `T_own_peer` of a peer whose odometry frame is 80 m east of this
/// robot's, turned by `yaw` degrees, moved by `(dx, dy)` more.
fn fix(dx: f32, dy: f32, yaw: f32) -> Isometry3<f32> {
    from_xyz_rpy(80.0 + dx, dy, 0.0, 0.0, 0.0, yaw.to_radians())
}

/// Both robots meet at the robot's (30, 5), the peer's place as the fix
/// puts it.
fn places(t: &Isometry3<f32>) -> ([f32; 3], Option<[f32; 3]>) {
    let q = t.inverse() * nalgebra::Point3::new(30.0, 5.0, 0.0);
    ([30.0, 5.0, 0.0], Some([q.x, q.y, q.z]))
}

/// A history of `rounds` confirmed rounds of overlap 0.5 at `fix(0, 0, 0)`.
fn trusted(rounds: usize) -> History {
    let mut h = History::new();
    let t = fix(0.0, 0.0, 0.0);
    let (at, peer_at) = places(&t);
    for _ in 0..rounds {
        h.drive(at, peer_at);
        assert!(!h.confirmed(&t, 0.5, at, peer_at));
    }
    h
}

#[test]
fn a_fix_drift_explains_continues_the_history() {
    let mut h = trusted(3);
    // A metre and a degree off: the drift of one meeting to the next.
    let moved = fix(1.0, -0.5, 1.0);
    let (at, peer_at) = places(&moved);
    assert!(!h.contests(&moved, at, peer_at));
    assert!(!h.confirmed(&moved, 0.5, at, peer_at));
    assert_eq!(h.trusted(), Some(&moved));
    // No history: nothing is contested.
    assert!(!History::new().contests(&fix(0.0, 40.0, 90.0), at, peer_at));
}

#[test]
fn a_look_alike_is_contested_until_it_outweighs_the_history() {
    for look_alike in [fix(0.0, 0.0, 90.0), fix(40.0, 0.0, 0.0), fix(0.0, 0.0, 180.0)] {
        let mut h = trusted(3);
        let (at, peer_at) = places(&look_alike);
        assert!(h.contests(&look_alike, at, peer_at), "{look_alike:?}");
        // Three rounds of 0.5 weigh 1.5: a challenger of 0.4 a round is
        // contested for three rounds, not for the fourth.
        for round in 0..3 {
            assert!(h.confirmed(&look_alike, 0.4, at, peer_at), "round {round}");
            assert_eq!(h.trusted(), Some(&fix(0.0, 0.0, 0.0)));
        }
        assert!(!h.confirmed(&look_alike, 0.4, at, peer_at));
        assert_eq!(h.trusted(), Some(&look_alike));
        // The old history is now the one contested.
        assert!(h.contests(&fix(0.0, 0.0, 0.0), at, peer_at));
    }
    // A challenger that changes starts again: two look-alikes do not add up.
    let mut h = trusted(1);
    let (at, peer_at) = places(&fix(0.0, 0.0, 0.0));
    assert!(h.confirmed(&fix(0.0, 0.0, 90.0), 0.4, at, peer_at));
    assert!(h.confirmed(&fix(0.0, 0.0, 180.0), 0.4, at, peer_at));
    assert_eq!(h.trusted(), Some(&fix(0.0, 0.0, 0.0)));
    // A non-finite overlap weighs nothing.
    assert!(h.confirmed(&fix(0.0, 0.0, 180.0), f32::NAN, at, peer_at));
}

#[test]
fn a_slip_is_not_contested() {
    // The benchmark's slip: 2 m and 10 degrees about the slipping robot's
    // place, which moves the peer's frame 2 m there and more at the peer.
    let h = trusted(5);
    let t = fix(0.0, 0.0, 0.0);
    let turn = from_xyz_rpy(30.0, 5.0, 0.0, 0.0, 0.0, 10f32.to_radians())
        * from_xyz_rpy(-30.0 + 2.0, -5.0, 0.0, 0.0, 0.0, 0.0);
    let slipped = turn * t;
    let (at, peer_at) = places(&slipped);
    assert!(!h.contests(&slipped, at, peer_at), "{slipped:?}");
    // Beyond the bounds, with no driving since: contested.
    let turned = from_xyz_rpy(0.0, 0.0, 0.0, 0.0, 0.0, (HISTORY_DEG + 1.0).to_radians()) * t;
    assert!(h.contests(&turned, at, peer_at));
    assert!(h.contests(&fix(HISTORY_M + 1.0, 0.0, 0.0), at, peer_at));
}

#[test]
fn the_bounds_grow_with_the_driving() {
    let mut h = trusted(5);
    let slid = fix(40.0, 0.0, 0.0);
    let (at, peer_at) = places(&slid);
    assert!(h.contests(&slid, at, peer_at));
    // Both robots drive 400 m out and 400 m back (the places the same):
    // 10 m + 5% of their 1,600 m allow a block's slide, and the turn's
    // bound, 20 + 32 degrees, still not a quarter turn.
    for step in 1..=40 {
        let x = if step <= 20 { 30.0 + 20.0 * step as f32 } else { 30.0 + 20.0 * (40 - step) as f32 };
        let peer = peer_at.map(|p| [p[0] - (x - 30.0), p[1], p[2]]);
        h.drive([x, 5.0, 0.0], peer);
    }
    assert!(!h.contests(&slid, at, peer_at));
    // A junction turned by 90 degrees is still a look-alike.
    assert!(h.contests(&fix(0.0, 0.0, 90.0), at, peer_at));
}

#[test]
fn an_old_history_weighs_less() {
    let mut h = trusted(5);
    let (at, peer_at) = places(&fix(0.0, 0.0, 0.0));
    // Both robots drive 100 m out and back: 400 m together, two of
    // HISTORY_HALF_M, so the history's 2.5 weigh 0.625 now.
    for x in [50.0, 70.0, 90.0, 110.0, 130.0, 110.0, 90.0, 70.0, 50.0, 30.0] {
        let peer = peer_at.map(|p| [p[0] - (x - 30.0), p[1], p[2]]);
        h.drive([x, 5.0, 0.0], peer);
    }
    let turned = fix(0.0, 0.0, 90.0);
    assert!(h.contests(&turned, at, peer_at));
    assert!(h.confirmed(&turned, 0.4, at, peer_at));
    assert!(!h.confirmed(&turned, 0.4, at, peer_at));
    assert_eq!(h.trusted(), Some(&turned));
}
