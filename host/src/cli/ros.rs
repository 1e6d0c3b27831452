//! `cosem ros`: cosem beside a robot's ROS 2 stack, over DDS (feature
//! `ros`, on by default; pure Rust, no ROS installation).

use super::Error;
use cosem_host::evaluation::team::RobotSpec;

#[derive(clap::Subcommand, Debug)]
pub enum What {
    /// Publish scans live over DDS as a robot's drivers would (like `ros2
    /// bag play`): each robot's labelled PointCloud2 on /robot_<i>/points,
    /// its odometry on /tf (robot_<i>/odom -> robot_<i>/base_link),
    /// /tf_static (base_link -> velodyne). Prints each robot's odometry
    /// origin in the source's world (JSON lines), then what it published.
    Play(PlayArgs),
    /// Run one robot live: read its labelled PointCloud2 and its motion
    /// (/tf and /tf_static, or --odometry), keep its bounded map, trade map
    /// updates with its peers over DDS, and publish where each peer is:
    /// /tf (the robot's odometry frame under the lowest-named Converged
    /// peer's below its own), /<name>/peers/<peer>/pose (with covariance)
    /// and /diagnostics. Prints each estimate (JSON lines), then a summary.
    Node(Box<NodeArgs>),
}

#[derive(clap::Args, Debug)]
pub struct NodeArgs {
    /// The robot's name: its topics' namespace, its frames' prefix; robots
    /// are ordered by name (the lower one is the parent on /tf).
    #[arg(long, default_value = "robot_0", value_parser = ros_name)]
    name: String,
    /// The DDS domain id (0-232).
    #[arg(long, default_value_t = 0)]
    domain: u16,
    /// The labelled scans' topic [default: /<name>/points].
    #[arg(long)]
    points: Option<String>,
    /// The scans' QoS: best-effort (ROS 2's sensor data: takes a writer of
    /// either kind) or reliable (every scan of a reliable driver; no
    /// best-effort driver matches).
    #[arg(long, default_value = "best-effort", value_parser = ["best-effort", "reliable"])]
    points_qos: String,
    /// The scans' label field (SemanticKITTI ids).
    #[arg(long, default_value = "label")]
    label_field: String,
    /// A class table (TOML) mapping the label field's ids to classes, as
    /// `cosem map --classes` [default: SemanticKITTI ids].
    #[arg(long)]
    classes: Option<std::path::PathBuf>,
    /// The odometry frame, the map's [default: <name>/odom].
    #[arg(long)]
    odom_frame: Option<String>,
    /// Take the motion from this nav_msgs/Odometry topic, not /tf.
    #[arg(long)]
    odometry: Option<String>,
    /// The topic of every robot's map updates.
    #[arg(long, default_value = "/cosem/map_updates")]
    updates: String,
    /// The topic of every robot's map snapshots (transient local).
    #[arg(long, default_value = "/cosem/map_snapshots")]
    snapshots: String,
    /// The topic of every robot's fixes of its peers (for their agreement).
    #[arg(long, default_value = "/cosem/fixes")]
    fixes: String,
    /// Scans a round: each round publishes an update and re-estimates.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=1000))]
    every: u32,
    /// Every this many updates, a snapshot.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=1000))]
    snapshot_every: u32,
    /// Voxel size (m).
    #[arg(long, default_value_t = 0.5, value_parser = super::args::voxel)]
    voxel: f32,
    /// Voxels the map holds, and each copy of a peer's.
    #[arg(long, default_value_t = 8000, value_parser = clap::value_parser!(u32).range(64..=1_048_576))]
    capacity: u32,
    /// Leave out points farther than this from their sensor (m).
    #[arg(long, default_value_t = 25.0, value_parser = super::args::crop)]
    crop: f32,
    /// With nothing new for this long (s), a round runs on what came.
    #[arg(long, default_value_t = 0.5, value_parser = delay)]
    settle: f64,
    /// Exit after this long (s, more than 0) with no scan and no peer
    /// update [default: run until stopped].
    #[arg(long, value_parser = idle)]
    idle: Option<f64>,
    /// Peers followed at most (each holds a copy of a map); a new robot
    /// beyond them takes the place of one silent for a minute, else its
    /// updates are dropped.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=64))]
    max_peers: u32,
}

/// Seconds of idleness: more than 0, an hour at most.
fn idle(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 3600.0 => Ok(v),
        _ => Err(format!("`{s}`: expected seconds, more than 0 and 3600 at most")),
    }
}

