//! The endpoint state machine.

use super::Clock;
use crate::classes::CLASS_TABLE_VERSION;
use crate::map::{LocalMap, VoxelStorage};
use crate::wire::codec::{DecodeError, MapDecoder, MapEncoder, MIN_CHUNK};
use crate::wire::frame::{Deframer, MAX_FRAME, MAX_PAYLOAD};
use crate::wire::message::{AbortReason, Hello, MapHeader, Message};
use embedded_io::{Read, ReadReady, Write};

/// Timing and sizes of a link.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkConfig {
    /// First retransmission timeout (ms); doubles on each retry (default 150).
    pub timeout_ms: u32,
    /// Ceiling of the retransmission timeout (ms, default 600).
    pub max_timeout_ms: u32,
    /// Retries of one frame before giving up (default 100: on a line that
    /// corrupts one byte in twenty, a small frame and its ack get through
    /// about one time in ten).
    pub max_retries: u8,
    /// Largest chunk of voxel encoding in a frame (bytes, default 240).
    pub max_chunk: u16,
    /// Smallest chunk the size adapts down to (bytes, default 20).
    pub min_chunk: u16,
    /// Give up when nothing valid arrived for this long (ms, default 90000:
    /// longer than a sender's whole retry budget, so that on a bad line the
    /// retries decide, and silence only catches a peer that is gone).
    pub silence_ms: u32,
    /// After both maps are through, keep answering for this long (ms), so a
    /// peer whose last ack was lost still gets one (default 1500).
    pub linger_ms: u32,
    /// The line carries one direction at a time (a radio modem, RS-485): the
    /// two maps go one after the other. Robot 0 sends first; any other robot
    /// starts its own map once it holds the peer's. Within one transfer,
    /// stop-and-wait already keeps one side talking at a time. Default off
    /// (both maps at once on full-duplex lines).
    pub half_duplex: bool,
}

impl Default for LinkConfig {
    fn default() -> Self {
        LinkConfig {
            timeout_ms: 150,
            max_timeout_ms: 600,
            max_retries: 100,
            max_chunk: 240,
            min_chunk: 20,
            silence_ms: 90_000,
            linger_ms: 1500,
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
    /// A frame was resent `max_retries` times without an answer.
    GaveUp {
        /// Sequence number of the frame.
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
            LinkError::GaveUp { seq } => write!(f, "gave up: frame {seq} unanswered after all retries"),
            LinkError::Silent => f.write_str("peer silent"),
            LinkError::PeerAborted(r) => write!(f, "peer aborted the transfer ({r:?})"),
            LinkError::TooLarge { voxels } => write!(f, "peer map of {voxels} voxels does not fit"),
            LinkError::Incompatible => f.write_str("peer uses another voxel size or class table"),
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
    /// Voxels received.
    pub voxels_received: u32,
    /// Encoded voxel bytes sent (chunk data only, first transmissions).
    pub chunk_bytes_sent: u64,
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

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum TxPhase {
    Header,
    Chunks,
    End,
    Done,
}

struct Tx<'a, S: VoxelStorage> {
    encoder: MapEncoder<'a, S>,
    /// When the frame in flight was last sent.
    sent_at: u64,
    header: MapHeader,
    phase: TxPhase,
    /// First voxel of the chunk in flight (`End`: count plus one).
    seq: u32,
    /// One past the last voxel of the chunk in flight.
    end: u32,
    /// Bytes of voxel encoding in the frame in flight (0 for other frames).
    chunk_len: usize,
    frame: [u8; MAX_FRAME],
    frame_len: usize,
    deadline: u64,
    timeout: u32,
    retries: u8,
    chunk: usize,
    /// Bytes of frames sent, and of those how many frames failed (decayed):
    /// the byte error rate estimate that sizes the chunks.
    est_bytes: u32,
    est_fails: u32,
}

/// Frame bytes around a chunk's data (message fields, chunk header, CRC,
/// COBS, delimiter) plus its ack: the overhead a chunk pays each attempt.
const CHUNK_OVERHEAD: usize = 32;

impl<S: VoxelStorage> Tx<'_, S> {
    /// Records an attempt of the frame in flight and sizes the next chunks.
    /// A failure halves them, to get through a bad patch at once. A success
    /// grows them by a quarter, but not past the size the line's estimated
    /// byte error rate `r` favours: a frame of `L` bytes gets through with
    /// probability about `(1 - r)^L`, so data per attempt peaks at `L = 1/r`.
    fn record(&mut self, failed: bool, config: &LinkConfig) {
        self.est_bytes = self.est_bytes.saturating_add(self.frame_len as u32);
        if failed {
            self.est_fails += 1;
        }
        if self.est_bytes > 64_000 {
            self.est_bytes /= 2;
            self.est_fails /= 2;
        }
        let (min, max) = (usize::from(config.min_chunk), usize::from(config.max_chunk));
        if failed {
            self.chunk = (self.chunk / 2).max(min);
        } else {
            // A prior of one error in 4000 bytes until evidence accumulates.
            let rate = (self.est_fails as f32 + 0.5) / (self.est_bytes as f32 + 2000.0);
            let target = ((1.0 / rate) as usize).saturating_sub(CHUNK_OVERHEAD).clamp(min, max);
            if self.chunk < target {
                self.chunk = (self.chunk + (self.chunk / 4).max(8)).min(target);
            }
        }
    }
}

struct Rx<'a, S: VoxelStorage> {
    /// The last nack sent for a broken frame: (voxel index, time).
    nacked: Option<(u32, u64)>,
    /// `None`: this endpoint receives nothing.
    map: Option<&'a mut LocalMap<S>>,
    decoder: Option<MapDecoder>,
    map_id: Option<u32>,
    digest: u32,
    expected: u32,
    done: bool,
}

/// One robot's end of the link: sends its map, receives the peer's.
pub struct Endpoint<'a, M: VoxelStorage, R: VoxelStorage> {
    config: LinkConfig,
    robot_id: u8,
    resolution: f32,
    tx: Option<Tx<'a, M>>,
    rx: Rx<'a, R>,
    deframer: Deframer,
    started: bool,
    last_heard: u64,
    linger_until: Option<u64>,
    failed: Option<LinkError>,
    stats: LinkStats,
}

