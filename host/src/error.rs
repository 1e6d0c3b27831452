//! The host library's one error: a layer's typed error carried as it is
//! (whose message names the file, frame or value at fault), the core's
//! matching errors, I/O on a named path, an invalid argument.

use cosem_core::matching::{MatchError, PyramidError};

/// A layer's typed error (a source's, the camera's, a map's, the
/// matcher's): its message names the file, frame or value at fault. The
/// one [`Error`] carries it as it is, so this base module names no layer.
pub trait LayerError: std::error::Error + Send + Sync + 'static {}

/// Anything the host library can fail at.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A layer's typed error ([`LayerError`]), as it is.
    #[error("{0}")]
    Layer(Box<dyn LayerError>),
    /// Preparing a map for matching.
    #[error("preparing a map: {0}")]
    Pyramid(PyramidError),
    /// Matching.
    #[error("matching: {0}")]
    Match(MatchError),
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

impl Error {
    /// The layer error of type `E` this is, if it is one.
    pub fn layer<E: LayerError>(&self) -> Option<&E> {
        match self {
            Error::Layer(e) => (e.as_ref() as &dyn std::error::Error).downcast_ref::<E>(),
            _ => None,
        }
    }
}

impl<E: LayerError> From<E> for Error {
    fn from(e: E) -> Self {
        Error::Layer(Box::new(e))
    }
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
