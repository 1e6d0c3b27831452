//! `cosem ros node`: one robot of a team, live beside its ROS 2 stack. It
//! reads the robot's labelled `PointCloud2` and its motion (`/tf` and
//! `/tf_static`, or a `nav_msgs/Odometry` topic), keeps the continuous
//! robot's bounded map in its odometry frame, trades map updates with
//! its peers over DDS, and publishes where each peer is:
//!
//! - its map updates on one topic every robot shares (`cosem_msgs/MapUpdate`,
//!   reliable, transient local, the last [`UPDATE_HISTORY`]) and every
//!   `snapshot_every`th update, a snapshot, on another (transient local,
//!   the last one): a peer that joins late or missed one catches up from
//!   the snapshot and the updates after it ([`super::follow`]);
//! - each peer's map followed from them, the peer's relative pose tracked
//!   as the continuous session's robot does ([`cosem_core::session::Tracker`]);
//! - each estimate that passed the verdict on a shared fixes topic
//!   (`tf2_msgs/TFMessage`, own odometry frame the parent), from which the
//!   peers confirm theirs: two robots' estimates that compose to the
//!   identity ([`cosem_core::session::agree`]);
//! - while an estimate is `Converged` (passed and confirmed): the pose of
//!   the peer's odometry frame in the robot's, with its covariance, on
//!   `/<robot>/peers/<peer>/pose`; and on `/tf` one edge, the robot's
//!   odometry frame under the odometry frame of the lowest-named peer it
//!   holds `Converged` whose name is below its own (so each frame has one
//!   parent and the edges form no cycle, as tf2 requires);
//! - every estimate's status on `/diagnostics`.

use super::dds::{edge, published, stamp_now, DdsNode, TopicKind};
use super::follow::Follower;
use crate::error::Error;
use crate::evaluation::session::estimate_on;
use crate::evaluation::session::prepared::Prepared;
use crate::maps::mapping::{fuse_frames, new_map, HostMap, PointFilter};
use crate::sources::recording::{iso_of, live_cloud, TfTree};
use crate::sources::ros_msgs::*;
use crate::sources::ros_pose::pose_with_covariance;
use cosem_core::map::{FullPolicy, MapConfig};
use cosem_core::matching::search::SearchScratch;
use cosem_core::matching::{Alignment, MatchStatus, Reach, Role};
use cosem_core::session::{Estimate, PeerView, Publisher, ShadowEntry, Tracker};
use nalgebra::Isometry3;
use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

/// Updates a robot's update topic keeps for late joiners: more than the
/// updates between two snapshots.
pub const UPDATE_HISTORY: usize = 32;

/// Scans waiting for their pose, at most (the oldest dropped beyond).
pub const CLOUD_QUEUE: usize = 10;

/// How long a scan may wait for its pose on `/tf` (s) before it is dropped.
pub const POSE_WAIT: f64 = 2.0;