fn send_msg<IO: Write>(io: &mut IO, msg: &Message<'_>, stats: &mut LinkStats) -> Result<(), LinkError> {
    let mut frame = [0u8; MAX_FRAME];
    let f = msg.to_frame(&mut frame).map_err(|_| LinkError::Setup)?;
    write_frame(io, frame.get(..f).unwrap_or(&[]), stats)
}

/// A stream error as a link error, keeping its kind.
fn io_error<E: embedded_io::Error>(e: E) -> LinkError {
    LinkError::Io(e.kind())
}

fn write_frame<IO: Write>(io: &mut IO, frame: &[u8], stats: &mut LinkStats) -> Result<(), LinkError> {
    io.write_all(frame).map_err(io_error)?;
    io.flush().map_err(io_error)?;
    stats.bytes_sent += frame.len() as u64;
    stats.frames_sent += 1;
    Ok(())
}

impl<'a, M: VoxelStorage> Tx<'a, M> {
    /// Builds the frame of the current sequence number.
    fn build(&mut self) -> Result<(), LinkError> {
        self.chunk_len = 0;
        let map_id = self.header.map_id;
        let msg_frame = match self.phase {
            TxPhase::Header => Message::MapHeader(self.header).to_frame(&mut self.frame),
            TxPhase::Chunks => {
                let mut data = [0u8; MAX_PAYLOAD];
                self.encoder.seek(self.seq as usize);
                let chunk = data.get_mut(..self.chunk).ok_or(LinkError::Setup)?;
                let len = self.encoder.next_chunk(chunk).map_err(|_| LinkError::Setup)?;
                self.end = self.encoder.position() as u32;
                self.chunk_len = len;
                let data = data.get(..len).ok_or(LinkError::Setup)?;
                Message::Chunk { map_id, seq: self.seq, data }.to_frame(&mut self.frame)
            }
            TxPhase::End | TxPhase::Done => Message::End { map_id, seq: self.seq }.to_frame(&mut self.frame),
        };
        self.frame_len = msg_frame.map_err(|_| LinkError::Setup)?;
        Ok(())
    }

    fn transmit<IO: Write>(&mut self, io: &mut IO, now: u64, stats: &mut LinkStats) -> Result<(), LinkError> {
        write_frame(io, &self.frame[..self.frame_len], stats)?;
        self.sent_at = now;
        self.deadline = now + u64::from(self.timeout);
        Ok(())
    }

