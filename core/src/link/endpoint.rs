//! The endpoint state machine: one map stream out, one in, by selective
//! repeat.

use super::Clock;
use crate::classes::CLASS_TABLE_VERSION;
use crate::map::{LocalMap, VoxelSink, VoxelStorage};
use crate::wire::codec::{CodecModel, DecodeError, MapDecoder, MapEncoder};
use crate::wire::frame::{Deframer, MAX_FRAME, MAX_PAYLOAD};
use crate::wire::message::{
    AbortReason, Ack, Hello, MapHeader, Message, MessageError, SackBlock, ACK_ALL_BLOCKS, ACK_COMPLETE, ACK_FINISHED,
    DATA_OVERHEAD, MAX_SACK, OFFSET_MODULUS,
};
use embedded_io::{Read, ReadReady, Write, WriteReady};

/// Bytes of map stream each side buffers: the sender what is not yet
/// acknowledged, the receiver what arrived ahead of a gap.
pub const STREAM_BUFFER: usize = 2048;
/// Largest record of the stream: a length byte and up to 255 bytes.
const MAX_RECORD: usize = 256;
/// Most stream bytes in flight: the receiver's buffer less one partial
/// record it may hold before the first gap (at 115200 baud, 0.69 s: on a
/// line that breaks most small frames, the oldest bytes may need a dozen
/// round trips, and the window must not close meanwhile).
const WINDOW: u32 = (STREAM_BUFFER - MAX_RECORD) as u32;
/// Most frames in flight (a window of the smallest frames a bad line needs).
const MAX_SEGMENTS: usize = 128;
/// Segments kept free for cutting lost ones smaller: a frame too long for
/// the line must always be able to shrink.
const CUT_RESERVE: usize = 24;
/// Bytes of voxel encoding per codec chunk in the stream.
const RECORD_CHUNK: usize = 240;
/// The receiver acknowledges after this many data frames, or at once when
/// a frame asks (poll) or the map is complete.
const ACK_EVERY: u8 = 4;

/// Timing and sizes of a link.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkConfig {
    /// Retransmission timeout (ms) until the round trip is measured
    /// (default 150); then twice the smoothed round trip, doubling on each
    /// timeout in a row.
    pub timeout_ms: u32,
    /// Ceiling of the retransmission timeout (ms, default 800).
    pub max_timeout_ms: u32,
    /// Probes of a line on which nothing is heard before giving up (default
    /// 100: with the timeout's ceiling, over a minute).
    pub max_retries: u8,
    /// Largest data of a frame (bytes, default 240).
    pub max_chunk: u16,
    /// Smallest data of a frame the size adapts down to (bytes, default 8).
    pub min_chunk: u16,
    /// Give up when nothing valid arrived for this long (ms, default 90000:
    /// longer than a sender's whole retry budget, so that on a bad line the
    /// retries decide, and silence only catches a peer that is gone).
    pub silence_ms: u32,
    /// After both maps are through, keep answering for at most this long
    /// (ms, default 3000) unless the peer says it is finished too: a peer
    /// whose last acknowledgement was lost still gets one.
    pub linger_ms: u32,
    /// The line carries one direction at a time (a radio modem, RS-485): the
    /// two maps go one after the other, each stop-and-wait (one frame in
    /// flight). Robot 0 sends first; any other robot starts its own map once
    /// it holds the peer's. Default off (both maps at once, each with a
    /// window of frames in flight).
    pub half_duplex: bool,
}

impl Default for LinkConfig {
    fn default() -> Self {
        LinkConfig {
            timeout_ms: 150,
            max_timeout_ms: 800,
            max_retries: 100,
            max_chunk: 240,
            min_chunk: 8,
            silence_ms: 90_000,
            linger_ms: 3000,
            half_duplex: false,
        }
    }
}

/// Why a link failed. The staging map must then be discarded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkError {
    /// The byte stream reported an error of this kind (`NotConnected`,
    /// `BrokenPipe`, `ConnectionReset`: the peer closed the line).
    Io(embedded_io::ErrorKind),
    /// `max_retries` probes in a row went unanswered.
    GaveUp {
        /// Stream offset of the bytes.
        seq: u32,
    },
    /// Nothing valid arrived for `silence_ms`.
    Silent,
    /// The peer aborted its transfer or ours.
    PeerAborted(AbortReason),
    /// The peer's map does not fit the staging map.
    TooLarge {
        /// Voxels announced.
        voxels: u32,
    },
    /// Different voxel size or class table.
    Incompatible,
    /// The peer speaks another version of the link protocol (told apart at
    /// its first intact frame).
    Version(u8),
    /// The peer's `Hello` holds a non-finite voxel size.
    BadHello,
    /// A chunk passed its CRC but did not decode.
    Decode(DecodeError),
    /// The received map's digest differs from the announced one.
    Digest,
    /// The staging map cannot take the map (configuration).
    Setup,
}

impl core::fmt::Display for LinkError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LinkError::Io(
                embedded_io::ErrorKind::NotConnected
                | embedded_io::ErrorKind::BrokenPipe
                | embedded_io::ErrorKind::ConnectionReset
                | embedded_io::ErrorKind::ConnectionAborted,
            ) => f.write_str("the peer closed the line"),
            LinkError::Io(kind) => write!(f, "I/O error on the line ({kind:?})"),
            LinkError::GaveUp { seq } => write!(f, "gave up: stream bytes at {seq} unacknowledged after all retries"),
            LinkError::Silent => f.write_str("peer silent"),
            LinkError::PeerAborted(r) => write!(f, "peer aborted the transfer ({r:?})"),
            LinkError::TooLarge { voxels } => write!(f, "peer map of {voxels} voxels does not fit"),
            LinkError::Incompatible => f.write_str("peer uses another voxel size or class table"),
            LinkError::Version(v) => write!(
                f,
                "the peer speaks link protocol version {v}, this robot version {}: run the same cosem release on both",
                crate::wire::PROTOCOL_VERSION
            ),
            LinkError::BadHello => {
                f.write_str("the peer's Hello is invalid: its voxel size (resolution) is not finite")
            }
            LinkError::Decode(e) => write!(f, "chunk did not decode: {e}"),
            LinkError::Digest => f.write_str("received map differs from the announced one (digest)"),
            LinkError::Setup => f.write_str("link set-up error"),
        }
    }
}

