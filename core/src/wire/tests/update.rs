//! Wire tests: map updates (removals as runs of ranks, the cut, changed
//! voxels against the held records).

use super::*;

/// An update's removals are runs of ranks: written and read back in order,
/// refused out of order, and a message whose runs lie is a typed error
/// (never a panic, never ranks past what it holds).
#[test]
fn update_removals_are_runs_of_ranks() {
    use crate::wire::update::{write_update, Removed, UpdateError, UpdateHeader, UpdateModel, UpdateView};
    let header = |removals: u32| UpdateHeader {
        epoch: 1,
        base: 4,
        version: 5,
        voxels: 10,
        digest: 0,
        removals,
        upserts: 0,
        changed: 0,
    };
    let unchanged = core::iter::empty();
    let ranks = [0u32, 1, 2, 9, 10, 40, 1000, 1001];
    let mut out = vec![0u8; 256];
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let removed = Removed { cut: None, ranks: ranks.iter().copied(), count: 8 };
    let n = write_update(&header(8), removed, unchanged, none, &mut UpdateModel::new(), &mut out).unwrap();
    // Fixed fields, six varints of a byte, no cut (a byte), 4 runs of 2
    // bytes but the last's gap (959: 2 bytes), the CRC.
    assert_eq!(n, crate::wire::update::UPDATE_HEADER + 6 + 1 + 9 + 4);
    let view = UpdateView::parse(&out[..n]).unwrap();
    assert_eq!(view.removed().collect::<Vec<_>>(), ranks);
    assert_eq!(view.cut, None);
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let removed = Removed { cut: None, ranks: [5u32, 3].into_iter(), count: 2 };
    let disorder = write_update(&header(2), removed, core::iter::empty(), none, &mut UpdateModel::new(), &mut out);
    assert_eq!(disorder, Err(UpdateError::Removal));
    // Runs that lie: more removals announced than the runs hold, and a run
    // past u32::MAX (the CRC made to match).
    let forged = |body: &[u8], removals: u8| {
        // Epoch 1, digest 0; base 4, version 5 (a step of 1), 10 voxels.
        let mut bytes = vec![crate::wire::update::UPDATE_KIND, 1, 0, 0, 0, 0, 0, 4, 1, 10, removals, 0, 0];
        bytes.push(0); // no cut
        bytes.extend_from_slice(body);
        let crc = crate::wire::crc32(&bytes);
        bytes.extend_from_slice(&crc.to_le_bytes());
        UpdateView::parse(&bytes).map(|v| v.removed().count())
    };
    assert_eq!(forged(&[0, 2], 3), Ok(3));
    // A header varint beyond 32 bits, or one that does not end: refused.
    let mut wide =
        vec![crate::wire::update::UPDATE_KIND, 1, 0, 0, 0, 0, 0, 0x80, 0x80, 0x80, 0x80, 0x10, 1, 10, 0, 0, 0, 0];
    let crc = crate::wire::crc32(&wide);
    wide.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(UpdateView::parse(&wide).map(|_| ()), Err(UpdateError::Counts));
    let mut endless = vec![crate::wire::update::UPDATE_KIND, 1, 0, 0, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF];
    let crc = crate::wire::crc32(&endless);
    endless.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(UpdateView::parse(&endless).map(|_| ()), Err(UpdateError::Truncated));
    assert_eq!(forged(&[0, 2], 4), Err(UpdateError::Truncated));
    assert_eq!(forged(&[0, 2], 2), Err(UpdateError::Counts), "a run past the removals announced");
    assert_eq!(forged(&[0xFF, 0xFF, 0xFF, 0xFF, 0x0F, 5], 6), Err(UpdateError::Removal));
}

