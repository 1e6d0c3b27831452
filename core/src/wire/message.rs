//! The messages robots exchange, versioned and postcard-encoded.
//!
//! Every frame payload starts with [`PROTOCOL_VERSION`]; a peer speaking
//! another version is told apart at the first frame. Floats from the wire
//! are checked: a NaN or infinity is a typed error, never a value.

use super::frame::{frame_with, FrameError};
use serde::{Deserialize, Serialize};

/// Version of the link protocol (first byte of every payload).
pub const PROTOCOL_VERSION: u8 = 1;

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

/// One message.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Message<'a> {
    /// Who I am.
    Hello(Hello),
    /// A map follows.
    MapHeader(MapHeader),
    /// Part of the map's encoding.
    Chunk {
        /// The transfer.
        map_id: u32,
        /// Index of the chunk's first voxel in the stream.
        seq: u32,
        /// Encoded voxels ([`super::codec`]).
        #[serde(borrow)]
        data: &'a [u8],
    },
    /// All voxels were sent; `seq` is the voxel count plus one.
    End {
        /// The transfer.
        map_id: u32,
        /// Voxel count plus one.
        seq: u32,
    },
    /// Cumulative acknowledgement: the receiver holds the first `seq`
    /// voxels (after the header: 0; after `End`: the count plus one).
    Ack {
        /// The transfer.
        map_id: u32,
        /// Voxels held (or `End`'s `seq`).
        seq: u32,
    },
    /// A frame was lost or broken: send again from voxel `seq`.
    Nack {
        /// The transfer.
        map_id: u32,
        /// First voxel wanted.
        seq: u32,
    },
    /// The transfer is over without a map.
    Abort {
        /// The transfer.
        map_id: u32,
        /// Why.
        reason: AbortReason,
    },
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

impl<'a> Message<'a> {
    /// Encodes the message (version byte first) into `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, MessageError> {
        self.check()?;
        encode_versioned(PROTOCOL_VERSION, self, out)
    }

    /// Encodes the message as one frame (delimiter included) into `out`.
    pub fn to_frame(&self, out: &mut [u8]) -> Result<usize, MessageError> {
        frame_with(out, |payload| self.encode(payload))
    }

    /// Decodes a payload; borrows chunk data from it.
    pub fn decode(payload: &'a [u8]) -> Result<Self, MessageError> {
        let msg: Message<'a> = decode_versioned(PROTOCOL_VERSION, payload)?;
        msg.check()?;
        Ok(msg)
    }

    fn check(&self) -> Result<(), MessageError> {
        match self {
            Message::Hello(h) => finite(&[h.resolution]),
            Message::MapHeader(h) => {
                finite(&[h.resolution])?;
                finite(&h.bounds)
            }
            _ => Ok(()),
        }
    }
}

/// Every message type with its exact bytes: the wire format, frozen. The
/// unit tests and the on-target self-test both check it, so a host and a
/// robot that pass agree on every byte.
pub const GOLDEN: [(Message<'static>, &[u8]); 7] = [
    (
        Message::Hello(Hello { robot_id: 1, class_table: 1, resolution: 0.2, max_payload: 512 }),
        &[1, 0, 1, 1, 205, 204, 76, 62, 128, 4],
    ),
    (
        Message::MapHeader(MapHeader {
            map_id: 7,
            robot_id: 1,
            class_table: 1,
            anchor_time_us: 1_000_000,
            voxel_count: 300,
            resolution: 0.5,
            bounds: [-1.0, -2.0, -3.0, 1.0, 2.0, 3.0],
            digest: 0xDEAD_BEEF,
        }),
        &[
            1, 1, 7, 1, 1, 192, 132, 61, 172, 2, 0, 0, 0, 63, 0, 0, 128, 191, 0, 0, 0, 192, 0, 0, 64, 192, 0, 0, 128,
            63, 0, 0, 0, 64, 0, 0, 64, 64, 239, 253, 182, 245, 13,
        ],
    ),
    (Message::Chunk { map_id: 7, seq: 1, data: &[1, 2, 0, 255] }, &[1, 2, 7, 1, 4, 1, 2, 0, 255]),
    (Message::End { map_id: 7, seq: 9 }, &[1, 3, 7, 9]),
    (Message::Ack { map_id: 7, seq: 300 }, &[1, 4, 7, 172, 2]),
    (Message::Nack { map_id: 7, seq: 3 }, &[1, 5, 7, 3]),
    (Message::Abort { map_id: 7, reason: AbortReason::Digest }, &[1, 6, 7, 2]),
];

/// Encodes and decodes every [`GOLDEN`] message; `Err(i)` names the first
/// that differs.
pub fn check_golden() -> Result<(), usize> {
    for (i, (msg, bytes)) in GOLDEN.iter().enumerate() {
        let mut buf = [0u8; 96];
        let ok = msg.encode(&mut buf).ok().and_then(|n| buf.get(..n)) == Some(*bytes)
            && Message::decode(bytes).as_ref() == Ok(msg);
        if !ok {
            return Err(i);
        }
    }
    Ok(())
}
