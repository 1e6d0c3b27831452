//! A round and what it publishes: the map's update, each peer's
//! estimate (its pose, the `/tf` edge) and every status on `/diagnostics`.

use super::*;

impl RosNode {
    /// A round: the map's update published, every peer re-estimated, the
    /// estimates published.
    pub(super) fn round(&mut self, log: &mut impl FnMut(&Event)) -> Result<(), Error> {
        self.dirty = false;
        self.own.fresh = 0;
        self.summary.rounds += 1;
        self.summary.walk = self.own.walk.excess();
        if self.own.changed {
            self.publish_update()?;
        }
        let names: Vec<String> = self.peers.keys().cloned().collect();
        // Peers tracked from a fix first: they need the own map prepared
        // for tracking alone, a search needs it whole.
        let mut order: Vec<&String> = names.iter().collect();
        order.sort_by_key(|n| self.peers.get(*n).is_none_or(|p| p.tracker.fix().is_none()));
        let mut mine = Prepared::new(&self.own.map, Role::Model);
        let mut done = Vec::new();
        for name in order {
            let Some(peer) = self.peers.get_mut(name) else { continue };
            let copy = peer.follower.map();
            if copy.is_empty() || self.own.map.is_empty() {
                continue;
            }
            let t = Instant::now();
            if peer.refused.is_some() {
                continue;
            }
            let heard = peer.heard.filter(|h| h.1.elapsed().as_secs_f64() <= HEARD_FOR).map(|h| h.0);
            let view = self.own.view_of(peer, heard);
            let room = &mut self.room;
            let (mut e, _) = match estimate_on(&mut mine, copy, &mut peer.tracker, &self.spec.alignment, &view, room) {
                Ok(e) => e,
                Err(why) => {
                    // A peer's map this robot cannot match (another voxel
                    // size, ...): said, and the other peers go on.
                    self.summary.dropped += 1;
                    log(&Event::Dropped(format!("{name}: no estimate: {why}")));
                    continue;
                }
            };
            if let Some(theirs) = heard {
                peer.tracker.confirm(&mut e, &theirs, self.own.place, view.peer_at);
            }
            peer.last = Some(e);
            peer.estimated = peer.follower.version();
            peer.made_in = self.summary.rounds;
            let voxels = (self.own.map.len(), copy.len());
            let seconds = t.elapsed().as_secs_f64();
            log(&Event::Estimate {
                round: self.summary.rounds,
                peer: name.clone(),
                estimate: Box::new(e),
                voxels,
                seconds,
                origin: Origin::Made,
                walk: (self.own.walk.excess(), peer.walk),
            });
            done.push(name.clone());
        }
        drop(mine);
        for name in &done {
            self.publish_estimate(name)?;
        }
        self.publish_edge()?;
        self.publish_diagnostics()
    }

    /// The map's next update (every `snapshot_every`th a snapshot), to
    /// every peer at once.
    pub(super) fn publish_update(&mut self) -> Result<(), Error> {
        let p = &mut self.own.publisher;
        if self.summary.updates.is_multiple_of(self.spec.snapshot_every as usize) {
            p.snapshot_next();
        }
        let n = p
            .next_update(&self.own.map, &mut self.words, &mut self.out)
            .map_err(|e| Error::Invalid(format!("update: {e}")))?;
        p.delivered();
        let snapshot = p.counts().snapshot;
        let header = Header { stamp: stamp_now(), frame_id: self.spec.odom_frame.clone() };
        let payload = self.out.get(..n).unwrap_or(&[]).to_vec();
        let m = MapUpdate {
            header,
            robot: self.spec.name.clone(),
            peer: String::new(),
            protocol: MAP_UPDATE_PROTOCOL,
            voxel_size: self.spec.voxel,
            heading_walk: self.own.walk.excess().unwrap_or(-1.0),
            payload,
        };
        let (topic, name) = if snapshot {
            (&self.topics.snapshots, &self.spec.snapshots)
        } else {
            (&self.topics.updates, &self.spec.updates)
        };
        topic.publish(m).map_err(|e| published(name, e))?;
        self.own.changed = false;
        self.summary.updates += 1;
        self.summary.snapshots += usize::from(snapshot);
        self.summary.update_bytes += n;
        Ok(())
    }

