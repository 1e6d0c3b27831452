//! Object-level semantic landmarks of a map, for prior-free alignment: the
//! connected clusters of voxels of compact classes (poles, trunks, traffic
//! signs, vehicles, people), each reduced to its class, centroid, extent
//! and size. Two robots that met with any relative heading see the same
//! poles and trunks; the distances between them do not depend on the frame,
//! which is what a consistency search over correspondences uses.
//!
//! Extraction is allocation-free: a union-find over the map's voxels lives
//! in a caller-provided scratch of one `u32` per voxel, clusters are joined
//! through the map's own hash index (26 neighbours), and at most
//! [`MAX_LANDMARKS`] of the largest clusters are kept.

use crate::classes::Class;
use crate::map::{LocalMap, VoxelStorage};

/// Most landmarks kept per map (the largest clusters).
pub const MAX_LANDMARKS: usize = 128;

/// Smallest cluster kept (voxels).
pub const MIN_VOXELS: u32 = 3;

/// Whether a class makes compact, countable objects.
pub fn is_compact(class: Class) -> bool {
    matches!(
        class,
        Class::Pole
            | Class::Trunk
            | Class::TrafficSign
            | Class::Car
            | Class::Truck
            | Class::OtherVehicle
            | Class::Bicycle
            | Class::Motorcycle
            | Class::Person
            | Class::Bicyclist
            | Class::Motorcyclist
    )
}

/// One landmark.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Landmark {
    /// Class of its voxels.
    pub class: Class,
    /// Mean of its voxels' positions (m, map frame).
    pub centroid: [f32; 3],
    /// Size of its bounding box of voxel positions (m).
    pub extent: [f32; 3],
    /// Voxels.
    pub voxels: u32,
}

/// Why landmarks could not be extracted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LandmarkError {
    /// The scratch holds fewer `u32` than the map has voxels.
    Scratch,
}

impl core::fmt::Display for LandmarkError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("landmark scratch smaller than the map")
    }
}

impl core::error::Error for LandmarkError {}

/// A root of the union-find: top bit set, the cluster's size below.
const ROOT: u32 = 1 << 31;
/// A voxel of no compact class.
const NONE: u32 = ROOT;

fn find(parent: &mut [u32], mut i: usize) -> usize {
    // Path halving.
    loop {
        let Some(&p) = parent.get(i) else { return i };
        if p & ROOT != 0 {
            return i;
        }
        let gp = parent.get(p as usize).copied().unwrap_or(ROOT);
        if gp & ROOT == 0 {
            if let Some(slot) = parent.get_mut(i) {
                *slot = gp;
            }
        }
        i = p as usize;
    }
}

fn union(parent: &mut [u32], a: usize, b: usize) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra == rb {
        return;
    }
    let size = |p: &[u32], r: usize| p.get(r).map(|v| v & !ROOT).unwrap_or(0);
    let (sa, sb) = (size(parent, ra), size(parent, rb));
    // The larger tree takes the smaller; ties to the lower index (determinism).
    let (big, small) = if sa > sb || (sa == sb && ra < rb) { (ra, rb) } else { (rb, ra) };
    if let Some(s) = parent.get_mut(small) {
        *s = big as u32;
    }
    if let Some(r) = parent.get_mut(big) {
        *r = ROOT | (sa + sb);
    }
}

