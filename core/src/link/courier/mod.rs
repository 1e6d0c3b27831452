//! One message each way a round, over any byte line: the transport of
//! robots that keep driving (each round a map update one way and one the
//! other, [`crate::wire::update`]), where the [`super::Endpoint`] moves
//! one whole map once.
//!
//! A message is cut into units of [`UNIT`] bytes; a data frame
//! ([`crate::wire::frame`]: Reed-Solomon parity, CRC-32, COBS) carries a
//! run of them, tagged with the round, the message's length and the first
//! unit. The receiver acknowledges every data frame with what it holds
//! (all units below a count, and three runs held beyond it: the first two
//! and the last). The line keeps order, so a frame sent before one now
//! acknowledged, and not acknowledged itself, was lost: it is sent again
//! at once; a timeout (twice the round trip, doubling only while the peer
//! is silent) sends everything unacknowledged again. The frames' size and
//! parity follow the line as the peer's frames judge it (the link's
//! estimate, [`super::Endpoint`]'s: what the deframer repaired and the
//! frames lost), each data frame's acknowledgement counted in its cost;
//! while nothing is heard, each timeout also halves the largest frame. A
//! whole message is handed to the caller, who answers it
//! ([`Courier::reply`]: an update's answer,
//! [`crate::wire::update::UpdateAck`]); the answer rides the receiver's
//! acknowledgements. A round is over when this side holds the peer's whole
//! message and has answered it, and the peer has acknowledged all of this
//! side's and answered it.
//!
//! A side that finished a round keeps its last acknowledgement and answers
//! the peer's resends of that round with it (the peer may have missed it)
//! while it fuses its next scans and starts the next round; the peer's
//! frames of the next round are taken as they come, before this side
//! starts it.

use super::endpoint::line::{FrameShape, LineEstimate};
use crate::wire::frame::{encode_frame_parity, frame_len, max_payload, Deframer, MAX_FRAME};
use crate::wire::rs::MAX_PARITY;
use embedded_io::{Read, ReadReady, Write, WriteReady};

/// First byte of a courier's data frame (clear of the link's, the feed's
/// and the share messages' first bytes).
pub const COURIER_DATA: u8 = 0x0E;
/// First byte of a courier's acknowledgement.
pub const COURIER_ACK: u8 = 0x0F;
/// Bytes of message a unit holds: frames carry whole units (the last one
/// of a message may be short).
pub const UNIT: usize = 8;
/// Most units of a message (a message of at most 128 KiB).
pub const MAX_UNITS: usize = 16384;
/// Longest answer to a message.
pub const MAX_REPLY: usize = 32;
/// Bytes of a data frame before its units: kind, round, length (24 bits),
/// first unit.
const DATA_HEADER: usize = 1 + 1 + 3 + 2;
/// Bytes of an acknowledgement before its answer: kind, round, count,
/// three runs held beyond it (first unit, units), flags.
const ACK_HEADER: usize = 1 + 1 + 2 + 12 + 1;
/// Runs of units held beyond the count an acknowledgement tells: the
/// first two after the gap and the last (the line keeps order: what was
/// sent before the last run and is not held was lost).
const ACK_RUNS: usize = 3;
/// Most frames in flight.
const IN_FLIGHT: usize = 48;
/// Flag of an acknowledgement: the whole message is held.
const COMPLETE: u8 = 1;
/// Flag: the answer follows.
const REPLIED: u8 = 2;

/// Sizes and timing of a courier.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CourierConfig {
    /// Most units a data frame carries (default 24: 192 bytes); on a line
    /// that damages bytes frames carry fewer.
    pub max_units: u8,
    /// Least parity bytes of every frame (even, default 4: two bytes
    /// repaired a frame); a line that damages bytes gets more.
    pub parity: u8,
    /// Units in flight beyond the first unacknowledged one (default 192:
    /// 1.5 KiB).
    pub window: u16,
    /// Resend what is unacknowledged this long after the last frame went
    /// out (ms, default 150), doubling while nothing moves, up to 8 times.
    pub timeout_ms: u32,
    /// Give up when nothing valid arrived for this long during a round
    /// (ms, default 90,000).
    pub silence_ms: u32,
}