/// What a node runs.
#[derive(Clone, Debug)]
pub struct NodeSpec {
    /// The robot's name: its topics' namespace and its frames' prefix.
    /// Robots are ordered by name: the lower one is the parent on `/tf`.
    pub name: String,
    /// The DDS domain.
    pub domain: u16,
    /// The labelled scans' topic.
    pub points: String,
    /// Read the scans reliably (else best effort, ROS 2's sensor-data QoS,
    /// which takes a writer of either).
    pub points_reliable: bool,
    /// The scans' label field (SemanticKITTI ids, as `cosem map` reads).
    pub label_field: String,
    /// A class table mapping the label field's ids to classes (as
    /// `cosem map --classes`); `None`: SemanticKITTI ids.
    pub classes: Option<crate::sources::class_table::ClassTable>,
    /// The odometry frame (the map's frame, and the robot's on `/tf`).
    pub odom_frame: String,
    /// A `nav_msgs/Odometry` topic to take the motion from, instead of
    /// `/tf` (its `header.frame_id` the odometry frame, `child_frame_id`
    /// the one `/tf_static` chains to the scans').
    pub odometry: Option<String>,
    /// The topics every robot shares: updates, snapshots and fixes.
    pub updates: String,
    /// Snapshots.
    pub snapshots: String,
    /// Fixes.
    pub fixes: String,
    /// Scans a round: a round publishes an update and re-estimates.
    pub every: usize,
    /// Every this many updates, a snapshot.
    pub snapshot_every: u32,
    /// Voxel size (m).
    pub voxel: f32,
    /// Voxels the map holds, and each copy of a peer's.
    pub capacity: usize,
    /// Points farther than this from their sensor are left out (m).
    pub crop: f32,
    /// The matcher.
    pub alignment: Alignment,
    /// With nothing new for this long (s), a round runs on what came.
    pub settle: f64,
    /// Exit after this long (s) with no scan and no peer message (`None`:
    /// run until stopped).
    pub idle: Option<f64>,
    /// Peers followed at most (1 to [`MAX_PEERS`]): each holds a copy of a
    /// map of `capacity` voxels, so a network that names ever new robots
    /// cannot grow the node without bound ([`room_for`]).
    pub max_peers: usize,
}

/// What the node saw happen, for its log (JSON lines on stdout) and
/// summary.
#[derive(Clone, Debug)]
pub enum Event {
    /// A round's estimate of a peer.
    Estimate {
        /// Rounds run.
        round: usize,
        /// The peer.
        peer: String,
        /// The estimate.
        estimate: Box<Estimate>,
        /// Voxels of the own map and of the peer's copy.
        voxels: (usize, usize),
        /// Seconds the estimate took.
        seconds: f64,
    },
    /// An input dropped: what and why.
    Dropped(String),
    /// A peer restarted (a new epoch's snapshot came): its copy replaced,
    /// its track started again.
    Restarted(String),
    /// A peer silent for longer than [`FORGET_AFTER`] forgotten, its copy
    /// and track dropped, to follow another: who, and for how long (s) it
    /// had been silent.
    Forgotten(String, f64),
    /// A remote endpoint on one of the node's topics whose QoS cannot
    /// match (found once).
    Qos(super::dds::QosMismatch),
}

/// What a node did, when it stops.
#[derive(Clone, Debug, Default)]
pub struct NodeSummary {
    /// Scans fused.
    pub scans: usize,
    /// Rounds run.
    pub rounds: usize,
    /// Updates published (snapshots among them) and their payload bytes.
    pub updates: usize,
    /// Snapshots published.
    pub snapshots: usize,
    /// Payload bytes published.
    pub update_bytes: usize,
    /// Inputs dropped (scans, updates, fixes).
    pub dropped: usize,
    /// Per peer: updates applied.
    pub applied: BTreeMap<String, usize>,
    /// Remote endpoints whose QoS could not match the node's.
    pub qos_mismatches: usize,
}

/// One peer as this robot knows it.
struct Peer {
    odom_frame: String,
    follower: Follower,
    tracker: Tracker,
    /// The peer's last estimate of `T_peer_own` that passed its verdict,
    /// and when it came.
    heard: Option<(Isometry3<f32>, Instant)>,
    /// The last estimate, and the copy's version it was made on.
    last: Option<Estimate>,
    estimated: u32,
    /// When an update of it last came.
    updated: Instant,
    /// Why it is not estimated, if it is not (another voxel size).
    refused: Option<String>,
    pose: Option<ros2_client::Publisher<PoseWithCovarianceStamped>>,
}

