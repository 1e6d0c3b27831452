//! Stage 2: the bytes between robots (and in map files).
//!
//! - [`crc`]: CRC-32 of frames and maps;
//! - [`bits`]: bit-level writer and reader;
//! - [`codec`]: the compact, chunked voxel encoding (Morton order, adaptive
//!   Golomb-Rice gaps, quantised labels, occupancy and position);
//! - [`frame`]: COBS framing with a CRC-32 per frame;
//! - [`message`]: the versioned messages (postcard);
//! - [`mapfile`]: reading `.cmap` map files without an allocator.

pub mod bits;
pub mod codec;
pub mod crc;
pub mod frame;
pub mod mapfile;
pub mod message;

pub use codec::{DecodeError, EncodeError, MapDecoder, MapEncoder};
pub use crc::{crc32, Crc32};
pub use frame::{encode_frame, DeframeError, Deframer, FrameError, MAX_FRAME, MAX_PAYLOAD};
pub use message::{AbortReason, Hello, MapHeader, MatchReport, Message, MessageError, PROTOCOL_VERSION};

#[cfg(test)]
mod tests;
