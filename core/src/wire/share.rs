//! The team's estimates as they travel between robots: after the maps
//! crossed and every robot matched its peers, each robot sends every peer
//! its own estimates (`T_a_b` with information and status), so that all
//! robots check the same matches for consistency and solve the same pose
//! graph.
//!
//! A message is the byte [`SHARE_VERSION`] and postcard, in one frame. The
//! first byte differs from every link message's (version bits 6..4 are 6,
//! the link's are 3) and from the feed's, so frames of one protocol that
//! linger on a line are refused by the other.

use super::frame::frame_with;
use super::message::{decode_versioned, encode_versioned, MessageError};
use crate::geometry::{from_rows, Isometry3};
use serde::{Deserialize, Serialize};

/// First byte of every share message (protocol 1).
pub const SHARE_VERSION: u8 = 0x61;

/// Status of an estimate whose maps never met (the link to that peer
/// failed): not a match at all.
pub const NO_EXCHANGE: u8 = 0xFF;

/// Words of an [`Estimate`] in a `u32` table ([`Estimate::to_words`]).
pub const ESTIMATE_WORDS: usize = 35;

/// One robot's estimate of another.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Estimate {
    /// The estimating robot (its map was the model).
    pub a: u8,
    /// The estimated robot: the estimate is `T_a_b`.
    pub b: u8,
    /// Status code (`MatchStatus::code`), or [`NO_EXCHANGE`].
    pub status: u8,
    /// `T_a_b`, the top three rows, row by row.
    pub transform: [f32; 12],
    /// Information matrix (left perturbation, tx ty tz rx ry rz), upper
    /// triangle row by row.
    pub information: [f32; 21],
    /// Agreement of the match (0..1).
    pub agreement: f32,
}

impl Estimate {
    /// An estimate for a pair whose maps never met.
    pub fn none(a: u8, b: u8) -> Self {
        let mut transform = [0.0; 12];
        transform[0] = 1.0;
        transform[5] = 1.0;
        transform[10] = 1.0;
        Estimate { a, b, status: NO_EXCHANGE, transform, information: [0.0; 21], agreement: 0.0 }
    }

    /// An estimate of `T_a_b` with its status code, row-major transform,
    /// information matrix (upper triangle) and agreement (the matcher's
    /// side makes one from a match: `MatchResult::estimate`).
    pub fn new(a: u8, b: u8, status: u8, transform: [f32; 12], information: &[[f32; 6]; 6], agreement: f32) -> Self {
        Estimate { a, b, status, transform, information: Estimate::upper(information), agreement }
    }

    /// `T_a_b`.
    pub fn transform(&self) -> Isometry3<f32> {
        from_rows(&self.transform)
    }

    /// The full 6x6 information matrix (row-major).
    pub fn information(&self) -> [[f32; 6]; 6] {
        let mut m = [[0.0f32; 6]; 6];
        let mut k = 0;
        for r in 0..6 {
            for c in r..6 {
                let v = self.information.get(k).copied().unwrap_or(0.0);
                if let Some(row) = m.get_mut(r) {
                    if let Some(x) = row.get_mut(c) {
                        *x = v;
                    }
                }
                if let Some(row) = m.get_mut(c) {
                    if let Some(x) = row.get_mut(r) {
                        *x = v;
                    }
                }
                k += 1;
            }
        }
        m
    }

    /// The upper triangle of a symmetric 6x6 matrix, row by row.
    pub fn upper(m: &[[f32; 6]; 6]) -> [f32; 21] {
        let mut out = [0.0; 21];
        let mut k = 0;
        for (r, row) in m.iter().enumerate() {
            for v in row.iter().skip(r) {
                if let Some(o) = out.get_mut(k) {
                    *o = *v;
                }
                k += 1;
            }
        }
        out
    }

    /// Whether every number is finite.
    pub fn check(&self) -> Result<(), MessageError> {
        let finite = self.transform.iter().chain(&self.information).chain([&self.agreement]).all(|v| v.is_finite());
        if finite {
            Ok(())
        } else {
            Err(MessageError::NonFinite)
        }
    }

    /// As `u32` words (floats by their bits), to keep a team's table in a
    /// robot's scratch once its maps have crossed.
    pub fn to_words(&self) -> [u32; ESTIMATE_WORDS] {
        let mut w = [0u32; ESTIMATE_WORDS];
        w[0] = u32::from(self.a) | u32::from(self.b) << 8 | u32::from(self.status) << 16 | 1 << 24;
        for (o, v) in w.iter_mut().skip(1).zip(self.transform.iter().chain(&self.information).chain([&self.agreement]))
        {
            *o = v.to_bits();
        }
        w
    }

