//! The verdict's agreement: the standing pass equals the full one, and the
//! cover skips only what cannot agree.

use super::*;

/// Two maps of one corner, the second seen 0.3 m, -0.2 m and 0.05 rad
/// away.
fn corners_apart() -> (Map, Map) {
    let mut a = new_map();
    corner(&mut a, &Isometry3::identity());
    let mut b = new_map();
    corner(&mut b, &from_xyz_rpy(0.3, -0.2, 0.0, 0.0, 0.0, 0.05));
    (a, b)
}

/// Placements in the plane, `(x, y, yaw)`, numbered.
fn placements(xy_yaw: &[(f32, f32, f32)]) -> impl Iterator<Item = (usize, Isometry3<f32>)> + '_ {
    xy_yaw.iter().map(|&(x, y, yaw)| from_xyz_rpy(x, y, 0.0, 0.0, 0.0, yaw)).enumerate()
}

/// The look-alike check's agreement-only pass gives the full pass's
/// agreement to the bit, aligned, shifted and far off.
#[test]
fn standing_agreement_equals_the_full_pass() {
    use crate::matching::associate::{agreement, standing_agreement};
    let (a, b) = corners_apart();
    let (pa, pb) = (pyramid(&a), pyramid(&b));
    let (m0, c0) = (pa.level(0).unwrap(), pb.level(0).unwrap());
    let cover = pa.level(2);
    let mut seen = 0;
    for (i, t) in
        placements(&[(0.0, 0.0, 0.0), (0.3, -0.2, 0.05), (1.0, 0.5, -0.1), (-2.0, 3.0, 0.4), (40.0, 0.0, 0.0)])
    {
        for stride in [1, 3] {
            let full = agreement(&m0, cover.as_ref(), &c0, &t, stride).agreement;
            assert_eq!(standing_agreement(&m0, cover.as_ref(), &c0, &t, stride), full, "case {i} stride {stride}");
            seen += usize::from(full > 0.0);
        }
        assert_eq!(standing_agreement(&m0, None, &c0, &t, 1), agreement(&m0, None, &c0, &t, 1).agreement);
    }
    assert!(seen >= 4, "{seen}");
}

/// The agreement pass skips a scene entry whose neighbourhood a coarser
/// level (the cover) says is empty, with the same inliers, overlap and
/// RMSE as looking up all 27 cells: aligned, partly overlapping (half the
/// scene's entries skipped) and far off, with covers two and four cells
/// wide.
#[test]
fn skipping_where_the_cover_is_empty_changes_no_agreement() {
    use crate::matching::associate::agreement;
    let (a, b) = corners_apart();
    let (pa, pb) = (pyramid(&a), pyramid(&b));
    let (m0, c0) = (pa.level(0).unwrap(), pb.level(0).unwrap());
    let mut matched = 0;
    for (i, t) in placements(&[(0.0, 0.0, 0.0), (0.3, -0.2, 0.05), (4.0, 1.5, 0.3), (-6.0, 3.0, 0.4), (40.0, 0.0, 0.0)])
    {
        for stride in [1, 3] {
            let every = agreement(&m0, None, &c0, &t, stride);
            for l in [1, 2] {
                let skipping = agreement(&m0, pa.level(l).as_ref(), &c0, &t, stride);
                assert_eq!(skipping.inliers, every.inliers, "case {i} stride {stride} cover level {l}");
                assert_eq!(skipping.overlap.to_bits(), every.overlap.to_bits(), "case {i} stride {stride} level {l}");
                assert_eq!(skipping.rmse.to_bits(), every.rmse.to_bits(), "case {i} stride {stride} level {l}");
            }
            matched += usize::from(every.inliers > 0);
        }
    }
    assert!(matched >= 6, "{matched}");
}
