//! The head a session robot's message carries ahead of its update: its
//! last estimate of the peer and what it says of it, its place and its
//! walk figure ([`ESTIMATE_BYTES`]).

use crate::geometry::Isometry3;

/// Bytes of the head ahead of a round's update: a flag (0: no estimate;
/// 1: one follows that passed the sender's verdict; 2: one the sender
/// reports `Converged`; 3: a recall waiting for its vouch), then
/// `T_sender_receiver`'s top three rows, row by row, then
/// where the sender is (its frame: the agreement of two estimates is
/// judged at both robots' places, [`crate::session::agree`]), then the
/// sender's figure of its heading walk (degrees, negative while it has
/// none: the pair's figure holds back `Converged`,
/// [`crate::session::pair_walk`]), all little-endian `f32`.
pub const ESTIMATE_BYTES: usize = 1 + 48 + 12 + 4;

/// What a message's head says of the estimate it carries (its flag byte).
/// The peer adopts a fix said `Converged`, or a recall its own search found
/// too, with less agreement ([`crate::session::Tracker::adopt`], [`crate::session::adopt_backed`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Said {
    /// 1: it passed the sender's verdict.
    Passed = 1,
    /// 2: the sender reports it `Converged` (confirmed, not contested).
    Converged = 2,
    /// 3: a recall, the fix the pair confirmed before found again, waiting
    /// for its vouch ([`crate::session::Tracker::recalling`]).
    Recalling = 3,
}

impl Said {
    fn of(flag: u8) -> Option<Said> {
        [Said::Passed, Said::Converged, Said::Recalling].into_iter().find(|s| *s as u8 == flag)
    }
}

/// An estimate a message's head carries, and what its sender says of it.
pub(super) type HeadEstimate = (Isometry3<f32>, Said);

/// What a message's head says ([`ESTIMATE_BYTES`]): each part `None`
/// where the sender had none or a number in it is not finite.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Head {
    /// The sender's last estimate of the receiver that passed its verdict.
    pub(super) estimate: Option<HeadEstimate>,
    /// Where the sender is (its frame).
    pub(super) at: Option<[f32; 3]>,
    /// The sender's figure of its heading walk (degrees, not negative).
    pub(super) walk: Option<f32>,
}

impl Head {
    /// Writes the head to `out` ([`ESTIMATE_BYTES`]).
    pub(super) fn write(&self, out: &mut [u8]) {
        out.fill(0);
        let Some((flag, rest)) = out.split_first_mut() else { return };
        let (rows, rest) = rest.split_at_mut(rest.len().min(48));
        let (place, walk) = rest.split_at_mut(rest.len().min(12));
        if let Some((t, said)) = self.estimate {
            *flag = said as u8;
            for (o, v) in rows.chunks_exact_mut(4).zip(crate::geometry::rows(&t)) {
                o.copy_from_slice(&v.to_le_bytes());
            }
        }
        for (o, v) in place.chunks_exact_mut(4).zip(self.at.unwrap_or([f32::NAN; 3])) {
            o.copy_from_slice(&v.to_le_bytes());
        }
        for (o, v) in walk.chunks_exact_mut(4).zip([self.walk.unwrap_or(-1.0)]) {
            o.copy_from_slice(&v.to_le_bytes());
        }
    }

    /// Reads a head: all `None` when it is not [`ESTIMATE_BYTES`] long.
    pub(super) fn read(head: &[u8]) -> Head {
        fn floats<const N: usize>(b: &[u8]) -> Option<[f32; N]> {
            if b.len() != 4 * N {
                return None;
            }
            let mut v = [0f32; N];
            for (x, c) in v.iter_mut().zip(b.chunks_exact(4)) {
                *x = f32::from_le_bytes(c.try_into().ok()?);
            }
            v.iter().all(|x| x.is_finite()).then_some(v)
        }
        let none = Head { estimate: None, at: None, walk: None };
        let Some((&flag, rest)) = head.split_first().filter(|_| head.len() == ESTIMATE_BYTES) else { return none };
        let (rows, rest) = rest.split_at_checked(48).unwrap_or((&[], &[]));
        let (place, walk) = rest.split_at_checked(12).unwrap_or((&[], &[]));
        let estimate = floats::<12>(rows).zip(Said::of(flag)).map(|(r, said)| (crate::geometry::from_rows(&r), said));
        let walk = floats::<1>(walk).map(|[w]| w).filter(|w| *w >= 0.0);
        Head { estimate, at: floats::<3>(place), walk }
    }
}
