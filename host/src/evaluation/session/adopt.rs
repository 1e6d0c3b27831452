//! A robot without a fix adopts its peer's fix of the same round
//! ([`Tracker::adopt`]): the answer that carries the peer's estimate lets
//! the robot try it before the round's fixes are confirmed.

use super::{copy_of, errors_of, figures, Error, Lines, Links, MatchRoom, Record, Robot, SessionSpec};
use cosem_core::geometry::Isometry3;
use cosem_core::matching::{MatchStatus, Role};
use cosem_core::session::{adopt_backed, made_this_round, PeerView, Tracker};
use std::time::Instant;

use super::prepared::Prepared;

/// What the round's adoptions work on: every robot's tracks, places, where
/// each copy last changed, and the matcher's room.
pub(super) struct Adopting<'a> {
    pub trackers: &'a mut [Vec<Tracker>],
    pub places: &'a [[f32; 3]],
    pub copy_at: &'a [Vec<Option<[f32; 3]>>],
    /// What each robot heard of its peers' estimates in the last round
    /// (`[j][i]`: j's of i, where it passed j's verdict).
    pub heard: &'a [Vec<Option<Isometry3<f32>>>],
    pub room: &'a mut MatchRoom,
}

impl Adopting<'_> {
    /// Every estimate of the round (`records`) that did not pass its
    /// robot's verdict, with no fix held, while the peer's estimate of the
    /// robot passed the peer's and was made this round (its estimate of the
    /// last round did not pass: [`made_this_round`]; unconfirmed, or confirmed by the
    /// peer's history, `Tracker::search`'s recall): the peer's fix tried
    /// ([`Tracker::adopt`], with the slack where the peer reports it
    /// `Converged` or it is the peer's recall that this robot's own search
    /// found too: [`adopt_backed`]);
    /// where it is adopted, the record takes the new estimate, its errors
    /// and the seconds it took.
    pub fn round(
        &mut self,
        spec: &SessionSpec,
        shared_world: bool,
        records: &mut [Record],
        (robots, links, lines): (&[Robot], &Links, &Lines),
    ) -> Result<(), Error> {
        let trackers = &*self.trackers;
        let waiting: Vec<(usize, usize, Isometry3<f32>, bool, bool)> = records
            .iter()
            .filter_map(|r| {
                let e = r.estimate.as_ref().filter(|e| e.offered())?;
                let recall = trackers[r.robot][r.peer].recalling();
                Some((r.robot, r.peer, e.result.transform, e.status() == MatchStatus::Converged, recall))
            })
            .collect();
        for r in records.iter_mut() {
            let (i, j) = (r.robot, r.peer);
            let failed = r.estimate.as_ref().is_some_and(|e| e.result.status != MatchStatus::Converged);
            let tracker = &mut self.trackers[i][j];
            let Some(&(.., theirs, reported, recall)) =
                waiting.iter().find(|w| (w.0, w.1) == (j, i)).filter(|_| failed)
            else {
                continue;
            };
            let (at, peer_at) = (self.places[i], self.places.get(j).copied());
            // Only a fix the peer made this round: one it held the round
            // before, which this robot's own search did not find, is not
            // adopted, wherever tracking moved it (town seed 19: a street
            // slid 112 m, held by the peer unconfirmed for five rounds,
            // adopted at agreement 0.50; `made_this_round`).
            if tracker.fix().is_some() || !made_this_round(self.heard[j][i].as_ref()) {
                continue;
            }
            // The peer's recall, which this robot's own search found too, is
            // adopted with the slack, as a fix the peer reports `Converged`.
            let mine = r.estimate.as_ref().map(|e| (e.kind, &e.result.transform));
            let backed = adopt_backed(reported, recall, mine, &theirs, at, peer_at);
            let t0 = Instant::now();
            let copy = copy_of((i, j), links, lines)?;
            let (mut own, mut peer) = (Prepared::new(&robots[i].map, Role::Model), Prepared::new(copy, Role::Scene));
            let walk = robots[i].walk_with(&robots[j]);
            let view = PeerView { estimate: None, at, peer_at, copy_at: self.copy_at[i][j], walk };
            let pyramids = (own.tracked()?.0, peer.tracked()?.0);
            let adopted = tracker
                .adopt(pyramids, &spec.alignment, &mut self.room.tracking(), &view, &theirs, backed)
                .map_err(|e| Error::Invalid(format!("matching: {e}")))?;
            r.seconds += t0.elapsed().as_secs_f64();
            if let Some(e) = adopted {
                let truth =
                    shared_world.then(|| figures::truth(&robots[i], &robots[j], f64::from(spec.crop))).flatten();
                (r.errors, r.origin_error, r.local_errors) = errors_of(Some(&e), truth.as_ref());
                r.estimate = Some(e);
                r.adopted = true;
            }
        }
        Ok(())
    }
}
