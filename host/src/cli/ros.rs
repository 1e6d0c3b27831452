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
