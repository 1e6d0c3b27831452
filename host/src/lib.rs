//! cosem-host: the std side of cosem, as a library. The `cosem` binary
//! (feature `cli`, on by default) is a thin command line over it; with
//! `default-features = false` the library alone builds (no clap, rayon,
//! serial ports, PNG or JSON printing).
//!
//! - Data in: [`kitti`] (SemanticKITTI layout; every error names its file),
//!   [`synth`] (procedural streets, a simulated 64-beam LiDAR, camera
//!   segmentation), [`label`] (LiDAR labels from camera segmentation),
//!   [`noise`] (a segmentation network's label errors, seeded), [`cloud`]
//!   (users' scans as PCD or PLY files with poses in KITTI's layout).
//! - Maps: [`mapping`] (frames to a map on the heap), [`cmap`] (the core's
//!   map file with path context), [`ply`] (export).
//! - Matching: [`align`] (heap pyramids, alignment with or without a
//!   prior), [`pair`] (two robots' maps and their truth), [`eval`] (starts,
//!   thresholds, outcomes, summaries), [`stats`] (one quantile).
//! - Robots: [`link`] (one robot's end of the map exchange), [`robots`]
//!   (feeds, the host's run of the robots' pipeline, two QEMU boards),
//!   [`board`] (the boards a robot runs on), [`team`] and [`team_board`]
//!   (a team on the host and on boards), [`transport`] (TCP and serial
//!   ports behind embedded-io).
//! - Output: [`report`] (the JSON of the commands), [`boxplot`] (SVG).
//!
//! Transforms are nalgebra `Isometry3` throughout, with the conventions'
//! pose syntax and error measures from [`cosem_core::geometry`].

pub mod align;
pub mod bench;
pub mod board;
pub mod boxplot;
pub mod cdr_read;
pub mod class_table;
pub mod cloud;
pub mod cmap;
pub mod demo;
pub mod error;
pub mod eval;
pub mod kitti;
pub mod label;
pub mod link;
pub mod mapping;
pub mod mcap_read;
pub mod noise;
pub mod pair;
pub mod paths;
pub mod ply;
pub mod recording;
pub mod relay;
pub mod report;
pub mod rng;
pub mod robots;
pub mod source;
pub mod stats;
pub mod synth;
pub mod team;
pub mod team_board;
pub mod transport;

pub use error::Error;
