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
//!   identity ([`cosem_core::session::agree`]), and from which a robot
//!   with no fix adopts a peer's, with less agreement where the peer's
//!   pose of it (below) says the peer reports it `Converged`
//!   ([`reported_by`]);
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
use crate::evaluation::session::prepared::Prepared;
use crate::evaluation::session::{estimate_on, MatchRoom};
use crate::maps::mapping::{fuse_frames, new_map, scan_turn, HostMap, PointFilter};
use crate::sources::recording::{iso_of, live_cloud, TfTree};
use crate::sources::ros_msgs::*;
use crate::sources::ros_pose::pose_with_covariance;
use cosem_core::map::{FullPolicy, MapConfig};
use cosem_core::matching::{Alignment, MatchStatus, Role};
use cosem_core::session::{pair_walk, Estimate, OdometryWalk, PeerView, Publisher, ShadowEntry, Tracker};
use nalgebra::Isometry3;
use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

mod outputs;
mod own;
mod peers;
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
        /// How it came: made, adopted, or confirmed after it was made.
        origin: Origin,
        /// The two robots' figures of their heading walk when it was made
        /// (this robot's, the peer's last heard; degrees,
        /// `cosem_core::session::OdometryWalk::excess`).
        walk: (Option<f32>, Option<f32>),
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
    /// Estimates made (every peer's, every round), those `Converged`
    /// (when made, or once the peer's fix confirmed them), those that
    /// adopted the peer's fix, and those contested by the history
    /// (`core::session::History`).
    pub estimates: Tally,
    /// The node's last figure of its heading walk (degrees), if it has one.
    pub walk: Option<f32>,
}

/// The version of what `cosem ros node` prints (its estimate lines and
/// its summary, which says it): 1 before it was said; 2 since each line
/// has `adopted` and `confirmation` (an estimate that waited for its
/// peer, told again `Converged` when the peer's fix confirms it: a round
/// and peer may have two lines, the last what the node held) and the
/// summary counts `estimates`, `converged`, `adopted` and `contested`; 3
/// since each line has `disputed` (the peer's latest estimate disagrees
/// with the node's confirmed fix, so it is not `Converged` then) and the
/// summary counts them; 4 since each line has `walked`, `walk` and
/// `walk_peer` (the two robots' heading walk: over
/// `cosem_core::session::WALK_LIMIT_DEG` together, no estimate is
/// `Converged`) and the summary counts `walked` and gives the node's
/// last `walk`.
pub const NODE_SCHEMA: u32 = 4;

/// How an estimate a node tells of came about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// This robot's own estimate of the round.
    Made,
    /// The peer's fix of this robot, adopted ([`Tracker::adopt`]), not
    /// this robot's own estimate of the round.
    Adopted,
    /// An estimate of the round it names that waited for the peer's
    /// agreement, now confirmed (`Converged`) by the peer's fix heard
    /// since: the same estimate, told again.
    Confirmed,
}

/// How a node's estimates went, counted as they are told (`RosNode::run_until`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tally {
    /// Estimates made.
    pub made: usize,
    /// Of them, `Converged` when made or confirmed later.
    pub converged: usize,
    /// Of them, the peer's fix adopted.
    pub adopted: usize,
    /// Of them, contested.
    pub contested: usize,
    /// Of them, a confirmed fix disputed by the peer's estimate.
    pub disputed: usize,
    /// Of them, withheld while the two robots' odometry walked too much
    /// (`Estimate::walked`).
    pub walked: usize,
}

impl Tally {
    /// `e` counted, as it came (a confirmation counts it `Converged`, not
    /// made again).
    pub fn count(&mut self, e: &Estimate, origin: Origin) {
        self.converged += usize::from(e.status() == MatchStatus::Converged);
        if origin == Origin::Confirmed {
            return;
        }
        self.made += 1;
        self.adopted += usize::from(origin == Origin::Adopted);
        self.contested += usize::from(e.contested);
        self.disputed += usize::from(e.disputed);
        self.walked += usize::from(e.walked);
    }
}

/// One peer as this robot knows it.
struct Peer {
    odom_frame: String,
    follower: Follower,
    tracker: Tracker,
    /// The peer's last estimate of `T_peer_own` that passed its verdict,
    /// and when it came.
    heard: Option<(Isometry3<f32>, Instant)>,
    /// The last estimate, the copy's version it was made on, and the
    /// round it was made in.
    last: Option<Estimate>,
    estimated: u32,
    made_in: usize,
    /// When an update of it last came.
    updated: Instant,
    /// Why it is not estimated, if it is not (another voxel size).
    refused: Option<String>,
    pose: Option<ros2_client::Publisher<PoseWithCovarianceStamped>>,
    /// The peer's pose of this robot (`/<peer>/peers/<robot>/pose`,
    /// published only while the peer's estimate is `Converged`), and the
    /// last one heard (`T_peer_own`, its stamp): a fix of the same stamp
    /// is one the peer reports `Converged` ([`reported_by`]).
    reports: ros2_client::Subscription<PoseWithCovarianceStamped>,
    reported: Option<(Isometry3<f32>, Time)>,
    /// The peer's figure of its heading walk, from its last update.
    walk: Option<f32>,
}

/// The topic on which `robot` publishes its pose of `peer` while its
/// estimate of it is `Converged`.
fn pose_topic(robot: &str, peer: &str) -> String {
    format!("/{}/peers/{}/pose", robot.trim_start_matches('/'), peer.trim_start_matches('/'))
}

