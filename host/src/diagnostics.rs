//! What the library says that is not an error.

/// Says something the user should know that is not an error (a
/// recording read up to a cut, say), on standard error, one line.
pub fn warn(message: &str) {
    eprintln!("warning: {message}");
}