impl Default for CourierConfig {
    fn default() -> Self {
        CourierConfig { max_units: 24, parity: 4, window: 192, timeout_ms: 150, silence_ms: 90_000 }
    }
}

impl CourierConfig {
    /// The largest message ([`MAX_UNITS`] units).
    pub const MAX_MESSAGE: usize = UNIT * MAX_UNITS;

    fn valid(&self) -> bool {
        let parity = usize::from(self.parity);
        self.max_units > 0
            && self.window > 0
            && parity <= MAX_PARITY
            && parity.is_multiple_of(2)
            && DATA_HEADER + UNIT * usize::from(self.max_units) <= max_payload(parity)
            && ACK_HEADER + MAX_REPLY <= max_payload(parity)
    }
}

/// Why a courier stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CourierError {
    /// The line reported an error of this kind.
    Io(embedded_io::ErrorKind),
    /// Nothing valid arrived for the silence time.
    Silent,
    /// A message longer than the courier carries, or than the receiving
    /// buffer (bytes).
    TooLarge(u32),
    /// An answer longer than [`MAX_REPLY`], or given before a message came.
    Reply,
    /// Invalid sizes ([`CourierConfig`]).
    Config,
}

impl core::fmt::Display for CourierError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CourierError::Io(kind) => write!(f, "I/O error on the line ({kind:?})"),
            CourierError::Silent => f.write_str("peer silent"),
            CourierError::TooLarge(n) => write!(f, "a message of {n} bytes does not fit"),
            CourierError::Reply => f.write_str("answer too long, or to no message"),
            CourierError::Config => f.write_str("invalid courier sizes"),
        }
    }
}

impl core::error::Error for CourierError {}

/// What a step brought.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// Nothing to do for the caller.
    Busy,
    /// The peer's whole message is in the receiving buffer (this many
    /// bytes): answer it ([`Courier::reply`]).
    Delivered(usize),
    /// The round is over: the peer's message answered, this side's
    /// acknowledged and answered ([`Courier::answer`]).
    Done,
}

/// Units held: one bit each.
#[derive(Clone, Copy)]
struct Bits([u32; MAX_UNITS / 32]);

impl Bits {
    const fn new() -> Self {
        Bits([0; MAX_UNITS / 32])
    }
    fn get(&self, k: usize) -> bool {
        self.0.get(k / 32).is_some_and(|w| w & (1 << (k % 32)) != 0)
    }
    fn set(&mut self, k: usize) {
        if let Some(w) = self.0.get_mut(k / 32) {
            *w |= 1 << (k % 32);
        }
    }
    fn all(&self, from: usize, to: usize) -> bool {
        (from..to).all(|k| self.get(k))
    }
    /// The first unit at or after `from`, below `n`, held (`n` when none
    /// is).
    fn first_set(&self, from: usize, n: usize) -> usize {
        let mut k = from;
        while k < n {
            match self.0.get(k / 32) {
                Some(&0) if k.is_multiple_of(32) => k += 32,
                Some(&w) if w & (1 << (k % 32)) == 0 => k += 1,
                _ => return k.min(n),
            }
        }
        n
    }
    /// The first unit at or after `from`, below `n`, not held (`n` when
    /// all are).
    fn first_clear(&self, from: usize, n: usize) -> usize {
        let mut k = from;
        while k < n {
            match self.0.get(k / 32) {
                Some(&w) if k.is_multiple_of(32) && w == u32::MAX => k += 32,
                Some(&w) if w & (1 << (k % 32)) != 0 => k += 1,
                _ => return k,
            }
        }
        n
    }
}

/// Counters of a courier's line, over its life.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CourierStats {
    /// Bytes written to the line.
    pub bytes_sent: u64,
    /// Bytes read from the line.
    pub bytes_received: u64,
    /// Data frames sent again (lost, or not acknowledged in time).
    pub resent: u32,
    /// Frames refused (damaged beyond repair).
    pub bad_frames: u32,
}