/// The topics the node reads and writes.
struct Topics {
    points: ros2_client::Subscription<PointCloud2>,
    tf: ros2_client::Subscription<TfMessage>,
    tf_static: ros2_client::Subscription<TfMessage>,
    odometry: Option<ros2_client::Subscription<Odometry>>,
    updates_in: ros2_client::Subscription<MapUpdate>,
    snapshots_in: ros2_client::Subscription<MapUpdate>,
    fixes_in: ros2_client::Subscription<TfMessage>,
    updates: ros2_client::Publisher<MapUpdate>,
    snapshots: ros2_client::Publisher<MapUpdate>,
    fixes: ros2_client::Publisher<TfMessage>,
    tf_out: ros2_client::Publisher<TfMessage>,
    diagnostics: ros2_client::Publisher<DiagnosticArray>,
}

const TF: (&str, &str) = ("tf2_msgs", "TFMessage");
const UPDATE: (&str, &str) = ("cosem_msgs", "MapUpdate");

impl Topics {
    fn new(dds: &mut DdsNode, spec: &NodeSpec) -> Result<Self, Error> {
        let odometry = match &spec.odometry {
            Some(t) => Some(dds.subscription(t, ("nav_msgs", "Odometry"), TopicKind::Tf)?),
            None => None,
        };
        Ok(Topics {
            points: dds.subscription(
                &spec.points,
                ("sensor_msgs", "PointCloud2"),
                if spec.points_reliable { TopicKind::ReliableSensor } else { TopicKind::Sensor },
            )?,
            tf: dds.subscription("/tf", TF, TopicKind::Tf)?,
            tf_static: dds.subscription("/tf_static", TF, TopicKind::Latched)?,
            odometry,
            updates_in: dds.subscription(&spec.updates, UPDATE, TopicKind::History(UPDATE_HISTORY))?,
            snapshots_in: dds.subscription(&spec.snapshots, UPDATE, TopicKind::Latched)?,
            fixes_in: dds.subscription(&spec.fixes, TF, TopicKind::Tf)?,
            updates: dds.publisher(&spec.updates, UPDATE, TopicKind::History(UPDATE_HISTORY))?,
            snapshots: dds.publisher(&spec.snapshots, UPDATE, TopicKind::Latched)?,
            fixes: dds.publisher(&spec.fixes, TF, TopicKind::Tf)?,
            tf_out: dds.publisher("/tf", TF, TopicKind::Tf)?,
            diagnostics: dds.publisher("/diagnostics", ("diagnostic_msgs", "DiagnosticArray"), TopicKind::Tf)?,
        })
    }
}

/// The robot's own side: its map, its motion, its updates.
struct Own {
    map: HostMap,
    publisher: Publisher<Vec<ShadowEntry>>,
    tree: TfTree,
    /// Scans read and checked, waiting for their pose: when they came,
    /// their stamp (ns) and frame, their points.
    clouds: VecDeque<(Instant, i64, String, crate::sources::kitti::Cloud)>,
    filter: PointFilter,
    /// Scans fused since the last round; the last one's stamp and place.
    fresh: usize,
    stamp: Time,
    place: [f32; 3],
    /// The map changed since the last update.
    changed: bool,
}

/// The node: its DDS side, its own map and its peers.
pub struct RosNode {
    spec: NodeSpec,
    dds: DdsNode,
    topics: Topics,
    own: Own,
    peers: BTreeMap<String, Peer>,
    words: Vec<u32>,
    out: Vec<u8>,
    search: Vec<u32>,
    reach: Vec<Reach>,
    summary: NodeSummary,
    /// Something new (a scan, a peer's update) since the last round, and
    /// when the last thing came.
    dirty: bool,
    last_input: Instant,
    /// QoS mismatches found, and when the last look was.
    mismatches: Vec<super::dds::QosMismatch>,
    looked: Instant,
}

/// How long a peer's fix counts for the agreement (s): two rounds' worth
/// at any pace a robot keeps, not a fix from a past meeting.
pub const HEARD_FOR: f64 = 10.0;

/// How often the node looks for endpoints whose QoS cannot match (s).
pub const QOS_LOOK_EVERY: f64 = 1.0;

