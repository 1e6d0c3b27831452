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

mod exchange;
mod frames;
pub(in crate::link) mod line;
mod rx;
mod tx;

use exchange::Exchange;
use frames::{io_error, send_block, send_msg};

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
    exchange: Exchange<'a, M, R, O>,
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
        let exchange = Exchange::new(config, (robot_id, resolution), tx, staging);
        Ok(Endpoint { buffers, exchange })
    }

    /// What moved so far.
    pub fn stats(&self) -> LinkStats {
        self.exchange.stats
    }

    /// Whether the peer's map arrived whole (its digest checked), or this
    /// endpoint receives nothing.
    pub fn received(&self) -> bool {
        self.exchange.rx.done
    }

    /// Whether the peer said it holds our whole map.
    pub fn sent(&self) -> bool {
        self.exchange.sent()
    }

    /// Whether the peer takes our map, from its `Hello` (`None`: not heard
    /// yet). `Some(false)`: a one-sided exchange, nothing of ours is sent;
    /// a robot then tells the peer its match result instead
    /// ([`crate::wire::share`]).
    pub fn peer_takes_map(&self) -> Option<bool> {
        self.exchange.peer_takes_map
    }

    /// The peer's robot id, from its `Hello` (`None`: not heard yet).
    pub fn peer_id(&self) -> Option<u8> {
        self.exchange.peer_id
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
        let s = self.exchange;
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
                return Ok(self.exchange.stats);
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
            Some(b) => self.exchange.step(io, now, b),
            None => Err(LinkError::Setup),
        }
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