/// An answer: its bytes and length.
type Reply = ([u8; MAX_REPLY], u8);

/// A message this side answered: its round, its units and the answer.
#[derive(Clone, Copy)]
struct Answered {
    round: u16,
    units: u16,
    reply: Reply,
}

/// A data frame in flight: its first unit, its units, when it went out
/// (a count of frames sent).
#[derive(Clone, Copy)]
struct Flight {
    first: u16,
    units: u16,
    seq: u32,
    /// When it went out (ms), for the round trip.
    sent_ms: u64,
    /// Sent before (its acknowledgement says nothing of the round trip).
    again: bool,
}

/// One side of the exchange of one message each way per round, driven by
/// [`Courier::step`]; the messages live in the caller's buffers.
pub struct Courier {
    config: CourierConfig,
    deframer: Deframer,
    /// The round under way (`None` between rounds).
    round: Option<u16>,
    // Sending.
    out_len: u32,
    acked: Bits,
    /// The first unit never sent.
    frontier: usize,
    /// After a timeout: the units below the frontier from here on go
    /// again (those not acknowledged); `usize::MAX`: none.
    redo: usize,
    flights: heapless::Deque<Flight, IN_FLIGHT>,
    /// Frames found lost, to send again first.
    lost: heapless::Deque<Flight, IN_FLIGHT>,
    seq: u32,
    /// Units a data frame carries, and the parity of every frame: the
    /// shape the line estimate chose.
    frame_units: u8,
    parity: u8,
    line: LineEstimate,
    /// Most units a frame carries while the peer is not heard: halved at
    /// each timeout that heard nothing, doubled at each acknowledgement
    /// that moved.
    ceiling: u8,
    last_sent_ms: u64,
    backoff: u8,
    /// A valid frame of this round came since the last timeout.
    heard: bool,
    /// Smoothed round trip of data frames (ms, eighths), once measured.
    srtt8: Option<u64>,
    answer: Option<Reply>,
    // Receiving.
    /// The round of the message being received: the round under way, or,
    /// between rounds, the next (a peer that started it first is heard).
    in_round: Option<u16>,
    in_len: Option<u32>,
    held: Bits,
    delivered: bool,
    replied: Option<Reply>,
    /// The last round's answer, for a peer that missed it.
    last: Option<Answered>,
    heard_ms: u64,
    stats: CourierStats,
}

impl Courier {
    /// A courier with `config`'s sizes.
    pub fn new(config: CourierConfig) -> Result<Self, CourierError> {
        if !config.valid() {
            return Err(CourierError::Config);
        }
        Ok(Courier {
            config,
            deframer: Deframer::new(),
            round: None,
            out_len: 0,
            acked: Bits::new(),
            frontier: 0,
            redo: usize::MAX,
            flights: heapless::Deque::new(),
            lost: heapless::Deque::new(),
            seq: 0,
            frame_units: config.max_units,
            parity: config.parity,
            line: LineEstimate::default(),
            ceiling: config.max_units,
            last_sent_ms: 0,
            backoff: 0,
            heard: false,
            srtt8: None,
            answer: None,
            in_round: None,
            in_len: None,
            held: Bits::new(),
            delivered: false,
            replied: None,
            last: None,
            heard_ms: 0,
            stats: CourierStats::default(),
        })
    }

    /// What the line carried so far.
    pub fn stats(&self) -> CourierStats {
        self.stats
    }

    /// The round under way, if any.
    pub fn round(&self) -> Option<u16> {
        self.round
    }

    /// Starts `round` (after the last one ended): this side's message is
    /// the first `len` bytes of the buffer [`Courier::step`] sends from.
    pub fn start(&mut self, round: u16, len: usize, now_ms: u64) -> Result<(), CourierError> {
        if len > CourierConfig::MAX_MESSAGE {
            return Err(CourierError::TooLarge(len.min(u32::MAX as usize) as u32));
        }
        self.round = Some(round);
        self.out_len = len as u32;
        self.acked = Bits::new();
        self.frontier = 0;
        self.redo = usize::MAX;
        self.flights.clear();
        self.lost.clear();
        self.last_sent_ms = now_ms;
        self.backoff = 0;
        self.answer = None;
        if self.in_round != Some(round) {
            self.receive(round);
        }
        self.heard_ms = now_ms;
        Ok(())
    }

