//! Any bytes as a PCD file: no panic, never more points than bytes.
#![no_main]

use cosem_host::cloud::parse_pcd;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(c) = parse_pcd(data, "fuzz.pcd".as_ref(), "label") {
        assert!(c.points.len() + c.skipped <= data.len());
    }
});
