//! One robot of a session: its scans in its own odometry frame (drifted),
//! its true poses (for the truth only), and its bounded map, fused a few
//! scans a round around where it is.

use crate::error::Error;
use crate::maps::mapping::{fuse_frames, new_map, scan_turn, HostMap, PointFilter};
use crate::sources::drift::drifted;
use crate::sources::kitti::Frame;
use crate::sources::source::Source;
use cosem_core::map::{FullPolicy, MapConfig};
use cosem_core::session::{pair_walk, OdometryWalk};
use nalgebra::{Isometry3, Point3};

use super::SessionSpec;

/// A robot: what it sees (its scans, its odometry) and what only the
/// evaluation sees (its true poses, its map with ground-truth labels).
pub(super) struct Robot {
    /// Scans with points in the odometry frame; `pose`: the odometry's.
    frames: Vec<Frame>,
    /// The same scans with ground-truth labels (label noise only).
    truth_frames: Option<Vec<Frame>>,
    /// `T_world_base` of each scan (true).
    world: Vec<Isometry3<f64>>,
    /// The robot's map, in its odometry frame, bounded.
    pub map: HostMap,
    /// The same map with ground-truth labels (label noise only).
    truth_map: Option<HostMap>,
    /// Scans fused so far.
    pub fused: usize,
    filter: PointFilter,
    /// How far its odometry turned its last scans from its map.
    walk: OdometryWalk,
}

impl Robot {
    /// Robot `i` of `spec`: its scans read, drifted (seeded by `seed + i`),
    /// label noise on a copy.
    pub fn load(spec: &SessionSpec, i: usize, source: &Source) -> Result<Robot, Error> {
        let r = &spec.robots[i];
        let (mut frames, anchor, _) = source.load(Some(r.frames))?;
        if frames.is_empty() {
            return Err(Error::Invalid(format!("robot {i}: {}: no scans in frames {}", r.data.display(), r.frames)));
        }
        let anchor = crate::sources::kitti::isometry(&anchor);
        let truth: Vec<Isometry3<f64>> = frames.iter().map(|f| f.pose).collect();
        let slip_at = spec.slip.filter(|s| s.0 == i).map(|s| s.1 * spec.every);
        let odom = drifted(&truth, spec.drift, spec.seed.wrapping_add(i as u64), slip_at);
        let world = truth.iter().map(|t| anchor * t).collect();
        for (f, o) in frames.iter_mut().zip(&odom) {
            let to_odom = (o * f.pose.inverse()).cast::<f32>();
            for p in &mut f.points {
                let q = to_odom * Point3::from(*p);
                *p = [q.x, q.y, q.z];
            }
            f.pose = *o;
        }
        let truth_frames = (spec.label_noise != crate::maps::noise::LabelNoise::None).then(|| frames.clone());
        crate::maps::noise::corrupt_all(&mut frames, spec.label_noise, spec.seed.wrapping_add(i as u64));
        let config = MapConfig {
            when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] },
            ..MapConfig::with_resolution(spec.voxel)
        };
        let map = new_map(spec.capacity_of(i), config)?;
        let truth_map = truth_frames.as_ref().map(|_| new_map(spec.capacity_of(i), config)).transpose()?;
        let filter = PointFilter { max_range: Some(spec.crop), ..PointFilter::default() };
        Ok(Robot { frames, truth_frames, world, map, truth_map, fused: 0, filter, walk: OdometryWalk::new() })
    }

    /// Scan `k` (its points and pose in the odometry frame, drifted).
    pub fn frame(&self, k: usize) -> &Frame {
        &self.frames[k]
    }

    /// Scans the robot has.
    pub fn scans(&self) -> usize {
        self.frames.len()
    }

    /// Fuses its next `every` scans (fewer at the end), each with the map
    /// kept around where the robot is then; returns how many.
    pub fn drive(&mut self, every: usize) -> Result<usize, Error> {
        let end = (self.fused + every).min(self.frames.len());
        for k in self.fused..end {
            let f = &self.frames[k];
            let at = f.pose.translation.vector.cast::<f32>();
            let at = [at.x, at.y, at.z];
            self.map.move_anchor(at).map_err(|e| Error::Invalid(format!("scan {}: {e}", f.index)))?;
            self.walk.push(scan_turn(&self.map, f, &self.filter, at));
            fuse_frames(&mut self.map, std::slice::from_ref(f), &self.filter)?;
            if let (Some(map), Some(frames)) = (self.truth_map.as_mut(), self.truth_frames.as_ref()) {
                map.move_anchor(at).map_err(|e| Error::Invalid(format!("scan {}: {e}", f.index)))?;
                fuse_frames(map, std::slice::from_ref(&frames[k]), &self.filter)?;
            }
        }
        let n = end - self.fused;
        self.fused = end;
        Ok(n)
    }

    /// Its figure of its odometry's heading walk (degrees,
    /// [`OdometryWalk::excess`]), once it has one.
    pub fn walk(&self) -> Option<f32> {
        self.walk.excess()
    }

    /// Its walk and `peer`'s together ([`pair_walk`]): each robot measures
    /// its own, and the peer's comes with its update (in-process here).
    pub fn walk_with(&self, peer: &Robot) -> Option<f32> {
        pair_walk(self.walk(), peer.walk())
    }

    /// The odometry pose (`T_odom_base`) of the last scan fused.
    pub fn pose(&self) -> Option<Isometry3<f64>> {
        self.fused.checked_sub(1).map(|k| self.frames[k].pose)
    }

    /// The map with ground-truth labels (the map itself without label noise).
    pub fn truth_map(&self) -> &HostMap {
        self.truth_map.as_ref().unwrap_or(&self.map)
    }

    /// `T_world_odom` at scan `k`: where the odometry frame lies in the
    /// world, as the drifted odometry of scan `k` puts it.
    pub fn world_odom(&self, k: usize) -> Isometry3<f64> {
        self.world[k] * self.frames[k].pose.inverse()
    }

    /// Where the robot is (its own frame, the last scan fused; the origin
    /// before any): where its estimates are judged against its peers'.
    pub fn place(&self) -> [f32; 3] {
        self.pose().map_or([0.0; 3], |p| {
            let t = p.translation.vector.cast::<f32>();
            [t.x, t.y, t.z]
        })
    }

    /// Where the odometry put scan `k` (its own frame).
    pub fn odometry_position(&self, k: usize) -> nalgebra::Point3<f64> {
        nalgebra::Point3::from(self.frames[k].pose.translation.vector)
    }

    /// The true position of scan `k` in the world.
    pub fn world_position(&self, k: usize) -> nalgebra::Vector3<f64> {
        self.world[k].translation.vector
    }

    /// The fused scans whose place the map still holds: within the map's
    /// reach of where the robot is (the farthest voxel from it).
    pub fn scans_in_map(&self) -> Vec<usize> {
        let Some(last) = self.fused.checked_sub(1) else { return Vec::new() };
        let here = self.frames[last].pose.translation.vector;
        let res = self.map.resolution();
        let reach = self
            .map
            .iter()
            .map(|v| {
                let p = v.position(res);
                (nalgebra::Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])) - here).norm()
            })
            .fold(0.0, f64::max);
        (0..self.fused).filter(|&k| (self.frames[k].pose.translation.vector - here).norm() <= reach).collect()
    }
}