    /// Receives `round`'s message from nothing.
    fn receive(&mut self, round: u16) {
        self.in_round = Some(round);
        self.in_len = None;
        self.held = Bits::new();
        self.delivered = false;
        self.replied = None;
    }

    /// Answers the peer's message (once it was [`Event::Delivered`]).
    pub fn reply(&mut self, answer: &[u8]) -> Result<(), CourierError> {
        if !self.delivered || answer.len() > MAX_REPLY {
            return Err(CourierError::Reply);
        }
        let mut a = [0u8; MAX_REPLY];
        a.get_mut(..answer.len()).ok_or(CourierError::Reply)?.copy_from_slice(answer);
        self.replied = Some((a, answer.len() as u8));
        Ok(())
    }

    /// The peer's answer to this side's message, once it came.
    pub fn answer(&self) -> Option<&[u8]> {
        self.answer.as_ref().and_then(|(a, n)| a.get(..usize::from(*n)))
    }

    /// Units of a message of `len` bytes (an empty one is one empty unit).
    fn units(len: u32) -> usize {
        (len as usize).div_ceil(UNIT).max(1)
    }

    /// Reads the line, answers, sends what is due. `out`: this round's
    /// message (its first bytes, as [`Courier::start`] said); `input`: where
    /// the peer's message is put. Between rounds it only answers the last
    /// round's resends.
    pub fn step<L: Read + Write + ReadReady + WriteReady>(
        &mut self,
        port: &mut L,
        out: &[u8],
        input: &mut [u8],
        now_ms: u64,
    ) -> Result<Event, CourierError> {
        let io = |e: L::Error| CourierError::Io(embedded_io::Error::kind(&e));
        let mut buf = [0u8; 64];
        // A whole frame's payload, copied off the deframer (which the
        // frame's handling may not borrow across).
        let mut payload = [0u8; MAX_FRAME];
        // The line estimate changed: frames to be shaped anew.
        let mut judged = false;
        while port.read_ready().map_err(io)? {
            let n = port.read(&mut buf).map_err(io)?;
            if n == 0 {
                break;
            }
            self.stats.bytes_received += n as u64;
            for &b in buf.get(..n).unwrap_or(&[]) {
                if b != 0 {
                    self.line.byte();
                }
                let len = match self.deframer.push_frame(b) {
                    Ok(Some(f)) => {
                        self.line.frame(Some((f.damage, f.parity)));
                        judged = true;
                        let k = f.payload.len().min(payload.len());
                        payload.get_mut(..k).unwrap_or(&mut []).copy_from_slice(f.payload.get(..k).unwrap_or(&[]));
                        k
                    }
                    Ok(None) => continue,
                    Err(e) => {
                        self.stats.bad_frames += 1;
                        // No header read: its bytes tell nothing of the line.
                        if e == crate::wire::DeframeError::Header {
                            self.line.skip();
                        } else {
                            self.line.frame(None);
                            judged = true;
                        }
                        continue;
                    }
                };
                self.on_frame(port, payload.get(..len).unwrap_or(&[]), input, now_ms)?;
            }
        }
        if judged {
            self.reshape();
        }
        let Some(round) = self.round else { return Ok(Event::Busy) };
        if self.delivered && self.replied.is_none() && self.in_round == Some(round) {
            return Ok(Event::Delivered(self.in_len.unwrap_or(0) as usize));
        }
        let units = Self::units(self.out_len);
        let first = self.acked.first_clear(0, units);
        if first == units && self.answer.is_some() {
            if let Some(reply) = self.replied {
                // Remembered for a peer that missed the last acknowledgement.
                let held = Self::units(self.in_len.unwrap_or(0)) as u16;
                self.last = Some(Answered { round, units: held, reply });
                self.round = None;
                return Ok(Event::Done);
            }
        }
        if now_ms.saturating_sub(self.heard_ms) > u64::from(self.config.silence_ms) {
            return Err(CourierError::Silent);
        }
        self.send_due(port, out, round, first, now_ms)?;
        Ok(Event::Busy)
    }