impl core::error::Error for LinkError {}

/// What a link moved.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStats {
    /// Bytes written to the line.
    pub bytes_sent: u64,
    /// Bytes read from the line.
    pub bytes_received: u64,
    /// Frames sent (retransmissions included).
    pub frames_sent: u32,
    /// Valid frames received.
    pub frames_received: u32,
    /// Frames resent.
    pub retransmissions: u32,
    /// Frames rejected (CRC, COBS, malformed).
    pub bad_frames: u32,
    /// Frames repaired (one flipped bit or one duplicated byte) and used.
    pub repaired_frames: u32,
    /// Voxels received.
    pub voxels_received: u32,
    /// Encoded voxel bytes sent (chunk data only, first transmissions).
    pub chunk_bytes_sent: u64,
    /// Data frames received that brought no byte not held already (a copy
    /// sent while its acknowledgement was on the way or lost).
    pub duplicates: u32,
    /// Acknowledgements sent.
    pub acks_sent: u32,
}

/// Where an endpoint stands after a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Progress {
    /// Still working.
    Busy,
    /// Both maps are through and the linger time is over.
    Done,
}

/// The memory a link works in: the stream buffers of both directions, the
/// bookkeeping of frames in flight and the codec's models (about 14 KiB). Apart from the
/// [`Endpoint`], so that a robot keeps it in a static while the endpoint,
/// which moves between a robot's stages, stays small.
pub struct LinkBuffers {
    tx: [u8; STREAM_BUFFER],
    rx: [u8; STREAM_BUFFER],
    have: [u32; STREAM_BUFFER / 32],
    segs: heapless::Vec<Segment, MAX_SEGMENTS>,
    tx_model: CodecModel,
    rx_model: CodecModel,
}

impl LinkBuffers {
    /// Buffers for one endpoint.
    pub const fn new() -> Self {
        LinkBuffers {
            tx: [0; STREAM_BUFFER],
            rx: [0; STREAM_BUFFER],
            have: [0; STREAM_BUFFER / 32],
            segs: heapless::Vec::new(),
            tx_model: CodecModel::new(),
            rx_model: CodecModel::new(),
        }
    }
}

/// A link's buffers borrowed piece by piece: what an [`Endpoint`] works
/// in, and gives back at its end ([`Endpoint::finish`]) so that one set
/// of buffers serves several exchanges in a row (a team robot's peers).
pub struct LinkParts<'a> {
    tx: &'a mut [u8; STREAM_BUFFER],
    rx: &'a mut [u8; STREAM_BUFFER],
    have: &'a mut [u32; STREAM_BUFFER / 32],
    segs: &'a mut heapless::Vec<Segment, MAX_SEGMENTS>,
    tx_model: &'a mut CodecModel,
    rx_model: &'a mut CodecModel,
}

impl<'a> From<&'a mut LinkBuffers> for LinkParts<'a> {
    fn from(b: &'a mut LinkBuffers) -> Self {
        let LinkBuffers { tx, rx, have, segs, tx_model, rx_model } = b;
        LinkParts { tx, rx, have, segs, tx_model, rx_model }
    }
}

/// What an ended [`Endpoint`] gives back.
pub struct Finished<'a, R: VoxelSink> {
    /// The scratch its map was ordered in (`None`: it sent no map).
    pub scratch: Option<&'a mut [u32]>,
    /// The staging map, holding the peer's map when it arrived whole.
    pub staging: Option<&'a mut R>,
    /// The link's buffers, for the next endpoint.
    pub buffers: LinkParts<'a>,
}

impl Default for LinkBuffers {
    fn default() -> Self {
        Self::new()
    }
}

/// One frame's worth of the stream in flight.
#[derive(Clone, Copy, Debug)]
struct Segment {
    start: u32,
    len: u16,
    sends: u8,
    /// Known lost: waits for retransmission.
    lost: bool,
    /// Transmission number of its last send (a later number acknowledged
    /// while this one is not means this one was lost: the line keeps order).
    order: u32,
    /// Milliseconds (wrapping) of its last send.
    sent_at: u32,
}

/// The sending half: the map as a stream of records (header, then codec
/// chunks), kept from the first unacknowledged byte on.
struct Tx<'a, S: VoxelStorage> {
    encoder: MapEncoder<'a, S>,
    header: MapHeader,
    header_queued: bool,
    ring: &'a mut [u8; STREAM_BUFFER],
    /// Stream offsets: everything before `acked` is held by the receiver,
    /// before `sent_end` was sent at least once, before `produced` encoded.
    acked: u32,
    sent_end: u32,
    produced: u32,
    segs: &'a mut heapless::Vec<Segment, MAX_SEGMENTS>,
    order: u32,
    acked_order: u32,
    /// The receiver said it holds the whole map.
    complete: bool,
    /// Data bytes per frame, from the estimated byte error rate.
    size: usize,
    srtt: Option<u32>,
    /// Shortest round trip seen (ms).
    min_rtt: u32,
    /// Timeouts in a row with no progress at all.
    backoff: u32,
    /// When an acknowledgement last took bytes off our hands.
    last_progress: u64,
    /// When the stalled line was last probed.
    last_probe: u64,
    /// Resends while nothing new can go (every fourth asks for an answer).
    idle_resends: u32,
}