/// An update's cut names every cell at least its threshold from its centre
/// (in 32nds of a cell, integers: both sides find the same cells); it reads
/// back as written, beside ranks, and a cut that lies (a centre out of
/// range, a threshold longer than any distance, a cut in a snapshot) is a
/// typed error.
#[test]
fn an_update_cut_names_the_far_cells_and_is_checked() {
    use crate::map::VoxelKey;
    use crate::wire::update::{write_update, Cut, Removed, UpdateError, UpdateHeader, UpdateModel, UpdateView};
    let cut = Cut { threshold: 1000, ..Cut::about([1.0, -2.0, 0.0], 0.5) };
    assert_eq!(cut.centre, [64, -128, 0]);
    // Cell (2, -4, 0)'s centre is (80, -112, 16): 16 from the centre's on
    // each axis.
    assert_eq!(cut.distance_sq(VoxelKey::new(2, -4, 0)), 3 * 16 * 16);
    assert!(!cut.removes(VoxelKey::new(2, -4, 0)));
    // Cell (7, -4, 0): 176, 16, 16.
    assert_eq!(cut.distance_sq(VoxelKey::new(7, -4, 0)), 176 * 176 + 2 * 16 * 16);
    assert!(cut.removes(VoxelKey::new(7, -4, 0)));
    // Far keys and a centre not finite do not overflow or panic.
    let wild = Cut { threshold: 0, ..Cut::about([f32::NAN, 1e30, -1e30], 0.5) };
    assert_eq!(wild.centre, [0, Cut::MAX_CENTRE, -Cut::MAX_CENTRE]);
    assert!(wild.removes(VoxelKey::new(i16::MIN, i16::MAX, 0)));
    let header = |base: u32| UpdateHeader {
        epoch: 1,
        base,
        version: 5,
        voxels: 10,
        digest: 0,
        removals: 2,
        upserts: 0,
        changed: 0,
    };
    let mut out = vec![0u8; 256];
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let removed = Removed { cut: Some(cut), ranks: [3u32, 4].into_iter(), count: 2 };
    let n = write_update(&header(4), removed, core::iter::empty(), none, &mut UpdateModel::new(), &mut out).unwrap();
    let view = UpdateView::parse(&out[..n]).unwrap();
    assert_eq!(view.cut, Some(cut));
    assert_eq!(view.removed().collect::<Vec<_>>(), [3, 4]);
    // Forged: the cut's bytes as given (the CRC made to match).
    let forged = |cut: &[u8], base: u8| {
        // Epoch 1, digest 0; the base, version 5, 10 voxels, nothing else.
        let mut bytes = vec![crate::wire::update::UPDATE_KIND, 1, 0, 0, 0, 0, 0, base, 5 - base, 10, 0, 0, 0];
        bytes.extend_from_slice(cut);
        let crc = crate::wire::crc32(&bytes);
        bytes.extend_from_slice(&crc.to_le_bytes());
        UpdateView::parse(&bytes).map(|v| v.cut)
    };
    // 1001 (the threshold + 1), then 64, -128 and 0 zigzagged.
    let good = [0xE9, 0x07, 0x80, 0x01, 0xFF, 0x01, 0];
    assert_eq!(forged(&good, 4), Ok(Some(cut)));
    // A centre of 2^23: past the largest.
    assert_eq!(forged(&[0xE9, 0x07, 0x80, 0x80, 0x80, 0x08, 0, 0], 4), Err(UpdateError::Counts));
    let endless = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x01, 0, 0, 0];
    assert_eq!(forged(&endless, 4), Err(UpdateError::Counts), "a threshold past any distance");
    assert_eq!(forged(&good[..6], 4), Err(UpdateError::Counts), "a centre cut short");
    assert_eq!(forged(&good, 0), Err(UpdateError::Counts), "a snapshot has nothing to cut");
}

