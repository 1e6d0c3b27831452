//! The messages robots exchange, versioned: a version-and-tag byte, then
//! the fields (postcard for `Hello` and `Abort`, fixed little-endian fields and
//! varints for the frequent `Data` and `Ack`, which must be short).
//!
//! A `Data` payload starts with three bytes: the top bit set, the poll flag,
//! then the stream offset modulo 2^14 (on a bad line frames are short, and
//! each byte counts), then the frame's transmission tag, which the
//! receiver's `Ack`s echo (so the sender knows which copy of a resent frame
//! the peer read, and how far it read: a slow peer's queue is told from a
//! loss). Every other payload starts with one byte: the top bit
//! clear, [`PROTOCOL_VERSION`] in the next three bits, the message tag in
//! the low four. A peer speaking another version is told apart at the
//! first frame (its `Hello`; a version-2 `Data` byte reads as version 2). Floats from the wire
//! are checked: a NaN or infinity is a typed error, never a value.

use super::frame::{frame_with, frame_with_parity, FrameError};
use serde::{Deserialize, Serialize};

/// Version of the link protocol (in the first byte of every payload but
/// `Data`). At most 7.
pub const PROTOCOL_VERSION: u8 = 6;

/// `Data` offsets count stream bytes modulo this (the window is far smaller).
pub const OFFSET_MODULUS: u32 = 1 << 14;

/// First byte of a `Data` payload: this bit set, then [`DATA_POLL_BIT`],
/// then the offset's top six bits.
const DATA_BIT: u8 = 0x80;
const DATA_POLL_BIT: u8 = 0x40;

/// First message of each side: who it is and what it speaks.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hello {
    /// Sender's robot id.
    pub robot_id: u8,
    /// Class table version ([`crate::classes::CLASS_TABLE_VERSION`]).
    pub class_table: u16,
    /// Voxel size of its map (m).
    pub resolution: f32,
    /// Largest frame payload it can receive.
    pub max_payload: u16,
    /// Whether it takes the peer's map. A robot that cannot hold one (a
    /// small microcontroller) says no: the exchange is then one-sided, its
    /// map goes out, none comes in (version 4).
    pub takes_map: bool,
    /// Voxels of the peer's map it can hold (0 when it takes none): a
    /// larger peer sends the part of its map that fits (version 6).
    pub capacity: u32,
    /// Whether it has heard the peer's `Hello`. A robot sends no map before
    /// it knows what its peer can hold, so a `Hello` lost on the line is
    /// sent again until answered; one that says `false` is answered with a
    /// `Hello` (version 6).
    pub heard: bool,
}

/// Announces a map: what the receiver must end up with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapHeader {
    /// Identifies this transfer (the sender picks a new one per map).
    pub map_id: u32,
    /// Robot the map belongs to.
    pub robot_id: u8,
    /// Class table version the labels refer to.
    pub class_table: u16,
    /// Timestamp of the anchor scan (microseconds, sender's clock).
    pub anchor_time_us: u64,
    /// Voxels in the map.
    pub voxel_count: u32,
    /// Voxel size (m).
    pub resolution: f32,
    /// Bounds: min x, y, z, max x, y, z (m, anchor frame).
    pub bounds: [f32; 6],
    /// Digest of the whole map's encoded content (see `codec::MapDigest`).
    pub digest: u32,
}

/// Why a transfer was abandoned.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AbortReason {
    /// The receiver cannot hold the map.
    TooLarge,
    /// A chunk did not decode.
    BadChunk,
    /// The assembled map's digest differs from the header's.
    Digest,
    /// Incompatible resolution or class table.
    Incompatible,
    /// The sender gave up (retries exhausted).
    GaveUp,
}

/// One range of the stream the receiver holds beyond `cum`: bytes
/// `cum + start .. cum + start + len` (a selective acknowledgement).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SackBlock {
    /// First byte held, counted from `cum`.
    pub start: u16,
    /// Bytes held from there (at least one).
    pub len: u16,
}

