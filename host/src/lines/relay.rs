//! A line between two `cosem link` processes, as a UART would be: each
//! direction paced to a baud rate (8N1: ten bits a byte) and, with
//! probability `error_rate` per byte, the byte flipped (one bit, or with
//! [`Flip::Byte`] any value), dropped or duplicated (a third each), or
//! damaged in the shares a [`Mix`] names, from a seeded generator per
//! direction. For measuring the link on a realistic line, and for tests
//! (`cosem relay`).

use crate::error::Error;
use crate::lines::transport::{accept_within, Pacer};
use crate::rng::Rng;
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How the relay treats bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineModel {
    /// Line speed (baud, 8N1); 0: unpaced.
    pub baud: u32,
    /// Probability that a byte is flipped, dropped or duplicated.
    pub error_rate: f64,
    /// Seed of the errors (each direction draws from its own stream).
    pub seed: u64,
    /// What a flip does to a byte.
    pub flip: Flip,
    /// The shares of the kinds of damage (`None`: flips as `flip` says,
    /// drops and duplicates, a third each).
    pub mix: Option<Mix>,
}

pub use cosem_core::sim::Mix;

/// Reads a mix from the command line (`bit=1,byte=1,drop=1,dup=1`).
pub fn parse_mix(text: &str) -> Result<Mix, String> {
    Mix::parse(text).map_err(|e| format!("`{text}`: {e}"))
}

/// One kind of damage.
enum Damage {
    Bit,
    Byte,
    Drop,
    Dup,
}

impl LineModel {
    /// The damage a damaged byte gets.
    fn damage(&self, rng: &mut Rng) -> Damage {
        let Some(m) = self.mix else {
            // As before mixes existed: the same draws for the same seed.
            return match rng.below(3) {
                0 if self.flip == Flip::Bit => Damage::Bit,
                0 => Damage::Byte,
                1 => Damage::Drop,
                _ => Damage::Dup,
            };
        };
        match m.kind(rng.unit()) {
            0 => Damage::Bit,
            1 => Damage::Byte,
            2 => Damage::Drop,
            _ => Damage::Dup,
        }
    }
}

/// What a flip does to a byte: a UART's bit error flips one bit; noise
/// across a whole character (or a clock slip) garbles it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Flip {
    /// One bit flipped.
    #[default]
    Bit,
    /// XOR with a random non-zero byte.
    Byte,
}

/// What crossed the relay, per direction (first connection to second, then back).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RelayStats {
    /// Bytes read from each side.
    pub bytes_in: [u64; 2],
    /// Bytes damaged (flipped, dropped or duplicated) going each way.
    pub damaged: [u64; 2],
}

/// Copies `from` to `to` as the line model says, until `from` closes.
fn pump(mut from: TcpStream, mut to: TcpStream, model: LineModel, seed: u64, counts: [Arc<AtomicU64>; 2]) {
    let mut rng = Rng::new(seed);
    let mut pacer = Pacer::new(model.baud);
    let mut buf = [0u8; 4096];
    let mut out = Vec::with_capacity(8192);
    loop {
        let n = match from.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        counts[0].fetch_add(n as u64, Ordering::Relaxed);
        out.clear();
        for &b in &buf[..n] {
            if model.error_rate > 0.0 && rng.chance(model.error_rate) {
                counts[1].fetch_add(1, Ordering::Relaxed);
                match model.damage(&mut rng) {
                    Damage::Bit => out.push(b ^ (1 << rng.below(8))),
                    Damage::Byte => out.push(b ^ (1 + rng.below(255) as u8)),
                    Damage::Drop => {}
                    Damage::Dup => out.extend_from_slice(&[b, b]),
                }
            } else {
                out.push(b);
            }
        }
        // Paced as the UART would send, a few bytes at a time.
        for chunk in out.chunks(64) {
            pacer.wait();
            if to.write_all(chunk).is_err() {
                return;
            }
            pacer.sent(chunk.len());
        }
    }
    let _ = to.shutdown(std::net::Shutdown::Write);
}

