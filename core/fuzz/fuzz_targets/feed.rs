//! Any byte stream through the deframer and the feed decoders (what a robot
//! reads from its feeder, what a host reads from a robot): no panic, no
//! hang; what decodes re-encodes to a message that decodes the same.
#![no_main]

use cosem_core::wire::feed::{FeedMessage, RobotMessage};
use cosem_core::wire::Deframer;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = FeedMessage::decode(data);
    let _ = RobotMessage::decode(data);
    let mut d = Deframer::new();
    for &b in data {
        if let Ok(Some(payload)) = d.push(b) {
            if let Ok(msg) = FeedMessage::decode(payload) {
                let mut buf = [0u8; 1024];
                let n = msg.encode(&mut buf).expect("a decoded message encodes");
                assert_eq!(FeedMessage::decode(&buf[..n]).as_ref(), Ok(&msg));
            }
            let _ = RobotMessage::decode(payload);
        }
    }
});
