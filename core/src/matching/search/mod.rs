//! Coarse search: the best (x, y, yaw) within a window around the prior, by
//! branch and bound over the footprints (as Cartographer's fast correlative
//! scan matcher does for 2D scans).
//!
//! The score of a candidate is the number of (cell, class) pairs of the
//! scene's footprint that land on a model cell holding the same class:
//! `sum popcount(scene_mask & model_mask)`. A node of the search covers a
//! block of `2^h x 2^h` translations at one yaw; scoring it against the model
//! grid max-pooled over `2^h` cells bounds every translation in the block, so
//! whole blocks are discarded once a better leaf is known. The answer is the
//! exact optimum of the score over the window's lattice, found in a
//! deterministic order (ties go to the candidate nearest the prior).
//!
//! Three files: the scorer and the caller's scratch both searches work in
//! (`score.rs`), the search of a window around a prior (`window.rs`), and
//! the prior-free search of every heading and offset (`global.rs`).

mod global;
mod score;
mod window;

pub use global::{
    search_global, search_global_in, Candidate, GlobalSearch, GlobalSearchOutcome, MAX_GLOBAL_CANDIDATES,
    MAX_GLOBAL_POINTS,
};
pub use score::{SearchScratch, MAX_POINTS};
pub use window::{search, search_in, SearchOutcome, SearchWindow};
