//! A simulated serial line for tests and benchmarks: seeded, deterministic,
//! allocation-free. Bytes written at one end reach the other at a fixed rate
//! (e.g. 11.52 bytes per millisecond: 115200 baud, 8N1); each byte is, with
//! probability `error_rate`, damaged as a [`Mix`] says (by default replaced
//! by another value, dropped or duplicated, a third each);
//! with probability `stall_chance` per millisecond the line stalls for 0.2
//! to 2 s. Time is virtual: call [`SimLine::tick`] once per millisecond.

use super::fault::{Damaged, Fault, Mix, SimRng};
use core::cell::RefCell;
use core::convert::Infallible;

/// Parameters of a simulated line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimConfig {
    /// Seed of every random choice.
    pub seed: u64,
    /// Probability that a byte is flipped, dropped or duplicated.
    pub error_rate: f64,
    /// Probability per millisecond that the line stalls.
    pub stall_chance: f64,
    /// Bytes per millisecond each way.
    pub bytes_per_ms: f64,
    /// One medium for both directions: when both ends transmit in the same
    /// millisecond, the bytes of both collide and arrive garbled.
    pub half_duplex: bool,
    /// How a damaged byte is damaged.
    pub mix: Mix,
    /// Bytes a sender may have waiting to leave before its end says it
    /// cannot take more: a UART's FIFO, 16; a pipe, a socket or an
    /// emulator's line, thousands (bytes written then wait their turn, as
    /// a peer on a slow host reads them late).
    pub send_buffer: usize,
}

impl SimConfig {
    /// A clean full-duplex line of `baud` (8N1: ten bits a byte).
    pub fn clean(baud: u32, seed: u64) -> Self {
        SimConfig {
            seed,
            error_rate: 0.0,
            stall_chance: 0.0,
            bytes_per_ms: f64::from(baud) / 10.0 / 1000.0,
            half_duplex: false,
            mix: Mix::THIRDS,
            send_buffer: 16,
        }
    }
}

struct Ring<const N: usize> {
    buf: [u8; N],
    head: usize,
    len: usize,
}

impl<const N: usize> Ring<N> {
    const fn new() -> Self {
        Ring { buf: [0; N], head: 0, len: 0 }
    }
    /// Appends; a full buffer drops the byte (an overrun, as on a UART).
    fn push(&mut self, b: u8) {
        if self.len < N {
            self.buf[(self.head + self.len) % N] = b;
            self.len += 1;
        }
    }
    fn pop(&mut self) -> Option<u8> {
        if self.len == 0 {
            return None;
        }
        let b = self.buf[self.head];
        self.head = (self.head + 1) % N;
        self.len -= 1;
        Some(b)
    }
}

/// The line: `N` bytes of buffer in each direction, on the wire and in
/// each receiver's inbox.
pub struct SimLine<const N: usize> {
    config: SimConfig,
    wire: [Ring<N>; 2],
    inbox: [Ring<N>; 2],
    rng: SimRng,
    stall_until: u64,
    budget: f64,
    collisions: u64,
}

impl<const N: usize> SimLine<N> {
    /// Milliseconds in which both ends talked at once (half duplex).
    pub fn collisions(&self) -> u64 {
        self.collisions
    }

    /// A quiet line.
    pub fn new(config: SimConfig) -> Self {
        SimLine {
            config,
            wire: [Ring::new(), Ring::new()],
            inbox: [Ring::new(), Ring::new()],
            rng: SimRng::new(config.seed),
            stall_until: 0,
            budget: 0.0,
            collisions: 0,
        }
    }

    fn next(&mut self) -> u64 {
        self.rng.next_u64()
    }

    fn unit(&mut self) -> f64 {
        self.rng.unit()
    }

    /// Moves bytes for the millisecond `now`.
    pub fn tick(&mut self, now: u64) {
        if now < self.stall_until {
            return;
        }
        if self.config.stall_chance > 0.0 && self.unit() < self.config.stall_chance {
            self.stall_until = now + 200 + self.next() % 1800;
            return;
        }
        self.budget += self.config.bytes_per_ms;
        let collide = self.config.half_duplex && self.wire[0].len > 0 && self.wire[1].len > 0;
        while self.budget >= 1.0 {
            self.budget -= 1.0;
            for d in 0..2 {
                if let Some(b) = self.wire[d].pop() {
                    let garble = if collide { (self.next() as u8) | 1 } else { 0 };
                    self.inbox[1 - d].push(b ^ garble);
                }
            }
        }
        if collide {
            self.collisions += 1;
        }
    }

