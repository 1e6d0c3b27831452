//! The coarse levels' cell index (32- or 16-bit slots holding each cell's
//! first entry and run) and the merge that builds a level from the one
//! below.

use super::*;

/// Copies a map's index into 16-bit slots of the same count; `false` when
/// a slot's value does not fit 16 bits.
pub(super) fn copy_index(index: MapIndex<'_>, out: &mut [u16]) -> bool {
    match index {
        MapIndex::Narrow(s) if s.len() == out.len() => {
            out.copy_from_slice(s);
            true
        }
        MapIndex::Wide(s) if s.len() == out.len() && s.iter().all(|&v| v <= u32::from(u16::MAX)) => {
            for (o, &v) in out.iter_mut().zip(s) {
                *o = v as u16;
            }
            true
        }
        _ => false,
    }
}

/// Bits of a (32-bit) slot holding the number of entries of its cell.
pub(super) const RUN_BITS: u32 = 5;
pub(super) const RUN_MASK: u32 = (1 << RUN_BITS) - 1;

/// Storages of fewer entries than this index them with 16-bit slots, two to
/// a word, holding a cell's first entry plus one (its run is counted from
/// the sorted entries): half the index and merge table of 32-bit slots.
pub const NARROW_LIMIT: usize = 0xFFFF;

/// Slot `k` of 16-bit slots packed two to a word.
#[inline(always)]
pub(super) fn half(words: &[u32], k: usize) -> u32 {
    words.get(k >> 1).map_or(0, |w| (w >> ((k & 1) << 4)) & 0xFFFF)
}

/// Sets slot `k` of 16-bit slots packed two to a word.
pub(super) fn set_half(words: &mut [u32], k: usize, v: u32) {
    if let Some(w) = words.get_mut(k >> 1) {
        let shift = (k & 1) << 4;
        *w = (*w & !(0xFFFF << shift)) | ((v & 0xFFFF) << shift);
    }
}

/// Entries from `first` on in cell `key` (sorted entries: a cell's run is
/// contiguous, at most one per class).
pub(super) fn run_from(entries: &[CoarseEntry], first: usize, key: VoxelKey) -> usize {
    entries.get(first..).unwrap_or(&[]).iter().take_while(|e| e.key == key).count()
}

/// The range of a coarse level's entries in cell `key`.
#[inline]
pub(super) fn coarse_run(entries: &[CoarseEntry], slots: &[u32], narrow: bool, key: VoxelKey) -> (usize, usize) {
    if narrow {
        // A slot holds first entry + 1.
        let hit = |v: u32| entries.get((v - 1) as usize).map(|e| e.key) == Some(key);
        return match walk_by(2 * slots.len(), |k| half(slots, k), key.hash32(), hit) {
            Slot::Found { value, .. } => {
                let first = (value - 1) as usize;
                (first, first + run_from(entries, first, key))
            }
            Slot::Vacant(_) | Slot::Full => (0, 0),
        };
    }
    // A slot holds (first entry + 1) << 5 | entries in the cell.
    let first = |s: u32| ((s >> RUN_BITS) - 1) as usize;
    match walk(slots, key.hash32(), |s| entries.get(first(s)).map(|e| e.key) == Some(key)) {
        Slot::Found { value, .. } => (first(value), first(value) + (value & RUN_MASK) as usize),
        Slot::Vacant(_) | Slot::Full => (0, 0),
    }
}

/// Builds the index of one coarse level over its (sorted) entries.
pub(super) fn index_level(entries: &[CoarseEntry], slots: &mut [u32], narrow: bool) {
    slots.fill(0);
    if slots.is_empty() {
        return;
    }
    let mut i = 0;
    while let Some(e) = entries.get(i) {
        let run = run_from(entries, i, e.key).max(1);
        if narrow {
            if let Slot::Vacant(k) = walk_by(2 * slots.len(), |k| half(slots, k), e.key.hash32(), |_| false) {
                set_half(slots, k, i as u32 + 1);
            }
        } else {
            // One entry per class: a run never exceeds the class count (< 32).
            let value = ((i as u32 + 1) << RUN_BITS) | (run as u32 & RUN_MASK);
            if let Slot::Vacant(s) = walk(slots, e.key.hash32(), |_| false) {
                if let Some(slot) = slots.get_mut(s) {
                    *slot = value;
                }
            }
        }
        i += run;
    }
}

