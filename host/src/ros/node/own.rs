//! The robot's own side: its motion from `/tf`, `/tf_static` or an
//! odometry topic, and its scans fused into its map once their pose is known.

use super::*;

impl RosNode {
    /// The transforms of `/tf` or `/tf_static` into the tree (all of them:
    /// the chain from the odometry frame to the scans' may pass through
    /// any); the tree kept to the last minute.
    pub(super) fn own_transforms(&mut self, m: &TfMessage, fixed: bool) {
        for t in &m.transforms {
            if let Some(iso) = iso_of(&t.transform) {
                let edge = (t.header.frame_id.clone(), t.child_frame_id.clone());
                self.own.tree.add(fixed, edge, t.header.stamp.nanos(), iso);
            }
        }
        if let Some(newest) = m.transforms.iter().map(|t| t.header.stamp.nanos()).max() {
            self.own.tree.trim(newest - 60_000_000_000);
        }
    }

    /// An odometry message: its pose joins the tree as a `/tf` edge.
    pub(super) fn odometry(&mut self, o: &Odometry, log: &mut impl FnMut(&Event)) {
        let t = Transform { translation: o.pose.pose.position, rotation: o.pose.pose.orientation };
        match iso_of(&t) {
            Some(iso) if o.header.frame_id == self.spec.odom_frame => {
                let edge = (o.header.frame_id.clone(), o.child_frame_id.clone());
                self.own.tree.add(false, edge, o.header.stamp.nanos(), iso);
                self.own.tree.trim(o.header.stamp.nanos() - 60_000_000_000);
            }
            Some(_) => self
                .drop_input(format!("odometry in frame `{}`, not `{}`", o.header.frame_id, self.spec.odom_frame), log),
            None => self.drop_input("odometry whose pose is not a rigid transform".into(), log),
        }
    }

    /// Fuses each waiting scan whose pose the tree has; drops one that
    /// waited past [`POSE_WAIT`] or does not read.
    pub(super) fn fuse_ready(&mut self, log: &mut impl FnMut(&Event)) -> Result<(), Error> {
        while let Some((since, stamp, frame, _)) = self.own.clouds.front() {
            let pose = self.own.tree.pose(&self.spec.odom_frame, frame, *stamp);
            let waited = since.elapsed().as_secs_f64();
            match pose {
                Ok(pose) => {
                    if let Some((_, stamp, _, cloud)) = self.own.clouds.pop_front() {
                        if let Err(e) = self.fuse(cloud, stamp, &pose) {
                            self.drop_input(format!("{}: {e}", self.spec.points), log);
                        }
                    }
                }
                Err(why) if waited > POSE_WAIT => {
                    self.own.clouds.pop_front();
                    self.drop_input(
                        format!("{}: a scan with no pose after {POSE_WAIT} s: {why}", self.spec.points),
                        log,
                    );
                }
                Err(_) => return Ok(()),
            }
        }
        Ok(())
    }

    /// One scan (its sensor's pose `pose` in the odometry frame) into the
    /// map, the map kept around the sensor.
    pub(super) fn fuse(
        &mut self,
        cloud: crate::sources::kitti::Cloud,
        stamp: i64,
        pose: &Isometry3<f64>,
    ) -> Result<(), Error> {
        let index = self.summary.scans;
        let mut frame = crate::sources::kitti::frame_of(index, None, &pose.to_homogeneous(), cloud);
        if let Some(table) = &self.spec.classes {
            table.relabel(std::slice::from_mut(&mut frame)).map_err(|(_, point, id)| {
                Error::Invalid(format!("point {point}: label id {id} is not in the class table"))
            })?;
        }
        let at = pose.translation.vector.cast::<f32>();
        let at = [at.x, at.y, at.z];
        self.own.map.move_anchor(at).map_err(|e| Error::Invalid(format!("scan {index}: {e}")))?;
        self.own.walk.push(scan_turn(&self.own.map, &frame, &self.own.filter, at));
        fuse_frames(&mut self.own.map, std::slice::from_ref(&frame), &self.own.filter)?;
        self.summary.scans += 1;
        self.own.fresh += 1;
        self.own.stamp = time_of(stamp);
        self.own.place = at;
        self.own.changed = true;
        self.dirty = true;
        Ok(())
    }
}
