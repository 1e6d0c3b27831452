//! Any bytes as a `.cmap` map file: a typed error or a map no larger than
//! the file's count and the map's capacity; never a panic or a hang.
#![no_main]

use cosem_core::map::{ArrayStorage, LocalMap, MapConfig};
use cosem_core::wire::mapfile;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut map = LocalMap::new(ArrayStorage::<512>::new(), MapConfig::with_resolution(0.5)).unwrap();
    if let Ok(file) = mapfile::parse(data) {
        let count = file.header.voxel_count as usize;
        if file.decode_into(&mut map).is_ok() {
            assert_eq!(map.len(), count);
        }
        assert!(map.len() <= count.min(512));
    }
});
