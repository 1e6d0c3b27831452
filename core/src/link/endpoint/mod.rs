//! The endpoint state machine: one map stream out, one in, by selective
//! repeat.

use super::Clock;
use crate::classes::CLASS_TABLE_VERSION;
use crate::map::{LocalMap, VoxelKey, VoxelSink, VoxelStorage};
use crate::wire::block::{encode_block, BlockDeframer, BlockShape};
use crate::wire::codec::{CodecModel, DecodeError, MapDecoder, MapEncoder};
use crate::wire::frame::{FrameError, MAX_FRAME, MAX_PAYLOAD};
use crate::wire::message::{
    AbortReason, Ack, Hello, MapHeader, Message, MessageError, SackBlock, ACK_ALL_BLOCKS, ACK_COMPLETE, ACK_FINISHED,
    MAX_SACK, OFFSET_MODULUS,
};
use core::borrow::Borrow;
use embedded_io::{Read, ReadReady, Write, WriteReady};

pub(in crate::link) mod line;
mod rx;
mod tx;

use line::{FrameShape, LineEstimate};
use rx::Rx;
use tx::{SegList, Tx};

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
/// Half duplex: most bytes a turn sends before it asks for an answer (the
/// window: the peer acknowledges nothing before the turn is over).
const BURST: u32 = WINDOW;
/// Half duplex: a line quiet this long (ms) after data ends the peer's turn.
const TURN_QUIET_MS: u64 = 15;

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
    /// Largest data of a frame (bytes, default 300: a clean line's frames,
    /// without parity; frames with parity hold at most 247 less the parity;
    /// longer ones would leave fewer than the four frames an acknowledgement
    /// waits for in the window).
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
            max_chunk: 300,
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
    /// Frames repaired by the forward error correction and used.
    pub repaired_frames: u32,
    /// Bytes the correction rebuilt in frames used: substituted, dropped
    /// and duplicated on the line.
    pub repaired_bytes: [u32; 3],
    /// Data and parity bytes of the last data frame sent: the shape the
    /// line estimate chose.
    pub frame_shape: (u16, u8),
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

impl LinkStats {
    /// Adds what the deframer rebuilt in a frame.
    fn count_repairs(&mut self, d: crate::wire::Damage) {
        for (count, k) in self.repaired_bytes.iter_mut().zip([d.substituted, d.dropped, d.duplicated]) {
            *count += u32::from(k);
        }
    }
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
/// bookkeeping of frames in flight and the codec's models (about 14 KiB).
/// Apart from the [`Endpoint`], so that a robot keeps it in a static while
/// the endpoint, which moves between a robot's stages, stays small. Plain
/// integers, any value valid (an endpoint resets what it reads), so a
/// robot may carve it out of memory that serves other stages before and
/// after (see [`LinkMemory`]).
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct LinkBuffers {
    tx: [u8; STREAM_BUFFER],
    rx: [u8; STREAM_BUFFER],
    have: [u32; STREAM_BUFFER / 32],
    segs: SegList,
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
            segs: SegList::new(),
            tx_model: CodecModel::new(),
            rx_model: CodecModel::new(),
        }
    }

    /// The sending half's and the receiving half's parts.
    fn split(&mut self) -> (TxBufs<'_>, RxBufs<'_>) {
        let LinkBuffers { tx, rx, have, segs, tx_model, rx_model } = self;
        (TxBufs { ring: tx, segs, model: tx_model }, RxBufs { ring: rx, have, model: rx_model })
    }
}

impl Default for LinkBuffers {
    fn default() -> Self {
        Self::new()
    }
}

/// Where an [`Endpoint`] finds its [`LinkBuffers`]: it holds this owner
/// whole for its life and gives it back whole ([`Endpoint::finish`]), so
/// memory lent to a link returns to its owner in one piece.
pub trait LinkMemory {
    /// The buffers (`None`: the memory cannot hold them).
    fn buffers(&mut self) -> Option<&mut LinkBuffers>;
}

