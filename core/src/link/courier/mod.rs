//! One message each way a round, over any byte line: the transport of
//! robots that keep driving (each round a map update one way and one the
//! other, [`crate::wire::update`]), where the [`super::Endpoint`] moves
//! one whole map once.
//!
//! A message is cut into units of [`UNIT`] bytes; a data frame
//! ([`crate::wire::frame`]: Reed-Solomon parity, CRC-32, COBS) carries a
//! run of them, tagged with the round, the message's length and the first
//! unit. The receiver acknowledges every data frame with what it holds
//! (all units below a count, and up to three runs held beyond it: the
//! first two and the last; only those it has, so that most
//! acknowledgements are short frames, which survive a damaged line), and
//! one of the whole message as many times as the line estimate says it
//! takes for one to arrive but once in a hundred. The line keeps order,
//! so a frame sent before one now acknowledged, and not acknowledged
//! itself, was lost: it is sent again at once; a timeout (twice the round trip, doubling only while the peer
//! is silent) sends everything unacknowledged again. The frames' size and
//! parity follow the line as the peer's frames judge it (the link's
//! estimate, [`super::Endpoint`]'s: what the deframer repaired and the
//! frames lost), each data frame's acknowledgement counted in its cost;
//! before any round trip was measured, or at a second silent timeout
//! running, a timeout also halves the largest frame. A
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
use crate::wire::block::{BlockDeframer, BlockShape, BLOCK_DATA};
use crate::wire::frame::{frame_len, max_payload, MAX_FRAME};
use crate::wire::rs::MAX_PARITY;
use embedded_io::{Read, ReadReady, Write, WriteReady};

mod bits;
mod receive;
mod send;

use bits::Bits;

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
/// Most units a block carries (its data: the header, the units and the
/// CRC-32, within [`BLOCK_DATA`]).
const BLOCK_UNITS: usize = (BLOCK_DATA - DATA_HEADER - 4) / UNIT;
/// Longest answer to a message.
pub const MAX_REPLY: usize = 32;
/// Bytes of a data frame before its units: kind, round, length (24 bits),
/// first unit.
const DATA_HEADER: usize = 1 + 1 + 3 + 2;
/// Bytes of an acknowledgement before its runs and answer: kind, round,
/// count, flags (the number of runs held beyond the count in its top
/// bits); each run then takes four bytes (first unit, units).
const ACK_HEADER: usize = 1 + 1 + 2 + 1;
/// Where the flags keep the number of runs.
const RUNS_SHIFT: u8 = 4;
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
/// Most copies of an acknowledgement of a whole message.
const MAX_ANSWER_COPIES: u8 = 3;

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
            && ACK_HEADER + 4 * ACK_RUNS + MAX_REPLY <= max_payload(parity)
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
    /// Data sent in blocks (a line that damages many bytes), not frames.
    pub blocks: u32,
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
    deframer: BlockDeframer,
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
    /// Data goes in blocks of this shape ([`crate::wire::block`]), each of
    /// `frame_units` units, where the line damages so many bytes that
    /// blocks carry more than frames; `None`: in frames.
    block: Option<BlockShape>,
    line: LineEstimate,
    /// Copies of an acknowledgement of a whole message: enough that all
    /// are lost once in a hundred, at most [`MAX_ANSWER_COPIES`].
    answer_copies: u8,
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
            deframer: BlockDeframer::new(),
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
            block: None,
            line: LineEstimate::default(),
            answer_copies: 1,
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
                let (pushed, pieces) = self.deframer.push(b);
                // A header not read tells nothing of the line (or a
                // block's segment whose descriptors were lost).
                judged |= self.line.judge(pieces, &pushed, false);
                let len = match pushed {
                    Ok(Some(f)) => {
                        let k = f.payload.len().min(payload.len());
                        payload.get_mut(..k).unwrap_or(&mut []).copy_from_slice(f.payload.get(..k).unwrap_or(&[]));
                        k
                    }
                    Ok(None) => continue,
                    Err(_) => {
                        self.stats.bad_frames += 1;
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
        // An acknowledgement of a whole message (the answer, mostly) ends
        // the peer's round; a lost one costs it a timeout and a resend.
        let ack = line.arrival(FrameShape {
            chunk: ACK_HEADER + MAX_REPLY - crate::wire::message::DATA_HEADER,
            parity: usize::from(best.2),
            arrival: 0.0,
            block: None,
            clean: false,
        });
        let lost = (1.0 - ack).max(1e-6);
        let copies = libm::ceilf(libm::logf(0.01) / libm::logf(lost)).clamp(1.0, f32::from(MAX_ANSWER_COPIES));
        self.answer_copies = copies as u8;
        // Blocks, weighed as the link weighs them against frames: a lost
        // one's wait counts (its arrival twice), for frames too.
        let frames = best.0
            * line.arrival(FrameShape {
                chunk: UNIT * usize::from(best.1) + DATA_HEADER - crate::wire::message::DATA_HEADER,
                parity: usize::from(best.2),
                arrival: 0.0,
                block: None,
                clean: false,
            });
        let units = BLOCK_UNITS.min(usize::from(self.config.window));
        let data = UNIT * units;
        let chunk = data + DATA_HEADER - crate::wire::message::DATA_HEADER;
        let ack = frame_len(ACK_HEADER, best.2.into()) as f32;
        let block = line.best_block(chunk).map(|(shape, _, arrival)| {
            let bytes = shape.line_len(data + DATA_HEADER) as f32 + ack;
            (shape, data as f32 / bytes * arrival * arrival)
        });
        // Only while the peer is heard: a silent line halves the frames.
        match block {
            Some((shape, goodput)) if goodput > frames && self.ceiling >= self.config.max_units => {
                self.block = Some(shape);
                (self.frame_units, self.parity) = (units as u8, best.2);
            }
            _ => {
                self.block = None;
                (self.frame_units, self.parity) = (best.1.min(self.ceiling), best.2);
            }
        }
    }
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