/// A ROS 2 name segment: a letter or underscore, then letters, digits,
/// underscores.
fn ros_name(s: &str) -> Result<String, String> {
    let mut c = s.chars();
    let first = c.next().is_some_and(|f| f.is_ascii_alphabetic() || f == '_');
    if first && c.all(|c| c.is_ascii_alphanumeric() || c == '_') && s.len() <= 64 {
        Ok(s.to_string())
    } else {
        Err(format!("`{s}`: a robot's name is a letter or _, then letters, digits or _ (64 at most)"))
    }
}

#[derive(clap::Args, Debug)]
pub struct PlayArgs {
    /// A robot: a source of scans (a SemanticKITTI-layout folder, a ROS 2
    /// recording, a folder of PCD/PLY scans with poses.txt) and its frames,
    /// PATH:START:END[:STRIDE]; one or more, named robot_0, robot_1, ...
    #[arg(long = "robot", num_args = 1, required = true)]
    robots: Vec<RobotSpec>,
    /// The DDS domain id (0-232).
    #[arg(long, default_value_t = 0)]
    domain: u16,
    /// Scans a second where a source has no timestamps (KITTI's times.txt).
    #[arg(long, default_value_t = 10.0, value_parser = bounded::<1, 1000>)]
    rate: f64,
    /// Times the recorded rate.
    #[arg(long, default_value_t = 1.0, value_parser = bounded::<1, 10000>)]
    speed: f64,
    /// Leave out points farther than this from their sensor (m; 0: keep
    /// all). A full KITTI scan is about 2 MB; cropped to 50 m, about half.
    #[arg(long, default_value_t = 50.0, value_parser = super::args::non_negative)]
    crop: f64,
    /// Seed of the robots' odometry origins (each at its first scan,
    /// turned and moved by a random transform).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Seconds between the publishers' start and the first scan: time for
    /// the subscribers to be discovered.
    #[arg(long, default_value_t = 1.0, value_parser = delay)]
    delay: f64,
    /// Before the first scan, wait (at most 20 s, else fail) until every
    /// topic has this many readers; the delay counts from then.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..=1000))]
    wait_readers: u16,
}

/// A number from LO/100 to HI/100 (scans a second, times a rate).
fn bounded<const LO: u32, const HI: u32>(s: &str) -> Result<f64, String> {
    let (lo, hi) = (f64::from(LO) / 100.0, f64::from(HI) / 100.0);
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && (lo..=hi).contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: expected a number from {lo} to {hi}")),
    }
}

/// Seconds to wait: 0 to an hour.
fn delay(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && (0.0..=3600.0).contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: expected seconds from 0 to 3600")),
    }
}

pub fn run(what: What) -> Result<(), Error> {
    match what {
        What::Play(a) => play(a),
        What::Node(a) => node(*a),
    }
}

#[cfg(feature = "ros")]
fn play(a: PlayArgs) -> Result<(), Error> {
    use cosem_host::ros::play::{play, PlaySpec, PlayedRobot};
    use std::io::Write;
    let spec = PlaySpec {
        robots: a.robots,
        domain: a.domain,
        rate: a.rate,
        speed: a.speed,
        crop: (a.crop > 0.0).then_some(a.crop as f32),
        seed: a.seed,
        delay: a.delay,
        wait_readers: usize::from(a.wait_readers),
    };
    let row = |r: &PlayedRobot| {
        let m = r.world_odom.to_homogeneous();
        let t: Vec<f64> = (0..3).flat_map(|i| (0..4).map(move |j| (i, j))).map(|(i, j)| m[(i, j)]).collect();
        serde_json::json!({ "robot": r.name, "topic": r.topic, "frames": r.frames, "T_world_odom": t })
    };
    let played = play(&spec, |robots| {
        for r in robots {
            println!("{}", row(r));
        }
        let _ = std::io::stdout().flush();
    })?;
    let published: Vec<_> = played
        .iter()
        .map(|r| serde_json::json!({ "robot": r.name, "published": r.published, "bytes": r.bytes }))
        .collect();
    println!("{}", serde_json::json!({ "summary": { "robots": published } }));
    Ok(())
}

#[cfg(not(feature = "ros"))]
fn play(_: PlayArgs) -> Result<(), Error> {
    Err("cosem ros: built without the `ros` feature (cargo build --features ros)".into())
}