/// Most [`SackBlock`]s an [`Ack`] carries.
pub const MAX_SACK: usize = 3;

/// [`Ack::flags`]: the receiver holds the sender's whole map, digest checked
/// (or receives none).
pub const ACK_COMPLETE: u8 = 1;
/// [`Ack::flags`]: the sender of this ack is finished: it holds the peer's
/// map and its own was acknowledged whole. The last word of an exchange.
pub const ACK_FINISHED: u8 = 2;
/// [`Ack::flags`]: the blocks are every range held up to the last one's
/// end. Without it, more ranges were held than an ack carries: the blocks
/// are the first ones after `cum`, then the one that grew last, and only
/// the stream up to the end of the next-to-last block is described.
pub const ACK_ALL_BLOCKS: u8 = 4;

/// What the receiver of a map stream holds: everything before `cum`, plus
/// up to [`MAX_SACK`] ranges after it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ack {
    /// First stream byte not held, modulo 2^16 (the window is far smaller).
    pub cum: u16,
    /// [`ACK_COMPLETE`], [`ACK_FINISHED`], [`ACK_ALL_BLOCKS`].
    pub flags: u8,
    /// Ranges held beyond `cum`, in stream order; the first `blocks` count.
    pub sack: [SackBlock; MAX_SACK],
    /// How many of `sack` are used.
    pub blocks: u8,
    /// The [`Message::Data`] tag of the last data frame received before
    /// this ack (0 before any; version 5): everything the peer sent before
    /// that frame has arrived or is lost.
    pub echo: u8,
}

/// One message. A map travels as a byte *stream* (its [`MapHeader`], then
/// its codec chunks, each record prefixed by its length), cut into `Data`
/// frames at any byte: so a frame's size follows the line, not the map,
/// and a lost frame can be resent cut smaller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message<'a> {
    /// Who I am.
    Hello(Hello),
    /// Bytes of the sender's map stream.
    Data {
        /// Stream offset of the first byte, modulo [`OFFSET_MODULUS`].
        offset: u16,
        /// Answer with an [`Ack`] at once (the sender is about to wait).
        poll: bool,
        /// The sender's count of data frames sent, this one included,
        /// modulo 256 (version 5): echoed by [`Ack::echo`].
        tag: u8,
        /// The bytes.
        data: &'a [u8],
    },
    /// What the receiver holds (cumulative plus selective).
    Ack(Ack),
    /// The transfer is over without a map.
    Abort {
        /// The transfer.
        map_id: u32,
        /// Why.
        reason: AbortReason,
    },
}

/// Message tags (low nibble of the first byte; 1 and 2 were `Data` in
/// version 2).
const TAG_HELLO: u8 = 0;
const TAG_ACK: u8 = 3;
const TAG_ABORT: u8 = 4;

/// Bytes of a `Data` payload before its data: flags and offset, tag.
pub const DATA_HEADER: usize = 3;

/// Bytes a `Data` frame adds to its data, besides its parity: flags,
/// offset and tag, CRC-32, the frame's header and delimiter.
pub const DATA_OVERHEAD: usize = DATA_HEADER + 4 + super::frame::HEADER + 1;

#[derive(Serialize, Deserialize)]
struct AbortFields {
    map_id: u32,
    reason: AbortReason,
}

/// Why a payload is not a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MessageError {
    /// Empty payload.
    Empty,
    /// Another protocol version.
    Version(u8),
    /// Not a well-formed message of this version.
    Malformed,
    /// Bytes after the message.
    Trailing,
    /// A float is NaN or infinite.
    NonFinite,
    /// The output buffer is too small.
    Buffer,
}

impl core::fmt::Display for MessageError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            MessageError::Empty => f.write_str("empty payload"),
            MessageError::Version(v) => write!(f, "protocol version {v}, expected {PROTOCOL_VERSION}"),
            MessageError::Malformed => f.write_str("malformed message"),
            MessageError::Trailing => f.write_str("bytes after the message"),
            MessageError::NonFinite => f.write_str("non-finite number in a message"),
            MessageError::Buffer => f.write_str("buffer too small for the message"),
        }
    }
}

