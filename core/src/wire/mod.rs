//! Stage 2: the bytes between robots (and in map files).
//!
//! - [`crc`]: CRC-32 of frames and maps;
//! - [`bits`]: bit-level writer and reader;
//! - [`codec`]: the compact, chunked voxel encoding (Morton order, adaptive
//!   Golomb-Rice gaps, quantised labels, occupancy and position).

pub mod bits;
pub mod codec;
pub mod crc;

pub use codec::{DecodeError, EncodeError, MapDecoder, MapEncoder};
pub use crc::{crc32, Crc32};

#[cfg(test)]
mod tests;
