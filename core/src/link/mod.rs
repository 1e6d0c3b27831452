//! Stage 4: moving maps over a narrow, lossy line.
//!
//! An [`Endpoint`] sends its own map and receives the peer's, over any
//! byte stream implementing `embedded_io`'s `Read + Write + ReadReady` (a
//! UART driver, a TCP socket, a simulated line), with time from a
//! [`Clock`]. It is a non-blocking state machine: call [`Endpoint::step`]
//! as often as convenient; it reads what is there, answers, retransmits when
//! a deadline passed, and never blocks on the line.
//!
//! The protocol is stop-and-wait ARQ, which suits half-duplex lines: the
//! sender sends one frame (a `MapHeader`, then numbered `Chunk`s, then
//! `End`) and waits for its `Ack`. A lost frame or ack is resent after a
//! timeout that doubles up to a ceiling; a `Nack` asks for it at once;
//! duplicates are recognised by sequence number and acknowledged again;
//! after too many retries the sender gives up with a typed error. The
//! sender estimates the line's byte error rate from its own attempts and
//! sizes chunks for the most data per attempt (frames of about one over the
//! rate); a chunk that must be resent is re-encoded at the current size.
//! The receiver decodes into a staging map the caller provides, checks the
//! voxel count and the digest of the whole map at `End`, and only then
//! reports success: an aborted or corrupted transfer leaves the caller's
//! current map untouched.

mod endpoint;
pub mod sim;

pub use endpoint::{Endpoint, LinkConfig, LinkError, LinkStats, Progress};

/// Milliseconds from a monotonic source: a SysTick counter on the chip, a
/// `std::time::Instant` on the host, a simulated clock in tests.
pub trait Clock {
    /// Milliseconds since an arbitrary origin; never decreases.
    fn now_ms(&self) -> u64;
}

#[cfg(test)]
mod tests;
