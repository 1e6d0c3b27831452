//! The odometry's heading walk as a robot measures it: a scan turned about
//! its sensor against the map before it, and the figure over scans.

use super::*;
use crate::session::walk::{
    walk_stride, OdometryWalk, ScanFit, WALK_MAX_SD_DEG, WALK_MIN_SCANS, WALK_POINTS, WALK_SCANS, WALK_STRIDE,
};

/// A point of a block's street at draw `(u, v, w)`: walls either side, a
/// cross wall at its end, poles, ground.
fn place(u: f32, v: f32, w: f32) -> [f32; 3] {
    match (v * 5.0) as u32 {
        0 => [-20.0 + 40.0 * u, 6.0, 3.0 * w],
        1 => [-20.0 + 40.0 * u, -6.0 + 0.3 * u, 3.0 * w],
        2 => [18.0, -6.0 + 12.0 * u, 3.0 * w],
        3 => [libm::floorf(8.0 * u) * 4.0 - 14.0, 4.0, 4.0 * w],
        _ => [-20.0 + 38.0 * u, -6.0 + 12.0 * w, 0.0],
    }
}

fn mapped(rng: &mut Lcg, points: usize) -> VecMap {
    let mut map = robot_map();
    for _ in 0..points {
        let p = place(rng.unit(), rng.unit(), rng.unit());
        map.insert_point(p, Class::Building).unwrap();
    }
    map
}

/// The turn of a scan the odometry turned by `deg` about its sensor at
/// `centre`.
fn turn_of(map: &VecMap, rng: &mut Lcg, centre: [f32; 3], deg: f32) -> Option<f32> {
    let fit = fit_of(map, rng, centre, deg, 32_000, WALK_STRIDE);
    assert!(fit.pairs() > 500, "{}", fit.pairs());
    fit.yaw()
}

/// A scan of `points` points that the odometry turned by `deg` about its
/// sensor at `centre`, taken one point in `stride`.
fn fit_of(map: &VecMap, rng: &mut Lcg, centre: [f32; 3], deg: f32, points: usize, stride: u32) -> ScanFit {
    let (s, c) = libm::sincosf(deg.to_radians());
    let mut fit = ScanFit::with_stride(centre, stride);
    for _ in 0..points {
        let p = place(rng.unit(), rng.unit(), rng.unit());
        let (dx, dy) = (p[0] - centre[0], p[1] - centre[1]);
        fit.add(map, [centre[0] + c * dx - s * dy, centre[1] + s * dx + c * dy, p[2]]);
    }
    fit
}

/// A scan of few points (a camera's view keeps a tenth of a LiDAR's) is
/// taken densely enough to give a turn, where one point in 16 of it gives
/// too few pairs; a LiDAR's scan is taken one in 16.
#[test]
fn a_scan_of_few_points_is_taken_densely_enough_to_turn() {
    assert_eq!(walk_stride(30_000), WALK_STRIDE);
    assert_eq!(walk_stride(WALK_STRIDE as usize * WALK_POINTS), WALK_STRIDE);
    assert_eq!(walk_stride(4 * WALK_POINTS), 4);
    assert_eq!((walk_stride(WALK_POINTS), walk_stride(0)), (1, 1));
    let mut rng = Lcg(11);
    let map = mapped(&mut rng, 60_000);
    let centre = [2.0, 0.5, 1.7];
    let sparse = fit_of(&map, &mut rng, centre, 0.4, 600, WALK_STRIDE);
    assert_eq!(sparse.yaw(), None, "{} pairs", sparse.pairs());
    let dense = fit_of(&map, &mut rng, centre, 0.4, 600, walk_stride(600));
    let turn = dense.yaw().unwrap();
    assert!((turn - 0.4).abs() < 0.05, "measured {turn} from {} pairs", dense.pairs());
}