/// Extracts the landmarks of `map` into `out` (cleared first), largest
/// first (ties by position in the map). `scratch` holds one `u32` per voxel.
pub fn extract<S: VoxelStorage>(
    map: &LocalMap<S>,
    scratch: &mut [u32],
    out: &mut heapless::Vec<Landmark, MAX_LANDMARKS>,
) -> Result<(), LandmarkError> {
    out.clear();
    let voxels = map.voxels();
    let parent = scratch.get_mut(..voxels.len()).ok_or(LandmarkError::Scratch)?;
    for (p, v) in parent.iter_mut().zip(voxels) {
        *p = if v.class().is_some_and(is_compact) { ROOT | 1 } else { NONE };
    }
    // Join each compact voxel with its same-class neighbours.
    for (i, v) in voxels.iter().enumerate() {
        let Some(class) = v.class().filter(|c| is_compact(*c)) else { continue };
        for (j, n) in map.neighbours(v.key) {
            if j < i && n.class() == Some(class) {
                union(parent, i, j);
            }
        }
    }
    // The largest clusters: (size, root), kept sorted, largest first.
    let mut chosen: heapless::Vec<(u32, usize), MAX_LANDMARKS> = heapless::Vec::new();
    for (r, &p) in parent.iter().enumerate() {
        let size = p & !ROOT;
        if p & ROOT == 0 || size < MIN_VOXELS {
            continue;
        }
        let at = chosen.iter().position(|&(s, _)| s < size).unwrap_or(chosen.len());
        if at < MAX_LANDMARKS {
            if chosen.is_full() {
                chosen.pop();
            }
            let _ = chosen.insert(at, (size, r));
        }
    }
    // Centroids and extents of the chosen clusters.
    let mut acc = [([0.0f32; 3], [f32::INFINITY; 3], [f32::NEG_INFINITY; 3]); MAX_LANDMARKS];
    let mut classes = [None; MAX_LANDMARKS];
    let res = map.resolution();
    for (i, v) in voxels.iter().enumerate() {
        if parent.get(i).is_none_or(|p| *p == NONE) {
            continue;
        }
        let root = find(parent, i);
        let Some(k) = chosen.iter().position(|&(_, r)| r == root) else { continue };
        let p = v.position(res);
        let (sum, lo, hi) = &mut acc[k];
        for a in 0..3 {
            sum[a] += p[a];
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
        classes[k] = v.class();
    }
    for (k, &(size, _)) in chosen.iter().enumerate() {
        let (sum, lo, hi) = acc[k];
        let Some(class) = classes[k] else { continue };
        let n = size as f32;
        let _ = out.push(Landmark {
            class,
            centroid: [sum[0] / n, sum[1] / n, sum[2] / n],
            extent: [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]],
            voxels: size,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::MapConfig;

    #[test]
    fn poles_and_a_car_become_landmarks() {
        let mut map = crate::test_util::heap_map(4096, MapConfig::with_resolution(0.2));
        // Three poles (3 m tall), a car (4 x 1.8 x 1.4 m), a road.
        for (i, x) in [0.0f32, 8.0, 20.0].iter().enumerate() {
            for k in 0..15 {
                map.insert_point([*x, 2.0 + i as f32, k as f32 * 0.2], Class::Pole).unwrap();
            }
        }
        for a in 0..20 {
            for b in 0..9 {
                for c in 0..7 {
                    map.insert_point([10.0 + a as f32 * 0.2, -3.0 + b as f32 * 0.2, c as f32 * 0.2], Class::Car)
                        .unwrap();
                }
            }
        }
        for a in 0..100 {
            for b in 0..10 {
                map.insert_point([a as f32 * 0.2, b as f32 * 0.2 - 1.0, -0.2], Class::Road).unwrap();
            }
        }
        let mut scratch = std::vec![0u32; map.len()];
        let mut out = heapless::Vec::new();
        extract(&map, &mut scratch, &mut out).unwrap();
        assert_eq!(out.len(), 4, "{out:?}");
        assert_eq!(out[0].class, Class::Car);
        assert_eq!(out[0].voxels, 20 * 9 * 7);
        assert!((out[0].centroid[0] - 11.9).abs() < 0.15, "{:?}", out[0]);
        for l in &out[1..] {
            assert_eq!(l.class, Class::Pole);
            assert_eq!(l.voxels, 15);
            assert!((l.extent[2] - 2.8).abs() < 0.1);
        }
        assert!(extract(&map, &mut scratch[..10], &mut out).is_err());
    }
}
