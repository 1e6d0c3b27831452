//! The host library's error: each variant a layer's typed error, whose
//! message names the file, frame or value at fault.

use cosem_core::matching::{MatchError, PyramidError};

/// Says something the user should know that is not an error (a
/// recording read up to a cut, say), on standard error, one line.
pub fn warn(message: &str) {
    eprintln!("warning: {message}");
}

/// Anything the host library can fail at.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading a SemanticKITTI-layout folder.
    #[error(transparent)]
    Kitti(#[from] crate::kitti::KittiError),
    /// Building a map.
    #[error(transparent)]
    Build(#[from] crate::mapping::BuildError),
    /// Reading a user's scans (PCD, PLY) or their poses.
    #[error(transparent)]
    Cloud(#[from] crate::cloud::CloudError),
    /// Reading or writing a ROS 2 recording (MCAP).
    #[error(transparent)]
    Recording(#[from] crate::recording::RecordingError),
    /// Reading or writing a map file.
    #[error(transparent)]
    Cmap(#[from] crate::cmap::CmapError),
    /// Labelling scans from camera segmentation.
    #[error(transparent)]
    Label(#[from] crate::label::LabelError),
    /// Segmenting camera images with a network.
    #[cfg(feature = "segment")]
    #[error(transparent)]
    Segment(#[from] crate::segment::SegmentError),
    /// Preparing a map for matching.
    #[error("preparing a map: {0}")]
    Pyramid(PyramidError),
    /// Matching.
    #[error("matching: {0}")]
    Match(MatchError),
    /// Aligning (with or without a prior).
    #[error(transparent)]
    Align(#[from] crate::align::AlignError),
    /// A file or folder the library writes or runs.
    #[error("{path}: {source}")]
    Io {
        /// The file or program.
        path: std::path::PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// An argument out of range, with what is expected.
    #[error("{0}")]
    Invalid(String),
}

impl From<PyramidError> for Error {
    fn from(e: PyramidError) -> Self {
        Error::Pyramid(e)
    }
}

impl From<MatchError> for Error {
    fn from(e: MatchError) -> Self {
        Error::Match(e)
    }
}

impl From<cosem_core::team::TeamError> for Error {
    fn from(e: cosem_core::team::TeamError) -> Self {
        Error::Invalid(format!("team: {e}"))
    }
}
