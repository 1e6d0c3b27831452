//! A line between two `cosem link` processes, as a UART would be: each
//! direction paced to a baud rate (8N1: ten bits a byte) and damaged by
//! the one fault model ([`Fault`]: each byte with probability `rate`, as a
//! [`Mix`] says), from a seeded generator per direction. For measuring the
//! link on a realistic line, and for tests (`cosem relay`); [`pump`] is
//! also the line between two boards' UARTs.

use crate::error::Error;
use crate::lines::transport::{accept_within, Paced, TcpWriter};
use cosem_core::sim::Lossy;
use std::io::Read;
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

pub use cosem_core::sim::{Fault, Mix};

/// How the relay treats bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineModel {
    /// Line speed (baud, 8N1); 0: unpaced.
    pub baud: u32,
    /// What the line does to bytes.
    pub fault: Fault,
    /// Seed of the errors (each direction draws from its own stream).
    pub seed: u64,
}

/// Reads a mix from the command line (`bit=1,byte=1,drop=1,dup=1`).
pub fn parse_mix(text: &str) -> Result<Mix, String> {
    Mix::parse(text).map_err(|e| format!("`{text}`: {e}"))
}

/// The mix of a line whose damage is a flip (one bit, or the whole byte),
/// a drop or a duplicate, a third each.
pub fn flip_mix(whole_byte: bool) -> Mix {
    if whole_byte {
        Mix::THIRDS
    } else {
        Mix { bit: 1.0, byte: 0.0, drop: 1.0, dup: 1.0 }
    }
}

/// What crossed the relay, per direction (first connection to second, then back).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RelayStats {
    /// Bytes read from each side.
    pub bytes_in: [u64; 2],
    /// Bytes damaged (flipped, dropped or duplicated) going each way.
    pub damaged: [u64; 2],
}

/// Copies `from` to `to` through `fault` (seeded with `seed`), paced to
/// `baud` (0: unpaced), until either side closes; counts the bytes read
/// (`counts[0]`) and damaged (`counts[1]`).
pub fn pump(from: TcpStream, to: TcpStream, (fault, seed, baud): (Fault, u64, u32), counts: [Arc<AtomicU64>; 2]) {
    use embedded_io::Write;
    let (mut from, shut) = (from, to.try_clone());
    let mut out = Lossy::new(Paced::new(TcpWriter(to), baud), fault, seed);
    let mut buf = [0u8; 4096];
    loop {
        let n = match from.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        counts[0].fetch_add(n as u64, Ordering::Relaxed);
        let before = out.damaged();
        // Paced as the UART would send, a few bytes at a time.
        let sent = buf[..n].chunks(64).try_for_each(|chunk| out.write_all(chunk));
        counts[1].fetch_add(out.damaged() - before, Ordering::Relaxed);
        if sent.is_err() {
            return;
        }
    }
    if let Ok(s) = shut {
        let _ = s.shutdown(std::net::Shutdown::Write);
    }
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
    let (fault, seed, baud) = (model.fault, model.seed, model.baud);
    let t0 = std::thread::spawn(move || pump(s0, b, (fault, seed, baud), c0));
    let t1 = std::thread::spawn(move || pump(s1, a, (fault, seed ^ 0x05EE_D0FB, baud), c1));
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

    /// A relay damages at the rate asked, in both directions, and passes
    /// a clean line's bytes as they are.
    #[test]
    fn the_relay_damages_what_it_is_told_to() {
        use std::io::Write;
        for (rate, want) in [(0.0, 0..1), (0.2, 1_500..2_500)] {
            let fault = Fault::new(rate, flip_mix(false)).unwrap();
            let listeners = [TcpListener::bind("127.0.0.1:0").unwrap(), TcpListener::bind("127.0.0.1:0").unwrap()];
            let (tx, rx) = std::sync::mpsc::channel();
            let relay = std::thread::spawn(move || {
                run(listeners, LineModel { baud: 0, fault, seed: 3 }, Duration::from_secs(10), |a| {
                    tx.send(a).unwrap();
                })
            });
            let [x, y] = rx.recv().unwrap();
            let mut a = TcpStream::connect(x).unwrap();
            let mut b = TcpStream::connect(y).unwrap();
            let bytes = vec![0xA5u8; 10_000];
            a.write_all(&bytes).unwrap();
            a.shutdown(std::net::Shutdown::Write).unwrap();
            let mut got = Vec::new();
            b.read_to_end(&mut got).unwrap();
            drop(b);
            let stats = relay.join().unwrap().unwrap();
            assert_eq!(stats.bytes_in[0], 10_000);
            assert!(want.contains(&stats.damaged[0]), "rate {rate}: {stats:?}");
            if rate == 0.0 {
                assert_eq!(got, bytes);
            } else {
                assert_ne!(got, bytes);
            }
        }
    }
}