    /// The frames' size and parity for the line as the peer's frames judge
    /// it (the link's estimate: what the deframer repaired, the frames
    /// lost), within the configured largest frame.
    fn reshape(&mut self) {
        let line = self.line.model();
        let most = usize::from(self.config.max_units);
        let mut best = (0.0f32, self.frame_units, self.parity);
        for parity in (usize::from(self.config.parity)..=MAX_PARITY.min(16)).step_by(2) {
            let room = max_payload(parity).saturating_sub(DATA_HEADER) / UNIT;
            // Every data frame brings an acknowledgement back: its bytes count.
            let ack = frame_len(ACK_HEADER, parity) as f32;
            for units in 1..=most.min(room) {
                let data = UNIT * units;
                // The link's data header is shorter: the rest counts as data.
                let chunk = data + DATA_HEADER - crate::wire::message::DATA_HEADER;
                let shape = FrameShape { chunk, parity, arrival: 0.0, block: None, clean: false };
                let bytes = frame_len(DATA_HEADER + data, parity) as f32 + ack;
                let goodput = data as f32 / bytes * line.arrival(shape);
                if goodput > best.0 {
                    best = (goodput, units as u8, parity as u8);
                }
            }
        }
        (self.frame_units, self.parity) = (best.1.min(self.ceiling), best.2);
    }

    /// Sends what is due: frames found lost, then new units of the window,
    /// while the line has room; after a timeout, everything in flight again
    /// (or, all acknowledged and the answer missing, the last unit, to ask).
    fn send_due<L: Write + WriteReady>(
        &mut self,
        port: &mut L,
        out: &[u8],
        round: u16,
        first: usize,
        now_ms: u64,
    ) -> Result<(), CourierError> {
        let io = |e: L::Error| CourierError::Io(embedded_io::Error::kind(&e));
        let units = Self::units(self.out_len);
        let end = units.min(first + usize::from(self.config.window));
        // Twice the measured round trip, at least the configured timeout.
        let rtt = self.srtt8.map_or(0, |s| s / 8);
        // All acknowledged, the answer missing: a probe is one short frame,
        // asked again without backing off much (an answer lost on a bad
        // line must not cost seconds).
        let cap = if first == units { 1 } else { 3 };
        let timeout = u64::from(self.config.timeout_ms).max(2 * rtt) << self.backoff.min(cap);
        let stalled =
            (self.lost.is_empty() && self.redo >= self.frontier && self.frontier >= end) || self.flights.is_full();
        if stalled && now_ms.saturating_sub(self.last_sent_ms) >= timeout {
            // Backing off only while the peer is silent: a line that
            // carries frames loses some, it is not down.
            self.backoff = if self.heard { 0 } else { self.backoff.saturating_add(1).min(8) };
            if !self.heard {
                // Nothing came back: frames too long for the line, perhaps,
                // before any of the peer's frames could say so.
                self.ceiling = (self.ceiling / 2).max(1);
                self.frame_units = self.frame_units.min(self.ceiling);
            }
            self.heard = false;
            if first == units {
                let last = units.saturating_sub(1) as u16;
                self.send_units(port, out, round, (last, 1), (now_ms, true))?;
                self.last_sent_ms = now_ms;
                return Ok(());
            }
            // Everything unacknowledged below the frontier goes again.
            self.flights.clear();
            self.lost.clear();
            self.redo = first;
        }
        while port.write_ready().map_err(io)? && (!self.flights.is_full() || !self.lost.is_empty()) {
            let room = usize::from(self.frame_units);
            let (from, n, resend) = if let Some(f) = self.lost.pop_front() {
                (usize::from(f.first), usize::from(f.units), true)
            } else if self.redo < self.frontier {
                let from = self.acked.first_clear(self.redo, self.frontier);
                let n = room.min(self.frontier - from);
                self.redo = if from + n >= self.frontier { usize::MAX } else { from + n };
                if n == 0 {
                    continue;
                }
                (from, n, true)
            } else if self.frontier < end {
                let n = room.min(end - self.frontier);
                self.frontier += n;
                (self.frontier - n, n, false)
            } else {
                break;
            };
            // Units acknowledged meanwhile are not sent again.
            let mut k = self.acked.first_clear(from, from + n);
            while k < from + n {
                let stop = (k..from + n).find(|&u| self.acked.get(u)).unwrap_or(from + n);
                let take = (stop - k).min(room);
                self.send_units(port, out, round, (k as u16, take as u16), (now_ms, resend))?;
                self.stats.resent += u32::from(resend);
                self.last_sent_ms = now_ms;
                k = self.acked.first_clear(k + take, from + n);
            }
        }
        Ok(())
    }