#[cfg(feature = "ros")]
fn node(a: NodeArgs) -> Result<(), Error> {
    use cosem_host::ros::node::{Event, NodeSpec, Origin, RosNode, NODE_SCHEMA};
    use std::io::Write;
    let name = a.name;
    let classes = a.classes.as_deref().map(cosem_host::sources::class_table::ClassTable::read).transpose()?;
    let spec = NodeSpec {
        classes,
        points_reliable: a.points_qos == "reliable",
        points: a.points.unwrap_or_else(|| format!("/{name}/points")),
        odom_frame: a.odom_frame.unwrap_or_else(|| format!("{name}/odom")),
        domain: a.domain,
        label_field: a.label_field,
        odometry: a.odometry,
        updates: a.updates,
        snapshots: a.snapshots,
        fixes: a.fixes,
        every: a.every as usize,
        snapshot_every: a.snapshot_every,
        voxel: a.voxel,
        capacity: a.capacity as usize,
        crop: a.crop,
        alignment: cosem_host::evaluation::session::DEFAULT_ALIGNMENT,
        settle: a.settle,
        idle: a.idle,
        max_peers: a.max_peers as usize,
        name: name.clone(),
    };
    // Before the node's set-up (its participant, readers and writers: a
    // while on a loaded machine), so that a launcher's SIGTERM meanwhile
    // ends it as cleanly as one later.
    stop_on_signals();
    let node = RosNode::new(spec)?;
    let summary = node.run_until(&STOP, |event| match event {
        Event::Estimate { round, peer, estimate: e, voxels, seconds, origin, walk } => {
            let m = e.result.transform.to_homogeneous();
            let t: Vec<f64> =
                (0..3).flat_map(|i| (0..4).map(move |j| (i, j))).map(|(i, j)| f64::from(m[(i, j)])).collect();
            let line = serde_json::json!({
                "round": round, "robot": name, "peer": peer, "status": e.status().as_str(),
                "kind": e.kind.as_str(), "fix": e.fix.as_str(), "confirmed": e.confirmed,
                "contested": e.contested,
                "disputed": e.disputed, "walked": e.walked, "walk": walk.0, "walk_peer": walk.1,
                "adopted": *origin == Origin::Adopted,
                "confirmation": *origin == Origin::Confirmed,
                "T_own_peer": t, "overlap": e.result.overlap, "agreement": e.result.agreement,
                "voxels": voxels.0, "peer_voxels": voxels.1, "seconds": seconds,
            });
            println!("{line}");
            let _ = std::io::stdout().flush();
        }
        Event::Dropped(why) => eprintln!("warning: dropped: {why}"),
        Event::Restarted(peer) => eprintln!("info: {peer}: restarted (a new epoch): its copy replaced"),
        Event::Forgotten(peer, silent) => {
            eprintln!("info: {peer}: forgotten after {silent:.0} s of silence, to follow a new peer");
        }
        Event::Qos(m) => eprintln!("warning: QoS: {}: {} ({})", m.topic, m.what, m.remote),
    })?;
    println!(
        "{}",
        serde_json::json!({ "summary": {
            "schema_version": NODE_SCHEMA, "scans": summary.scans, "rounds": summary.rounds, "updates": summary.updates,
            "snapshots": summary.snapshots, "update_bytes": summary.update_bytes, "dropped": summary.dropped,
            "applied": summary.applied, "qos_mismatches": summary.qos_mismatches,
            "estimates": summary.estimates.made, "converged": summary.estimates.converged,
            "adopted": summary.estimates.adopted, "contested": summary.estimates.contested,
            "disputed": summary.estimates.disputed, "walked": summary.estimates.walked, "walk": summary.walk,
        }})
    );
    Ok(())
}

/// Set by SIGINT or SIGTERM: the node ends its loop and prints its
/// summary, as a ROS 2 node stopped by its launcher does.
#[cfg(feature = "ros")]
static STOP: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

#[cfg(feature = "ros")]
extern "C" fn on_stop(_: libc::c_int) {
    // An atomic store is async-signal-safe.
    STOP.store(true, std::sync::atomic::Ordering::Relaxed);
}

/// SIGINT and SIGTERM set [`STOP`] once; a second one (the handler reset
/// by `SA_RESETHAND`) ends the process as by default, should the loop not
/// answer.
#[cfg(feature = "ros")]
fn stop_on_signals() {
    for signal in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: a zeroed sigaction with a handler that only stores to an
        // atomic, installed before any thread of ours reads STOP.
        unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = on_stop as extern "C" fn(libc::c_int) as libc::sighandler_t;
            action.sa_flags = libc::SA_RESETHAND;
            libc::sigemptyset(&mut action.sa_mask);
            libc::sigaction(signal, &action, std::ptr::null_mut());
        }
    }
}

#[cfg(not(feature = "ros"))]
fn node(_: NodeArgs) -> Result<(), Error> {
    Err("cosem ros: built without the `ros` feature (cargo build --features ros)".into())
}