impl<S: VoxelStorage> Tx<'_, S> {
    /// Encodes records into the buffer while a whole record fits.
    fn fill(&mut self) -> Result<(), LinkError> {
        loop {
            if STREAM_BUFFER - (self.produced.wrapping_sub(self.acked) as usize) < MAX_RECORD {
                return Ok(());
            }
            let mut rec = [0u8; MAX_RECORD];
            let body = rec.get_mut(1..).ok_or(LinkError::Setup)?;
            let n = if !self.header_queued {
                self.header_queued = true;
                self.header.encode(body).map_err(|_| LinkError::Setup)?
            } else if self.encoder.is_done() {
                return Ok(());
            } else {
                let chunk = body.get_mut(..RECORD_CHUNK).ok_or(LinkError::Setup)?;
                self.encoder.next_chunk(chunk).map_err(|_| LinkError::Setup)?
            };
            rec[0] = u8::try_from(n).map_err(|_| LinkError::Setup)?;
            for &b in rec.get(..=n).ok_or(LinkError::Setup)? {
                self.ring[self.produced as usize % STREAM_BUFFER] = b;
                self.produced = self.produced.wrapping_add(1);
            }
        }
    }

    fn exhausted(&self) -> bool {
        self.header_queued && self.encoder.is_done()
    }

    /// Bytes allowed in flight: 1 KiB until something came back (frames
    /// sized before the line was known may all be lost, and must not fill
    /// the window), then all the receiver can hold.
    fn window(&self) -> u32 {
        if self.srtt.is_some() {
            WINDOW
        } else {
            1024
        }
    }

    fn can_send_new(&self, config: &LinkConfig) -> bool {
        self.sent_end != self.produced
            && self.sent_end.wrapping_sub(self.acked) < self.window()
            && self.segs.len() + CUT_RESERVE < MAX_SEGMENTS
            && (!config.half_duplex || self.segs.is_empty())
    }

    /// How long bytes may go unacknowledged before they are sent again:
    /// twice the smoothed round trip (before any, `timeout_ms`).
    fn rto(&self, config: &LinkConfig) -> u32 {
        let base = match self.srtt {
            Some(s) => (2 * s + 20).max(30),
            None => config.timeout_ms,
        };
        base.min(config.max_timeout_ms)
    }

    /// Sizes frames for the most data per byte of line. A frame of `L`
    /// bytes (`h` of them overhead) arrives whole with probability
    /// `exp(-tL)` and is repaired with probability `cL exp(-tL)` (one error
    /// of the repairable kind), so data per byte sent is `g(L) = (L - h) / L
    /// * exp(-tL) * (1 + cL)`. `ln g` is concave: its peak is where the
    /// derivative `h / (L (L - h)) - t + c / (1 + cL)` crosses zero, found
    /// by bisection (without repair, `L = (h + sqrt(h^2 + 4h/t)) / 2`).
    fn resize(&mut self, line: LineModel, config: &LinkConfig) {
        let h = DATA_OVERHEAD as f32;
        let slope = |l: f32| h / (l * (l - h)) - line.rate + line.repairable / (1.0 + line.repairable * l);
        let (mut lo, mut hi) = (h + f32::from(config.min_chunk), h + f32::from(config.max_chunk));
        if slope(hi) >= 0.0 {
            lo = hi;
        }
        for _ in 0..24 {
            let mid = 0.5 * (lo + hi);
            if slope(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        self.size = ((lo - h) as usize).clamp(usize::from(config.min_chunk), usize::from(config.max_chunk));
    }

    /// Cuts segment `i` to the current frame size; the rest stays lost.
    fn cut(&mut self, i: usize) {
        let Some(s) = self.segs.get(i).copied() else { return };
        if usize::from(s.len) <= self.size || self.segs.is_full() {
            return;
        }
        let keep = self.size as u16;
        let rest = Segment { start: s.start.wrapping_add(u32::from(keep)), len: s.len - keep, ..s };
        if self.segs.insert(i + 1, rest).is_ok() {
            if let Some(first) = self.segs.get_mut(i) {
                first.len = keep;
            }
        }
    }

    fn transmit<IO: Write>(
        &mut self,
        i: usize,
        poll: bool,
        io: &mut IO,
        now: u64,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        let seg = self.segs.get_mut(i).ok_or(LinkError::Setup)?;
        let mut data = [0u8; MAX_PAYLOAD];
        let len = usize::from(seg.len);
        for (k, d) in data.iter_mut().take(len).enumerate() {
            *d = self.ring[seg.start.wrapping_add(k as u32) as usize % STREAM_BUFFER];
        }
        self.order += 1;
        seg.order = self.order;
        seg.sends = seg.sends.saturating_add(1);
        seg.sent_at = now as u32;
        seg.lost = false;
        let offset = (seg.start % OFFSET_MODULUS) as u16;
        let msg = Message::Data { offset, poll, data: data.get(..len).unwrap_or(&[]) };
        send_msg(io, &msg, stats)?;
        Ok(())
    }

    /// Sends at most one data frame: a lost one first (cut to the current
    /// size), else new bytes, else bytes unacknowledged for a while again.
    /// The last uses a line that would idle: the oldest bytes hold the
    /// window, so on a bad line they go out again and again until one copy
    /// gets through. When not a byte came from the peer (`heard`) for four
    /// timeouts the line may be down: then only the oldest bytes, at a
    /// timeout that doubles.
    fn send_next<IO: Write>(
        &mut self,
        io: &mut IO,
        now: u64,
        heard: u64,
        line: LineModel,
        config: &LinkConfig,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        if self.complete {
            return Ok(());
        }
        self.fill()?;
        // Frames sized for the line as the peer's frames show it (after a
        // stall, no larger than the probes were).
        let probe = self.size;
        self.resize(line, config);
        if self.backoff > 0 {
            self.size = self.size.min(probe);
        }
        if let Some(i) = self.segs.iter().position(|s| s.lost) {
            self.cut(i);
            let more = self.segs.iter().skip(i + 1).any(|s| s.lost);
            let poll = !more && !self.can_send_new(config);
            // One copy: since the deframer repairs single errors, extra
            // copies of bytes lost again and again no longer paid (measured).
            stats.retransmissions += 1;
            return self.transmit(i, poll, io, now, stats);
        }
        if self.can_send_new(config) {
            let room = self.window().saturating_sub(self.sent_end.wrapping_sub(self.acked)) as usize;
            let len = self.size.min(self.produced.wrapping_sub(self.sent_end) as usize).min(room);
            let seg =
                Segment { start: self.sent_end, len: len as u16, sends: 0, lost: false, order: 0, sent_at: now as u32 };
            if self.segs.is_empty() {
                // The timers start with the first bytes in flight.
                self.last_progress = now;
            }
            self.segs.push(seg).map_err(|_| LinkError::Setup)?;
            self.sent_end = self.sent_end.wrapping_add(len as u32);
            self.fill()?;
            stats.chunk_bytes_sent += len as u64;
            let poll = !self.can_send_new(config);
            return self.transmit(self.segs.len() - 1, poll, io, now, stats);
        }
        if self.segs.is_empty() {
            return Ok(());
        }
        let rto = self.rto(config);
        if now >= self.last_progress.max(heard) + 4 * u64::from(rto) {
            let wait = u64::from(rto.saturating_mul(1 << self.backoff.min(8)).min(config.max_timeout_ms.max(rto)));
            if now < self.last_probe + wait {
                return Ok(());
            }
            // Nothing heard: the line may have got worse. Size for what the
            // frames that do arrive say, and at most half the last size.
            if self.backoff >= u32::from(config.max_retries) {
                return Err(LinkError::GaveUp { seq: self.acked });
            }
            self.backoff += 1;
            self.last_probe = now;
            let half = (self.size / 2).max(usize::from(config.min_chunk));
            self.resize(line, config);
            self.size = self.size.min(half);
            self.cut(0);
            stats.retransmissions += 1;
            return self.transmit(0, true, io, now, stats);
        }
        // On a clean line, bytes not acknowledged in a timeout; on a lossy
        // one, sooner (a round trip and a half): there the oldest bytes are
        // likely lost again, and the line would idle meanwhile.
        let wait = match self.srtt {
            Some(s) if line.residual(self.size + DATA_OVERHEAD) > 0.005 => s + s / 2 + 5,
            _ => rto,
        };
        let due = self.segs.iter().take(8).position(|s| (now as u32).wrapping_sub(s.sent_at) >= wait);
        if let Some(i) = due {
            self.idle_resends += 1;
            self.cut(i);
            stats.retransmissions += 1;
            return self.transmit(i, self.idle_resends.is_multiple_of(4), io, now, stats);
        }
        Ok(())
    }

    /// Takes an acknowledgement: drops what it covers, marks lost what was
    /// sent before something it covers, measures the round trip.
    fn on_ack(&mut self, ack: &Ack, now: u64, config: &LinkConfig) {
        let ahead = ack.cum.wrapping_sub(self.acked as u16) as u32;
        if ahead > self.sent_end.wrapping_sub(self.acked) {
            return; // stale or foreign
        }
        let cum = self.acked.wrapping_add(ahead);
        let mut ranges = [(0u32, 0u32); MAX_SACK];
        for (r, b) in ranges.iter_mut().zip(ack.blocks()) {
            let from = cum.wrapping_add(u32::from(b.start));
            *r = (from, from.wrapping_add(u32::from(b.len)));
        }
        let held = |s: &Segment| {
            let end = s.start.wrapping_add(u32::from(s.len));
            end.wrapping_sub(self.acked) <= ahead
                || ranges
                    .iter()
                    .any(|&(a, b)| b != a && s.start.wrapping_sub(a) < 1 << 30 && b.wrapping_sub(end) < 1 << 30)
        };
        let mut progress = ahead > 0;
        // The round trip of the last-sent bytes acknowledged now (sent once:
        // older ones may have waited behind a gap, or for a lost ack).
        let mut freshest: Option<Segment> = None;
        let mut i = 0;
        while let Some(s) = self.segs.get(i).copied() {
            if held(&s) {
                // An ack sooner than any round trip after a resend is for an
                // earlier copy: its order says nothing.
                let since = (now as u32).wrapping_sub(s.sent_at);
                let ambiguous = s.sends > 1 && self.min_rtt != u32::MAX && since < self.min_rtt;
                if !ambiguous {
                    if freshest.is_none_or(|f| s.order > f.order) {
                        freshest = Some(s);
                    }
                    self.acked_order = self.acked_order.max(s.order);
                }
                self.segs.remove(i);
                progress = true;
            } else {
                i += 1;
            }
        }
        if let Some(s) = freshest {
            let sample = (now as u32).wrapping_sub(s.sent_at).min(config.max_timeout_ms);
            self.min_rtt = self.min_rtt.min(sample);
            self.srtt = Some(self.srtt.map_or(sample, |r| (7 * r + sample) / 8));
        }
        self.acked = cum;
        // With all its blocks, the ack describes the whole stream: what it
        // does not hold is missing. Otherwise it describes the stream up to
        // the end of its next-to-last block; beyond, nothing is known.
        let all = ack.flags & ACK_ALL_BLOCKS != 0;
        let known = ranges.get(..usize::from(ack.blocks).saturating_sub(1)).unwrap_or(&[]).last().map_or(cum, |r| r.1);
        // Only bytes out for a round trip: an ack for an earlier copy of
        // what was resent since says nothing of what followed that copy.
        let settled = self.srtt.unwrap_or(0);
        for s in self.segs.iter_mut() {
            let within = all || known.wrapping_sub(s.start.wrapping_add(u32::from(s.len))) < 1 << 30;
            let out_long = (now as u32).wrapping_sub(s.sent_at) >= settled;
            if !s.lost && s.order < self.acked_order && within && out_long {
                s.lost = true;
            }
        }
        if progress {
            self.backoff = 0;
            self.last_progress = now;
        }
        if ack.flags & ACK_COMPLETE != 0 && self.exhausted() && self.acked == self.produced {
            self.complete = true;
            self.segs.clear();
        }
    }
}

/// The receiving half: stream bytes into a ring until the records before
/// the first gap are whole, then records into the map.
struct Rx<'a, S: VoxelSink> {
    /// `None`: this endpoint receives nothing.
    map: Option<&'a mut S>,
    ring: &'a mut [u8; STREAM_BUFFER],
    have: &'a mut [u32; STREAM_BUFFER / 32],
    /// Everything before `cum` arrived; before `consumed` was decoded;
    /// `highest` is one past the last byte that arrived.
    cum: u32,
    consumed: u32,
    highest: u32,
    header: Option<MapHeader>,
    /// The codec's model, until the header names the map; then the decoder's.
    model: Option<&'a mut CodecModel>,
    decoder: Option<MapDecoder<'a>>,
    done: bool,
    /// Last stream byte that arrived new.
    latest: u32,
    /// Data frames since the last acknowledgement.
    unacked: u8,
    ack_now: bool,
}