impl LinkMemory for &mut LinkBuffers {
    fn buffers(&mut self) -> Option<&mut LinkBuffers> {
        Some(self)
    }
}

/// A region of words ([`crate::region`]) holds the buffers at its start
/// (at least [`LINK_WORDS`] words); the rest serves the owner's next stage
/// once the endpoint gives the region back.
impl LinkMemory for &mut [u32] {
    fn buffers(&mut self) -> Option<&mut LinkBuffers> {
        let head = self.get_mut(..LINK_WORDS)?;
        let raw: &mut [u8] = bytemuck::cast_slice_mut(head);
        bytemuck::try_from_bytes_mut(raw.get_mut(..core::mem::size_of::<LinkBuffers>())?).ok()
    }
}

/// Words of a region that [`LinkBuffers`] take.
pub const LINK_WORDS: usize = crate::region::words_for::<LinkBuffers>(1);

/// The sending half's buffers, for one step.
pub(super) struct TxBufs<'b> {
    pub(super) ring: &'b mut [u8; STREAM_BUFFER],
    pub(super) segs: &'b mut SegList,
    pub(super) model: &'b mut CodecModel,
}

/// The receiving half's buffers, for one step.
pub(super) struct RxBufs<'b> {
    pub(super) ring: &'b mut [u8; STREAM_BUFFER],
    pub(super) have: &'b mut [u32; STREAM_BUFFER / 32],
    pub(super) model: &'b mut CodecModel,
}

/// What an ended [`Endpoint`] gives back.
pub struct Finished<'a, R: VoxelSink, B, O> {
    /// The map it sent (`None`: it sent no map).
    pub map: Option<O>,
    /// The scratch its map was ordered in (`None`: it sent no map).
    pub scratch: Option<&'a mut [u32]>,
    /// The staging map, holding the peer's map when it arrived whole.
    pub staging: Option<&'a mut R>,
    /// The link's buffers, whole, for the next endpoint or another use.
    pub buffers: B,
}

/// One robot's end of the link: sends its map (borrowed, or owned as `O`
/// and given back), receives the peer's, working in the buffers of `B`.
pub struct Endpoint<
    'a,
    M: VoxelStorage,
    R: VoxelSink,
    B: LinkMemory = &'a mut LinkBuffers,
    O: Borrow<LocalMap<M>> = &'a LocalMap<M>,
> {
    buffers: B,
    session: Session<'a, M, R, O>,
}

/// An endpoint's state apart from its buffers.
struct Session<'a, M: VoxelStorage, R: VoxelSink, O: Borrow<LocalMap<M>>> {
    config: LinkConfig,
    robot_id: u8,
    resolution: f32,
    tx: Option<Tx<'a, M, O>>,
    rx: Rx<'a, R>,
    deframer: BlockDeframer,
    line: LineEstimate,
    /// Frames sized and protected for the line as the peer's frames show it
    /// (recomputed when one arrives).
    shape: FrameShape,
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
    /// When our last `Hello` went out: sent again until the peer's is heard.
    hello_at: u64,
    /// The peer has not heard our `Hello` (its own said so): answer it.
    answer_hello: bool,
    failed: Option<LinkError>,
    stats: LinkStats,
}

/// Parity of a `Hello`: it is sent once, and the damage it arrives with is
/// the peer's first measure of the line.
const HELLO_PARITY: usize = 16;

/// Sends one message as a frame; returns the bytes written.
fn send_msg<IO: Write>(
    io: &mut IO,
    msg: &Message<'_>,
    parity: usize,
    stats: &mut LinkStats,
) -> Result<usize, LinkError> {
    let mut frame = [0u8; MAX_FRAME];
    let f = msg.to_frame_parity(&mut frame, parity).map_err(|_| LinkError::Setup)?;
    io.write_all(frame.get(..f).unwrap_or(&[])).map_err(io_error)?;
    io.flush().map_err(io_error)?;
    stats.bytes_sent += f as u64;
    stats.frames_sent += 1;
    Ok(f)
}