/// An update's changed voxels: each named by its rank in the base map and
/// coded against the record held there, read back exactly (ranks and
/// records); ranks out of order are refused when writing, and a section
/// that names a rank the base does not hold, or is cut short, is a typed
/// error, never a panic.
#[test]
fn update_changes_are_ranks_and_records_against_the_held_ones() {
    use crate::wire::update::{write_update, ChangeSink, Removed, UpdateError, UpdateHeader, UpdateModel, UpdateView};
    // A base of 40 cells, rank k holding a record of its own.
    let record =
        |class: u32, confidence: u32, p: [u32; 3]| class | confidence << 5 | p[0] << 10 | p[1] << 14 | p[2] << 18;
    let held: Vec<u32> = (0..40u32).map(|k| record(k % 19, k % 8, [k % 4, (k / 4) % 4, 1])).collect();
    struct Copy(Vec<u32>, Vec<(u32, u32)>);
    impl ChangeSink for Copy {
        fn held(&mut self, rank: u32) -> Option<u32> {
            self.0.get(rank as usize).copied()
        }
        fn change(&mut self, rank: u32, _held: u32, record: u32) -> Result<(), crate::wire::DecodeError> {
            self.1.push((rank, record));
            Ok(())
        }
    }
    // Confidence up two levels, a class changed (and to none: 31), a mean
    // moved across the cell.
    let changes = [
        (0u32, held[0], record(0, 2, [0, 0, 1])),
        (7, held[7], record(12, 7, [3, 1, 1])),
        (8, held[8], record(31, 0, [0, 2, 1])),
        (39, held[39], record(1, 7, [0, 1, 1])),
    ];
    let header =
        UpdateHeader { epoch: 1, base: 4, version: 5, voxels: 40, digest: 0, removals: 0, upserts: 0, changed: 4 };
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let removed = Removed { cut: None, ranks: core::iter::empty(), count: 0 };
    let mut out = vec![0u8; 256];
    let (mut sent, mut got) = (UpdateModel::new(), UpdateModel::new());
    let n = write_update(&header, removed, changes.iter().copied(), none, &mut sent, &mut out).unwrap();
    let view = UpdateView::parse(&out[..n]).unwrap();
    let mut copy = Copy(held.clone(), Vec::new());
    view.decode_changes(&mut got.changes, &mut copy).unwrap();
    assert_eq!(copy.1, changes.iter().map(|&(r, _, now)| (r, now)).collect::<Vec<_>>());
    // Out of order: refused when writing.
    let removed = Removed { cut: None, ranks: core::iter::empty(), count: 0 };
    let none: Option<&mut MapEncoder<'_, Heap, &LocalMap<Heap>>> = None;
    let disorder = [changes[1], changes[0], changes[2], changes[3]];
    let mut m = UpdateModel::new();
    let mut other = vec![0u8; 256];
    let r = write_update(&header, removed, disorder.into_iter(), none, &mut m, &mut other);
    assert_eq!(r, Err(UpdateError::Changed));
    // A base that holds fewer cells than a rank named: a typed error.
    let mut short = Copy(held[..20].to_vec(), Vec::new());
    let r = view.decode_changes(&mut UpdateModel::new().changes, &mut short);
    assert_eq!(r, Err(UpdateError::Changed));
    // Every byte of the section changed in turn (the CRC made to match):
    // an error or some records, never a panic; cut short: an error.
    // The section's length after the fixed fields, six varints of a byte
    // and the cut's byte.
    let at = crate::wire::update::UPDATE_HEADER + 6 + 1;
    for i in at..n - 4 {
        for b in [0u8, 0x55, 0xFF] {
            let mut forged = out[..n].to_vec();
            forged[i] = b;
            let crc = crate::wire::crc32(&forged[..n - 4]);
            forged[n - 4..].copy_from_slice(&crc.to_le_bytes());
            if let Ok(v) = UpdateView::parse(&forged) {
                let _ = v.decode_changes(&mut UpdateModel::new().changes, &mut Copy(held.clone(), Vec::new()));
            }
        }
    }
    let mut cut_short = out[..n].to_vec();
    cut_short[at] -= 1;
    cut_short.truncate(n - 5);
    let crc = crate::wire::crc32(&cut_short);
    cut_short.extend_from_slice(&crc.to_le_bytes());
    assert!(
        UpdateView::parse(&cut_short).is_err() || {
            let v = UpdateView::parse(&cut_short).unwrap();
            v.decode_changes(&mut UpdateModel::new().changes, &mut Copy(held.clone(), Vec::new())).is_err()
        }
    );
}