impl<S: VoxelSink> Rx<'_, S> {
    fn bit(&self, pos: u32) -> bool {
        let p = pos as usize % STREAM_BUFFER;
        self.have.get(p / 32).is_some_and(|w| w & (1 << (p % 32)) != 0)
    }

    fn set_bit(&mut self, pos: u32, on: bool) {
        let p = pos as usize % STREAM_BUFFER;
        if let Some(w) = self.have.get_mut(p / 32) {
            if on {
                *w |= 1 << (p % 32);
            } else {
                *w &= !(1 << (p % 32));
            }
        }
    }

    fn on_data(
        &mut self,
        offset: u16,
        poll: bool,
        data: &[u8],
        resolution: f32,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        if self.map.is_none() {
            return Ok(());
        }
        // The frame's place in the stream, near what we hold.
        let ahead = (u32::from(offset).wrapping_sub(self.cum) % OFFSET_MODULUS) as i64;
        let delta = if ahead >= i64::from(OFFSET_MODULUS / 2) { ahead - i64::from(OFFSET_MODULUS) } else { ahead };
        let start = i64::from(self.cum) + delta;
        let limit = i64::from(self.consumed) + STREAM_BUFFER as i64;
        let mut fresh = false;
        for (k, &b) in data.iter().enumerate() {
            let pos = start + k as i64;
            if pos < i64::from(self.cum) || pos < 0 {
                continue;
            }
            if pos >= limit {
                break;
            }
            let pos = pos as u32;
            fresh |= !self.bit(pos);
            self.ring[pos as usize % STREAM_BUFFER] = b;
            self.set_bit(pos, true);
            self.latest = pos;
        }
        let end = (start + data.len() as i64).clamp(0, limit) as u32;
        if !fresh {
            stats.duplicates += 1;
        }
        self.highest = self.highest.max(end);
        while i64::from(self.cum) < limit && self.bit(self.cum) {
            self.cum += 1;
        }
        self.unacked = self.unacked.saturating_add(1);
        if poll || self.unacked >= ACK_EVERY {
            self.ack_now = true;
        }
        self.take_records(resolution, stats)
    }

    /// Decodes every whole record before the first gap.
    fn take_records(&mut self, resolution: f32, stats: &mut LinkStats) -> Result<(), LinkError> {
        while self.cum > self.consumed && !self.done {
            let len = usize::from(self.ring[self.consumed as usize % STREAM_BUFFER]);
            if len == 0 {
                return Err(LinkError::Decode(DecodeError::Empty));
            }
            if ((self.cum - self.consumed) as usize) < 1 + len {
                return Ok(());
            }
            let mut rec = [0u8; MAX_RECORD];
            for (k, r) in rec.iter_mut().take(len).enumerate() {
                *r = self.ring[(self.consumed as usize + 1 + k) % STREAM_BUFFER];
            }
            for k in 0..=len as u32 {
                self.set_bit(self.consumed + k, false);
            }
            self.consumed += 1 + len as u32;
            self.record(rec.get(..len).unwrap_or(&[]), resolution, stats)?;
        }
        Ok(())
    }

    fn record(&mut self, rec: &[u8], resolution: f32, stats: &mut LinkStats) -> Result<(), LinkError> {
        let Some(map) = self.map.as_mut() else { return Ok(()) };
        match (self.header, self.decoder.as_mut()) {
            (None, _) => {
                let h = MapHeader::decode(rec).map_err(|_| LinkError::Decode(DecodeError::Truncated))?;
                if h.class_table != CLASS_TABLE_VERSION || (h.resolution - resolution).abs() > 1e-6 * resolution {
                    return Err(LinkError::Incompatible);
                }
                if h.voxel_count as usize > map.capacity() {
                    return Err(LinkError::TooLarge { voxels: h.voxel_count });
                }
                map.clear();
                self.header = Some(h);
                let model = self.model.take().ok_or(LinkError::Setup)?;
                self.decoder = Some(MapDecoder::new(h.voxel_count as usize, model));
            }
            (Some(_), Some(dec)) => {
                let n = dec.decode_chunk(rec, map).map_err(LinkError::Decode)?;
                stats.voxels_received += n as u32;
            }
            (Some(_), None) => return Err(LinkError::Setup),
        }
        if let (Some(h), Some(dec)) = (self.header, self.decoder.as_ref()) {
            if dec.is_complete() {
                if dec.digest() != h.digest {
                    return Err(LinkError::Digest);
                }
                self.done = true;
                self.ack_now = true;
            }
        }
        Ok(())
    }

    /// What we hold, as an acknowledgement.
    fn ack(&self, finished: bool) -> Ack {
        let mut ack = Ack { cum: self.cum as u16, ..Ack::default() };
        if self.done {
            ack.flags |= ACK_COMPLETE;
        }
        if finished {
            ack.flags |= ACK_FINISHED;
        }
        // The runs held after `cum`, first ones first; if there are more
        // than fit, the last slot goes to the run that grew last.
        let mut runs = [(0u32, 0u32); MAX_SACK + 1];
        let mut found = 0;
        let mut pos = self.cum;
        while pos < self.highest && found < runs.len() {
            if !self.bit(pos) {
                pos += 1;
                continue;
            }
            let from = pos;
            while pos < self.highest && self.bit(pos) {
                pos += 1;
            }
            runs[found] = (from, pos);
            found += 1;
        }
        if found > MAX_SACK {
            let latest = self.latest.max(self.cum);
            let (mut from, mut to) = (latest, latest);
            while from > self.cum && self.bit(from - 1) {
                from -= 1;
            }
            while to < self.highest && self.bit(to) {
                to += 1;
            }
            if from > runs[MAX_SACK - 2].1 && to > from {
                runs[MAX_SACK - 1] = (from, to);
            }
        } else {
            ack.flags |= ACK_ALL_BLOCKS;
        }
        for &(from, to) in runs.iter().take(found.min(MAX_SACK)) {
            if let Some(slot) = ack.sack.get_mut(usize::from(ack.blocks)) {
                *slot = SackBlock { start: (from - self.cum) as u16, len: (to - from) as u16 };
                ack.blocks += 1;
            }
        }
        ack
    }
}

