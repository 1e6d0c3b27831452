//! Any byte stream through the deframers (frames, and frames with blocks)
//! and the message decoder: no panic, no hang.
#![no_main]

use cosem_core::wire::{BlockDeframer, Deframer, Message};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut d = Deframer::new();
    let mut blocks = BlockDeframer::new();
    for &b in data {
        if let Ok(Some(payload)) = d.push(b) {
            let _ = Message::decode(payload);
        }
        if let Ok(Some(f)) = blocks.push_frame(b) {
            let _ = Message::decode(f.payload);
        }
    }
});
