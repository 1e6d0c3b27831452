//! Layer 4: every byte format of cosem, and nothing above it: this module
//! imports no type from the map's users (matching, link, robot), so a
//! format can be read, tested and fuzzed on its own.
//!
//! - [`crc`]: CRC-32 of frames and map files;
//! - [`range`]: the adaptive binary range coder the codec uses;
//! - [`change`]: the voxels an update changes, coded against the records
//!   the peer holds;
//! - [`codec`]: the compact, chunked voxel encoding (Morton order, range
//!   coded in context: gaps, quantised labels, occupancy and position);
//! - [`rs`]: Reed-Solomon over GF(256), the forward error correction;
//! - [`frame`]: frames of a Reed-Solomon codeword (payload, CRC-32, parity)
//!   that end in a zero byte, the decoder that repairs substituted, dropped
//!   and duplicated bytes, and [`frame::frame_with`], the one "encode a
//!   message, then frame it";
//! - [`message`]: the link's versioned messages (postcard);
//! - [`report`]: a match result as plain numbers;
//! - [`feed`]: the feed protocol between a host and a robot;
//! - [`share`]: a team's estimates, sent between robots after matching;
//! - [`update`]: map updates between robots that keep driving (changed
//!   voxels, removed cells, the map's digest) and their answers;
//! - [`mapfile`]: the `.cmap` map file, read and written without an
//!   allocator.
//!
//! Each format has golden bytes (`GOLDEN*`) that the unit tests and the
//! on-target self-test check, and a fuzz target in `core/fuzz`.

pub mod block;
pub mod change;
pub mod codec;
pub mod crc;
pub mod feed;
pub mod frame;
pub mod mapfile;
pub mod message;
pub mod range;
pub mod report;
pub mod rs;
pub mod share;
pub mod update;

pub use block::{encode_block, BlockDeframer, BlockShape};
pub use codec::{CodecModel, DecodeError, EncodeError, MapDecoder, MapEncoder};
pub use crc::{crc32, Crc32};
pub use feed::{FeedError, FeedMessage, RobotMessage, RobotReport, Setup};
pub use frame::{
    encode_frame, encode_frame_parity, frame_with, Arrived, Damage, DeframeError, Deframer, FrameError, MAX_FRAME,
    MAX_PAYLOAD,
};
pub use mapfile::{MapFileError, MapFileHeader};
pub use message::{AbortReason, Hello, MapHeader, Message, MessageError, PROTOCOL_VERSION};
pub use report::MatchReport;

#[cfg(test)]
mod tests;
