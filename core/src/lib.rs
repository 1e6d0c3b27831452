//! # cosem-core
//!
//! Collaborative semantic map matching for robots, in `no_std` Rust with no
//! allocator: the same code builds a robot's local semantic voxel map on a
//! microcontroller and on a laptop, bit for bit.
//!
//! Data flows one way, and the modules follow it in layers: a module
//! imports only from lower layers (the same numbers appear in each
//! module's documentation, in docs/architecture.md and in the test that
//! holds them, `tests/tests/layers.rs`):
//!
//! 1. [`classes`]: SemanticKITTI's 19-class table and raw ids.
//! 2. [`map`]: labelled points are fused into a [`map::LocalMap`], a
//!    fixed-capacity voxel hash map holding per voxel a sub-voxel mean
//!    position, an occupancy log-odds, a hit count and a Bayes-fused label
//!    distribution, in 24 bytes (32 with its index).
//! 3. [`camera`]: labels from a camera's semantic segmentation
//!    (projection, Cityscapes ids, per-pixel probabilities as a map's
//!    label evidence).
//! 4. [`wire`]: every byte format, importing nothing from the layers above
//!    it: the compact chunked voxel encoding, COBS frames with a CRC-32,
//!    the link's and the feed's versioned messages, a match result as plain
//!    numbers, the `.cmap` map file. Golden bytes freeze each format.
//! 5. [`link`]: an [`link::Endpoint`] sends its map and receives the peer's
//!    over any `embedded-io` byte stream (acks, retries, timeouts, a
//!    staging map accepted only whole).
//! 6. [`matching`]: a [`matching::Pyramid`] prepares each map once
//!    (per-class coarse levels, hash index, normals, footprint); a
//!    [`matching::Matcher`] aligns a scene to a model (coarse correlative
//!    search, then coarse-to-fine EM) and returns a
//!    [`matching::MatchResult`] with a status, inliers, overlap and the
//!    information matrix; [`matching::global`] aligns without a prior.
//!    Beside it, [`team`]: the kept pairwise matches of a team of robots
//!    place every robot in one frame (a small pose graph, with
//!    covariances); and [`pipeline`]: the one configuration of mapping and
//!    matching, its presets (host, boards) and its one validator.
//! 7. [`selftest`]: a fixed mapping, wire and matching case whose figures
//!    must agree to the bit on the chip and on a host.
//! 8. [`robot`]: one robot's sequence (feed, map, link, align, report) as a
//!    poll-driven step machine that the firmware and a host both drive.
//! 9. `sim` (feature `sim`, tests and hosts): a seeded lossy line and the
//!    one driver of N robots over simulated wires.
//!
//! Layer 0, [`geometry`] (rigid transforms, the conventions' pose syntax
//! and error measures) and [`region`] (memory that serves stages in turn,
//! handed over by ownership), underlies them all.
//!
//! Capacities are set by the storage: [`map::ArrayStorage`] fixes them at
//! compile time (`FixedMap<N>`), [`map::SliceStorage`] borrows buffers the
//! caller owns. A full map is a typed error or a documented eviction
//! ([`map::FullPolicy`]); NaN and out-of-range points are typed errors.
//!
//! ## Features
//! - `defmt`: derives `defmt::Format` for the public types, for firmware logs.
//! - `alloc`: heap-backed storages sized at run time (`map::VecStorage`,
//!   `matching::VecPyramidStorage`, sized by
//!   [`matching::PyramidCapacity::for_map`]) for hosts; off by default, and
//!   off in every firmware build.
//!
//! ## Example
//! ```
//! use cosem_core::classes::Class;
//! use cosem_core::map::{FixedMap, ArrayStorage, MapConfig};
//!
//! let mut map = FixedMap::<64>::new(ArrayStorage::new(), MapConfig::default()).unwrap();
//! map.insert_point([1.03, 2.0, 0.1], Class::Pole).unwrap();
//! map.insert_point([1.05, 2.1, 0.1], Class::Pole).unwrap();
//! assert_eq!(map.len(), 1);
//! assert_eq!(map.voxels()[0].class(), Some(Class::Pole));
//! ```
#![no_std]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

#[cfg(test)]
extern crate std;

#[cfg(any(test, feature = "alloc"))]
extern crate alloc;

pub mod camera;
pub mod classes;
pub mod geometry;
pub mod link;
pub mod map;
pub mod matching;
pub mod pipeline;
pub mod region;
pub mod robot;
pub mod selftest;
pub mod session;
#[cfg(any(test, feature = "sim"))]
pub mod sim;
pub mod team;
pub mod wire;

#[cfg(test)]
mod test_util;
