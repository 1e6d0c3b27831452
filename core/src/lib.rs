//! # cosem-core
//!
//! Collaborative semantic map matching for robots, in `no_std` Rust with no
//! allocator: the same code builds a robot's local semantic voxel map on a
//! microcontroller and on a laptop, bit for bit.
//!
//! Data flows one way, and the modules follow it:
//!
//! 0. [`geometry`]: rigid transforms and the conventions' pose syntax.
//! 1. [`classes`]: the class table (SemanticKITTI's 19 classes) and the
//!    mapping from raw dataset ids.
//!    [`camera`] gives LiDAR points their labels from a camera's semantic
//!    segmentation when the LiDAR has none (projection, Cityscapes ids,
//!    per-pixel class probabilities).
//! 2. [`map`]: labelled points are fused into a [`map::LocalMap`], a
//!    fixed-capacity voxel hash map holding per voxel a sub-voxel mean
//!    position, an occupancy log-odds, a hit count and a Bayes-fused label
//!    distribution, in 24 bytes (32 with its index). Coarser levels of a
//!    resolution pyramid are built from it without allocation.
//! 3. [`matching`]: EM map matching. A [`matching::Pyramid`] prepares each
//!    map once (per-class coarse levels, hash index, normals); a
//!    [`matching::Matcher`] aligns a scene to a model coarse to fine with an
//!    annealed Gaussian weight and semantic compatibility, and returns a
//!    [`matching::MatchResult`] with a status, inliers, overlap and the
//!    information matrix.
//! 4. [`wire`]: checksums (and, later, the compact encoding maps travel in).
//!
//! 5. [`robot`]: one robot of a pair end to end (fed points, map, link,
//!    alignment, report), shared by the firmware and the host.
//!
//! [`selftest`] runs a fixed mapping, wire and matching case whose figures
//! must agree to the bit on the chip and on a host.
//!
//! Capacities are set by the storage: [`map::ArrayStorage`] fixes them at
//! compile time (`FixedMap<N>`), [`map::SliceStorage`] borrows buffers the
//! caller owns. A full map is a typed error or a documented eviction
//! ([`map::FullPolicy`]); NaN and out-of-range points are typed errors.
//!
//! ## Features
//! - `defmt`: derives `defmt::Format` for the public types, for firmware logs.
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

pub mod camera;
pub mod classes;
pub mod geometry;
pub mod link;
pub mod map;
pub mod matching;
pub mod robot;
pub mod selftest;
pub mod wire;

#[cfg(test)]
mod test_util;