/// The most peers a node may be set to follow.
pub const MAX_PEERS: usize = 64;

/// A followed peer silent this long (s) gives its place to a new one when
/// the node follows as many as it may: a robot gone for a minute is not in
/// the meeting at hand.
pub const FORGET_AFTER: f64 = 60.0;

/// Whether a robot not yet followed can be, among `followed` (each peer's
/// name and seconds since its last update), `max` at most.
#[derive(Clone, Debug, PartialEq)]
pub enum Room {
    /// Fewer than `max` followed.
    Free,
    /// As many as `max`; this one (the longest silent, over
    /// [`FORGET_AFTER`]) is forgotten to make room.
    Forget(String, f64),
    /// As many as `max`, none silent long enough: the new robot is not
    /// followed (its updates dropped).
    Full,
}

/// See [`Room`]; ties in silence go to the lowest name (deterministic).
pub fn room_for<'a>(followed: impl Iterator<Item = (&'a str, f64)>, max: usize) -> Room {
    let mut count = 0usize;
    let mut stalest: Option<(&str, f64)> = None;
    for (name, silent) in followed {
        count += 1;
        if stalest.is_none_or(|(_, s)| silent > s) {
            stalest = Some((name, silent));
        }
    }
    match stalest {
        _ if count < max => Room::Free,
        Some((name, silent)) if silent > FORGET_AFTER => Room::Forget(name.to_owned(), silent),
        _ => Room::Full,
    }
}

/// A random epoch (never 0): a restarted node's differs from its last run's.
fn fresh_epoch() -> u16 {
    let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
    let mixed = (t.as_nanos() as u64 ^ u64::from(std::process::id())).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    ((mixed >> 48) as u16).max(1)
}

/// A stamp (ns) as a ROS time.
fn time_of(ns: i64) -> Time {
    let sec = i32::try_from(ns.div_euclid(1_000_000_000)).unwrap_or(i32::MAX);
    Time { sec, nanosec: ns.rem_euclid(1_000_000_000) as u32 }
}