impl core::error::Error for MessageError {}

impl From<FrameError> for MessageError {
    fn from(_: FrameError) -> Self {
        MessageError::Buffer
    }
}

/// Encodes `msg` as a version byte and postcard into `out`; returns the
/// length. Shared by every protocol that travels in frames (this one and
/// [`super::feed`]).
pub(crate) fn encode_versioned<T: Serialize>(version: u8, msg: &T, out: &mut [u8]) -> Result<usize, MessageError> {
    let (first, rest) = out.split_first_mut().ok_or(MessageError::Buffer)?;
    *first = version;
    let used = postcard::to_slice(msg, rest).map_err(|_| MessageError::Buffer)?;
    Ok(1 + used.len())
}

/// Decodes a version byte and postcard, refusing another version and
/// trailing bytes.
pub(crate) fn decode_versioned<'a, T: Deserialize<'a>>(version: u8, payload: &'a [u8]) -> Result<T, MessageError> {
    let (&v, rest) = payload.split_first().ok_or(MessageError::Empty)?;
    if v != version {
        return Err(MessageError::Version(v));
    }
    let (msg, tail): (T, &[u8]) = postcard::take_from_bytes(rest).map_err(|_| MessageError::Malformed)?;
    if !tail.is_empty() {
        return Err(MessageError::Trailing);
    }
    Ok(msg)
}

fn finite(values: &[f32]) -> Result<(), MessageError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(MessageError::NonFinite)
    }
}

fn push(out: &mut [u8], at: &mut usize, byte: u8) -> Result<(), MessageError> {
    *out.get_mut(*at).ok_or(MessageError::Buffer)? = byte;
    *at += 1;
    Ok(())
}

fn push_varint(out: &mut [u8], at: &mut usize, mut v: u16) -> Result<(), MessageError> {
    loop {
        let byte = (v & 0x7F) as u8;
        v >>= 7;
        push(out, at, if v == 0 { byte } else { byte | 0x80 })?;
        if v == 0 {
            return Ok(());
        }
    }
}

fn take_varint(input: &[u8], at: &mut usize) -> Result<u16, MessageError> {
    let mut v = 0u32;
    for i in 0..3 {
        let byte = *input.get(*at).ok_or(MessageError::Malformed)?;
        *at += 1;
        v |= u32::from(byte & 0x7F) << (7 * i);
        if byte & 0x80 == 0 {
            if byte == 0 && i > 0 {
                return Err(MessageError::Malformed);
            }
            return u16::try_from(v).map_err(|_| MessageError::Malformed);
        }
    }
    Err(MessageError::Malformed)
}

impl Ack {
    /// The used selective blocks.
    pub fn blocks(&self) -> &[SackBlock] {
        self.sack.get(..usize::from(self.blocks)).unwrap_or(&[])
    }
}

