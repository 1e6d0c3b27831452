//! cosem-host: the std side of cosem. Reads SemanticKITTI-layout data, makes
//! synthetic sequences, builds maps with `cosem-core`, and reads and writes
//! map files. The `cosem` binary is a thin CLI over these modules.

pub mod align;
pub mod boxplot;
pub mod cmap;
pub mod kitti;
pub mod label;
pub mod mapping;
pub mod ply;
pub mod pose;
pub mod rng;
pub mod robots;
pub mod synth;
pub mod transport;
