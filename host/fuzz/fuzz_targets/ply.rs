//! Any bytes as a PLY file: no panic, never more points than bytes.
#![no_main]

use cosem_host::cloud::parse_ply;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(c) = parse_ply(data, "fuzz.ply".as_ref(), "label") {
        assert!(c.points.len() + c.skipped <= data.len());
    }
});
