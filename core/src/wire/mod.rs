//! Stage 2: the bytes between robots (and in map files).
//!
//! For now the checksum shared by map files and, later, link frames.

pub mod crc;

pub use crc::{crc32, Crc32};