impl RosNode {
    /// A node as `spec` says, its topics created.
    pub fn new(spec: NodeSpec) -> Result<Self, Error> {
        if spec.every == 0 || spec.snapshot_every == 0 || !(64..=1 << 20).contains(&spec.capacity) {
            return Err(Error::Invalid(format!(
                "a node fuses 1 scan a round at least (not {}), snapshots every 1 update at least (not {}), and its \
                 map holds 64 to 1048576 voxels (not {})",
                spec.every, spec.snapshot_every, spec.capacity
            )));
        }
        if !(1..=MAX_PEERS).contains(&spec.max_peers) {
            return Err(Error::Invalid(format!("a node follows 1 to {MAX_PEERS} peers (not {})", spec.max_peers)));
        }
        let mut dds = DdsNode::new(spec.domain, &spec.name.replace('/', "_"))?;
        let topics = Topics::new(&mut dds, &spec)?;
        let config = MapConfig {
            when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] },
            ..MapConfig::with_resolution(spec.voxel)
        };
        let records = || vec![ShadowEntry::default(); spec.capacity];
        let own = Own {
            map: new_map(spec.capacity, config)?,
            publisher: Publisher::new(fresh_epoch(), records(), records()),
            tree: TfTree::default(),
            clouds: VecDeque::new(),
            filter: PointFilter { max_range: Some(spec.crop), ..PointFilter::default() },
            fresh: 0,
            stamp: Time::default(),
            place: [0.0; 3],
            changed: false,
        };
        let capacity = spec.capacity;
        Ok(RosNode {
            dds,
            topics,
            own,
            peers: BTreeMap::new(),
            words: vec![0; 2 * capacity],
            out: vec![0; capacity * 24 + 4096],
            search: vec![0; SearchScratch::WINDOWED],
            reach: vec![Reach::EMPTY; crate::matching::align::reach_room(&spec.alignment)],
            summary: NodeSummary::default(),
            dirty: false,
            last_input: Instant::now(),
            mismatches: Vec::new(),
            looked: Instant::now(),
            spec,
        })
    }

    /// Runs until idle for `spec.idle` (or forever), telling `log` what
    /// happens; what it did.
    pub fn run(mut self, mut log: impl FnMut(&Event)) -> Result<NodeSummary, Error> {
        loop {
            let got = self.poll(&mut log)?;
            let settled = self.last_input.elapsed().as_secs_f64() >= self.spec.settle;
            if self.own.fresh >= self.spec.every || (self.dirty && settled) {
                self.round(&mut log)?;
            }
            if self.looked.elapsed().as_secs_f64() >= QOS_LOOK_EVERY {
                self.look_at_qos(&mut log);
            }
            if self.spec.idle.is_some_and(|s| self.last_input.elapsed().as_secs_f64() > s) && !self.dirty {
                return Ok(self.summary);
            }
            if !got {
                std::thread::sleep(Duration::from_millis(5));
            }
        }
    }

    /// Reports each remote endpoint whose QoS cannot match, once; they
    /// go on `/diagnostics` too.
    fn look_at_qos(&mut self, log: &mut impl FnMut(&Event)) {
        self.looked = Instant::now();
        for m in self.dds.qos_mismatches() {
            if !self.mismatches.contains(&m) {
                log(&Event::Qos(m.clone()));
                self.summary.qos_mismatches += 1;
                self.mismatches.push(m);
            }
        }
    }

    fn drop_input(&mut self, why: String, log: &mut impl FnMut(&Event)) {
        self.summary.dropped += 1;
        log(&Event::Dropped(why));
    }

    /// Reads what came on every topic; whether anything did.
    fn poll(&mut self, log: &mut impl FnMut(&Event)) -> Result<bool, Error> {
        let t = &self.topics;
        let s = &mut self.summary;
        let fixed = drain(&t.tf_static, "/tf_static", s, log);
        let moving = drain(&t.tf, "/tf", s, log);
        let odometry = t.odometry.as_ref().map(|o| drain(o, "odometry", s, log)).unwrap_or_default();
        let clouds = drain(&t.points, &self.spec.points, s, log);
        let snapshots = drain(&t.snapshots_in, &self.spec.snapshots, s, log);
        let updates = drain(&t.updates_in, &self.spec.updates, s, log);
        let fixes = drain(&t.fixes_in, &self.spec.fixes, s, log);
        let got =
            [fixed.len(), moving.len(), odometry.len(), clouds.len(), snapshots.len(), updates.len(), fixes.len()]
                .iter()
                .any(|&n| n > 0);
        for m in &fixed {
            self.own_transforms(m, true);
        }
        for m in &moving {
            self.own_transforms(m, false);
        }
        for o in &odometry {
            self.odometry(o, log);
        }
        for c in clouds {
            self.last_input = Instant::now();
            match live_cloud(&c, &self.spec.label_field, &self.spec.points) {
                Ok(cloud) if !cloud.points.is_empty() => {
                    let (stamp, frame) = (c.header.stamp.nanos(), c.header.frame_id);
                    self.own.clouds.push_back((Instant::now(), stamp, frame, cloud));
                }
                Ok(_) => self.drop_input(format!("{}: a scan with no point", self.spec.points), log),
                Err(e) => self.drop_input(e.to_string(), log),
            }
            if self.own.clouds.len() > CLOUD_QUEUE {
                self.own.clouds.pop_front();
                self.drop_input(format!("{}: a scan waited too long for its pose (queue full)", self.spec.points), log);
            }
        }
        self.fuse_ready(log)?;
        for m in snapshots.into_iter().chain(updates) {
            self.peer_update(m, log)?;
        }
        for m in &fixes {
            self.peer_fixes(m)?;
        }
        Ok(got)
    }
}

