//! Any bytes as a chunk of voxel encoding: no panic, no hang, never more
//! voxels than announced or than the map holds.
#![no_main]

use cosem_core::map::{ArrayStorage, LocalMap, MapConfig};
use cosem_core::wire::{CodecModel, MapDecoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&n, rest)) = data.split_first() else { return };
    let mut map = LocalMap::new(ArrayStorage::<256>::new(), MapConfig::default()).unwrap();
    let mut model = CodecModel::new();
    let mut dec = MapDecoder::new(usize::from(n), &mut model);
    for chunk in rest.split(|&b| b == 0xFF) {
        if dec.decode_chunk(&mut model, chunk, &mut map).is_err() {
            break;
        }
    }
    assert!(map.len() <= usize::from(n).min(256));
});
