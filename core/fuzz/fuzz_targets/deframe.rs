//! Any byte stream through the deframer and the message decoder: no panic,
//! no hang.
#![no_main]

use cosem_core::wire::{Deframer, Message};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut d = Deframer::new();
    for &b in data {
        if let Ok(Some(payload)) = d.push(b) {
            let _ = Message::decode(payload);
        }
    }
});
