//! Any text as a poses file: no panic; every pose read is rigid.
#![no_main]

use cosem_host::cloud::parse_poses;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(poses) = parse_poses(text, "fuzz.txt".as_ref()) {
        for m in poses {
            let r = m.fixed_view::<3, 3>(0, 0);
            assert!((r.transpose() * r - nalgebra::Matrix3::identity()).norm() < 1e-3);
        }
    }
});