/// Accepts one connection on each listener (within `accept_timeout`), then
/// relays both directions until both sides closed; `on_ready` learns the
/// two addresses before the first accept.
pub fn run(
    listeners: [TcpListener; 2],
    model: LineModel,
    accept_timeout: Duration,
    on_ready: impl FnOnce([std::net::SocketAddr; 2]),
) -> Result<RelayStats, Error> {
    let io = |what: &str| {
        let what = what.to_string();
        move |source| Error::Io { path: what.into(), source }
    };
    let addrs = [listeners[0].local_addr().map_err(io("relay"))?, listeners[1].local_addr().map_err(io("relay"))?];
    on_ready(addrs);
    let deadline = Instant::now() + accept_timeout;
    let mut streams = Vec::new();
    for (l, a) in listeners.iter().zip(addrs) {
        streams.push(accept_within(l, deadline).map_err(|source| Error::Io { path: a.to_string().into(), source })?);
    }
    let counts: Vec<Arc<AtomicU64>> = (0..4).map(|_| Arc::new(AtomicU64::new(0))).collect();
    let clone = |s: &TcpStream| s.try_clone().map_err(io("relay"));
    let (a, b) = (clone(&streams[0])?, clone(&streams[1])?);
    let (c0, c1) = ([counts[0].clone(), counts[1].clone()], [counts[2].clone(), counts[3].clone()]);
    let (s0, s1) = (streams.remove(0), streams.remove(0));
    let seed = model.seed;
    let t0 = std::thread::spawn(move || pump(s0, b, model, seed, c0));
    let t1 = std::thread::spawn(move || pump(s1, a, model, seed ^ 0x05EE_D0FB, c1));
    let _ = (t0.join(), t1.join());
    let load = |i: usize| counts[i].load(Ordering::Relaxed);
    Ok(RelayStats { bytes_in: [load(0), load(2)], damaged: [load(1), load(3)] })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mix_names_its_shares_and_refuses_what_is_not_one() {
        let m: Mix = parse_mix("bit=1, byte=2,drop=0.5").unwrap();
        assert_eq!(m, Mix { bit: 1.0, byte: 2.0, drop: 0.5, dup: 0.0 });
        let bad = ["", "bit", "bit=x", "bit=-1", "bit=inf", "bit=nan", "bite=1", "bit=0,dup=0"];
        // Shares whose sum overflows, and a kind given twice.
        for bad in bad.into_iter().chain(["bit=1e308,byte=1e308", "bit=1,bit=2", "drop=1, drop=0"]) {
            assert!(parse_mix(bad).is_err(), "{bad}");
        }
    }

    /// Draws follow the shares; without a mix, the draws of before (a third
    /// each, the flip as `flip` says).
    #[test]
    fn damage_follows_the_shares() {
        let model = |mix| LineModel { baud: 0, error_rate: 1.0, seed: 1, flip: Flip::Byte, mix };
        let count = |m: &LineModel| {
            let mut rng = Rng::new(7);
            let mut n = [0usize; 4];
            for _ in 0..30_000 {
                n[match m.damage(&mut rng) {
                    Damage::Bit => 0,
                    Damage::Byte => 1,
                    Damage::Drop => 2,
                    Damage::Dup => 3,
                }] += 1;
            }
            n
        };
        let n = count(&model(Some(Mix { bit: 0.0, byte: 1.0, drop: 1.0, dup: 2.0 })));
        assert_eq!(n[0], 0);
        assert!((7_000..8_000).contains(&n[1]) && (7_000..8_000).contains(&n[2]), "{n:?}");
        assert!((14_500..15_500).contains(&n[3]), "{n:?}");
        let thirds = count(&model(None));
        assert_eq!(thirds[0], 0);
        assert!(thirds[1..].iter().all(|&k| (9_500..10_500).contains(&k)), "{thirds:?}");
    }
}