impl<'a> Message<'a> {
    /// Encodes the message (version byte, tag, fields) into `out`; returns
    /// its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, MessageError> {
        self.check()?;
        let mut at = 0;
        match self {
            Message::Hello(h) => {
                push(out, &mut at, PROTOCOL_VERSION << 4 | TAG_HELLO)?;
                let rest = out.get_mut(at..).ok_or(MessageError::Buffer)?;
                at += postcard::to_slice(h, rest).map_err(|_| MessageError::Buffer)?.len();
            }
            Message::Data { offset, poll, tag, data } => {
                let [lo, hi] = offset.to_le_bytes();
                push(out, &mut at, DATA_BIT | if *poll { DATA_POLL_BIT } else { 0 } | hi)?;
                push(out, &mut at, lo)?;
                push(out, &mut at, *tag)?;
                let dst = out.get_mut(at..at + data.len()).ok_or(MessageError::Buffer)?;
                dst.copy_from_slice(data);
                at += data.len();
            }
            Message::Ack(a) => {
                push(out, &mut at, PROTOCOL_VERSION << 4 | TAG_ACK)?;
                for b in a.cum.to_le_bytes() {
                    push(out, &mut at, b)?;
                }
                push(out, &mut at, a.flags)?;
                push(out, &mut at, a.echo)?;
                for b in a.blocks() {
                    push_varint(out, &mut at, b.start)?;
                    push_varint(out, &mut at, b.len)?;
                }
            }
            Message::Abort { map_id, reason } => {
                push(out, &mut at, PROTOCOL_VERSION << 4 | TAG_ABORT)?;
                let rest = out.get_mut(at..).ok_or(MessageError::Buffer)?;
                let fields = AbortFields { map_id: *map_id, reason: *reason };
                at += postcard::to_slice(&fields, rest).map_err(|_| MessageError::Buffer)?.len();
            }
        }
        Ok(at)
    }

    /// Encodes the message as one frame (delimiter included) into `out`.
    pub fn to_frame(&self, out: &mut [u8]) -> Result<usize, MessageError> {
        frame_with(out, |payload| self.encode(payload))
    }

    /// As [`Message::to_frame`], with `parity` parity bytes.
    pub fn to_frame_parity(&self, out: &mut [u8], parity: usize) -> Result<usize, MessageError> {
        frame_with_parity(out, parity, |payload| self.encode(payload))
    }

    /// Decodes a payload; borrows `Data` bytes from it.
    pub fn decode(payload: &'a [u8]) -> Result<Self, MessageError> {
        let (&first, body) = payload.split_first().ok_or(MessageError::Empty)?;
        if first & DATA_BIT != 0 {
            let (&[lo, tag], data) = body.split_first_chunk().ok_or(MessageError::Malformed)?;
            let offset = u16::from_le_bytes([lo, first & !(DATA_BIT | DATA_POLL_BIT)]);
            return Ok(Message::Data { offset, poll: first & DATA_POLL_BIT != 0, tag, data });
        }
        if first >> 4 != PROTOCOL_VERSION {
            return Err(MessageError::Version(first >> 4));
        }
        let tag = first & 0x0F;
        let msg = match tag {
            TAG_HELLO => Message::Hello(decode_exact(body)?),
            TAG_ACK => {
                let (&[lo, hi, flags, echo], mut blocks) = body.split_first_chunk().ok_or(MessageError::Malformed)?;
                let mut ack = Ack { cum: u16::from_le_bytes([lo, hi]), flags, echo, ..Ack::default() };
                while !blocks.is_empty() {
                    let mut at = 0;
                    let start = take_varint(blocks, &mut at)?;
                    let len = take_varint(blocks, &mut at)?;
                    let slot = ack.sack.get_mut(usize::from(ack.blocks)).ok_or(MessageError::Trailing)?;
                    if len == 0 {
                        return Err(MessageError::Malformed);
                    }
                    *slot = SackBlock { start, len };
                    ack.blocks += 1;
                    blocks = blocks.get(at..).unwrap_or(&[]);
                }
                Message::Ack(ack)
            }
            TAG_ABORT => {
                let f: AbortFields = decode_exact(body)?;
                Message::Abort { map_id: f.map_id, reason: f.reason }
            }
            _ => return Err(MessageError::Malformed),
        };
        msg.check()?;
        Ok(msg)
    }

    fn check(&self) -> Result<(), MessageError> {
        match self {
            Message::Hello(h) => finite(&[h.resolution]),
            Message::Data { offset, .. } if u32::from(*offset) >= OFFSET_MODULUS => Err(MessageError::Malformed),
            _ => Ok(()),
        }
    }
}

/// Postcard of exactly `bytes`: trailing bytes are an error.
fn decode_exact<'a, T: Deserialize<'a>>(bytes: &'a [u8]) -> Result<T, MessageError> {
    let (msg, tail): (T, &[u8]) = postcard::take_from_bytes(bytes).map_err(|_| MessageError::Malformed)?;
    if !tail.is_empty() {
        return Err(MessageError::Trailing);
    }
    Ok(msg)
}

