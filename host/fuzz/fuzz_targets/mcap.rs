//! Any bytes as an MCAP file: no panic, no hang, every message handed out
//! lies within the input.
#![no_main]

use cosem_host::mcap_read::read_messages_from;
use libfuzzer_sys::fuzz_target;
use std::ops::ControlFlow;

fuzz_target!(|data: &[u8]| {
    let mut total = 0usize;
    let _ = read_messages_from(std::io::Cursor::new(data), data.len() as u64, "fuzz.mcap".as_ref(), |m| {
        total += m.data.len();
        Ok(ControlFlow::Continue(()))
    });
});