/// Whether the peer reports its fix `theirs` (`T_peer_own`), stamped
/// `stamp`, `Converged` ([`cosem_core::session::adopt_backed`]'s
/// `reported`): its last pose of this robot, `reported`, has the fix's
/// stamp and agrees with it where the robot is, `at`. Why the stamp: the
/// peer publishes its pose and its fix of one estimate with one stamp,
/// the pose first; a pose of another estimate, or one that comes after
/// the fix, leaves the fix adopted with the margin, as a fix that does
/// not say.
pub fn reported_by(
    reported: Option<&(Isometry3<f32>, Time)>,
    theirs: &Isometry3<f32>,
    stamp: Time,
    at: [f32; 3],
) -> bool {
    reported.is_some_and(|(pose, s)| *s == stamp && cosem_core::session::agree(&pose.inverse(), theirs, at, None))
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
const POSE: (&str, &str) = ("geometry_msgs", "PoseWithCovarianceStamped");

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
    /// How far its odometry turned its last scans from its map (sent with
    /// every update: `MapUpdate::heading_walk`).
    walk: OdometryWalk,
}

impl Own {
    /// How this robot sees `peer` for an estimate, with the peer's estimate
    /// of it heard, if any. No staleness by distance (`copy_at`): a peer's
    /// updates come at its own pace, which may be a second or more of
    /// driving apart (its silence is judged by time: `HEARD_FOR`,
    /// `FORGET_AFTER`).
    fn view_of(&self, peer: &Peer, estimate: Option<Isometry3<f32>>) -> PeerView {
        let walk = pair_walk(self.walk.excess(), peer.walk);
        PeerView { estimate, at: self.place, peer_at: peer.follower.peer_place(), copy_at: None, walk }
    }
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
    room: MatchRoom,
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
    if count < max {
        return Room::Free;
    }
    match stalest {
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
            walk: OdometryWalk::new(),
        };
        let capacity = spec.capacity;
        Ok(RosNode {
            dds,
            topics,
            own,
            peers: BTreeMap::new(),
            words: vec![0; 2 * capacity],
            out: vec![0; capacity * 24 + 4096],
            room: MatchRoom::new(&spec.alignment, capacity),
            summary: NodeSummary::default(),
            dirty: false,
            last_input: Instant::now(),
            mismatches: Vec::new(),
            looked: Instant::now(),
            spec,
        })
    }

    /// Runs until idle for `spec.idle`, or until `stop` is set (a signal's
    /// handler sets it: a node asked to stop says what it did), telling
    /// `log` what happens; what it did.
    pub fn run_until(mut self, stop: &AtomicBool, mut log: impl FnMut(&Event)) -> Result<NodeSummary, Error> {
        // Every estimate is counted as it is told, whichever way it came.
        let mut tally = Tally::default();
        let mut log = |event: &Event| {
            if let Event::Estimate { estimate, origin, .. } = event {
                tally.count(estimate, *origin);
            }
            log(event);
        };
        loop {
            if stop.load(Ordering::Relaxed) {
                break;
            }
            let got = self.poll(&mut log)?;
            let settled = self.last_input.elapsed().as_secs_f64() >= self.spec.settle;
            if self.own.fresh >= self.spec.every || (self.dirty && settled) {
                self.round(&mut log)?;
            }
            if self.looked.elapsed().as_secs_f64() >= QOS_LOOK_EVERY {
                self.look_at_qos(&mut log);
            }
            if self.spec.idle.is_some_and(|s| self.last_input.elapsed().as_secs_f64() > s) && !self.dirty {
                break;
            }
            if !got {
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        self.summary.estimates = tally;
        Ok(self.summary)
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
        // The peers' poses of this robot before their fixes: a peer
        // publishes an estimate's pose before its fix.
        for (name, peer) in &mut self.peers {
            let topic = pose_topic(name, &self.spec.name);
            for m in drain(&peer.reports, &topic, &mut self.summary, log) {
                let t = Transform { translation: m.pose.pose.position, rotation: m.pose.pose.orientation };
                if let Some(iso) = iso_of(&t) {
                    peer.reported = Some((nalgebra::convert(iso), m.header.stamp));
                }
            }
        }
        for m in &fixes {
            self.peer_fixes(m, log)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fix_is_reported_converged_only_by_a_pose_of_its_stamp_that_agrees() {
        let theirs = Isometry3::new(nalgebra::Vector3::new(30.0, -4.0, 0.5), nalgebra::Vector3::z() * 0.8);
        let (stamp, at) = (time_of(12_500_000_000), [3.0, 1.0, 0.0]);
        // The peer's pose of this estimate: the same transform, the same stamp.
        assert!(reported_by(Some(&(theirs, stamp)), &theirs, stamp, at));
        // None heard, or the pose of an earlier estimate (another stamp).
        assert!(!reported_by(None, &theirs, stamp, at));
        assert!(!reported_by(Some(&(theirs, time_of(12_300_000_000))), &theirs, stamp, at));
        // The same stamp, another placement: 1 m aside, or 2 degrees turned.
        let aside = Isometry3::new(nalgebra::Vector3::new(31.0, -4.0, 0.5), nalgebra::Vector3::z() * 0.8);
        let turned = Isometry3::new(nalgebra::Vector3::new(30.0, -4.0, 0.5), nalgebra::Vector3::z() * 0.835);
        assert!(!reported_by(Some(&(aside, stamp)), &theirs, stamp, at));
        assert!(!reported_by(Some(&(turned, stamp)), &theirs, stamp, at));
        // Its topic: the peer's namespace, this robot's name.
        assert_eq!(pose_topic("robot_1", "/robot_0"), "/robot_1/peers/robot_0/pose");
    }

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