/// Merges the entries of `src` by (cell `factor` times as large, class) into `dst`,
/// with `table` (zeroed here) as a scratch hash index of two slots per
/// entry of `dst` at most (16-bit slots, two to a word, when `narrow`: a
/// storage of fewer than [`NARROW_LIMIT`] entries); returns the count.
pub(super) fn merge_level(
    src: &Level<'_>,
    dst: &mut [CoarseEntry],
    table: &mut [u32],
    narrow: bool,
    factor: u16,
) -> Result<usize, PyramidError> {
    let n = if narrow { (2 * table.len()).min(2 * dst.len()) } else { table.len().min(2 * dst.len()) };
    let table = table.get_mut(..if narrow { n.div_ceil(2) } else { n }).ok_or(PyramidError::Full)?;
    table.fill(0);
    let get = |t: &[u32], k: usize| if narrow { half(t, k) } else { t.get(k).copied().unwrap_or(0) };
    let resolution = f32::from(factor) * src.resolution();
    let mut out = 0usize;
    for i in 0..src.len() {
        let Some(e) = src.entry(i) else { continue };
        let key = e.key.coarsen(factor);
        let hash = key.hash32() ^ u32::from(e.class).wrapping_mul(0x9E37_79B9);
        let same = |v: u32| dst.get((v - 1) as usize).is_some_and(|a| a.key == key && a.class == e.class);
        match walk_by(n, |k| get(table, k), hash, same) {
            Slot::Vacant(s) => {
                let fresh = dst.get_mut(out).ok_or(PyramidError::Full)?;
                *fresh = CoarseEntry { key, class: e.class, confidence: e.confidence, ..CoarseEntry::EMPTY };
                fresh.set_weight(e.weight);
                fresh.set_position(e.position, resolution);
                out += 1;
                if narrow {
                    set_half(table, s, out as u32);
                } else {
                    *table.get_mut(s).ok_or(PyramidError::Full)? = out as u32;
                }
            }
            Slot::Found { value, .. } => {
                let acc = dst.get_mut((value - 1) as usize).ok_or(PyramidError::Full)?;
                // Running weighted mean (weights as coded).
                let wa = acc.weight();
                let w = wa + e.weight;
                let mut p = acc.position(resolution);
                for (a, q) in p.iter_mut().zip(e.position) {
                    *a += (q - *a) * (e.weight / w);
                }
                acc.set_position(p, resolution);
                let conf = (f32::from(acc.confidence) * wa + f32::from(e.confidence) * e.weight) / w;
                acc.confidence = (conf + 0.5) as u8;
                acc.set_weight(w);
            }
            Slot::Full => return Err(PyramidError::Full),
        }
    }
    let merged = dst.get_mut(..out).ok_or(PyramidError::Full)?;
    merged.sort_unstable_by_key(CoarseEntry::order);
    Ok(out)
}

/// A scene entry's 2x2x2 block of model cells as the last E-step found it
/// (the block's cell and side, each cell's run of model entries): the next
/// E-step, whose transform moved by millimetres once EM is near an answer,
/// finds the same block for most entries and skips its eight lookups. The
/// same cells give the same entries in the same order, so the sums are the
/// same, bit for bit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reach {
    /// The block's cell and side ([`Reach::EMPTY`]'s: none).
    pub(crate) block: u64,
    /// Each cell's run of model entries.
    pub(crate) runs: [(u32, u32); 8],
}

impl Reach {
    /// A reach that holds no block.
    pub const EMPTY: Reach = Reach { block: u64::MAX, runs: [(0, 0); 8] };
}
