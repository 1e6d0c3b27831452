//! Layer 5: moving maps over a narrow, lossy line.
//!
//! An [`Endpoint`] sends its own map and receives the peer's, over any
//! byte stream implementing `embedded_io`'s `Read + Write + ReadReady + WriteReady` (a
//! UART driver, a TCP socket, a simulated line), with time from a
//! [`Clock`]. It is a non-blocking state machine: call [`Endpoint::step`]
//! as often as convenient; it reads what is there, answers, retransmits when
//! a deadline passed, and never blocks on the line.
//!
//! The protocol is selective repeat over a byte stream, which suits
//! full-duplex lines: each side's map is one stream of records (a
//! `MapHeader`, then codec chunks, each behind a length byte), cut into
//! `Data` frames wherever the sender likes. Frames carry a Reed-Solomon
//! codeword (payload, CRC-32, parity) and end in a zero byte, so a receiver
//! resynchronises after any substituted, dropped or duplicated byte, corrects
//! substituted bytes up to half the parity, repairs one or two dropped or
//! duplicated bytes by trying them against the code, and never takes a
//! frame whose CRC fails ([`crate::wire::Deframer`]). The receiver keeps what arrives
//! ahead of a gap (up to [`STREAM_BUFFER`] bytes), decodes records once the
//! bytes before them are in, and acknowledges every few frames, or at once
//! when a frame asks: a cumulative offset plus up to three ranges held
//! beyond it. A serial line keeps order, so bytes sent before bytes now
//! acknowledged, and not acknowledged themselves, were lost: they are sent
//! again at once, cut to the current frame size; a timer (twice the
//! measured round trip, backing off) catches the rest. Each side
//! estimates the line from the frames that arrive (the bytes the code
//! rebuilt: substituted, dropped, duplicated; and the frames lost) and picks
//! the frame size and parity that carry the most data per byte of line: on
//! a clean line long frames without parity, on a bad one short frames with
//! more. On a half-duplex line the same
//! machinery keeps one frame in flight (stop-and-wait: a second frame
//! would collide with the answer), and the two maps
//! go one after the other.
//!
//! The receiver checks the voxel count and the digest of the whole map and
//! only then reports success: an aborted or corrupted transfer leaves the
//! caller's current map untouched. An exchange ends when both sides said
//! they are finished (an acknowledgement flag), or after a linger time.

pub mod courier;
mod endpoint;

pub use endpoint::{
    Endpoint, Finished, LinkBuffers, LinkConfig, LinkError, LinkMemory, LinkStats, Progress, LINK_WORDS, STREAM_BUFFER,
};

/// Milliseconds from a monotonic source: a SysTick counter on the chip, a
/// `std::time::Instant` on the host, a simulated clock in tests.
pub trait Clock {
    /// Milliseconds since an arbitrary origin; never decreases.
    fn now_ms(&self) -> u64;
}

#[cfg(test)]
mod tests;
