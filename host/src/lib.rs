//! cosem-host: the std side of cosem, as a library. The `cosem` binary
//! (feature `cli`, on by default) is a thin command line over it; with
//! `default-features = false` the library alone builds (no clap, rayon,
//! serial ports, PNG or JSON printing).
//!
//! The modules are grouped by layer, lowest first, and a module imports
//! only from its own layer (without cycles) and the layers below
//! (`tests/tests/layers.rs`, `docs/architecture.md`):
//!
//! - base: [`paths`] (outputs never an input, written whole), [`rng`],
//!   [`limits`] (bounds on sizes and threads), [`diagnostics`] (warnings),
//!   [`knobs`] (settings as messages name them, spelled by the front end),
//!   [`poses`] (poses as text), [`error`] (the one error, carrying each
//!   layer's typed error);
//! - [`sources`]: labelled scans in (SemanticKITTI folders, ROS 2
//!   recordings, PCD/PLY scans with poses);
//! - [`camera`]: camera segmentation (images, a network in ONNX) and LiDAR
//!   labels from it;
//! - [`worlds`]: synthetic worlds and their sensors;
//! - [`maps`]: frames to maps on the heap, map files, exports, label noise;
//! - [`matching`]: alignment on the host;
//! - [`lines`]: links, ports, the paced lossy relay, simulated exchanges;
//! - [`evaluation`]: the map pipeline, pairs, protocols, teams on the
//!   host, benchmarks, the demo;
//! - [`boards`]: the robots' pipelines on emulated boards (QEMU);
//! - [`reports`]: the commands' JSON (stable field names) and text;
//! - `ros` (feature `ros`, on by default): ROS 2 over DDS, pure Rust
//!   (`cosem ros play`).
//!
//! Transforms are nalgebra `Isometry3` throughout, with the conventions'
//! pose syntax and error measures from [`cosem_core::geometry`].

pub mod diagnostics;
pub mod knobs;
pub mod limits;
pub mod paths;
pub mod poses;
pub mod rng;

/// Scans in: every source of labelled scans and its readers.
pub mod sources {
    pub mod cdr_read;
    pub mod class_table;
    pub mod cloud;
    pub mod drift;
    pub mod kitti;
    pub mod mcap_read;
    pub mod recording;
    pub mod ros_msgs;
    pub mod ros_pose;
    pub mod source;
}

/// The camera: segmentation images and probability maps, a network that
/// makes them (feature `segment`), LiDAR labels from them.
pub mod camera {
    pub mod label;
    pub mod seg_files;
    #[cfg(feature = "segment")]
    pub mod segment;
}

/// Synthetic worlds: procedural streets, a simulated 64-beam LiDAR and
/// camera segmentation.
pub mod worlds {
    pub mod synth;
    pub mod town;
}

/// Maps: frames to maps on the heap, map files, exports, label noise.
pub mod maps {
    pub mod cmap;
    pub mod mapping;
    pub mod noise;
    pub mod ply;
    pub mod thin;
}

/// Matching on the host: heap pyramids, alignment with or without a prior.
pub mod matching {
    pub mod align;
}

pub mod error;

/// Lines: one robot's end of a map exchange, the paced lossy relay, TCP
/// and serial ports behind embedded-io, two maps exchanged over a
/// simulated line.
pub mod lines {
    pub mod exchange;
    pub mod link;
    pub mod relay;
    pub mod transport;
}

/// The host's runs: the map pipeline, pairs and their truth, the
/// evaluation protocols, teams on the host, benchmarks, the demo.
pub mod evaluation {
    pub mod bench;
    pub mod boxplot;
    pub mod demo;
    pub mod eval;
    pub mod job;
    pub mod pair;
    pub mod session;
    pub mod stats;
    pub mod team;
}

/// Boards: the robots' pipelines on emulated boards (QEMU) and the host's
/// twin runs.
pub mod boards {
    pub mod board;
    pub mod emulator;
    pub mod feeds;
    pub mod firmware;
    pub mod pump;
    pub mod robots;
    pub mod session_board;
    pub mod team_board;
    pub mod twin;
}

/// Output: the commands' JSON (stable field names) and text.
pub mod reports {
    pub mod match_recording;
    pub mod report;
    pub mod robots;
    pub mod session;
    pub mod session_board;
    pub mod session_recording;
    pub mod team;
}

/// ROS 2 over DDS (ros2-client on RustDDS, pure Rust): topics and QoS,
/// `cosem ros play`.
#[cfg(feature = "ros")]
pub mod ros {
    pub mod dds;
    pub mod follow;
    pub mod node;
    pub mod play;
}