/// What the line does to frames, per byte: `rate` of any damage and
/// `repairable`, the part the deframer repairs when it is a frame's only
/// damage (a flipped bit, a duplicated byte). Both as `-ln(1 - p)`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct LineModel {
    rate: f32,
    repairable: f32,
}

impl LineModel {
    /// The rate of damage that costs a frame of `len` bytes: `u` with
    /// `exp(-u len)` the chance that it arrives usable.
    fn residual(&self, len: usize) -> f32 {
        let l = len.max(1) as f32;
        self.rate - libm::log1pf(self.repairable * l) / l
    }
}

/// The line, judged by the frames that arrive: a frame of `L` bytes
/// arrives whole with probability `exp(-tL)` and repaired with probability
/// `cL exp(-tL)`, so from the fractions of whole and repaired frames and
/// their mean length, `t = -ln(whole) / L` and `c = repaired / whole / L`.
/// Counts halve now and then, to follow a line that changes.
#[derive(Clone, Copy, Debug, Default)]
struct LineEstimate {
    good: u32,
    repaired: u32,
    bad: u32,
    bytes: u32,
    /// Bytes of the frame being received.
    current: u32,
}

impl LineEstimate {
    fn byte(&mut self) {
        self.current = self.current.saturating_add(1);
    }