    /// From [`Estimate::to_words`]; `None` for a slot never written (or
    /// words too short).
    pub fn from_words(w: &[u32]) -> Option<Self> {
        let head = *w.first()?;
        if head >> 24 != 1 || w.len() < ESTIMATE_WORDS {
            return None;
        }
        let f = |i: usize| f32::from_bits(w.get(i).copied().unwrap_or(0));
        let mut e = Estimate::none(head as u8, (head >> 8) as u8);
        e.status = (head >> 16) as u8;
        for (k, t) in e.transform.iter_mut().enumerate() {
            *t = f(1 + k);
        }
        for (k, t) in e.information.iter_mut().enumerate() {
            *t = f(13 + k);
        }
        e.agreement = f(34);
        Some(e)
    }
}

/// A message between two robots of a team after their maps crossed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ShareMessage {
    /// One of the sender's estimates (`a` is the sender).
    Estimate(Estimate),
    /// What the sender holds of the receiver's estimates.
    Ack {
        /// The sender.
        from: u8,
        /// Bit b set: the sender holds the receiver's estimate of robot b.
        held: u8,
        /// The sender holds all of the receiver's estimates and the
        /// receiver acknowledged all of the sender's: it will stop.
        finished: bool,
    },
}

impl ShareMessage {
    /// Encodes into `out` (version byte and postcard); returns the length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, MessageError> {
        encode_versioned(SHARE_VERSION, self, out)
    }

    /// Encodes and frames into `out`; returns the frame's length.
    pub fn to_frame(&self, out: &mut [u8]) -> Result<usize, MessageError> {
        frame_with(out, |payload| self.encode(payload))
    }

    /// Decodes and checks a payload.
    pub fn decode(payload: &[u8]) -> Result<Self, MessageError> {
        let msg: Self = decode_versioned(SHARE_VERSION, payload)?;
        if let ShareMessage::Estimate(e) = &msg {
            e.check()?;
        }
        Ok(msg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::frame::{Deframer, MAX_FRAME};

    fn sample() -> Estimate {
        let mut e = Estimate::none(2, 0);
        e.status = 0;
        e.transform[3] = -12.5;
        e.information[0] = 1.0e5;
        e.information[20] = 3.0e7;
        e.agreement = 0.61;
        e
    }

    #[test]
    fn round_trip_through_a_frame() {
        for msg in [ShareMessage::Estimate(sample()), ShareMessage::Ack { from: 3, held: 0b101, finished: true }] {
            let mut frame = [0u8; MAX_FRAME];
            let n = msg.to_frame(&mut frame).unwrap();
            let mut d = Deframer::new();
            let mut got = None;
            for &b in &frame[..n] {
                if let Some(p) = d.push(b).unwrap() {
                    got = Some(ShareMessage::decode(p).unwrap());
                }
            }
            assert_eq!(got, Some(msg));
        }
    }

    #[test]
    fn refuses_other_protocols_and_non_finite_numbers() {
        let mut buf = [0u8; 512];
        let n = ShareMessage::Estimate(sample()).encode(&mut buf).unwrap();
        assert_eq!(buf[0], SHARE_VERSION);
        // A link Hello's first byte (version 3, tag 0) and the feed's.
        for first in [0x30, crate::wire::feed::FEED_VERSION] {
            let mut other = buf;
            other[0] = first;
            assert_eq!(ShareMessage::decode(&other[..n]), Err(MessageError::Version(first)));
        }
        let mut e = sample();
        e.information[4] = f32::NAN;
        let n = ShareMessage::Estimate(e).encode(&mut buf).unwrap();
        assert_eq!(ShareMessage::decode(&buf[..n]), Err(MessageError::NonFinite));
        assert_eq!(ShareMessage::decode(&buf[..n - 1]), Err(MessageError::Malformed));
    }

    #[test]
    fn words_round_trip_and_empty_slots_read_as_none() {
        let e = sample();
        assert_eq!(Estimate::from_words(&e.to_words()), Some(e));
        assert_eq!(Estimate::from_words(&[0u32; ESTIMATE_WORDS]), None);
        assert_eq!(Estimate::from_words(&e.to_words()[..10]), None);
        let m = e.information();
        assert_eq!(Estimate::upper(&m), e.information);
    }
}
