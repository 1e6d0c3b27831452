//! Any bytes as a map update to a copy that holds a peer's map, its CRC-32
//! made to match (and, for an odd first byte, its kind and epoch those of
//! the copy's peer and its base, after a digest of four bytes, the copy's
//! version, so that the body's sections are reached): no panic, no hang,
//! and the copy is left as it was (refused, out of step, repeated),
//! emptied (diverged, restarted) or at the update's version.
#![no_main]

use cosem_core::classes::Class;
use cosem_core::map::{ArrayStorage, LocalMap, MapConfig};
use cosem_core::session::{Applied, Publisher, Replica, ShadowEntry};
use cosem_core::wire::{crc32, update::UPDATE_KIND};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // The peer's map, sent whole first: the copy holds version 1.
    let mut map = LocalMap::new(ArrayStorage::<256>::new(), MapConfig::default()).unwrap();
    for k in 0..60u8 {
        let class = if k % 3 == 0 { Class::Building } else { Class::Road };
        map.insert_point([f32::from(k) * 0.3, f32::from(k % 7) * 0.4, f32::from(k % 2)], class).unwrap();
    }
    let (mut held, mut sent) = ([ShadowEntry::EMPTY; 256], [ShadowEntry::EMPTY; 256]);
    let mut publisher = Publisher::new(1, &mut held[..], &mut sent[..]);
    let mut replica = Replica::new(LocalMap::new(ArrayStorage::<256>::new(), MapConfig::default()).unwrap());
    let (mut scratch, mut out) = ([0u32; 512], [0u8; 8192]);
    let n = publisher.next_update(&map, &mut scratch, &mut out).unwrap();
    assert_eq!(replica.apply(&out[..n], &mut scratch), Applied::Applied);
    let (version, len) = (replica.version(), replica.map().len());
    let Some((&first, mut rest)) = data.split_first() else { return };
    let mut bytes = Vec::with_capacity(data.len() + 8);
    if first % 2 == 1 {
        let Some((digest, after)) = rest.split_first_chunk::<4>() else { return };
        bytes.push(UPDATE_KIND);
        bytes.extend_from_slice(&1u16.to_le_bytes());
        bytes.extend_from_slice(digest);
        // The copy holds a small version: a varint of one byte.
        bytes.push(u8::try_from(version).unwrap());
        rest = after;
    }
    bytes.extend_from_slice(rest);
    let crc = crc32(&bytes);
    bytes.extend_from_slice(&crc.to_le_bytes());
    match replica.apply(&bytes, &mut scratch) {
        Applied::Refused(_) | Applied::OutOfStep | Applied::Repeated => {
            assert_eq!((replica.version(), replica.map().len()), (version, len));
        }
        Applied::Diverged | Applied::Restarted => {
            assert_eq!((replica.version(), replica.map().len()), (0, 0));
        }
        Applied::Applied => assert!(replica.version() != version && replica.map().len() <= 256),
    }
});