    fn on_ack<IO: Write>(
        &mut self,
        seq: u32,
        io: &mut IO,
        now: u64,
        config: &LinkConfig,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        let count = self.header.voxel_count;
        // What the receiver holds moves us on; anything else is stale.
        let next = match self.phase {
            TxPhase::Header => Some(seq),
            TxPhase::Chunks if seq >= self.end && seq <= count => Some(seq),
            TxPhase::End if seq == count + 1 => None,
            _ => return Ok(()),
        };
        self.record(false, config);
        self.retries = 0;
        self.timeout = config.timeout_ms;
        match next {
            None => {
                self.phase = TxPhase::Done;
                return Ok(());
            }
            Some(held) if held >= count => {
                self.phase = TxPhase::End;
                self.seq = count + 1;
            }
            Some(held) => {
                self.phase = TxPhase::Chunks;
                self.seq = held;
            }
        }
        self.build()?;
        stats.chunk_bytes_sent += self.chunk_len as u64;
        self.transmit(io, now, stats)
    }

    /// Sends the frame in flight again; a chunk is re-encoded from the same
    /// voxel at the (halved) current size, so a line that breaks long frames
    /// still lets short ones through.
    fn resend<IO: Write>(&mut self, io: &mut IO, now: u64, stats: &mut LinkStats) -> Result<(), LinkError> {
        if self.phase == TxPhase::Chunks {
            self.build()?;
        }
        self.transmit(io, now, stats)
    }

    /// Resends after a timeout (`timed_out`: the line may be stalled, so the
    /// timeout backs off) or a nack (the line is alive: resend at once, same
    /// timeout).
    fn retransmit<IO: Write>(
        &mut self,
        io: &mut IO,
        now: u64,
        config: &LinkConfig,
        stats: &mut LinkStats,
        timed_out: bool,
    ) -> Result<(), LinkError> {
        if self.retries >= config.max_retries {
            return Err(LinkError::GaveUp { seq: self.seq });
        }
        self.retries += 1;
        self.record(true, config);
        if timed_out {
            self.timeout = (self.timeout.saturating_mul(2)).min(config.max_timeout_ms);
        }
        stats.retransmissions += 1;
        self.resend(io, now, stats)
    }
}