    /// The peer's last estimate: as a pose with covariance when
    /// `Converged`, then on the fixes topic, with the same stamp, when it
    /// passed the verdict and is not doubted (`Estimate::offered`). The
    /// pose first: a peer that hears it before the fix knows the fix is
    /// reported `Converged` ([`reported_by`]).
    pub(super) fn publish_estimate(&mut self, name: &str) -> Result<(), Error> {
        let stamp = self.own.stamp;
        let own_frame = self.spec.odom_frame.clone();
        let Some(peer) = self.peers.get_mut(name) else { return Ok(()) };
        let Some(e) = peer.last else { return Ok(()) };
        if !e.offered() {
            return Ok(());
        }
        let t: Isometry3<f64> = nalgebra::convert(e.result.transform);
        let info: nalgebra::Matrix6<f64> = nalgebra::convert(e.result.information);
        if let (Some(pose), MatchStatus::Converged) = (pose_with_covariance(&t, &info), e.status()) {
            let topic = pose_topic(&self.spec.name, name);
            if peer.pose.is_none() {
                peer.pose = Some(self.dds.publisher(&topic, POSE, TopicKind::Tf)?);
            }
            if let Some(p) = &peer.pose {
                p.publish(PoseWithCovarianceStamped { header: Header { stamp, frame_id: own_frame.clone() }, pose })
                    .map_err(|e| published(&topic, e))?;
            }
        }
        let fix = edge(stamp, own_frame, peer.odom_frame.clone(), &t);
        self.topics.fixes.publish(TfMessage { transforms: vec![fix] }).map_err(|e| published(&self.spec.fixes, e))
    }

    /// The robot's odometry frame under the lowest-named peer's it holds
    /// `Converged` whose name is below its own, if any.
    pub(super) fn publish_edge(&mut self) -> Result<(), Error> {
        let own = &self.spec.name;
        let parent = self
            .peers
            .iter()
            .find(|(n, p)| n.as_str() < own.as_str() && p.last.is_some_and(|e| e.status() == MatchStatus::Converged));
        let Some((_, p)) = parent else { return Ok(()) };
        let Some(e) = p.last else { return Ok(()) };
        let t: Isometry3<f64> = nalgebra::convert(e.result.transform.inverse());
        let edge = edge(self.own.stamp, p.odom_frame.clone(), self.spec.odom_frame.clone(), &t);
        self.topics.tf_out.publish(TfMessage { transforms: vec![edge] }).map_err(|e| published("/tf", e))
    }

    /// Every peer's status.
    pub(super) fn publish_diagnostics(&mut self) -> Result<(), Error> {
        let mut status = Vec::new();
        for (name, p) in &self.peers {
            let value = |key: &str, value: String| KeyValue { key: key.into(), value };
            let mut values = vec![
                value("copy_version", p.follower.version().to_string()),
                value("copy_voxels", p.follower.map().len().to_string()),
                value("updates_waiting", p.follower.waiting().to_string()),
                value("since_update_s", format!("{:.1}", p.updated.elapsed().as_secs_f64())),
            ];
            // The two robots' heading walk (degrees), where known.
            let figure = |w: Option<f32>| w.map_or_else(|| "unknown".into(), |w| format!("{w:.3}"));
            values.extend([value("walk", figure(self.own.walk.excess())), value("walk_peer", figure(p.walk))]);
            let (level, message) = match p.last {
                Some(e) => {
                    let s = e.status();
                    values.extend([
                        value("kind", e.kind.as_str().into()),
                        value("fix", e.fix.as_str().into()),
                        value("confirmed", e.confirmed.to_string()),
                        value("contested", e.contested.to_string()),
                        value("disputed", e.disputed.to_string()),
                        value("walked", e.walked.to_string()),
                        value("agreement", format!("{:.3}", e.result.agreement)),
                        value("overlap", format!("{:.3}", e.result.overlap)),
                    ]);
                    let well = matches!(s, MatchStatus::Converged | MatchStatus::NoOverlap);
                    (if well { DiagnosticStatus::OK } else { DiagnosticStatus::WARN }, s.as_str().to_string())
                }
                None => match &p.refused {
                    Some(why) => (DiagnosticStatus::ERROR, why.clone()),
                    None => (DiagnosticStatus::WARN, "no estimate yet".to_string()),
                },
            };
            status.push(DiagnosticStatus {
                level,
                name: format!("cosem: {} / {name}", self.spec.name),
                message,
                hardware_id: self.spec.name.clone(),
                values,
            });
        }
        let value = |m: &crate::ros::dds::QosMismatch| KeyValue { key: m.topic.clone(), value: m.what.clone() };
        status.push(DiagnosticStatus {
            level: if self.mismatches.is_empty() { DiagnosticStatus::OK } else { DiagnosticStatus::ERROR },
            name: format!("cosem: {} / qos", self.spec.name),
            message: format!("{} endpoints whose QoS cannot match", self.mismatches.len()),
            hardware_id: self.spec.name.clone(),
            values: self.mismatches.iter().map(value).collect(),
        });
        let header = Header { stamp: self.own.stamp, frame_id: String::new() };
        self.topics.diagnostics.publish(DiagnosticArray { header, status }).map_err(|e| published("/diagnostics", e))
    }
}