/// Why a block was not sent: it does not fit its shape, or the line.
enum BlockFailure {
    Shape,
    Link(LinkError),
}

impl From<FrameError> for BlockFailure {
    fn from(_: FrameError) -> Self {
        BlockFailure::Shape
    }
}

/// Sends one message as a block of `shape`; returns the bytes written.
/// Should the block not fit the shape (or, rarely, every byte value occur
/// in it whatever the key), as a frame with `parity` parity bytes (none if
/// it is too long for them).
fn send_block<IO: Write>(
    io: &mut IO,
    msg: &Message<'_>,
    (shape, parity): (BlockShape, usize),
    stats: &mut LinkStats,
) -> Result<usize, LinkError> {
    let mut payload = [0u8; MAX_PAYLOAD];
    let n = msg.encode(&mut payload).map_err(|_| LinkError::Setup)?;
    let sent = encode_block(payload.get(..n).unwrap_or(&[]), shape, |bytes: &[u8]| {
        io.write_all(bytes).map_err(|e| BlockFailure::Link(io_error(e)))
    });
    match sent {
        Ok(len) => {
            io.flush().map_err(io_error)?;
            stats.bytes_sent += len as u64;
            stats.frames_sent += 1;
            Ok(len)
        }
        Err(BlockFailure::Link(e)) => Err(e),
        Err(BlockFailure::Shape) => {
            let parity = if n <= crate::wire::frame::max_payload(parity) { parity } else { 0 };
            send_msg(io, msg, parity, stats)
        }
    }
}

/// A stream error as a link error, keeping its kind.
fn io_error<E: embedded_io::Error>(e: E) -> LinkError {
    LinkError::Io(e.kind())
}