    fn frame(&mut self, whole: bool, repaired: bool) {
        if repaired {
            self.repaired += 1;
        } else if whole {
            self.good += 1;
        } else {
            self.bad += 1;
        }
        self.bytes = self.bytes.saturating_add(core::mem::take(&mut self.current));
        if self.good + self.repaired + self.bad > 400 {
            self.good /= 2;
            self.repaired /= 2;
            self.bad /= 2;
            self.bytes /= 2;
        }
    }

    /// The estimate, with a prior of one error in 2000 bytes worth four
    /// whole frames of 100 bytes.
    fn model(&self) -> LineModel {
        const PRIOR_FRAMES: f32 = 4.0;
        const PRIOR_RATE: f32 = 1.0 / 2000.0;
        let frames = (self.good + self.repaired + self.bad) as f32 + PRIOR_FRAMES;
        let whole = self.good as f32 + PRIOR_FRAMES * libm::expf(-PRIOR_RATE * 100.0);
        let mean = ((self.bytes as f32 + PRIOR_FRAMES * 100.0) / frames).max(1.0);
        let rate = (-libm::logf((whole / frames).max(0.01)) / mean).min(0.7);
        let repairable = (self.repaired as f32 / whole / mean).min(rate);
        LineModel { rate, repairable }
    }
}

type TxParts<'a> = (&'a mut [u8; STREAM_BUFFER], &'a mut heapless::Vec<Segment, MAX_SEGMENTS>, &'a mut CodecModel);

/// One robot's end of the link: sends its map, receives the peer's.
pub struct Endpoint<'a, M: VoxelStorage, R: VoxelSink> {
    config: LinkConfig,
    robot_id: u8,
    resolution: f32,
    tx: Option<Tx<'a, M>>,
    /// The sending half's buffers when there is no map to send.
    tx_spare: Option<TxParts<'a>>,
    rx: Rx<'a, R>,
    deframer: Deframer,
    line: LineEstimate,
    started: bool,
    last_heard: u64,
    /// When any byte last arrived, whole frame or not: the line is alive.
    last_byte: u64,
    /// We said we are finished (at this time).
    finished_at: Option<u64>,
    peer_finished: bool,
    /// What the peer's `Hello` said: whether it takes our map (`None`
    /// until heard).
    peer_takes_map: Option<bool>,
    /// The peer's robot id, from its `Hello`.
    peer_id: Option<u8>,
    failed: Option<LinkError>,
    stats: LinkStats,
}

/// Sends one message as a frame; returns the bytes written.
fn send_msg<IO: Write>(io: &mut IO, msg: &Message<'_>, stats: &mut LinkStats) -> Result<usize, LinkError> {
    let mut frame = [0u8; MAX_FRAME];
    let f = msg.to_frame(&mut frame).map_err(|_| LinkError::Setup)?;
    io.write_all(frame.get(..f).unwrap_or(&[])).map_err(io_error)?;
    io.flush().map_err(io_error)?;
    stats.bytes_sent += f as u64;
    stats.frames_sent += 1;
    Ok(f)
}

/// A stream error as a link error, keeping its kind.
fn io_error<E: embedded_io::Error>(e: E) -> LinkError {
    LinkError::Io(e.kind())
}

