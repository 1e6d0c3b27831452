//! The line between two boards' UART0s: bytes copied both ways through a
//! fault (none, silent, bit flips, or substituted, dropped and duplicated
//! bytes), seeded.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// What the line between the robots' UART0s does to bytes: `none`,
/// `silent` or `corrupt=P` on the command line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LineFault {
    /// Passes every byte.
    None,
    /// Passes nothing: each robot's peer is silent.
    Silent,
    /// Flips a bit of each byte with this probability (seeded).
    Corrupt(f64),
    /// Damages each byte with this probability (seeded): substitutes,
    /// drops or duplicates it, alike.
    Lossy(f64),
}

impl std::str::FromStr for LineFault {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" => Ok(LineFault::None),
            "silent" => Ok(LineFault::Silent),
            _ => {
                let (kind, p): (fn(f64) -> LineFault, _) = match s.split_once('=') {
                    Some(("corrupt", p)) => (LineFault::Corrupt, p),
                    Some(("lossy", p)) => (LineFault::Lossy, p),
                    _ => return Err(format!("`{s}`: expected none, silent, corrupt=P or lossy=P")),
                };
                match p.parse::<f64>() {
                    Ok(p) if (0.0..=1.0).contains(&p) => Ok(kind(p)),
                    _ => Err(format!("`{s}`: the probability must be a number in [0, 1]")),
                }
            }
        }
    }
}

/// Copies `from` to `to` through `fault` until either side closes; counts bytes.
pub(crate) fn pump(mut from: TcpStream, mut to: TcpStream, fault: LineFault, seed: u64, count: Arc<AtomicU64>) {
    let mut rng = crate::rng::Rng::new(seed);
    let mut buf = [0u8; 4096];
    let mut out = Vec::with_capacity(2 * buf.len());
    loop {
        let n = match from.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        count.fetch_add(n as u64, Ordering::Relaxed);
        out.clear();
        match fault {
            LineFault::Silent => continue,
            LineFault::Corrupt(p) => {
                for b in &mut buf[..n] {
                    if rng.chance(p) {
                        *b ^= 1 << (rng.below(8) as u8);
                    }
                }
                out.extend_from_slice(&buf[..n]);
            }
            LineFault::Lossy(p) => {
                for &b in &buf[..n] {
                    match (rng.chance(p), rng.below(3)) {
                        (false, _) => out.push(b),
                        (true, 0) => out.push(b ^ (1 + rng.below(255) as u8)),
                        (true, 1) => {}
                        (true, _) => out.extend([b, b]),
                    }
                }
            }
            LineFault::None => out.extend_from_slice(&buf[..n]),
        }
        if to.write_all(&out).is_err() {
            break;
        }
    }
    let _ = to.shutdown(std::net::Shutdown::Write);
}