impl<'a, M: VoxelStorage, R: VoxelSink, B: LinkMemory, O: Borrow<LocalMap<M>>> Endpoint<'a, M, R, B, O> {
    /// An endpoint that will send `map` (Morton order prepared in `scratch`,
    /// one `u32` per voxel; `None`: send nothing) as transfer `map_id`, and
    /// receive the peer's map into `staging` (cleared first; `None`: receive
    /// nothing), working in `buffers` (held whole until
    /// [`Endpoint::finish`]). At least one of the two maps must be given.
    pub fn new(
        config: LinkConfig,
        robot_id: u8,
        map_id: u32,
        anchor_time_us: u64,
        map: Option<(O, &'a mut [u32])>,
        mut staging: Option<&'a mut R>,
        mut buffers: B,
    ) -> Result<Self, LinkError> {
        let b = buffers.buffers().ok_or(LinkError::Setup)?;
        b.segs.clear();
        b.have.fill(0);
        if config.max_chunk < config.min_chunk.max(1)
            || usize::from(config.max_chunk) > MAX_PAYLOAD - 4
            || config.max_retries == 0
        {
            return Err(LinkError::Setup);
        }
        let config = LinkConfig { min_chunk: config.min_chunk.max(1), ..config };
        let resolution = match (&staging, &map) {
            (Some(s), _) => s.resolution(),
            (None, Some((m, _))) => m.borrow().resolution(),
            (None, None) => return Err(LinkError::Setup),
        };
        let tx = match map {
            None => None,
            Some((m, scratch)) => {
                if !same_resolution(m.borrow().resolution(), resolution) {
                    return Err(LinkError::Setup);
                }
                let ids = (map_id, robot_id, anchor_time_us);
                Some(Tx::new(m, scratch, &mut b.tx_model, ids, &config)?)
            }
        };
        if let Some(s) = staging.as_mut() {
            s.clear();
        }
        let session = Session {
            config,
            robot_id,
            resolution,
            tx,
            rx: Rx::new(staging),
            deframer: BlockDeframer::new(),
            line: LineEstimate::default(),
            shape: FrameShape::initial(&config),
            started: false,
            last_heard: 0,
            last_byte: 0,
            finished_at: None,
            peer_finished: false,
            peer_takes_map: None,
            peer_id: None,
            hello_at: 0,
            answer_hello: false,
            failed: None,
            stats: LinkStats::default(),
        };
        Ok(Endpoint { buffers, session })
    }

    /// What moved so far.
    pub fn stats(&self) -> LinkStats {
        self.session.stats
    }

    /// Whether the peer's map arrived whole (its digest checked), or this
    /// endpoint receives nothing.
    pub fn received(&self) -> bool {
        self.session.rx.done
    }

    /// Whether the peer said it holds our whole map.
    pub fn sent(&self) -> bool {
        self.session.sent()
    }

    /// Whether the peer takes our map, from its `Hello` (`None`: not heard
    /// yet). `Some(false)`: a one-sided exchange, nothing of ours is sent;
    /// a robot then tells the peer its match result instead
    /// ([`crate::wire::share`]).
    pub fn peer_takes_map(&self) -> Option<bool> {
        self.session.peer_takes_map
    }

    /// The peer's robot id, from its `Hello` (`None`: not heard yet).
    pub fn peer_id(&self) -> Option<u8> {
        self.session.peer_id
    }

    /// Ends the endpoint and gives back the scratch its map was ordered in
    /// and the staging map (which holds the peer's map when
    /// [`Endpoint::received`] is true).
    pub fn into_parts(self) -> (Option<&'a mut [u32]>, Option<&'a mut R>) {
        let f = self.finish();
        (f.scratch, f.staging)
    }

    /// Ends the endpoint and gives back everything it borrowed mutably,
    /// its buffers whole.
    pub fn finish(self) -> Finished<'a, R, B, O> {
        let s = self.session;
        let (map, scratch) = s.tx.map(|t| t.encoder.into_parts()).unzip();
        Finished { map, scratch, staging: s.rx.map, buffers: self.buffers }
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
                return Ok(self.session.stats);
            }
            idle();
        }
    }

    /// One step: read what is there, acknowledge, and, if the line is ready
    /// to take it at once, send one data frame (new, lost, or timed out).
    /// Never inlined: a robot's other stages do not carry its frame.
    #[inline(never)]
    pub fn step<IO: Read + Write + ReadReady + WriteReady>(
        &mut self,
        io: &mut IO,
        now: u64,
    ) -> Result<Progress, LinkError> {
        match self.buffers.buffers() {
            Some(b) => self.session.step(io, now, b),
            None => Err(LinkError::Setup),
        }
    }
}

