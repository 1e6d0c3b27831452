//! The line between two boards' UART0s: bytes copied both ways through a
//! fault (none, silent, bit flips, or substituted, dropped and duplicated
//! bytes), seeded: the relay's pump and the one fault model.

use crate::lines::relay::{Fault, Mix};
use std::net::TcpStream;
use std::sync::atomic::AtomicU64;
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

impl LineFault {
    /// The fault model of this line (the one of [`crate::lines::relay`]).
    pub fn fault(self) -> Fault {
        let only = |bit, drop| Mix { bit, byte: 0.0, drop, dup: 0.0 };
        match self {
            LineFault::None => Fault::NONE,
            LineFault::Silent => Fault { rate: 1.0, mix: only(0.0, 1.0) },
            LineFault::Corrupt(p) => Fault { rate: p, mix: only(1.0, 0.0) },
            LineFault::Lossy(p) => Fault { rate: p, mix: Mix::THIRDS },
        }
    }
}

/// Copies `from` to `to` through `fault` (seeded with `seed`, unpaced:
/// QEMU's UARTs keep their own time) until either side closes; counts the
/// bytes read.
pub fn pump(from: TcpStream, to: TcpStream, fault: LineFault, seed: u64, count: Arc<AtomicU64>) {
    crate::lines::relay::pump(from, to, (fault.fault(), seed, 0), [count, Arc::new(AtomicU64::new(0))]);
}