/// A turn known worse than [`WALK_MAX_SD_DEG`] (a narrow view of one
/// facade, where a turn and a sideways shift look alike) is passed over:
/// the camera's fits of 2 and 43 degrees once took the figure to 6.
#[test]
fn a_turn_known_worse_than_a_tenth_of_a_degree_is_passed_over() {
    let mut walk = OdometryWalk::new();
    for k in 0..WALK_MIN_SCANS {
        walk.push(Some((if k % 2 == 0 { 0.1 } else { -0.1 }, 0.0004)));
    }
    let calm = walk.rms().unwrap();
    assert!((calm - 0.1).abs() < 1e-6);
    walk.push(Some((-43.1, 3.4 * 3.4)));
    walk.push(Some((2.25, 0.78 * 0.78)));
    walk.push(Some((0.9, 1.01 * WALK_MAX_SD_DEG * WALK_MAX_SD_DEG)));
    assert_eq!(walk.rms(), Some(calm));
    // Known to the bound, it counts.
    walk.push(Some((0.5, 0.99 * WALK_MAX_SD_DEG * WALK_MAX_SD_DEG)));
    assert!(walk.rms().unwrap() > calm);
}

/// A scan turned by a few tenths of a degree about its sensor measures that
/// turn, signed, to a few hundredths; one the odometry did not turn, about
/// nothing.
#[test]
fn a_scan_turned_from_its_map_measures_the_turn() {
    let mut rng = Lcg(7);
    let map = mapped(&mut rng, 60_000);
    let centre = [2.0, 0.5, 1.7];
    for deg in [0.0f32, 0.3, -0.5, 0.8] {
        let turn = turn_of(&map, &mut rng, centre, deg).unwrap();
        assert!((turn - deg).abs() < 0.05, "turned {deg}: measured {turn}");
    }
}

/// A scan with no upright plane under it (a bare floor), or one the map has
/// not seen, gives no turn; a point that is not finite is passed over.
#[test]
fn a_scan_with_nothing_upright_gives_no_turn() {
    let mut rng = Lcg(3);
    let mut map = robot_map();
    for _ in 0..20_000 {
        map.insert_point([-10.0 + 20.0 * rng.unit(), -10.0 + 20.0 * rng.unit(), 0.0], Class::Road).unwrap();
    }
    let mut fit = ScanFit::new([0.0; 3]);
    for _ in 0..8_000 {
        fit.add(&map, [-10.0 + 20.0 * rng.unit(), -10.0 + 20.0 * rng.unit(), 0.0]);
    }
    assert_eq!((fit.pairs(), fit.yaw()), (0, None));
    let walls = mapped(&mut rng, 60_000);
    let mut far = ScanFit::new([100.0, 0.0, 0.0]);
    for _ in 0..8_000 {
        far.add(&walls, [100.0 + rng.unit(), 50.0 * rng.unit(), 1.0]);
    }
    assert_eq!(far.yaw(), None);
    let mut fit = ScanFit::new([2.0, 0.5, 1.7]);
    let before = fit;
    for _ in 0..WALK_STRIDE {
        fit.add(&walls, [f32::NAN, 0.0, 1.0]);
    }
    assert_eq!(fit.pairs(), before.pairs());
}

/// The figure is the root mean square of the last scans' turns, once there
/// are enough of them; scans with no turn are passed over.
#[test]
fn the_walk_is_the_root_mean_square_of_the_last_turns() {
    let mut walk = OdometryWalk::new();
    for k in 0..WALK_MIN_SCANS - 1 {
        walk.push(Some((if k % 2 == 0 { 0.3 } else { -0.3 }, 0.0)));
        walk.push(None);
        walk.push(Some((f32::NAN, 0.0)));
        walk.push(Some((0.1, -1.0)));
    }
    assert_eq!(walk.rms(), None);
    walk.push(Some((0.3, 0.0)));
    assert!((walk.rms().unwrap() - 0.3).abs() < 1e-6);
    // The window forgets: a walk that calmed down reads calm.
    for _ in 0..WALK_SCANS {
        walk.push(Some((0.05, 0.0016)));
    }
    assert!((walk.rms().unwrap() - 0.05).abs() < 1e-6);
    // Less the fits' own noise: 0.05 squared less 0.0016 is 0.03 squared.
    assert!((walk.excess().unwrap() - 0.03).abs() < 1e-4, "{:?}", walk.excess());
}
