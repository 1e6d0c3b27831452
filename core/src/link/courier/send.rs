//! The sending half of a courier: frames found lost, the window's new
//! units, everything again after a timeout; each data frame framed with
//! the line's parity.

use super::{Courier, CourierError, Flight, COURIER_DATA, UNIT};
use crate::wire::block::encode_block;
use crate::wire::frame::{encode_frame_parity, MAX_FRAME};
use embedded_io::{Write, WriteReady};

impl Courier {
    /// Sends what is due: frames found lost, then new units of the window,
    /// while the line has room; after a timeout, everything in flight again
    /// (or, all acknowledged and the answer missing, the last unit, to ask).
    pub(super) fn send_due<L: Write + WriteReady>(
        &mut self,
        port: &mut L,
        out: &[u8],
        round: u16,
        first: usize,
        now_ms: u64,
    ) -> Result<(), CourierError> {
        let io = |e: L::Error| CourierError::Io(embedded_io::Error::kind(&e));
        let units = Self::units(self.out_len);
        let end = units.min(first + usize::from(self.config.window));
        // Twice the measured round trip, at least the configured timeout.
        let rtt = self.srtt8.map_or(0, |s| s / 8);
        // All acknowledged, the answer missing: a probe is one short frame,
        // asked again without backing off much (an answer lost on a bad
        // line must not cost seconds).
        let cap = if first == units { 1 } else { 3 };
        let timeout = u64::from(self.config.timeout_ms).max(2 * rtt) << self.backoff.min(cap);
        let stalled =
            (self.lost.is_empty() && self.redo >= self.frontier && self.frontier >= end) || self.flights.is_full();
        if stalled && now_ms.saturating_sub(self.last_sent_ms) >= timeout {
            // Backing off only while the peer is silent: a line that
            // carries frames loses some, it is not down.
            self.backoff = if self.heard { 0 } else { self.backoff.saturating_add(1).min(8) };
            // Once a round trip was measured, the peer's frames judge the
            // line: one silent timeout is a lost acknowledgement (a third of
            // them on a line that damages 10% of bytes), and halving there
            // put a damaged line's data in frames of a few units, not blocks.
            if !self.heard && (self.srtt8.is_none() || self.backoff >= 2) {
                // Nothing came back: frames too long for the line, perhaps,
                // before any of the peer's frames could say so.
                self.ceiling = (self.ceiling / 2).max(1);
                self.frame_units = self.frame_units.min(self.ceiling);
            }
            self.heard = false;
            if first == units {
                let last = units.saturating_sub(1) as u16;
                self.send_units(port, out, round, (last, 1), (now_ms, true))?;
                self.last_sent_ms = now_ms;
                return Ok(());
            }
            // Everything unacknowledged below the frontier goes again.
            self.flights.clear();
            self.lost.clear();
            self.redo = first;
        }
        while port.write_ready().map_err(io)? && (!self.flights.is_full() || !self.lost.is_empty()) {
            let room = usize::from(self.frame_units);
            let (from, n, resend) = if let Some(f) = self.lost.pop_front() {
                (usize::from(f.first), usize::from(f.units), true)
            } else if self.redo < self.frontier {
                let from = self.acked.first_clear(self.redo, self.frontier);
                let n = room.min(self.frontier - from);
                self.redo = if from + n >= self.frontier { usize::MAX } else { from + n };
                if n == 0 {
                    continue;
                }
                (from, n, true)
            } else if self.frontier < end {
                let n = room.min(end - self.frontier);
                self.frontier += n;
                (self.frontier - n, n, false)
            } else {
                break;
            };
            // Units acknowledged meanwhile are not sent again.
            let mut k = self.acked.first_clear(from, from + n);
            while k < from + n {
                let stop = (k..from + n).find(|&u| self.acked.get(u)).unwrap_or(from + n);
                let take = (stop - k).min(room);
                self.send_units(port, out, round, (k as u16, take as u16), (now_ms, resend))?;
                self.stats.resent += u32::from(resend);
                self.last_sent_ms = now_ms;
                k = self.acked.first_clear(k + take, from + n);
            }
        }
        Ok(())
    }

    /// Sends `n` units of `out` from unit `first`, as one frame in flight
    /// from `now_ms` (`again`: sent before).
    fn send_units<L: Write>(
        &mut self,
        port: &mut L,
        out: &[u8],
        round: u16,
        (first, n): (u16, u16),
        (now_ms, again): (u64, bool),
    ) -> Result<(), CourierError> {
        let start = usize::from(first) * UNIT;
        let end = (start + usize::from(n) * UNIT).min(self.out_len as usize);
        let bytes = out.get(start..end.max(start)).ok_or(CourierError::TooLarge(self.out_len))?;
        let mut payload = [0u8; MAX_FRAME];
        let mut at = 0;
        for part in [&[COURIER_DATA, round as u8][..], &self.out_len.to_le_bytes()[..3], &first.to_le_bytes(), bytes] {
            payload.get_mut(at..at + part.len()).ok_or(CourierError::Config)?.copy_from_slice(part);
            at += part.len();
        }
        let payload = payload.get(..at).unwrap_or(&[]);
        match self.block {
            Some(shape) => {
                let written = encode_block(payload, shape, |bytes: &[u8]| {
                    port.write_all(bytes).map_err(|e| BlockOut::Io(embedded_io::Error::kind(&e)))
                });
                match written {
                    Ok(n) => {
                        self.stats.bytes_sent += n as u64;
                        self.stats.blocks += 1;
                    }
                    Err(BlockOut::Io(kind)) => return Err(CourierError::Io(kind)),
                    // A payload the shape does not carry, or every byte
                    // value in its segments (rare): a frame.
                    Err(BlockOut::Frame) => self.send(port, payload)?,
                }
            }
            None => self.send(port, payload)?,
        }
        self.seq = self.seq.wrapping_add(1);
        if self.flights.is_full() {
            // Forgotten: a timeout sends it again if it was lost.
            let _ = self.flights.pop_front();
        }
        let _ = self.flights.push_back(Flight { first, units: n, seq: self.seq, sent_ms: now_ms, again });
        Ok(())
    }

    /// Frames `payload` with the line's parity and writes it.
    pub(super) fn send<L: Write>(&mut self, port: &mut L, payload: &[u8]) -> Result<(), CourierError> {
        let mut frame = [0u8; MAX_FRAME];
        let n = encode_frame_parity(payload, usize::from(self.parity), &mut frame).map_err(|_| CourierError::Config)?;
        let bytes = frame.get(..n).unwrap_or(&[]);
        port.write_all(bytes).map_err(|e| CourierError::Io(embedded_io::Error::kind(&e)))?;
        self.stats.bytes_sent += n as u64;
        Ok(())
    }
}

/// Why a block was not written: the line, or a payload its shape does not
/// carry (then it goes as a frame).
enum BlockOut {
    Io(embedded_io::ErrorKind),
    Frame,
}

impl From<crate::wire::frame::FrameError> for BlockOut {
    fn from(_: crate::wire::frame::FrameError) -> Self {
        BlockOut::Frame
    }
}