    /// Sends `n` units of `out` from unit `first`, as one frame in flight
    /// from `now_ms` (`again`: sent before).
    fn send_units<L: Write>(
        &mut self,
        port: &mut L,
        out: &[u8],
        round: u16,
        (first, n): (u16, u16),
        (now_ms, again): (u64, bool),
    ) -> Result<(), CourierError> {
        let start = usize::from(first) * UNIT;
        let end = (start + usize::from(n) * UNIT).min(self.out_len as usize);
        let bytes = out.get(start..end.max(start)).ok_or(CourierError::TooLarge(self.out_len))?;
        let mut payload = [0u8; MAX_FRAME];
        let mut at = 0;
        for part in [&[COURIER_DATA, round as u8][..], &self.out_len.to_le_bytes()[..3], &first.to_le_bytes(), bytes] {
            payload.get_mut(at..at + part.len()).ok_or(CourierError::Config)?.copy_from_slice(part);
            at += part.len();
        }
        self.send(port, payload.get(..at).unwrap_or(&[]))?;
        self.seq = self.seq.wrapping_add(1);
        if self.flights.is_full() {
            // Forgotten: a timeout sends it again if it was lost.
            let _ = self.flights.pop_front();
        }
        let _ = self.flights.push_back(Flight { first, units: n, seq: self.seq, sent_ms: now_ms, again });
        Ok(())
    }

    fn send<L: Write>(&mut self, port: &mut L, payload: &[u8]) -> Result<(), CourierError> {
        let mut frame = [0u8; MAX_FRAME];
        let n = encode_frame_parity(payload, usize::from(self.parity), &mut frame).map_err(|_| CourierError::Config)?;
        let bytes = frame.get(..n).unwrap_or(&[]);
        port.write_all(bytes).map_err(|e| CourierError::Io(embedded_io::Error::kind(&e)))?;
        self.stats.bytes_sent += n as u64;
        Ok(())
    }