    /// Byte `b` onto the wire from `side`, through the line's fault (the
    /// one fault model, [`Fault`]).
    fn send(&mut self, side: usize, b: u8) {
        let fault = Fault { rate: self.config.error_rate, mix: self.config.mix };
        match fault.damage(&mut self.rng, b) {
            Damaged::Kept(v) | Damaged::Changed(v) => self.wire[side].push(v),
            Damaged::Dropped => {}
            Damaged::Doubled(v) => {
                self.wire[side].push(v);
                self.wire[side].push(v);
            }
        }
    }

    /// The two ends: side 0 and side 1.
    pub fn ports(line: &RefCell<Self>) -> (SimPort<'_, N>, SimPort<'_, N>) {
        (SimPort { line, side: 0 }, SimPort { line, side: 1 })
    }
}

/// One end of a [`SimLine`].
pub struct SimPort<'a, const N: usize> {
    line: &'a RefCell<SimLine<N>>,
    side: usize,
}

impl<const N: usize> embedded_io::ErrorType for SimPort<'_, N> {
    type Error = Infallible;
}

impl<const N: usize> embedded_io::Read for SimPort<'_, N> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let mut line = self.line.borrow_mut();
        let mut n = 0;
        for slot in buf.iter_mut() {
            match line.inbox[self.side].pop() {
                Some(b) => {
                    *slot = b;
                    n += 1;
                }
                None => break,
            }
        }
        Ok(n)
    }
}

impl<const N: usize> embedded_io::ReadReady for SimPort<'_, N> {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.line.borrow().inbox[self.side].len > 0)
    }
}

impl<const N: usize> embedded_io::WriteReady for SimPort<'_, N> {
    /// Whether the line's transmitter has room: fewer than
    /// [`SimConfig::send_buffer`] earlier bytes still waiting to leave.
    fn write_ready(&mut self) -> Result<bool, Infallible> {
        let line = self.line.borrow();
        Ok(line.wire[self.side].len < line.config.send_buffer)
    }
}

impl<const N: usize> embedded_io::Write for SimPort<'_, N> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        let mut line = self.line.borrow_mut();
        for &b in buf {
            line.send(self.side, b);
        }
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// A byte stream for a robot's feed line in tests and host runs: reads
/// yield `input` (at most `per_read` bytes per call, as a UART delivers a
/// few at a time), writes are kept in `output` (up to `OUT` bytes; more is
/// an error, as on a line whose peer stopped listening).
pub struct ScriptPort<'a, const OUT: usize> {
    input: &'a [u8],
    at: usize,
    per_read: usize,
    /// What was written.
    pub output: heapless::Vec<u8, OUT>,
}

impl<'a, const OUT: usize> ScriptPort<'a, OUT> {
    /// A port that reads `input`, `per_read` bytes at a time (at least one).
    pub fn new(input: &'a [u8], per_read: usize) -> Self {
        ScriptPort { input, at: 0, per_read: per_read.max(1), output: heapless::Vec::new() }
    }

    /// Bytes of the input not read yet.
    pub fn unread(&self) -> usize {
        self.input.len().saturating_sub(self.at)
    }
}

/// A [`ScriptPort`]'s output is full.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OutputFull;

impl embedded_io::Error for OutputFull {
    fn kind(&self) -> embedded_io::ErrorKind {
        embedded_io::ErrorKind::OutOfMemory
    }
}

impl<const OUT: usize> embedded_io::ErrorType for ScriptPort<'_, OUT> {
    type Error = OutputFull;
}

impl<const OUT: usize> embedded_io::Read for ScriptPort<'_, OUT> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, OutputFull> {
        let rest = self.input.get(self.at..).unwrap_or(&[]);
        let n = rest.len().min(buf.len()).min(self.per_read);
        if let (Some(dst), Some(src)) = (buf.get_mut(..n), rest.get(..n)) {
            dst.copy_from_slice(src);
        }
        self.at += n;
        Ok(n)
    }
}

impl<const OUT: usize> embedded_io::ReadReady for ScriptPort<'_, OUT> {
    fn read_ready(&mut self) -> Result<bool, OutputFull> {
        Ok(self.unread() > 0)
    }
}

impl<const OUT: usize> embedded_io::WriteReady for ScriptPort<'_, OUT> {
    fn write_ready(&mut self) -> Result<bool, OutputFull> {
        Ok(self.output.len() < OUT)
    }
}

impl<const OUT: usize> embedded_io::Write for ScriptPort<'_, OUT> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, OutputFull> {
        self.output.extend_from_slice(buf).map_err(|_| OutputFull)?;
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), OutputFull> {
        Ok(())
    }
}
