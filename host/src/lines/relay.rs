//! A line between two `cosem link` processes, as a UART would be: each
//! direction paced to a baud rate (8N1: ten bits a byte) and, with
//! probability `error_rate` per byte, the byte flipped (one bit, or with
//! [`Flip::Byte`] any value), dropped or duplicated (a third each), from a
//! seeded generator per direction. For
//! measuring the link on a realistic line, and for tests (`cosem relay`).

use crate::error::Error;
use crate::rng::Rng;
use crate::transport::{accept_within, Pacer};
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
                match rng.below(3) {
                    0 => out.push(match model.flip {
                        Flip::Bit => b ^ (1 << rng.below(8)),
                        Flip::Byte => b ^ (1 + rng.below(255) as u8),
                    }),
                    1 => {}
                    _ => out.extend_from_slice(&[b, b]),
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
