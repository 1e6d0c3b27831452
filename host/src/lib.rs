//! cosem-host: the std side of cosem, as a library. The `cosem` binary
//! (feature `cli`, on by default) is a thin command line over it; with
//! `default-features = false` the library alone builds (no clap, rayon,
//! serial ports, PNG or JSON printing).
//!
//! The modules are grouped by layer in folders ([`sources`], [`maps`],
//! [`lines`], [`evaluation`], [`boards`], [`reports`]), each also reachable
//! by its own name:
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

/// Layer 1, scans in: every source of labelled scans and its readers.
pub mod sources {
    pub mod cdr_read;
    pub mod class_table;
    pub mod cloud;
    pub mod kitti;
    pub mod label;
    pub mod mcap_read;
    pub mod recording;
    pub mod seg_files;
    #[cfg(feature = "segment")]
    pub mod segment;
    pub mod source;
    pub mod synth;
}

/// Layer 2, maps: frames to maps on the heap, map files, exports, label
/// noise.
pub mod maps {
    pub mod cmap;
    pub mod job;
    pub mod mapping;
    pub mod noise;
    pub mod ply;
}

/// Layer 3, lines: one robot's end of a map exchange, the paced lossy
/// relay, TCP and serial ports behind embedded-io, two maps exchanged
/// over a simulated line.
pub mod lines {
    pub mod exchange;
    pub mod link;
    pub mod relay;
    pub mod transport;
}

/// Layer 4, matching and evaluation: alignment, pairs and teams on the
/// host, the protocols, benchmarks, the demo.
pub mod evaluation {
    pub mod align;
    pub mod bench;
    pub mod boxplot;
    pub mod demo;
    pub mod eval;
    pub mod pair;
    pub mod stats;
    pub mod team;
}

/// Layer 5, boards: the robots' pipelines on emulated boards (QEMU) and
/// the host's twin runs.
pub mod boards {
    pub mod board;
    pub mod robots;
    pub mod team_board;
}

/// Output: the commands' JSON (stable field names).
pub mod reports {
    pub mod report;
    pub mod team;
}

pub mod error;
pub mod limits;
pub mod paths;
pub mod rng;

// The modules by their own names too (the paths the crate has always had).
pub use boards::{board, robots, team_board};
pub use evaluation::{align, bench, boxplot, demo, eval, pair, stats, team};
pub use lines::{exchange, link, relay, transport};
pub use maps::{cmap, job, mapping, noise, ply};
pub use reports::report;
#[cfg(feature = "segment")]
pub use sources::segment;
pub use sources::{cdr_read, class_table, cloud, kitti, label, mcap_read, recording, seg_files, source, synth};

pub use error::Error;
