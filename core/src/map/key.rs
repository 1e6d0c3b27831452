//! Voxel keys: integer cell coordinates, and the hash the table uses.

use serde::{Deserialize, Serialize};

/// Why a point could not be given a voxel key.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KeyError {
    /// A coordinate was NaN or infinite.
    NonFinite,
    /// The cell index does not fit the key's 16-bit range
    /// (±32767 cells: ±6.5 km at 0.2 m).
    OutOfRange,
}

impl core::fmt::Display for KeyError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            KeyError::NonFinite => f.write_str("coordinate is NaN or infinite"),
            KeyError::OutOfRange => f.write_str("voxel index out of the 16-bit key range"),
        }
    }
}

impl core::error::Error for KeyError {}

/// `floor(v)` for finite `v`, exact: truncation corrected for negatives
/// (cheaper than a software floor on targets without a rounding instruction).
/// Values beyond the `i32` range are returned as they are (they are whole
/// numbers already, and out of any key range).
#[inline]
pub fn floor_f32(v: f32) -> f32 {
    if v.is_nan() || v.abs() >= 2_147_483_520.0 {
        return v;
    }
    let t = v as i32 as f32;
    if t > v {
        t - 1.0
    } else {
        t
    }
}

/// Integer cell of a voxel: `floor(p / resolution)` per axis, in the map's
/// anchor frame. Sixteen bits per axis keep a stored voxel small; a local map
/// spans at most ±32767 cells.
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Default,
    Serialize,
    Deserialize,
    bytemuck::Pod,
    bytemuck::Zeroable,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(C)]
pub struct VoxelKey {
    /// Cell index along x.
    pub x: i16,
    /// Cell index along y.
    pub y: i16,
    /// Cell index along z.
    pub z: i16,
}

/// Where a point falls: its voxel and its position inside the voxel, each
/// axis in `[0, 1)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellPoint {
    /// The voxel the point falls in.
    pub key: VoxelKey,
    /// Position inside the voxel, each axis in `[0, 1)`.
    pub fraction: [f32; 3],
}

impl VoxelKey {
    /// A key from cell indices already in range.
    pub const fn new(x: i16, y: i16, z: i16) -> Self {
        VoxelKey { x, y, z }
    }

    /// A key from wide cell indices, checking the range.
    pub fn from_cell(x: i32, y: i32, z: i32) -> Result<Self, KeyError> {
        let c = |v: i32| i16::try_from(v).map_err(|_| KeyError::OutOfRange);
        Ok(VoxelKey { x: c(x)?, y: c(y)?, z: c(z)? })
    }