impl<'a, M: VoxelStorage, R: VoxelSink> Endpoint<'a, M, R> {
    /// An endpoint that will send `map` (Morton order prepared in `scratch`,
    /// one `u32` per voxel; `None`: send nothing) as transfer `map_id`, and
    /// receive the peer's map into `staging` (cleared first; `None`: receive
    /// nothing), working in `buffers`. At least one of the two maps must be
    /// given.
    pub fn new(
        config: LinkConfig,
        robot_id: u8,
        map_id: u32,
        anchor_time_us: u64,
        map: Option<(&'a LocalMap<M>, &'a mut [u32])>,
        mut staging: Option<&'a mut R>,
        buffers: impl Into<LinkParts<'a>>,
    ) -> Result<Self, LinkError> {
        let LinkParts { tx: tx_ring, rx: rx_ring, have, segs, tx_model, rx_model } = buffers.into();
        segs.clear();
        have.fill(0);
        if config.max_chunk < config.min_chunk.max(1)
            || usize::from(config.max_chunk) > MAX_PAYLOAD - 4
            || config.max_retries == 0
        {
            return Err(LinkError::Setup);
        }
        let config = LinkConfig { min_chunk: config.min_chunk.max(1), ..config };
        let resolution = match (&staging, &map) {
            (Some(s), _) => s.resolution(),
            (None, Some((m, _))) => m.resolution(),
            (None, None) => return Err(LinkError::Setup),
        };
        let (tx, tx_spare) = match map {
            None => (None, Some((tx_ring, segs, tx_model))),
            Some((m, scratch)) => {
                if (m.resolution() - resolution).abs() > 1e-6 * resolution {
                    return Err(LinkError::Setup);
                }
                let bounds = m.bounds().map(|(lo, hi)| [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]]).unwrap_or([0.0; 6]);
                let encoder = MapEncoder::new(m, scratch, tx_model).map_err(|_| LinkError::Setup)?;
                let header = MapHeader {
                    map_id,
                    robot_id,
                    class_table: CLASS_TABLE_VERSION,
                    anchor_time_us,
                    voxel_count: m.len() as u32,
                    resolution: m.resolution(),
                    bounds,
                    digest: encoder.digest(),
                };
                let mut tx = Tx {
                    encoder,
                    header,
                    header_queued: false,
                    ring: tx_ring,
                    acked: 0,
                    sent_end: 0,
                    produced: 0,
                    segs,
                    order: 0,
                    acked_order: 0,
                    complete: false,
                    size: usize::from(config.max_chunk),
                    srtt: None,
                    min_rtt: u32::MAX,
                    backoff: 0,
                    last_progress: 0,
                    last_probe: 0,
                    idle_resends: 0,
                };
                tx.resize(LineEstimate::default().model(), &config);
                (Some(tx), None)
            }
        };
        if let Some(s) = staging.as_mut() {
            s.clear();
        }
        let receiving = staging.is_some();
        Ok(Endpoint {
            config,
            robot_id,
            resolution,
            tx,
            tx_spare,
            rx: Rx {
                map: staging,
                ring: rx_ring,
                have,
                cum: 0,
                consumed: 0,
                highest: 0,
                header: None,
                model: Some(rx_model),
                decoder: None,
                done: !receiving,
                latest: 0,
                unacked: 0,
                ack_now: false,
            },
            deframer: Deframer::new(),
            line: LineEstimate::default(),
            started: false,
            last_heard: 0,
            last_byte: 0,
            finished_at: None,
            peer_finished: false,
            peer_takes_map: None,
            peer_id: None,
            failed: None,
            stats: LinkStats::default(),
        })
    }

    /// What moved so far.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Whether the peer's map arrived whole (its digest checked), or this
    /// endpoint receives nothing.
    pub fn received(&self) -> bool {
        self.rx.done
    }

    /// Whether the peer said it holds our whole map.
    pub fn sent(&self) -> bool {
        self.tx.as_ref().is_none_or(|t| t.complete) || self.peer_takes_map == Some(false)
    }

    /// Whether the peer takes our map, from its `Hello` (`None`: not heard
    /// yet). `Some(false)`: a one-sided exchange, nothing of ours is sent;
    /// a robot then tells the peer its match result instead
    /// ([`crate::wire::share`]).
    pub fn peer_takes_map(&self) -> Option<bool> {
        self.peer_takes_map
    }

    /// The peer's robot id, from its `Hello` (`None`: not heard yet).
    pub fn peer_id(&self) -> Option<u8> {
        self.peer_id
    }

    /// Ends the endpoint and gives back what it borrowed mutably: the
    /// scratch its map was ordered in and the staging map (which holds the
    /// peer's map when [`Endpoint::received`] is true).
    pub fn into_parts(self) -> (Option<&'a mut [u32]>, Option<&'a mut R>) {
        (self.tx.map(|t| t.encoder.into_scratch()), self.rx.map)
    }

    /// Ends the endpoint and gives back everything it borrowed mutably,
    /// the link's buffers included (`None` only if they were lost, which
    /// does not happen: each part is always held somewhere).
    pub fn finish(self) -> Option<Finished<'a, R>> {
        let (scratch, (tx, segs, tx_model)) = match (self.tx, self.tx_spare) {
            (Some(t), _) => {
                let (scratch, model) = t.encoder.into_parts();
                (Some(scratch), (t.ring, t.segs, model))
            }
            (None, Some(spare)) => (None, spare),
            (None, None) => return None,
        };
        let rx_model = match (self.rx.decoder, self.rx.model) {
            (Some(d), _) => d.into_model(),
            (None, Some(m)) => m,
            (None, None) => return None,
        };
        let buffers = LinkParts { tx, rx: self.rx.ring, have: self.rx.have, segs, tx_model, rx_model };
        Some(Finished { scratch, staging: self.rx.map, buffers })
    }

    /// Runs the link until done or failed, calling `idle` between steps
    /// (e.g. to sleep or wait for an interrupt).
    pub fn run<IO: Read + Write + ReadReady + WriteReady, C: Clock>(
        &mut self,
        io: &mut IO,
        clock: &C,
        mut idle: impl FnMut(),
    ) -> Result<LinkStats, LinkError> {
        loop {
            if self.step(io, clock.now_ms())? == Progress::Done {
                return Ok(self.stats);
            }
            idle();
        }
    }

    /// One step: read what is there, acknowledge, and, if the line is ready
    /// to take it at once, send one data frame (new, lost, or timed out).
    pub fn step<IO: Read + Write + ReadReady + WriteReady>(
        &mut self,
        io: &mut IO,
        now: u64,
    ) -> Result<Progress, LinkError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        let r = self.step_inner(io, now);
        // Lingering only serves the peer: if it hung up, we are done.
        if matches!(r, Err(LinkError::Io(_))) && self.finished_at.is_some() {
            return Ok(Progress::Done);
        }
        if let Err(e) = r {
            self.failed = Some(e);
            // Tell the peer, best effort, so it does not wait for nothing.
            let reason = match e {
                LinkError::TooLarge { .. } => AbortReason::TooLarge,
                LinkError::Decode(_) => AbortReason::BadChunk,
                LinkError::Digest => AbortReason::Digest,
                LinkError::Incompatible | LinkError::Version(_) | LinkError::BadHello => AbortReason::Incompatible,
                _ => AbortReason::GaveUp,
            };
            if !matches!(e, LinkError::Io(_) | LinkError::PeerAborted(_)) {
                let map_id = self.rx.header.map(|h| h.map_id).or(self.tx.as_ref().map(|t| t.header.map_id));
                let msg = Message::Abort { map_id: map_id.unwrap_or(0), reason };
                let _ = send_msg(io, &msg, &mut self.stats);
            }
        }
        r
    }

    fn finished(&self) -> bool {
        self.sent() && self.received()
    }

    fn send_ack<IO: Write>(&mut self, io: &mut IO) -> Result<(), LinkError> {
        let ack = self.rx.ack(self.finished());
        send_msg(io, &Message::Ack(ack), &mut self.stats)?;
        self.stats.acks_sent += 1;
        self.rx.unacked = 0;
        self.rx.ack_now = false;
        Ok(())
    }

    fn step_inner<IO: Read + Write + ReadReady + WriteReady>(
        &mut self,
        io: &mut IO,
        now: u64,
    ) -> Result<Progress, LinkError> {
        if !self.started {
            self.started = true;
            self.last_heard = now;
            let hello = Hello {
                robot_id: self.robot_id,
                class_table: CLASS_TABLE_VERSION,
                resolution: self.resolution,
                max_payload: MAX_PAYLOAD as u16,
                takes_map: self.rx.map.is_some(),
            };
            send_msg(io, &Message::Hello(hello), &mut self.stats)?;
        }
        // Read everything that is there.
        let mut buf = [0u8; 64];
        while io.read_ready().map_err(io_error)? {
            let n = io.read(&mut buf).map_err(io_error)?;
            if n == 0 {
                break;
            }
            self.stats.bytes_received += n as u64;
            self.last_byte = now;
            for &b in buf.get(..n).unwrap_or(&[]) {
                self.on_byte(b, now)?;
            }
        }
        if self.rx.ack_now && self.rx.map.is_some() {
            self.send_ack(io)?;
        }
        // Our map goes out now, or (half duplex, not robot 0) once the peer's
        // is in.
        // A data frame only when the line takes it at once: acknowledgements
        // never wait behind a queue of data.
        let may_send = (!self.config.half_duplex || self.robot_id == 0 || self.rx.done)
            && self.peer_takes_map != Some(false)
            && io.write_ready().map_err(io_error)?;
        if let (Some(tx), true) = (self.tx.as_mut(), may_send) {
            let line = self.line.model();
            tx.send_next(io, now, self.last_byte.max(self.last_heard), line, &self.config, &mut self.stats)?;
        }
        if self.finished() {
            if self.finished_at.is_none() {
                // Say so twice: the peer may be waiting for exactly this.
                self.finished_at = Some(now);
                self.send_ack(io)?;
                self.send_ack(io)?;
            }
            let lingered = self.finished_at.is_some_and(|t| now >= t + u64::from(self.config.linger_ms));
            if self.peer_finished || lingered {
                return Ok(Progress::Done);
            }
        } else if now.saturating_sub(self.last_heard) > u64::from(self.config.silence_ms) {
            return Err(LinkError::Silent);
        }
        Ok(Progress::Busy)
    }

    fn on_byte(&mut self, b: u8, now: u64) -> Result<(), LinkError> {
        let Endpoint {
            deframer,
            rx,
            tx,
            stats,
            config,
            resolution,
            last_heard,
            peer_finished,
            peer_takes_map,
            peer_id,
            line,
            ..
        } = self;
        if b != 0 {
            line.byte();
        }
        let (payload, repaired) = match deframer.push_frame(b) {
            Ok(Some(f)) => (f.payload, f.repaired),
            Ok(None) => return Ok(()),
            Err(_) => {
                stats.bad_frames += 1;
                line.frame(false, false);
                return Ok(());
            }
        };
        let msg = match Message::decode(payload) {
            Ok(msg) => msg,
            // An intact frame (its CRC-32 holds, nothing repaired) in another
            // version, or a Hello with a non-finite field: the peer, not the
            // line, says so, and waiting would only end at the deadline.
            Err(MessageError::Version(v)) if !repaired => return Err(LinkError::Version(v)),
            Err(MessageError::NonFinite) if !repaired => return Err(LinkError::BadHello),
            Err(_) => {
                stats.bad_frames += 1;
                line.frame(false, false);
                return Ok(());
            }
        };
        line.frame(true, repaired);
        stats.repaired_frames += u32::from(repaired);
        stats.frames_received += 1;
        *last_heard = now;
        match msg {
            Message::Hello(h) => {
                if h.class_table != CLASS_TABLE_VERSION || (h.resolution - *resolution).abs() > 1e-6 * *resolution {
                    return Err(LinkError::Incompatible);
                }
                *peer_takes_map = Some(h.takes_map);
                *peer_id = Some(h.robot_id);
            }
            Message::Data { offset, poll, data } => rx.on_data(offset, poll, data, *resolution, stats)?,
            Message::Ack(ack) => {
                if ack.flags & ACK_FINISHED != 0 {
                    *peer_finished = true;
                }
                if let Some(t) = tx.as_mut() {
                    t.on_ack(&ack, now, config);
                }
            }
            Message::Abort { map_id, reason } => {
                let ours = tx.as_ref().is_some_and(|t| t.header.map_id == map_id);
                let theirs = rx.header.is_none_or(|h| h.map_id == map_id);
                if ours || theirs {
                    return Err(LinkError::PeerAborted(reason));
                }
            }
        }
        Ok(())
    }
}
