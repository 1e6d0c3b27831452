//! One message onto the line: as a frame, or as a block of segments
//! shaped for the line.

use super::*;

/// Sends one message as a frame; returns the bytes written.
pub(super) fn send_msg<IO: Write>(
    io: &mut IO,
    msg: &Message<'_>,
    parity: usize,
    stats: &mut LinkStats,
) -> Result<usize, LinkError> {
    let mut frame = [0u8; MAX_FRAME];
    let f = msg.to_frame_parity(&mut frame, parity).map_err(|_| LinkError::Setup)?;
    io.write_all(frame.get(..f).unwrap_or(&[])).map_err(io_error)?;
    io.flush().map_err(io_error)?;
    stats.bytes_sent += f as u64;
    stats.frames_sent += 1;
    Ok(f)
}

/// Why a block was not sent: it does not fit its shape, or the line.
enum BlockFailure {
    Shape,
    Link(LinkError),
}

impl From<FrameError> for BlockFailure {
    fn from(_: FrameError) -> Self {
        BlockFailure::Shape
    }
}

/// Sends one message as a block of `shape`; returns the bytes written.
/// Should the block not fit the shape (or, rarely, every byte value occur
/// in it whatever the key), as a frame with `parity` parity bytes (none if
/// it is too long for them).
pub(super) fn send_block<IO: Write>(
    io: &mut IO,
    msg: &Message<'_>,
    (shape, parity): (BlockShape, usize),
    stats: &mut LinkStats,
) -> Result<usize, LinkError> {
    let mut payload = [0u8; MAX_PAYLOAD];
    let n = msg.encode(&mut payload).map_err(|_| LinkError::Setup)?;
    let sent = encode_block(payload.get(..n).unwrap_or(&[]), shape, |bytes: &[u8]| {
        io.write_all(bytes).map_err(|e| BlockFailure::Link(io_error(e)))
    });
    match sent {
        Ok(len) => {
            io.flush().map_err(io_error)?;
            stats.bytes_sent += len as u64;
            stats.frames_sent += 1;
            Ok(len)
        }
        Err(BlockFailure::Link(e)) => Err(e),
        Err(BlockFailure::Shape) => {
            let parity = if n <= crate::wire::frame::max_payload(parity) { parity } else { 0 };
            send_msg(io, msg, parity, stats)
        }
    }
}

/// A stream error as a link error, keeping its kind.
pub(super) fn io_error<E: embedded_io::Error>(e: E) -> LinkError {
    LinkError::Io(e.kind())
}