impl MapHeader {
    /// Encodes the header (postcard) into `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, MessageError> {
        finite(&[self.resolution])?;
        finite(&self.bounds)?;
        Ok(postcard::to_slice(self, out).map_err(|_| MessageError::Buffer)?.len())
    }

    /// Decodes a header, refusing trailing bytes and non-finite numbers.
    pub fn decode(bytes: &[u8]) -> Result<Self, MessageError> {
        let h: MapHeader = decode_exact(bytes)?;
        finite(&[h.resolution])?;
        finite(&h.bounds)?;
        Ok(h)
    }
}

/// Every message type with its exact bytes: the wire format, frozen. The
/// unit tests and the on-target self-test both check it, so a host and a
/// robot that pass agree on every byte.
pub const GOLDEN: [(Message<'static>, &[u8]); 5] = [
    (
        Message::Hello(Hello {
            robot_id: 1,
            class_table: 1,
            resolution: 0.2,
            max_payload: 512,
            takes_map: true,
            capacity: 3000,
            heard: false,
        }),
        &[0x60, 1, 1, 205, 204, 76, 62, 128, 4, 1, 0xB8, 0x17, 0],
    ),
    (Message::Data { offset: 0x1234, poll: false, tag: 5, data: &[1, 2, 0, 255] }, &[0x92, 0x34, 5, 1, 2, 0, 255]),
    (Message::Data { offset: 7, poll: true, tag: 0xFE, data: &[9] }, &[0xC0, 7, 0xFE, 9]),
    (
        Message::Ack(Ack {
            cum: 300,
            flags: ACK_COMPLETE,
            sack: [SackBlock { start: 20, len: 200 }, SackBlock { start: 400, len: 1 }, SackBlock { start: 0, len: 0 }],
            blocks: 2,
            echo: 9,
        }),
        &[0x63, 44, 1, 1, 9, 20, 200, 1, 144, 3, 1],
    ),
    (Message::Abort { map_id: 7, reason: AbortReason::Digest }, &[0x64, 7, 2]),
];

/// The golden map header (a record of the map stream) and its bytes.
pub const GOLDEN_HEADER: (MapHeader, &[u8]) = (
    MapHeader {
        map_id: 7,
        robot_id: 1,
        class_table: 1,
        anchor_time_us: 1_000_000,
        voxel_count: 300,
        resolution: 0.5,
        bounds: [-1.0, -2.0, -3.0, 1.0, 2.0, 3.0],
        digest: 0xDEAD_BEEF,
    },
    &[
        7, 1, 1, 192, 132, 61, 172, 2, 0, 0, 0, 63, 0, 0, 128, 191, 0, 0, 0, 192, 0, 0, 64, 192, 0, 0, 128, 63, 0, 0,
        0, 64, 0, 0, 64, 64, 239, 253, 182, 245, 13,
    ],
);

/// Encodes and decodes every [`GOLDEN`] message and [`GOLDEN_HEADER`];
/// `Err(i)` names the first that differs (the header is last).
pub fn check_golden() -> Result<(), usize> {
    for (i, (msg, bytes)) in GOLDEN.iter().enumerate() {
        let mut buf = [0u8; 96];
        let ok = msg.encode(&mut buf).ok().and_then(|n| buf.get(..n)) == Some(*bytes)
            && Message::decode(bytes).as_ref() == Ok(msg);
        if !ok {
            return Err(i);
        }
    }
    let (h, bytes) = GOLDEN_HEADER;
    let mut buf = [0u8; 96];
    let ok = h.encode(&mut buf).ok().and_then(|n| buf.get(..n)) == Some(bytes) && MapHeader::decode(bytes) == Ok(h);
    if !ok {
        return Err(GOLDEN.len());
    }
    Ok(())
}