impl<M: VoxelStorage, R: VoxelSink, O: Borrow<LocalMap<M>>> Session<'_, M, R, O> {
    fn sent(&self) -> bool {
        self.tx.as_ref().is_none_or(|t| t.complete) || self.peer_takes_map == Some(false)
    }

    fn step<IO: Read + Write + ReadReady + WriteReady>(
        &mut self,
        io: &mut IO,
        now: u64,
        buffers: &mut LinkBuffers,
    ) -> Result<Progress, LinkError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        let r = self.step_inner(io, now, buffers);
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
                let _ = send_msg(io, &msg, self.shape.parity, &mut self.stats);
            }
        }
        r
    }

    fn finished(&self) -> bool {
        self.sent() && self.rx.done
    }

    fn send_ack<IO: Write>(&mut self, io: &mut IO, have: &[u32; STREAM_BUFFER / 32]) -> Result<(), LinkError> {
        let ack = self.rx.ack(have, self.finished());
        send_msg(io, &Message::Ack(ack), self.shape.parity, &mut self.stats)?;
        self.stats.acks_sent += 1;
        self.rx.unacked = 0;
        self.rx.ack_now = false;
        Ok(())
    }

    fn step_inner<IO: Read + Write + ReadReady + WriteReady>(
        &mut self,
        io: &mut IO,
        now: u64,
        buffers: &mut LinkBuffers,
    ) -> Result<Progress, LinkError> {
        let (mut tb, mut rb) = buffers.split();
        if !self.started {
            self.started = true;
            self.last_heard = now;
            self.send_hello(io, now)?;
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
                self.on_byte(b, now, &mut tb, &mut rb)?;
            }
        }
        // Half duplex: a turn whose last frame (the one asking) was lost
        // still gets its answer once the line has been quiet a while.
        let quiet = now.saturating_sub(self.last_byte) >= TURN_QUIET_MS;
        // Our `Hello` again, while the peer's is not heard (ours may have
        // been lost: nothing is sent before both are; on a half-duplex line
        // only robot 0 repeats, when the line is quiet, so that two repeats
        // never collide), or at once when the peer says it has not heard ours.
        let hello_due = self.peer_takes_map.is_none()
            && now.saturating_sub(self.hello_at) >= u64::from(self.config.timeout_ms)
            && (!self.config.half_duplex || (quiet && self.robot_id == 0));
        if self.answer_hello || hello_due {
            self.answer_hello = false;
            self.send_hello(io, now)?;
        }
        if self.config.half_duplex && self.rx.unacked > 0 && quiet {
            self.rx.ack_now = true;
        }
        let acked_now = self.rx.ack_now && self.rx.map.is_some();
        if acked_now {
            self.send_ack(io, rb.have)?;
        }
        // Our map goes out now, or (half duplex, not robot 0) once the peer's
        // is in.
        // A data frame only when the line takes it at once: acknowledgements
        // never wait behind a queue of data.
        let may_send = (!self.config.half_duplex || self.robot_id == 0 || self.rx.done)
            && self.peer_takes_map == Some(true)
            && io.write_ready().map_err(io_error)?;
        if let (Some(tx), true) = (self.tx.as_mut(), may_send) {
            let heard = self.last_byte.max(self.last_heard);
            tx.send_next(&mut tb, io, (now, heard), self.shape, &self.config, &mut self.stats)?;
        }
        if self.finished() {
            if self.finished_at.is_none() {
                // Say so twice: the peer may be waiting for exactly this (on
                // a half-duplex line once, and not after an ack of this step:
                // the peer answers the first at once, into the second).
                self.finished_at = Some(now);
                let says = if self.config.half_duplex { usize::from(!acked_now) } else { 2 };
                for _ in 0..says {
                    self.send_ack(io, rb.have)?;
                }
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

    /// Sends our `Hello`: who we are, what we take of the peer's map, and
    /// whether we heard the peer's. Well protected: the first frame the
    /// peer judges the line by.
    fn send_hello<IO: Write>(&mut self, io: &mut IO, now: u64) -> Result<(), LinkError> {
        let hello = Hello {
            robot_id: self.robot_id,
            class_table: CLASS_TABLE_VERSION,
            resolution: self.resolution,
            max_payload: MAX_PAYLOAD as u16,
            takes_map: self.rx.map.is_some(),
            capacity: self.rx.map.as_ref().map_or(0, |m| m.capacity().min(u32::MAX as usize) as u32),
            heard: self.peer_takes_map.is_some(),
        };
        self.hello_at = now;
        send_msg(io, &Message::Hello(hello), HELLO_PARITY, &mut self.stats).map(|_| ())
    }

    fn on_byte(&mut self, b: u8, now: u64, tb: &mut TxBufs<'_>, rb: &mut RxBufs<'_>) -> Result<(), LinkError> {
        let Session {
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
            answer_hello,
            line,
            shape,
            ..
        } = self;
        let Some((payload, repaired, in_block)) = take_frame(deframer, line, stats, config, shape, b) else {
            return Ok(());
        };
        let Some(msg) = decode_frame(payload, repaired, stats)? else { return Ok(()) };
        stats.repaired_frames += u32::from(repaired);
        stats.frames_received += 1;
        *last_heard = now;
        match msg {
            Message::Hello(h) => {
                if !compatible(h.class_table, h.resolution, *resolution) {
                    return Err(LinkError::Incompatible);
                }
                if peer_takes_map.is_none() {
                    // First heard: our map cut to what the peer holds,
                    // before anything of it goes out.
                    if let Some(t) = tx.take() {
                        *tx = Some(t.fit(h.capacity, tb.model, config)?);
                    }
                }
                *peer_takes_map = Some(h.takes_map);
                *peer_id = Some(h.robot_id);
                // A peer that has not heard ours gets it (again).
                *answer_hello |= !h.heard;
            }
            Message::Data { offset, poll, tag, data } => {
                rx.echo = tag;
                // Half duplex: an answer only when asked (the turn is over).
                // Blocks carry up to 300 data bytes each: acknowledged every
                // two (every four, the sender's window filled before the
                // acks came: 5% took 1.96 s instead of 1.86, simulated).
                let every = match (config.half_duplex, in_block) {
                    (true, _) => u8::MAX,
                    (false, true) => 2,
                    (false, false) => ACK_EVERY,
                };
                rx.on_data(rb, (offset, poll, every), data, *resolution, stats)?
            }
            Message::Ack(ack) => {
                if ack.flags & ACK_FINISHED != 0 {
                    *peer_finished = true;
                }
                if let Some(t) = tx.as_mut() {
                    t.on_ack(tb.segs, &ack, now, config);
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

/// Whether a peer's map (its class table version and voxel size) can be
/// taken by a map of voxels of `ours` metres: the one test of the Hello,
/// of a received map's header and of a staging map against its map.
pub(super) fn compatible(class_table: u16, resolution: f32, ours: f32) -> bool {
    class_table == CLASS_TABLE_VERSION && same_resolution(resolution, ours)
}

/// Two voxel sizes that are the same one (to a millionth).
pub(super) fn same_resolution(a: f32, b: f32) -> bool {
    (a - b).abs() <= 1e-6 * b
}

/// One byte into the deframer, and what it told of the line (the line
/// estimate and the frame shape follow it): the frame it completed, if
/// any, as (payload, repaired, came in a block).
fn take_frame<'d>(
    deframer: &'d mut BlockDeframer,
    line: &mut LineEstimate,
    stats: &mut LinkStats,
    config: &LinkConfig,
    shape: &mut FrameShape,
    b: u8,
) -> Option<(&'d [u8], bool, bool)> {
    if b != 0 {
        line.byte();
    }
    // What a block's segments told of the line (a frame tells below).
    let (pushed, pieces) = deframer.push(b);
    for o in pieces {
        line.piece(o.bytes, o.damage, o.parity);
    }
    let taken = match pushed {
        Ok(Some(f)) => {
            if f.segments == 0 {
                line.frame(Some((f.damage, f.parity)));
            }
            stats.count_repairs(f.damage);
            Some((f.payload, f.repaired, f.segments > 0))
        }
        Ok(None) if pieces.is_empty() => return None,
        Ok(None) => None,
        Err(e) => {
            stats.bad_frames += 1;
            // No header read: a frame with two of its first bytes hit, or
            // a segment of a block whose descriptors were both lost (its
            // bytes no frame's, and its errors unknown). Half duplex has
            // no blocks, and there it is a frame a collision garbled.
            if e == crate::wire::DeframeError::Header && !config.half_duplex {
                line.skip();
            } else if pieces.is_empty() {
                line.frame(None);
            }
            None
        }
    };
    *shape = FrameShape::for_line(line.model(), config);
    taken
}

/// A frame's message: `None` (counted as a bad frame) when it does not
/// decode; an error when an intact frame (its CRC-32 holds, nothing
/// repaired) is in another version or a Hello with a non-finite field:
/// the peer, not the line, says so, and waiting would only end at the
/// deadline.
fn decode_frame<'p>(
    payload: &'p [u8],
    repaired: bool,
    stats: &mut LinkStats,
) -> Result<Option<Message<'p>>, LinkError> {
    match Message::decode(payload) {
        Ok(msg) => Ok(Some(msg)),
        Err(MessageError::Version(v)) if !repaired => Err(LinkError::Version(v)),
        Err(MessageError::NonFinite) if !repaired => Err(LinkError::BadHello),
        Err(_) => {
            stats.bad_frames += 1;
            Ok(None)
        }
    }
}
