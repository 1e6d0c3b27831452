//! The link's Reed-Solomon code against an independent implementation:
//! Python's `reedsolo` (installed by the test command, as the MCAP writers
//! are) encodes random messages and decodes random damage within the
//! code's bound; cosem's encoder must give the same codewords and its
//! decoder the same messages. Skipped, saying why, where Python or
//! `reedsolo` is missing.

use cosem_core::wire::rs;
use serde_json::Value;
use std::process::Command;

const SCRIPT: &str = r#"
import json, random, sys
from reedsolo import RSCodec
rng = random.Random(2026)
cases = []
for i in range(400):
    nsym = 2 * rng.randint(1, 16)
    k = rng.randint(1, 255 - nsym)
    msg = bytes(rng.randrange(256) for _ in range(k))
    code = bytes(RSCodec(nsym).encode(msg))
    n = len(code)
    e = rng.randint(0, nsym)
    v = (nsym - e) // 2
    where = rng.sample(range(n), min(n, e + v))
    bad = bytearray(code)
    for p in where:
        bad[p] ^= rng.randrange(1, 256)
    erasures = sorted(where[:e])
    fixed = bytes(RSCodec(nsym).decode(bytes(bad), erase_pos=erasures)[0])
    assert fixed == msg
    cases.append({"nsym": nsym, "msg": list(msg), "code": list(code), "bad": list(bad), "erasures": erasures})
json.dump(cases, sys.stdout)
"#;

#[test]
fn reed_solomon_agrees_with_pythons_reedsolo() {
    let out = match Command::new("python3").args(["-c", SCRIPT]).output() {
        Ok(o) if o.status.success() => o,
        Ok(o) => {
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(err.contains("reedsolo"), "the reference script failed: {err}");
            eprintln!("skipped: Python's reedsolo is not installed (pip install reedsolo)");
            return;
        }
        Err(e) => {
            eprintln!("skipped: python3 is not available ({e})");
            return;
        }
    };
    let cases: Vec<Value> = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(cases.len(), 400);
    let bytes = |v: &Value| -> Vec<u8> { v.as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as u8).collect() };
    for (i, c) in cases.iter().enumerate() {
        let nsym = c["nsym"].as_u64().unwrap() as usize;
        let (msg, code, mut bad) = (bytes(&c["msg"]), bytes(&c["code"]), bytes(&c["bad"]));
        let erasures: Vec<usize> =
            c["erasures"].as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as usize).collect();
        let mut parity = vec![0u8; nsym];
        rs::encode(&msg, &mut parity).unwrap();
        assert_eq!(&code[msg.len()..], &parity[..], "case {i}: parity differs from reedsolo's");
        assert!(rs::decode(&mut bad, nsym, &erasures).is_some(), "case {i}: not decoded");
        assert_eq!(&bad[..msg.len()], &msg[..], "case {i}: decoded to another message than reedsolo");
    }
}