    /// The voxel holding point `p` on a grid of cell size `1 / inv_resolution`,
    /// and the point's position inside it.
    pub fn locate(p: [f32; 3], inv_resolution: f32) -> Result<CellPoint, KeyError> {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(KeyError::NonFinite);
        }
        let mut cell = [0i16; 3];
        let mut fraction = [0f32; 3];
        for axis in 0..3 {
            let scaled = p[axis] * inv_resolution;
            let floor = floor_f32(scaled);
            // Checked in float before the cast: out-of-range values saturate.
            if !(i16::MIN as f32..=i16::MAX as f32).contains(&floor) {
                return Err(KeyError::OutOfRange);
            }
            cell[axis] = floor as i16;
            let f = scaled - floor;
            // `scaled - floor` can round up to 1.0 for values just below an integer.
            fraction[axis] = if f < 1.0 { f } else { 0.999_999_9 };
        }
        Ok(CellPoint { key: VoxelKey { x: cell[0], y: cell[1], z: cell[2] }, fraction })
    }

    /// The key `(dx, dy, dz)` cells away, if it is in range.
    #[inline]
    pub fn offset(self, dx: i32, dy: i32, dz: i32) -> Option<Self> {
        let add = |v: i16, d: i32| i16::try_from(i32::from(v) + d).ok();
        Some(VoxelKey { x: add(self.x, dx)?, y: add(self.y, dy)?, z: add(self.z, dz)? })
    }

    /// The key of the coarser cell, `factor` times larger, that contains this one.
    pub fn coarsen(self, factor: u16) -> Self {
        let f = i32::from(factor.max(1));
        let d = |v: i16| (i32::from(v).div_euclid(f)) as i16;
        VoxelKey { x: d(self.x), y: d(self.y), z: d(self.z) }
    }

    /// The axis-aligned bounds (m) of cells of `resolution` m: the lowest
    /// corner and the highest cell's upper corner; `None` without a cell.
    pub fn bounds(keys: impl IntoIterator<Item = VoxelKey>, resolution: f32) -> Option<([f32; 3], [f32; 3])> {
        let (lo, hi) = VoxelKey::extent(keys)?;
        let r = resolution;
        let top = hi.corner(r);
        Some((lo.corner(r), [top[0] + r, top[1] + r, top[2] + r]))
    }

    /// The least and greatest cell index along each axis of `keys`, as the
    /// keys of the two extreme corners; `None` without a cell.
    pub fn extent(keys: impl IntoIterator<Item = VoxelKey>) -> Option<(VoxelKey, VoxelKey)> {
        let mut keys = keys.into_iter();
        let first = keys.next()?;
        Some(keys.fold((first, first), |(lo, hi), k| {
            (
                VoxelKey::new(lo.x.min(k.x), lo.y.min(k.y), lo.z.min(k.z)),
                VoxelKey::new(hi.x.max(k.x), hi.y.max(k.y), hi.z.max(k.z)),
            )
        }))
    }

    /// Lower corner of the cell in metres.
    pub fn corner(self, resolution: f32) -> [f32; 3] {
        [f32::from(self.x) * resolution, f32::from(self.y) * resolution, f32::from(self.z) * resolution]
    }

    /// Centre of the cell in metres.
    pub fn center(self, resolution: f32) -> [f32; 3] {
        let h = 0.5;
        [
            (f32::from(self.x) + h) * resolution,
            (f32::from(self.y) + h) * resolution,
            (f32::from(self.z) + h) * resolution,
        ]
    }

    /// A 48-bit packing of the key (x in the high bits); also its order.
    pub fn packed(self) -> u64 {
        let u = |v: i16| u64::from(v as u16);
        (u(self.x) << 32) | (u(self.y) << 16) | u(self.z)
    }

    /// The key's place in x, then y, then z order of the signed
    /// coordinates, for `(x, y, z)` given as `i32` (one cell beyond the
    /// `i16` range still orders: 18 bits per axis).
    #[inline]
    pub fn sweep_order(x: i32, y: i32, z: i32) -> u64 {
        let f = |v: i32| (v.wrapping_add(1 << 17) as u32 & 0x3_FFFF) as u64;
        (f(x) << 36) | (f(y) << 18) | f(z)
    }

    /// [`VoxelKey::sweep_order`] of this key.
    #[inline]
    pub fn sweep(self) -> u64 {
        Self::sweep_order(i32::from(self.x), i32::from(self.y), i32::from(self.z))
    }

    /// A well-mixed 32-bit hash, the same on every platform: each
    /// coordinate times an odd constant, then murmur3's finaliser, all in
    /// 32-bit arithmetic (a 32-bit core has no 64-bit multiply; hashing is
    /// a tenth of preparing a map on board).
    #[inline]
    pub fn hash32(self) -> u32 {
        let u = |v: i16, k: u32| u32::from(v as u16).wrapping_mul(k);
        let mut h =
            u(self.x, 0x9E37_79B1) ^ u(self.y, 0x85EB_CA77).rotate_left(11) ^ u(self.z, 0xC2B2_AE3D).rotate_left(22);
        h ^= h >> 16;
        h = h.wrapping_mul(0x85EB_CA6B);
        h ^= h >> 13;
        h = h.wrapping_mul(0xC2B2_AE35);
        h ^ (h >> 16)
    }
}