impl<'a, M: VoxelStorage, R: VoxelStorage> Endpoint<'a, M, R> {
    /// An endpoint that will send `map` (Morton order prepared in `scratch`,
    /// one `u32` per voxel; `None`: send nothing) as transfer `map_id`, and
    /// receive the peer's map into `staging` (cleared first; `None`: receive
    /// nothing). At least one of the two must be given.
    pub fn new(
        config: LinkConfig,
        robot_id: u8,
        map_id: u32,
        anchor_time_us: u64,
        map: Option<(&'a LocalMap<M>, &'a mut [u32])>,
        mut staging: Option<&'a mut LocalMap<R>>,
    ) -> Result<Self, LinkError> {
        let min = MIN_CHUNK.max(usize::from(config.min_chunk));
        if usize::from(config.max_chunk) < min
            || usize::from(config.max_chunk) > MAX_PAYLOAD - 24
            || config.max_retries == 0
        {
            return Err(LinkError::Setup);
        }
        let config = LinkConfig { min_chunk: min as u16, ..config };
        let resolution = match (&staging, &map) {
            (Some(s), _) => s.resolution(),
            (None, Some((m, _))) => m.resolution(),
            (None, None) => return Err(LinkError::Setup),
        };
        let tx = match map {
            None => None,
            Some((m, scratch)) => {
                if (m.resolution() - resolution).abs() > 1e-6 * resolution {
                    return Err(LinkError::Setup);
                }
                let bounds = m.bounds().map(|(lo, hi)| [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]]).unwrap_or([0.0; 6]);
                let encoder = MapEncoder::new(m, scratch).map_err(|_| LinkError::Setup)?;
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
                Some(Tx {
                    encoder,
                    sent_at: 0,
                    header,
                    phase: TxPhase::Header,
                    seq: 0,
                    end: 0,
                    chunk_len: 0,
                    frame: [0; MAX_FRAME],
                    frame_len: 0,
                    deadline: 0,
                    timeout: config.timeout_ms,
                    retries: 0,
                    chunk: usize::from(config.max_chunk),
                    est_bytes: 0,
                    est_fails: 0,
                })
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
            rx: Rx {
                nacked: None,
                map: staging,
                decoder: None,
                map_id: None,
                digest: 0,
                expected: 0,
                done: !receiving,
            },
            deframer: Deframer::new(),
            started: false,
            last_heard: 0,
            linger_until: None,
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

    /// Whether our map was acknowledged to the end.
    pub fn sent(&self) -> bool {
        self.tx.as_ref().is_none_or(|t| t.phase == TxPhase::Done)
    }

    /// Ends the endpoint and gives back what it borrowed mutably: the
    /// scratch its map was ordered in and the staging map (which holds the
    /// peer's map when [`Endpoint::received`] is true).
    pub fn into_parts(self) -> (Option<&'a mut [u32]>, Option<&'a mut LocalMap<R>>) {
        (self.tx.map(|t| t.encoder.into_scratch()), self.rx.map)
    }

    /// Runs the link until done or failed, calling `idle` between steps
    /// (e.g. to sleep or wait for an interrupt).
    pub fn run<IO: Read + Write + ReadReady, C: Clock>(
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

    /// One step: read what is there, answer, retransmit what timed out.
    pub fn step<IO: Read + Write + ReadReady>(&mut self, io: &mut IO, now: u64) -> Result<Progress, LinkError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        let r = self.step_inner(io, now);
        // Lingering only serves the peer: if it hung up, we are done.
        if matches!(r, Err(LinkError::Io(_))) && self.linger_until.is_some() {
            return Ok(Progress::Done);
        }
        if let Err(e) = r {
            self.failed = Some(e);
            // Tell the peer, best effort, so it does not wait for nothing.
            let reason = match e {
                LinkError::TooLarge { .. } => AbortReason::TooLarge,
                LinkError::Decode(_) => AbortReason::BadChunk,
                LinkError::Digest => AbortReason::Digest,
                LinkError::Incompatible => AbortReason::Incompatible,
                _ => AbortReason::GaveUp,
            };
            if !matches!(e, LinkError::Io(_) | LinkError::PeerAborted(_)) {
                let map_id = self.rx.map_id.or(self.tx.as_ref().map(|t| t.header.map_id)).unwrap_or(0);
                let _ = send_msg(io, &Message::Abort { map_id, reason }, &mut self.stats);
            }
        }
        r
    }

    fn step_inner<IO: Read + Write + ReadReady>(&mut self, io: &mut IO, now: u64) -> Result<Progress, LinkError> {
        if !self.started {
            self.started = true;
            self.last_heard = now;
            let hello = Hello {
                robot_id: self.robot_id,
                class_table: CLASS_TABLE_VERSION,
                resolution: self.resolution,
                max_payload: MAX_PAYLOAD as u16,
            };
            send_msg(io, &Message::Hello(hello), &mut self.stats)?;
        }
        // Our map goes out now, or (half duplex, not robot 0) once the peer's
        // is in.
        let may_send = !self.config.half_duplex || self.robot_id == 0 || self.rx.done;
        if let Some(tx) = self.tx.as_mut() {
            if tx.frame_len == 0 && may_send {
                tx.build()?;
                self.stats.chunk_bytes_sent += tx.chunk_len as u64;
                tx.transmit(io, now, &mut self.stats)?;
            }
        }
        // Read everything that is there.
        let mut buf = [0u8; 64];
        while io.read_ready().map_err(io_error)? {
            let n = io.read(&mut buf).map_err(io_error)?;
            if n == 0 {
                break;
            }
            self.stats.bytes_received += n as u64;
            for &b in buf.get(..n).unwrap_or(&[]) {
                self.on_byte(b, io, now)?;
            }
        }
        // Deadlines.
        if let Some(tx) = self.tx.as_mut() {
            if tx.frame_len > 0 && tx.phase != TxPhase::Done && now >= tx.deadline {
                tx.retransmit(io, now, &self.config, &mut self.stats, true)?;
            }
        }
        if now.saturating_sub(self.last_heard) > u64::from(self.config.silence_ms) && self.linger_until.is_none() {
            return Err(LinkError::Silent);
        }
        if self.sent() && self.received() {
            let until = *self.linger_until.get_or_insert(now + u64::from(self.config.linger_ms));
            if now >= until {
                return Ok(Progress::Done);
            }
        }
        Ok(Progress::Busy)
    }

    fn on_byte<IO: Write>(&mut self, b: u8, io: &mut IO, now: u64) -> Result<(), LinkError> {
        let Endpoint { deframer, rx, tx, stats, config, resolution, last_heard, .. } = self;
        let payload = match deframer.push(b) {
            Ok(Some(p)) => p,
            Ok(None) => return Ok(()),
            Err(_) => {
                stats.bad_frames += 1;
                // Receiving: ask at once for what is missing rather than let
                // the sender wait for its timeout; once per position and
                // half-timeout, so broken acks on a shared line do not set
                // off a storm of resends.
                if let (Some(map_id), Some(dec), false) = (rx.map_id, rx.decoder.as_ref(), rx.done) {
                    let held = dec.decoded() as u32;
                    let recent =
                        rx.nacked.is_some_and(|(s, t)| s == held && now < t + u64::from(config.timeout_ms / 2));
                    if !recent {
                        rx.nacked = Some((held, now));
                        send_msg(io, &Message::Nack { map_id, seq: held }, stats)?;
                    }
                }
                return Ok(());
            }
        };
        let Ok(msg) = Message::decode(payload) else {
            stats.bad_frames += 1;
            return Ok(());
        };
        stats.frames_received += 1;
        *last_heard = now;
        match msg {
            Message::Hello(h) => {
                if h.class_table != CLASS_TABLE_VERSION || (h.resolution - *resolution).abs() > 1e-6 * *resolution {
                    return Err(LinkError::Incompatible);
                }
            }
            Message::Ack { map_id, seq } => {
                if let Some(t) = tx.as_mut() {
                    if map_id == t.header.map_id {
                        t.on_ack(seq, io, now, config, stats)?;
                    }
                }
            }
            Message::Nack { map_id, seq } => {
                if let Some(t) = tx.as_mut() {
                    if map_id == t.header.map_id
                        && t.phase != TxPhase::Done
                        && (seq == t.seq || t.phase == TxPhase::End)
                    {
                        t.retransmit(io, now, config, stats, false)?;
                    }
                }
            }
            Message::Abort { map_id, reason } => {
                let ours = tx.as_ref().is_some_and(|t| t.header.map_id == map_id);
                if ours || rx.map_id == Some(map_id) || rx.map_id.is_none() {
                    return Err(LinkError::PeerAborted(reason));
                }
            }
            Message::MapHeader(h) => {
                let Some(map) = rx.map.as_mut() else { return Ok(()) };
                if rx.map_id == Some(h.map_id) {
                    let held = rx.decoder.as_ref().map(|d| d.decoded() as u32).unwrap_or(0);
                    let seq = if rx.done { h.voxel_count + 1 } else { held };
                    return send_msg(io, &Message::Ack { map_id: h.map_id, seq }, stats);
                }
                if rx.map_id.is_some() {
                    return Ok(()); // one transfer per endpoint
                }
                if h.class_table != CLASS_TABLE_VERSION || (h.resolution - *resolution).abs() > 1e-6 * *resolution {
                    return Err(LinkError::Incompatible);
                }
                if h.voxel_count as usize > map.capacity() {
                    return Err(LinkError::TooLarge { voxels: h.voxel_count });
                }
                map.clear();
                rx.decoder = Some(MapDecoder::new(h.voxel_count as usize));
                rx.map_id = Some(h.map_id);
                rx.digest = h.digest;
                rx.expected = h.voxel_count;
                send_msg(io, &Message::Ack { map_id: h.map_id, seq: 0 }, stats)?;
            }
            Message::Chunk { map_id, seq, data } => {
                if rx.map_id != Some(map_id) {
                    return Ok(());
                }
                let (Some(dec), Some(map)) = (rx.decoder.as_mut(), rx.map.as_mut()) else { return Ok(()) };
                let held = dec.decoded() as u32;
                if seq == held && !rx.done {
                    let n = dec.decode_chunk(data, map).map_err(LinkError::Decode)?;
                    stats.voxels_received += n as u32;
                    send_msg(io, &Message::Ack { map_id, seq: dec.decoded() as u32 }, stats)?;
                } else if seq < held || rx.done {
                    // Already have it: say how far we are.
                    let ack = if rx.done { rx.expected + 1 } else { held };
                    send_msg(io, &Message::Ack { map_id, seq: ack }, stats)?;
                } else {
                    send_msg(io, &Message::Nack { map_id, seq: held }, stats)?;
                }
            }
            Message::End { map_id, seq } => {
                if rx.map_id != Some(map_id) {
                    return Ok(());
                }
                let Some(dec) = rx.decoder.as_ref() else { return Ok(()) };
                if seq != rx.expected + 1 {
                    return Ok(());
                }
                if !rx.done {
                    if !dec.is_complete() {
                        return send_msg(io, &Message::Nack { map_id, seq: dec.decoded() as u32 }, stats);
                    }
                    if dec.digest() != rx.digest {
                        return Err(LinkError::Digest);
                    }
                    rx.done = true;
                }
                send_msg(io, &Message::Ack { map_id, seq }, stats)?;
            }
        }
        Ok(())
    }
}