/// The messages waiting on `sub`; one that could not be read is logged
/// and dropped.
fn drain<T: serde::de::DeserializeOwned + 'static>(
    sub: &ros2_client::Subscription<T>,
    topic: &str,
    summary: &mut NodeSummary,
    log: &mut impl FnMut(&Event),
) -> Vec<T> {
    let mut got = Vec::new();
    loop {
        match sub.take() {
            Ok(Some((m, _))) => got.push(m),
            Ok(None) => return got,
            Err(e) => {
                summary.dropped += 1;
                log(&Event::Dropped(format!("{topic}: a message that does not read: {e:?}")));
            }
        }
    }
}

impl RosNode {
    /// The transforms of `/tf` or `/tf_static` into the tree (all of them:
    /// the chain from the odometry frame to the scans' may pass through
    /// any); the tree kept to the last minute.
    fn own_transforms(&mut self, m: &TfMessage, fixed: bool) {
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
    fn odometry(&mut self, o: &Odometry, log: &mut impl FnMut(&Event)) {
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
    fn fuse_ready(&mut self, log: &mut impl FnMut(&Event)) -> Result<(), Error> {
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
    fn fuse(&mut self, cloud: crate::sources::kitti::Cloud, stamp: i64, pose: &Isometry3<f64>) -> Result<(), Error> {
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

impl RosNode {
    /// A robot's update heard: whether it is followed, met now if there is
    /// room for it ([`room_for`]: a peer silent for [`FORGET_AFTER`] may
    /// give its place), else its update dropped.
    fn meet(&mut self, m: &MapUpdate, log: &mut impl FnMut(&Event)) -> Result<bool, Error> {
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
        let peer = Peer {
            odom_frame: m.header.frame_id.clone(),
            follower: Follower::new(copy),
            tracker: Tracker::new(),
            heard: None,
            last: None,
            estimated: 0,
            updated: Instant::now(),
            refused: None,
            pose: None,
        };
        self.peers.insert(m.robot.clone(), peer);
        Ok(true)
    }

    /// A peer's update: a new peer met, the update offered to its copy.
    fn peer_update(&mut self, m: MapUpdate, log: &mut impl FnMut(&Event)) -> Result<(), Error> {
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
                *self.summary.applied.entry(m.robot).or_default() += done.applied;
                self.dirty |= done.applied > 0;
            }
            Err(why) => self.drop_input(format!("{}: {why}", m.robot), log),
        }
        Ok(())
    }

    /// Peers' fixes of this robot (`T_peer_own`): heard for their
    /// estimates' agreement, and a fix of ours waiting for it confirmed.
    fn peer_fixes(&mut self, m: &TfMessage) -> Result<(), Error> {
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
            peer.heard = Some((theirs, Instant::now()));
            let Some(mut e) = peer.last.filter(|e| e.result.status == MatchStatus::Converged && !e.confirmed) else {
                continue;
            };
            peer.tracker.confirm(&mut e, &theirs, place);
            if e.confirmed {
                peer.last = Some(e);
                self.publish_estimate(&name)?;
                self.publish_edge()?;
            }
        }
        Ok(())
    }

    /// A round: the map's update published, every peer re-estimated, the
    /// estimates published.
    fn round(&mut self, log: &mut impl FnMut(&Event)) -> Result<(), Error> {
        self.dirty = false;
        self.own.fresh = 0;
        self.summary.rounds += 1;
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
            let view = PeerView { estimate: heard, at: self.own.place };
            let room = (&mut self.search[..], &mut self.reach[..]);
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
                peer.tracker.confirm(&mut e, &theirs, self.own.place);
            }
            peer.last = Some(e);
            peer.estimated = peer.follower.version();
            let voxels = (self.own.map.len(), copy.len());
            let seconds = t.elapsed().as_secs_f64();
            log(&Event::Estimate {
                round: self.summary.rounds,
                peer: name.clone(),
                estimate: Box::new(e),
                voxels,
                seconds,
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
    fn publish_update(&mut self) -> Result<(), Error> {
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

    /// The peer's last estimate: on the fixes topic when it passed the
    /// verdict; as a pose with covariance when `Converged`.
    fn publish_estimate(&mut self, name: &str) -> Result<(), Error> {
        let stamp = self.own.stamp;
        let own_frame = self.spec.odom_frame.clone();
        let Some(peer) = self.peers.get_mut(name) else { return Ok(()) };
        let Some(e) = peer.last else { return Ok(()) };
        if e.result.status != MatchStatus::Converged {
            return Ok(());
        }
        let t: Isometry3<f64> = nalgebra::convert(e.result.transform);
        let fix = edge(stamp, own_frame.clone(), peer.odom_frame.clone(), &t);
        self.topics.fixes.publish(TfMessage { transforms: vec![fix] }).map_err(|e| published(&self.spec.fixes, e))?;
        let info: nalgebra::Matrix6<f64> = nalgebra::convert(e.result.information);
        let (Some(pose), MatchStatus::Converged) = (pose_with_covariance(&t, &info), e.status()) else { return Ok(()) };
        let topic = format!("/{}/peers/{}/pose", self.spec.name.trim_start_matches('/'), name.trim_start_matches('/'));
        if peer.pose.is_none() {
            peer.pose =
                Some(self.dds.publisher(&topic, ("geometry_msgs", "PoseWithCovarianceStamped"), TopicKind::Tf)?);
        }
        if let Some(p) = &peer.pose {
            p.publish(PoseWithCovarianceStamped { header: Header { stamp, frame_id: own_frame }, pose })
                .map_err(|e| published(&topic, e))?;
        }
        Ok(())
    }

    /// The robot's odometry frame under the lowest-named peer's it holds
    /// `Converged` whose name is below its own, if any.
    fn publish_edge(&mut self) -> Result<(), Error> {
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
    fn publish_diagnostics(&mut self) -> Result<(), Error> {
        let mut status = Vec::new();
        for (name, p) in &self.peers {
            let value = |key: &str, value: String| KeyValue { key: key.into(), value };
            let mut values = vec![
                value("copy_version", p.follower.version().to_string()),
                value("copy_voxels", p.follower.map().len().to_string()),
                value("updates_waiting", p.follower.waiting().to_string()),
                value("since_update_s", format!("{:.1}", p.updated.elapsed().as_secs_f64())),
            ];
            let (level, message) = match p.last {
                Some(e) => {
                    let s = e.status();
                    values.extend([
                        value("kind", e.kind.as_str().into()),
                        value("fix", e.fix.as_str().into()),
                        value("confirmed", e.confirmed.to_string()),
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
        let value = |m: &super::dds::QosMismatch| KeyValue { key: m.topic.clone(), value: m.what.clone() };
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_node_forgets_only_a_peer_silent_for_a_minute() {
        let followed = [("robot_1", 3.0), ("robot_2", 61.0), ("robot_3", 90.0)];
        assert_eq!(room_for(followed.iter().copied(), 4), Room::Free);
        assert_eq!(room_for(followed.iter().copied(), 3), Room::Forget("robot_3".into(), 90.0));
        assert_eq!(room_for(followed.iter().copied(), 1), Room::Forget("robot_3".into(), 90.0));
        let busy = [("robot_1", 3.0), ("robot_2", FORGET_AFTER)];
        assert_eq!(room_for(busy.iter().copied(), 2), Room::Full);
        assert_eq!(room_for(std::iter::empty(), 1), Room::Free);
        // Ties go to the first (lowest) name, as a BTreeMap lists them.
        let tied = [("robot_1", 70.0), ("robot_2", 70.0)];
        assert_eq!(room_for(tied.iter().copied(), 2), Room::Forget("robot_1".into(), 70.0));
    }
}
