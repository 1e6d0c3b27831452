//! A scan thinned to one labelled point per voxel: what a robot on a board
//! is fed (its feed line is narrow), in a deterministic order.

use crate::maps::mapping::PointFilter;
use crate::sources::kitti::Frame;
use cosem_core::classes::{Class, NUM_CLASSES};
use cosem_core::wire::feed::{self, POINT_BYTES};
use std::collections::BTreeMap;

/// One fed point.
pub type Point = [u8; POINT_BYTES];

/// Thins one scan (already in the anchor frame) to one labelled point per
/// voxel of `resolution`: the mean of the voxel's points of its most common
/// class (ties to the lower class index), within `crop` metres of the
/// sensor. Points come out in key order, so the feed is deterministic.
pub fn thin_scan(frame: &Frame, resolution: f32, crop: f32, filter: &PointFilter) -> Vec<Point> {
    let inv = 1.0 / resolution;
    // Per voxel: per class, count and sum.
    type PerClass = [(u32, [f64; 3]); NUM_CLASSES];
    let mut cells: BTreeMap<(i32, i32, i32), PerClass> = BTreeMap::new();
    for ((p, &r), &l) in frame.points.iter().zip(&frame.ranges).zip(&frame.labels) {
        if r > crop {
            continue;
        }
        // The boards' robots keep the default filter: classes only.
        let Some(Some(class)) = filter.keep(r, l) else { continue };
        let k = ((p[0] * inv).floor() as i32, (p[1] * inv).floor() as i32, (p[2] * inv).floor() as i32);
        let cell = cells.entry(k).or_insert([(0, [0.0; 3]); NUM_CLASSES]);
        let c = &mut cell[usize::from(class.index())];
        c.0 += 1;
        for (sum, v) in c.1.iter_mut().zip(p) {
            *sum += f64::from(*v);
        }
    }
    cells
        .values()
        .filter_map(|cell| {
            let (best, (n, sum)) = cell.iter().enumerate().max_by(|a, b| a.1 .0.cmp(&b.1 .0).then(b.0.cmp(&a.0)))?;
            let class = Class::from_index(best as u8)?;
            let mean =
                [(sum[0] / f64::from(*n)) as f32, (sum[1] / f64::from(*n)) as f32, (sum[2] / f64::from(*n)) as f32];
            Some(feed::pack_point(mean, class))
        })
        .collect()
}