    /// One intact frame from the peer.
    fn on_frame<L: Write>(
        &mut self,
        port: &mut L,
        p: &[u8],
        input: &mut [u8],
        now_ms: u64,
    ) -> Result<(), CourierError> {
        let u16_at = |i: usize| p.get(i..i + 2).and_then(|b| b.try_into().ok()).map(u16::from_le_bytes);
        let same = |r: Option<u16>| r.is_some_and(|r| Some(&(r as u8)) == p.get(1));
        match p.first().copied() {
            Some(COURIER_DATA) if p.len() >= DATA_HEADER => {
                let len = p.get(2..5).map_or(0, |b| b.iter().rev().fold(0u32, |a, &x| a << 8 | u32::from(x)));
                let first = u16_at(5).unwrap_or(0);
                let body = p.get(DATA_HEADER..).unwrap_or(&[]);
                // The round a message may come for: the one under way, or,
                // between rounds, the next (the last one's is answered).
                let next = self.last.map_or(0, |l| l.round.wrapping_add(1));
                let expected = self.round.unwrap_or(next);
                let last_round = self.last.map(|l| l.round).filter(|&r| r != expected);
                if same(Some(expected)) {
                    if self.in_round != Some(expected) {
                        self.receive(expected);
                    }
                    self.heard_ms = now_ms;
                    self.heard = true;
                    self.take_units(len, first, body, input)?;
                    let ack = self.ack_now();
                    self.send_ack(port, &ack)?;
                } else if let Some(last) = self.last.filter(|_| same(last_round)) {
                    // The peer missed the last round's answer.
                    let ack = AckView {
                        round: last.round,
                        count: last.units,
                        runs: [(0, 0); ACK_RUNS],
                        complete: true,
                        reply: Some(last.reply),
                    };
                    self.send_ack(port, &ack)?;
                }
            }
            Some(COURIER_ACK) if same(self.round) && p.len() >= ACK_HEADER => {
                let count = u16_at(2).unwrap_or(0);
                let mut runs = [(0u16, 0u16); ACK_RUNS];
                for (k, r) in runs.iter_mut().enumerate() {
                    *r = (u16_at(4 + 4 * k).unwrap_or(0), u16_at(6 + 4 * k).unwrap_or(0));
                }
                let flags = p.get(ACK_HEADER - 1).copied().unwrap_or(0);
                self.heard_ms = now_ms;
                self.heard = true;
                self.on_ack(usize::from(count), &runs, now_ms);
                if flags & REPLIED != 0 && flags & COMPLETE != 0 {
                    let reply = p.get(ACK_HEADER..).unwrap_or(&[]);
                    let mut a = [0u8; MAX_REPLY];
                    let n = reply.len().min(MAX_REPLY);
                    a.get_mut(..n).unwrap_or(&mut []).copy_from_slice(reply.get(..n).unwrap_or(&[]));
                    self.answer = Some((a, n as u8));
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// What an acknowledgement says is held: the frames it covers leave
    /// the flight; those sent before the latest of them, not covered, were
    /// lost (the line keeps order) and go out again.
    fn on_ack(&mut self, count: usize, runs: &[(u16, u16); ACK_RUNS], now_ms: u64) {
        let units = Self::units(self.out_len);
        let before = self.acked.first_clear(0, units);
        for k in 0..count.min(units) {
            self.acked.set(k);
        }
        for &(start, len) in runs {
            let start = usize::from(start);
            for k in start..(start + usize::from(len)).min(units) {
                self.acked.set(k);
            }
        }
        let acked = &self.acked;
        let covered = |f: &Flight| acked.all(usize::from(f.first), usize::from(f.first) + usize::from(f.units));
        let Some(latest) = self.flights.iter().filter(|f| covered(f)).map(|f| f.seq).max() else { return };
        let mut kept: heapless::Deque<Flight, IN_FLIGHT> = heapless::Deque::new();
        while let Some(f) = self.flights.pop_front() {
            if covered(&f) {
                if !f.again {
                    let sample = 8 * now_ms.saturating_sub(f.sent_ms);
                    self.srtt8 = Some(self.srtt8.map_or(sample, |s| s - s / 8 + sample / 8));
                }
            } else if f.seq < latest {
                let _ = self.lost.push_back(f);
            } else {
                let _ = kept.push_back(f);
            }
        }
        self.flights = kept;
        if self.acked.first_clear(0, units) > before {
            self.backoff = 0;
            self.ceiling = self.ceiling.saturating_mul(2).min(self.config.max_units);
        }
    }

    /// Puts units of the peer's message in place.
    fn take_units(&mut self, len: u32, first: u16, body: &[u8], input: &mut [u8]) -> Result<(), CourierError> {
        if len as usize > input.len().min(CourierConfig::MAX_MESSAGE) {
            return Err(CourierError::TooLarge(len));
        }
        if *self.in_len.get_or_insert(len) != len {
            return Ok(());
        }
        let start = usize::from(first) * UNIT;
        let units = body.len().div_ceil(UNIT).max(1);
        let end = start + body.len();
        // Whole units, the last one short only at the message's end.
        let whole = body.len().is_multiple_of(UNIT) || end == len as usize;
        if !whole || end > len as usize || (body.is_empty() && len != 0) {
            return Ok(());
        }
        if let Some(dst) = input.get_mut(start..end) {
            dst.copy_from_slice(body);
            for k in 0..units {
                self.held.set(usize::from(first) + k);
            }
        }
        let n = Self::units(len);
        self.delivered |= self.held.first_clear(0, n) == n;
        Ok(())
    }

    /// The acknowledgement of what is held of this round's message now.
    fn ack_now(&self) -> AckView {
        let n = Self::units(self.in_len.unwrap_or(0));
        let count = self.held.first_clear(0, n);
        // The runs held beyond the gap: the first two and the last.
        let mut runs = [(0u16, 0u16); ACK_RUNS];
        let (mut k, mut found) = (count, 0usize);
        while k < n {
            let start = self.held.first_set(k, n);
            if start >= n {
                break;
            }
            let end = self.held.first_clear(start, n);
            let at = found.min(ACK_RUNS - 1);
            if let Some(r) = runs.get_mut(at) {
                *r = (start as u16, (end - start).min(usize::from(u16::MAX)) as u16);
            }
            found += 1;
            k = end;
        }
        AckView {
            round: self.in_round.unwrap_or(0),
            count: count as u16,
            runs,
            complete: self.delivered,
            reply: if self.delivered { self.replied } else { None },
        }
    }

    fn send_ack<L: Write>(&mut self, port: &mut L, ack: &AckView) -> Result<(), CourierError> {
        let mut p = [0u8; ACK_HEADER + MAX_REPLY];
        let reply = ack.reply.as_ref().and_then(|(a, n)| a.get(..usize::from(*n))).unwrap_or(&[]);
        let flags = (u8::from(ack.complete) * COMPLETE) | (u8::from(ack.reply.is_some()) * REPLIED);
        let mut at = 0;
        for part in
            [&[COURIER_ACK, ack.round as u8][..], &ack.count.to_le_bytes(), &runs_bytes(&ack.runs), &[flags], reply]
        {
            p.get_mut(at..at + part.len()).ok_or(CourierError::Reply)?.copy_from_slice(part);
            at += part.len();
        }
        self.send(port, p.get(..at).unwrap_or(&[]))
    }

    /// After the caller answered: tells the peer at once (it may have
    /// nothing left to send that would ask).
    pub fn send_answer<L: Write>(&mut self, port: &mut L) -> Result<(), CourierError> {
        if self.round.is_none() || self.in_round != self.round || self.replied.is_none() {
            return Err(CourierError::Reply);
        }
        let ack = self.ack_now();
        self.send_ack(port, &ack)
    }
}

/// An acknowledgement's runs as its bytes (first unit, units: each
/// little-endian).
fn runs_bytes(runs: &[(u16, u16); ACK_RUNS]) -> [u8; 4 * ACK_RUNS] {
    let mut out = [0u8; 4 * ACK_RUNS];
    for (o, &(start, len)) in out.chunks_exact_mut(4).zip(runs) {
        let (s, l) = (start.to_le_bytes(), len.to_le_bytes());
        o.copy_from_slice(&[s[0], s[1], l[0], l[1]]);
    }
    out
}

/// An acknowledgement's fields.
struct AckView {
    round: u16,
    count: u16,
    runs: [(u16, u16); ACK_RUNS],
    complete: bool,
    reply: Option<Reply>,
}

#[cfg(test)]
impl Courier {
    /// A line of state, for a test that got stuck.
    pub(super) fn debug_state(&self) -> std::string::String {
        let units = Self::units(self.out_len);
        std::format!(
            "round {:?} out {} acked to {} frontier {} flights {} lost {} units/frame {} parity {} line {:?} backoff {} answer {} | in {:?} held to {} delivered {} replied {} last {:?} | {:?}",
            self.round,
            self.out_len,
            self.acked.first_clear(0, units),
            self.frontier,
            self.flights.len(),
            self.lost.len(),
            self.frame_units,
            self.parity,
            self.line.model(),
            self.backoff,
            self.answer.is_some(),
            self.in_len,
            self.held.first_clear(0, Self::units(self.in_len.unwrap_or(0))),
            self.delivered,
            self.replied.is_some(),
            self.last.map(|l| l.round),
            self.stats
        )
    }
}

#[cfg(test)]
mod tests;
