//! What the peers send: their map updates (a new robot met while there
//! is room for it) and their fixes of this robot.

use super::*;
use cosem_core::session::made_this_round;

impl RosNode {
    /// A robot's update heard: whether it is followed, met now if there is
    /// room for it ([`room_for`]: a peer silent for [`FORGET_AFTER`] may
    /// give its place), else its update dropped.
    pub(super) fn meet(&mut self, m: &MapUpdate, log: &mut impl FnMut(&Event)) -> Result<bool, Error> {
        if self.peers.contains_key(&m.robot) {
            return Ok(true);
        }
        let now = Instant::now();
        let followed = self.peers.iter().map(|(n, p)| (n.as_str(), now.duration_since(p.updated).as_secs_f64()));
        match room_for(followed, self.spec.max_peers) {
            Room::Free => {}
            Room::Forget(name, silent) => {
                self.peers.remove(&name);
                log(&Event::Forgotten(name, silent));
            }
            Room::Full => {
                let max = self.spec.max_peers;
                let why = format!(
                    "{}: not followed: this node follows {max} peer{} at most, none silent for {FORGET_AFTER} s",
                    m.robot,
                    if max == 1 { "" } else { "s" }
                );
                self.drop_input(why, log);
                return Ok(false);
            }
        }
        let copy = new_map(self.spec.capacity, *self.own.map.config())?;
        let reports = self.dds.subscription(&pose_topic(&m.robot, &self.spec.name), POSE, TopicKind::Tf)?;
        let peer = Peer {
            odom_frame: m.header.frame_id.clone(),
            follower: Follower::new(copy),
            tracker: Tracker::new(),
            heard: None,
            last: None,
            estimated: 0,
            made_in: 0,
            updated: now,
            refused: None,
            pose: None,
            reports,
            reported: None,
            walk: None,
        };
        self.peers.insert(m.robot.clone(), peer);
        Ok(true)
    }

    /// A peer's update: a new peer met, the update offered to its copy.
    pub(super) fn peer_update(&mut self, m: MapUpdate, log: &mut impl FnMut(&Event)) -> Result<(), Error> {
        if m.robot == self.spec.name {
            return Ok(());
        }
        self.last_input = Instant::now();
        if m.protocol != MAP_UPDATE_PROTOCOL {
            let why = format!("{}: an update of protocol {}, not {MAP_UPDATE_PROTOCOL}", m.robot, m.protocol);
            self.drop_input(why, log);
            return Ok(());
        }
        if m.robot.is_empty() || m.header.frame_id.is_empty() {
            self.drop_input("an update naming no robot or no odometry frame".into(), log);
            return Ok(());
        }
        if !m.heading_walk.is_finite() {
            let why = format!("{}: an update whose heading walk is {}", m.robot, m.heading_walk);
            self.drop_input(why, log);
            return Ok(());
        }
        if let Err(e) = cosem_core::wire::update::UpdateView::parse(&m.payload) {
            let why = format!("{}: a malformed map update ({} bytes): {e}", m.robot, m.payload.len());
            self.drop_input(why, log);
            return Ok(());
        }
        if !self.meet(&m, log)? {
            return Ok(());
        }
        let Some(peer) = self.peers.get_mut(&m.robot) else { return Ok(()) };
        // The payload names cells, not metres: a peer of another voxel
        // size is not matched (said once, on the log and on /diagnostics),
        // never read as this robot's cells.
        let own = self.spec.voxel;
        if !(m.voxel_size.is_finite() && (m.voxel_size - own).abs() <= 1e-6) {
            let why = format!("its map's voxels are {} m, this robot's {own} m: not matched", m.voxel_size);
            if peer.refused.as_deref() != Some(why.as_str()) {
                self.summary.dropped += 1;
                log(&Event::Dropped(format!("{}: {why}", m.robot)));
                peer.refused = Some(why);
                peer.last = None;
            }
            return Ok(());
        }
        peer.refused = None;
        match peer.follower.offer(m.header.stamp.nanos(), m.payload, &mut self.words) {
            Ok(done) => {
                if done.restarted || done.diverged > 0 {
                    peer.tracker.reset();
                    peer.last = None;
                    peer.heard = None;
                }
                if done.restarted {
                    log(&Event::Restarted(m.robot.clone()));
                }
                if done.diverged > 0 {
                    let why = "an update did not come out as the peer's map (its digest, or more voxels than the copy \
                               holds): the copy emptied until a snapshot";
                    self.summary.dropped += 1;
                    log(&Event::Dropped(format!("{}: {why}", m.robot)));
                }
                peer.updated = Instant::now();
                peer.odom_frame = m.header.frame_id;
                peer.walk = (m.heading_walk >= 0.0).then_some(m.heading_walk);
                *self.summary.applied.entry(m.robot).or_default() += done.applied;
                self.dirty |= done.applied > 0;
            }
            Err(why) => self.drop_input(format!("{}: {why}", m.robot), log),
        }
        Ok(())
    }

