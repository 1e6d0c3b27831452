//! Any text as a class table: no panic.
#![no_main]

use cosem_host::class_table::ClassTable;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = ClassTable::parse(text);
    }
});