/// Sorts the first `count` words of `words` (indices, each below
/// `indices_below`) by `code` of each (a code below 2^48, or `u64::MAX` for
/// none), ties by index; false when `words` has fewer than `count`. With
/// two words an index (and indices below 2^16) each index is sorted beside
/// its code, not the code computed again at each comparison: the same order
/// in a tenth of the time (7,500 voxels by Morton code: 0.85 to 0.09 ms).
pub(crate) fn sort_indices_by_code(
    words: &mut [u32],
    count: usize,
    indices_below: usize,
    code: impl Fn(u32) -> u64,
) -> bool {
    match words.get_mut(..2 * count).filter(|_| indices_below <= 1 << 16) {
        Some(pairs) => {
            // Index k's pair at 2k, spread from the last (a pair lands at or
            // above its index, never on one not yet read): the code's high
            // 32 bits, then its low 16 above the index's 16.
            for k in (0..count).rev() {
                let i = pairs.get(k).copied().unwrap_or(0);
                let c = code(i);
                if let Some(p) = pairs.get_mut(2 * k..2 * k + 2) {
                    p.copy_from_slice(&[(c >> 16) as u32, ((c as u32) << 16) | (i & 0xFFFF)]);
                }
            }
            // Compared as one u64 (the same order as the pair's): about
            // twice as fast as the pair's two comparisons.
            let as_pairs: &mut [[u32; 2]] = bytemuck::cast_slice_mut(pairs);
            as_pairs.sort_unstable_by_key(|p| (u64::from(p[0]) << 32) | u64::from(p[1]));
            // Back to indices (index k lands at or below the pair it reads).
            for k in 0..count {
                let i = pairs.get(2 * k + 1).map_or(0, |w| w & 0xFFFF);
                if let Some(w) = pairs.get_mut(k) {
                    *w = i;
                }
            }
            true
        }
        None => match words.get_mut(..count) {
            Some(order) => {
                order.sort_unstable_by_key(|&i| (code(i), i));
                true
            }
            None => false,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn locate_floors_and_checks_range() {
        let c = VoxelKey::locate([0.25, -0.05, 1.0], 5.0).unwrap();
        assert_eq!(c.key, VoxelKey::new(1, -1, 5));
        assert!(c.fraction.iter().all(|f| (0.0..1.0).contains(f)));
        assert_eq!(VoxelKey::locate([f32::NAN, 0.0, 0.0], 5.0), Err(KeyError::NonFinite));
        assert_eq!(VoxelKey::locate([0.0, f32::INFINITY, 0.0], 5.0), Err(KeyError::NonFinite));
        assert_eq!(VoxelKey::locate([0.0, 0.0, 7000.0], 5.0), Err(KeyError::OutOfRange));
        assert_eq!(VoxelKey::locate([0.0, -6553.6, 0.0], 5.0).map(|c| c.key.y), Ok(-32768));
        assert_eq!(VoxelKey::locate([0.0, 0.0, 1e30], 5.0), Err(KeyError::OutOfRange));
    }

    #[test]
    fn floor_matches_libm() {
        for v in [0.0f32, -0.0, 0.5, -0.5, 1.0, -1.0, 2.999_999_8, -2.999_999_8, 1e9, -1e9, 3e9, -3e9, 1e-30, -1e-30] {
            assert_eq!(floor_f32(v), libm::floorf(v), "{v}");
        }
    }

    #[test]
    fn coarsen_is_floor_division() {
        assert_eq!(VoxelKey::new(3, -1, -4).coarsen(2), VoxelKey::new(1, -1, -2));
        assert_eq!(VoxelKey::new(i16::MIN, i16::MAX, 0).coarsen(4), VoxelKey::new(-8192, 8191, 0));
        assert_eq!(VoxelKey::new(0, 0, 0).offset(0, 0, i32::from(i16::MAX) + 1), None);
    }
}