    /// Peers' fixes of this robot (`T_peer_own`): heard for their
    /// estimates' agreement, and a fix of ours waiting for it confirmed;
    /// with no fix of ours and our last estimate refused by our verdict,
    /// the peer's adopted ([`Tracker::adopt`]).
    pub(super) fn peer_fixes(&mut self, m: &TfMessage, log: &mut impl FnMut(&Event)) -> Result<(), Error> {
        let own_frame = self.spec.odom_frame.clone();
        for t in m.transforms.iter().filter(|t| t.child_frame_id == own_frame) {
            let Some(name) = self.peers.iter().find(|(_, p)| p.odom_frame == t.header.frame_id).map(|(n, _)| n.clone())
            else {
                continue;
            };
            let Some(iso) = iso_of(&t.transform) else { continue };
            let theirs: Isometry3<f32> = nalgebra::convert(iso);
            let place = self.own.place;
            let Some(peer) = self.peers.get_mut(&name) else { continue };
            // Adopted only when no fix of the peer's was heard in the
            // `HEARD_FOR` before it (the peer made it since): one it held,
            // which our own searches did not find, is not, wherever its
            // tracking moved it.
            let before = peer.heard.filter(|h| h.1.elapsed().as_secs_f64() <= HEARD_FOR);
            let fresh = made_this_round(before.as_ref().map(|(b, _)| b));
            peer.heard = Some((theirs, Instant::now()));
            let refused = peer.last.is_some_and(|e| e.result.status != MatchStatus::Converged);
            if fresh && refused && peer.tracker.fix().is_none() {
                let reported = reported_by(peer.reported.as_ref(), &theirs, t.header.stamp, place);
                self.adopt(&name, &theirs, reported, log)?;
                continue;
            }
            let Some(mut e) = peer.last.filter(|e| e.result.status == MatchStatus::Converged && !e.confirmed) else {
                continue;
            };
            let peer_at = peer.follower.peer_place();
            peer.tracker.confirm(&mut e, &theirs, place, peer_at);
            if e.confirmed {
                peer.last = Some(e);
                // Told again, now `Converged`: its line said it waited.
                let (round, voxels) = (peer.made_in, (self.own.map.len(), peer.follower.map().len()));
                let estimate = Box::new(e);
                log(&Event::Estimate {
                    round,
                    peer: name.clone(),
                    estimate,
                    voxels,
                    seconds: 0.0,
                    origin: Origin::Confirmed,
                    walk: (self.own.walk.excess(), peer.walk),
                });
                self.publish_estimate(&name)?;
                self.publish_edge()?;
            }
        }
        Ok(())
    }

    /// The peer `name`'s fix of this robot, `theirs`, tried as ours
    /// ([`Tracker::adopt`], with the slack where the peer reports it
    /// `Converged`, `reported`): adopted, it is our estimate, confirmed,
    /// and published.
    fn adopt(
        &mut self,
        name: &str,
        theirs: &Isometry3<f32>,
        reported: bool,
        log: &mut impl FnMut(&Event),
    ) -> Result<(), Error> {
        let Some(peer) = self.peers.get_mut(name) else { return Ok(()) };
        let copy = peer.follower.map();
        if copy.is_empty() || self.own.map.is_empty() || peer.refused.is_some() {
            return Ok(());
        }
        let t = Instant::now();
        let (mut own, mut them) = (Prepared::new(&self.own.map, Role::Model), Prepared::new(copy, Role::Scene));
        let view = self.own.view_of(peer, None);
        let pyramids = (own.tracked()?.0, them.tracked()?.0);
        // The peer's pose topic says whether it reports the fix
        // `Converged`; whether it is a recall waiting for its vouch, which
        // the session also adopts with the slack where this robot's own
        // search found it too, nothing the node hears says: adopted with
        // the margin then.
        let adopted =
            peer.tracker.adopt(pyramids, &self.spec.alignment, &mut self.room.tracking(), &view, theirs, reported);
        let Some(e) = adopted.map_err(|e| Error::Invalid(format!("{name}: matching: {e}")))? else { return Ok(()) };
        peer.last = Some(e);
        peer.estimated = peer.follower.version();
        peer.made_in = self.summary.rounds;
        let voxels = (self.own.map.len(), copy.len());
        let seconds = t.elapsed().as_secs_f64();
        let round = self.summary.rounds;
        let (peer, estimate) = (name.to_string(), Box::new(e));
        let walk = (self.own.walk.excess(), self.peers.get(name).and_then(|p| p.walk));
        log(&Event::Estimate { round, peer, estimate, voxels, seconds, origin: Origin::Adopted, walk });
        self.publish_estimate(name)?;
        self.publish_edge()
    }
}
