//! Two robots on emulated boards (`cosem robots`): what the host feeds each
//! robot, the line between their UART0s, and the host's own run of the
//! robots' pipeline on the same data.
//!
//! Each robot is a QEMU `mps2-an386` running the firmware's `robot` binary.
//! Its UART1 connects to a TCP listener of this process (the feeder: its
//! scans in, its report out); its UART0 connects to another listener that
//! joins the two robots' UART0s, byte for byte in both directions (and can
//! drop or corrupt bytes, to test the firmware against a bad peer).

use crate::board::Board;
use crate::error::Error;
use crate::kitti::{Frame, FrameRange};
use crate::mapping::PointFilter;
use cosem_core::classes::{Class, NUM_CLASSES};
use cosem_core::geometry::{errors_of, from_rows, pose_deg, row_major, rows, Isometry3};
use cosem_core::map::{SceneMap, ScenePoint};
use cosem_core::matching::{MatchStatus, PyramidCapacity, VecPyramidStorage};
use cosem_core::robot::{Capacity, Robot, RobotConfig};
use cosem_core::sim::{self, SimRobot, Wire};
use cosem_core::wire::feed::{
    self, FeedMessage, RobotMessage, RobotReport, Setup, MAX_POINTS_PER_MESSAGE, POINT_BYTES,
};
use cosem_core::wire::frame::{Deframer, MAX_FRAME};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// One fed point.
pub type Point = [u8; POINT_BYTES];

/// Thins one scan (already in the anchor frame) to one labelled point per
/// voxel of `resolution`: the mean of the voxel's points of its most common
/// class (ties to the lower class index), within `crop` metres of the
/// sensor. Points come out in key order, so the feed is deterministic.
pub fn thin_scan(frame: &Frame, resolution: f32, crop: f32, filter: &PointFilter) -> Vec<Point> {
    let inv = 1.0 / resolution;
    // Per voxel: per class, count and sum.
    type PerClass = [(u32, [f64; 3]); NUM_CLASSES];
    let mut cells: BTreeMap<(i32, i32, i32), PerClass> = BTreeMap::new();
    for ((p, &r), &l) in frame.points.iter().zip(&frame.ranges).zip(&frame.labels) {
        if r > crop {
            continue;
        }
        // The boards' robots keep the default filter: classes only.
        let Some(Some(class)) = filter.keep(r, l) else { continue };
        let k = ((p[0] * inv).floor() as i32, (p[1] * inv).floor() as i32, (p[2] * inv).floor() as i32);
        let cell = cells.entry(k).or_insert([(0, [0.0; 3]); NUM_CLASSES]);
        let c = &mut cell[usize::from(class.index())];
        c.0 += 1;
        for (sum, v) in c.1.iter_mut().zip(p) {
            *sum += f64::from(*v);
        }
    }
    cells
        .values()
        .filter_map(|cell| {
            let (best, (n, sum)) = cell.iter().enumerate().max_by(|a, b| a.1 .0.cmp(&b.1 .0).then(b.0.cmp(&a.0)))?;
            let class = Class::from_index(best as u8)?;
            let mean =
                [(sum[0] / f64::from(*n)) as f32, (sum[1] / f64::from(*n)) as f32, (sum[2] / f64::from(*n)) as f32];
            Some(feed::pack_point(mean, class))
        })
        .collect()
}

/// What one robot is fed.
#[derive(Clone, Debug)]
pub struct Feed {
    /// Its set-up.
    pub setup: Setup,
    /// Its scans, thinned.
    pub scans: Vec<Vec<Point>>,
}

impl Feed {
    /// Points over all scans.
    pub fn points(&self) -> usize {
        self.scans.iter().map(Vec::len).sum()
    }

    /// The feed as framed bytes: the set-up, the points in messages of up
    /// to [`MAX_POINTS_PER_MESSAGE`], the end.
    pub fn bytes(&self) -> Result<Vec<u8>, Error> {
        self.bytes_in_team(None)
    }

    /// The feed as framed bytes for a robot of a team of `team` robots
    /// (`None`: a pair robot): [`FeedMessage::Team`] after the set-up.
    pub fn bytes_in_team(&self, team: Option<u8>) -> Result<Vec<u8>, Error> {
        let mut out = Vec::new();
        let mut frame = [0u8; MAX_FRAME];
        let mut push = |msg: FeedMessage<'_>| -> Result<(), Error> {
            let n = msg.to_frame(&mut frame).map_err(|e| Error::Invalid(format!("feed message: {e}")))?;
            out.extend_from_slice(&frame[..n]);
            Ok(())
        };
        push(FeedMessage::Setup(self.setup))?;
        if let Some(robots) = team {
            push(FeedMessage::Team { robots })?;
        }
        for (i, scan) in self.scans.iter().enumerate() {
            for part in scan.chunks(MAX_POINTS_PER_MESSAGE) {
                let data: Vec<u8> = part.iter().flatten().copied().collect();
                push(FeedMessage::Points { scan: i as u16, data: &data })?;
            }
        }
        push(FeedMessage::EndOfFeed { scans: self.scans.len() as u16, points: self.points() as u32 })?;
        Ok(out)
    }
}

/// Both robots' feeds from one sequence: robot A (id 0) maps `a`, robot B
/// (id 1) `b`; each scan thinned to one point per `voxel` within `crop` m,
/// its labels first corrupted by `noise` (seeded with `seed` plus the
/// robot's id, as `cosem team` does). A gets the prior `T_A_B`, B its
/// inverse (none: both without).
#[allow(clippy::too_many_arguments)]
pub fn feeds(
    seq: &crate::source::Source,
    ranges: [FrameRange; 2],
    voxel: f32,
    crop: f32,
    prior_ab: Option<&Isometry3<f64>>,
    silence_ms: u32,
    noise: crate::noise::LabelNoise,
    seed: u64,
) -> Result<[Feed; 2], Error> {
    let filter = PointFilter::default();
    let priors = [prior_ab.copied(), prior_ab.map(Isometry3::inverse)];
    let mut out = Vec::new();
    for (id, (range, prior)) in ranges.into_iter().zip(priors).enumerate() {
        let (mut frames, _, _) = seq.load(Some(range))?;
        crate::noise::corrupt_all(&mut frames, noise, seed.wrapping_add(id as u64));
        let scans = frames.iter().map(|f| thin_scan(f, voxel, crop, &filter)).collect();
        let prior = prior.map(|p| rows(&p.cast::<f32>()));
        let setup = Setup { robot_id: id as u8, resolution: voxel, prior, silence_ms };
        out.push(Feed { setup, scans });
    }
    let [a, b]: [Feed; 2] = out.try_into().map_err(|_| Error::Invalid("two feeds expected".into()))?;
    Ok([a, b])
}

/// A received map as a board holds it: a scene of its capacity's points.
pub(crate) type Received = SceneMap<Vec<ScenePoint>>;

/// An empty received map of `voxels` points (voxels of `resolution` m).
pub(crate) fn received_scene(voxels: usize, resolution: f32) -> Result<Received, Error> {
    SceneMap::new(vec![ScenePoint::EMPTY; voxels], resolution)
        .map_err(|e| Error::Invalid(format!("received map: {e:?}")))
}

/// A team robot's pyramid storages (model, scene) on the heap, of a board's
/// capacities (the model's level 0 is its map, with extras).
pub(crate) fn board_pyramids(c: Capacity) -> (impl Fn() -> VecPyramidStorage, impl Fn() -> VecPyramidStorage) {
    let model = move || {
        VecPyramidStorage::new(PyramidCapacity {
            voxels: c.voxels,
            entries: c.coarse,
            slots: c.coarse,
            words: c.model_words,
        })
    };
    let scene = move || {
        VecPyramidStorage::new(PyramidCapacity { voxels: 0, entries: c.coarse, slots: 0, words: c.scene_words })
    };
    (model, scene)
}

/// The two robots' pipeline run on this host, exactly as on the boards:
/// the core's robot step machines with each board's capacities, the maps
/// exchanged over a clean simulated 115200-baud line, in the core's
/// simulation ([`sim::run`]). Returns each robot's report (`T_own_peer`).
pub fn host_run(feeds: [&Feed; 2], boards: [Board; 2]) -> Result<[RobotReport; 2], Error> {
    if !boards.iter().any(|b| b.matches()) {
        return Err(Error::Invalid("neither robot's board can match: one must hold both maps".into()));
    }
    let bytes = [feeds[0].bytes()?, feeds[1].bytes()?];
    let resolution = feeds[0].setup.resolution;
    // Each board's memory, as its firmware declares it: two regions of
    // words sized by its capacities.
    let capacity = boards.map(Board::capacity);
    let mut own = capacity.map(|c| vec![0u32; c.own_words()]);
    let mut turn = capacity.map(|c| vec![0u32; c.turn_words()]);
    let mut points = capacity.map(|c| vec![ScenePoint::EMPTY; c.voxels]);
    let mut received = Vec::new();
    for p in &mut points {
        received
            .push(SceneMap::new(&mut p[..], resolution).map_err(|e| Error::Invalid(format!("received map: {e:?}")))?);
    }
    let robot_config = RobotConfig::default();
    // Each robot in its board's role: the full robot, or one that sends
    // its map and is told the result (a small board's).
    let mut robots: Vec<Box<SimRobot<'_, '_, RobotReport>>> = Vec::new();
    let memory = |e: cosem_core::robot::RobotError| Error::Invalid(format!("host run: {e}"));
    for (((board, own), turn), received) in boards.iter().zip(&mut own).zip(&mut turn).zip(&mut received) {
        let c = board.capacity();
        robots.push(if board.matches() {
            Box::new(Robot::new(robot_config, own, turn, c, received).map_err(memory)?)
        } else {
            Box::new(Robot::sender(robot_config, own, turn, c).map_err(memory)?)
        });
    }
    let mut polled: Vec<&mut SimRobot<'_, '_, RobotReport>> = robots.iter_mut().map(|r| &mut **r).collect();
    let out = sim::run(&mut polled, &[&bytes[0], &bytes[1]], &[Wire::clean(0, 1, 115_200, 1)], 3_600_000);
    let named = |i: usize| match out.get(i).and_then(|o| o.result) {
        Some(Ok(r)) => Ok(r),
        Some(Err(e)) => Err(Error::Invalid(format!("host run of robot {i}: {} stage: {e}", e.stage().as_str()))),
        None => Err(Error::Invalid(format!("host run of robot {i}: no report within an hour of robot time"))),
    };
    Ok([named(0)?, named(1)?])
}

/// What `cosem robots` runs: two robots' frames of one source, their
/// boards, the line between them and how the feeds are made.
#[derive(Clone, Debug)]
pub struct RobotsSpec {
    /// The source and its options.
    pub source: crate::source::Source,
    /// Robot A's frames, then B's.
    pub ranges: [FrameRange; 2],
    /// Voxel size (m).
    pub voxel: f32,
    /// Points farther than this from their sensor are not fed (m).
    pub crop: f32,
    /// `T_A_B` prior; `None`: the default prior (the truth moved 2 m and
    /// 10 degrees) unless `no_prior`.
    pub prior: Option<Isometry3<f64>>,
    /// Prior-free on board.
    pub no_prior: bool,
    /// The mps2 robot's firmware (the STM32F405's is at its default path).
    pub firmware: PathBuf,
    /// Robot A's board, then B's.
    pub boards: [Board; 2],
    /// What the line between them does.
    pub line: LineFault,
    /// A robot gives up after this long without a valid frame (s).
    pub silence_s: f64,
    /// Kill the emulators after this long (s).
    pub timeout_s: f64,
    /// Label noise on the fed scans and its seed.
    pub label_noise: (crate::noise::LabelNoise, u64),
}

/// Runs `spec`: the feeds made, the host's twin run, both boards under QEMU,
/// all compared with the truth. Returns the report and the exit code (the
/// worse status of the two robots; `None`: a robot did not report).
pub fn run_robots(spec: &RobotsSpec) -> Result<(RobotsJson, Option<u8>), Error> {
    if !spec.boards.iter().any(|b| b.matches()) {
        return Err(Error::Invalid(
            "--board-a and --board-b: one robot must be able to match (an mps2-an386 board)".into(),
        ));
    }
    let [ra, rb] = spec.ranges;
    let gt = spec.source.relative_pose(ra.start, rb.start)?;
    let prior = (!spec.no_prior).then(|| spec.prior.unwrap_or_else(|| default_prior(&gt)));
    let silence_ms = (spec.silence_s * 1000.0).min(f64::from(u32::MAX)) as u32;
    let (noise, seed) = spec.label_noise;
    let feeds = feeds(&spec.source, spec.ranges, spec.voxel, spec.crop, prior.as_ref(), silence_ms, noise, seed)?;
    // The host runs both robots' pipeline too, as the boards do.
    let t = std::time::Instant::now();
    let host = host_run([&feeds[0], &feeds[1]], spec.boards)?;
    let host_ms = t.elapsed().as_secs_f64() * 1e3;
    let elf = |b: Board| match b {
        Board::Mps2An386 => firmware(&spec.firmware),
        Board::Stm32f405 | Board::Stm32f405Sender => firmware(Path::new(b.default_firmware())),
    };
    let elves = [elf(spec.boards[0])?, elf(spec.boards[1])?];
    let timeout = Duration::from_secs_f64(spec.timeout_s.min(86_400.0));
    let run = run_pair([&elves[0], &elves[1]], spec.boards, [&feeds[0], &feeds[1]], spec.line, timeout)?;
    let mut report = summarise(&run, feeds[0].setup.prior.as_ref(), &host, host_ms, &gt);
    if noise != crate::noise::LabelNoise::None {
        report.label_noise = Some(format!("{noise:?}, seed {seed} (+ robot id)"));
    }
    let statuses = run.robots.iter().map(|r| match &r.outcome {
        Outcome::Report(rep) => Some(crate::report::status_code(rep.result.status)),
        _ => None,
    });
    let code = statuses.collect::<Option<Vec<u8>>>().map(|c| c.into_iter().max().unwrap_or(0));
    Ok((report, code))
}

/// Where `cargo build --release` in firmware/ puts the robot binary.
pub const DEFAULT_FIRMWARE: &str = "firmware/target/thumbv7em-none-eabihf/release/robot";

/// The robot firmware to run: at the default path (from the repository
/// root) it is built, or brought up to date, first (a no-op when it is),
/// so a run never uses a stale build; any other path must exist.
pub fn firmware(path: &Path) -> Result<PathBuf, Error> {
    let dir = PathBuf::from("firmware");
    // A binary at the default place (robot, team) is built first.
    let built_here = Path::new(DEFAULT_FIRMWARE).parent();
    let bin = path.file_name().and_then(|b| b.to_str()).unwrap_or("robot");
    let default = path.parent() == built_here
        && matches!(bin, "robot" | "team" | "stm32f405-robot" | "stm32f405-sender" | "stm32f405-team");
    if !default || !dir.join("Cargo.toml").exists() {
        return if path.exists() {
            Ok(path.to_path_buf())
        } else {
            Err(Error::Invalid(format!(
                "{}: no such firmware (build it with `cargo build --release` in firmware/)",
                path.display()
            )))
        };
    }
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(&cargo)
        .args(["build", "--release", "--bin", bin])
        .current_dir(&dir)
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("RUSTFLAGS")
        .output()
        .map_err(|source| Error::Io { path: PathBuf::from(cargo), source })?;
    if !out.status.success() || !path.exists() {
        return Err(Error::Invalid(format!("building the firmware failed:\n{}", String::from_utf8_lossy(&out.stderr))));
    }
    Ok(path.to_path_buf())
}

/// What the line between the robots' UART0s does to bytes: `none`,
/// `silent` or `corrupt=P` on the command line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LineFault {
    /// Passes every byte.
    None,
    /// Passes nothing: each robot's peer is silent.
    Silent,
    /// Flips a bit of each byte with this probability (seeded).
    Corrupt(f64),
    /// Damages each byte with this probability (seeded): substitutes,
    /// drops or duplicates it, alike.
    Lossy(f64),
}

impl std::str::FromStr for LineFault {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" => Ok(LineFault::None),
            "silent" => Ok(LineFault::Silent),
            _ => {
                let (kind, p): (fn(f64) -> LineFault, _) = match s.split_once('=') {
                    Some(("corrupt", p)) => (LineFault::Corrupt, p),
                    Some(("lossy", p)) => (LineFault::Lossy, p),
                    _ => return Err(format!("`{s}`: expected none, silent, corrupt=P or lossy=P")),
                };
                match p.parse::<f64>() {
                    Ok(p) if (0.0..=1.0).contains(&p) => Ok(kind(p)),
                    _ => Err(format!("`{s}`: the probability must be a number in [0, 1]")),
                }
            }
        }
    }
}

/// How a robot ended.
#[derive(Clone, Debug)]
pub enum Outcome {
    /// It reported a result.
    Report(RobotReport),
    /// It reported a failure.
    Failed {
        /// Where.
        stage: String,
        /// Why.
        message: String,
    },
    /// It said nothing before its end (or the deadline).
    Lost(String),
}

/// One robot's run.
#[derive(Clone, Debug)]
pub struct RobotRun {
    /// What it said.
    pub outcome: Outcome,
    /// QEMU's exit code (`None`: killed at the deadline).
    pub exit_code: Option<i32>,
    /// Its board.
    pub board: Board,
    /// Static RAM of its firmware image (bytes, from the ELF).
    pub static_ram_bytes: u64,
}

/// Both robots' runs and what the line carried.
#[derive(Clone, Debug)]
pub struct PairRun {
    /// Robot 0 (A) and robot 1 (B).
    pub robots: [RobotRun; 2],
    /// Bytes the line carried from each robot's UART0.
    pub line_bytes: [u64; 2],
    /// Wall time of the whole run (s).
    pub wall_s: f64,
}

/// An mps2-an386 QEMU with `serials` as its UARTs, its standard error
/// kept for the board's messages.
pub(crate) fn qemu(board: Board, elf: &Path, serials: &[Option<u16>]) -> std::io::Result<Child> {
    board.qemu_command(elf, serials).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::piped()).spawn()
}

/// Waits for every QEMU to exit, killing those still running at
/// `deadline`; their exit codes (`None`: killed).
pub(crate) fn reap(children: &mut [Child], deadline: Instant) -> Vec<Option<i32>> {
    let mut codes = Vec::new();
    for c in children {
        let code = loop {
            match c.try_wait() {
                Ok(Some(s)) => break s.code(),
                Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
                _ => {
                    let _ = c.kill();
                    let _ = c.wait();
                    break None;
                }
            }
        };
        codes.push(code);
    }
    codes
}

pub(crate) fn debug_args() -> Vec<String> {
    static NEXT: std::sync::atomic::AtomicU16 = std::sync::atomic::AtomicU16::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let mut args = match std::env::var("COSEM_DEBUG_GDB").ok().and_then(|v| v.parse::<u16>().ok()) {
        Some(base) => vec!["-gdb".into(), format!("tcp::{}", base + n)],
        None => vec![],
    };
    // A TCG plugin for every QEMU (e.g. a profiler); `{n}` becomes the
    // instance's number, so each writes its own file.
    if let Ok(plugin) = std::env::var("COSEM_QEMU_PLUGIN") {
        args.extend(["-plugin".into(), plugin.replace("{n}", &n.to_string())]);
    }
    args
}

pub(crate) fn accept(listener: &TcpListener, deadline: Instant) -> Result<TcpStream, String> {
    crate::transport::accept_within(listener, deadline)
        .map_err(|e| format!("QEMU did not connect its serial port: {e}"))
}

/// Copies `from` to `to` through `fault` until either side closes; counts bytes.
pub(crate) fn pump(mut from: TcpStream, mut to: TcpStream, fault: LineFault, seed: u64, count: Arc<AtomicU64>) {
    let mut rng = crate::rng::Rng::new(seed);
    let mut buf = [0u8; 4096];
    let mut out = Vec::with_capacity(2 * buf.len());
    loop {
        let n = match from.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        count.fetch_add(n as u64, Ordering::Relaxed);
        out.clear();
        match fault {
            LineFault::Silent => continue,
            LineFault::Corrupt(p) => {
                for b in &mut buf[..n] {
                    if rng.chance(p) {
                        *b ^= 1 << (rng.below(8) as u8);
                    }
                }
                out.extend_from_slice(&buf[..n]);
            }
            LineFault::Lossy(p) => {
                for &b in &buf[..n] {
                    match (rng.chance(p), rng.below(3)) {
                        (false, _) => out.push(b),
                        (true, 0) => out.push(b ^ (1 + rng.below(255) as u8)),
                        (true, 1) => {}
                        (true, _) => out.extend([b, b]),
                    }
                }
            }
            LineFault::None => out.extend_from_slice(&buf[..n]),
        }
        if to.write_all(&out).is_err() {
            break;
        }
    }
    let _ = to.shutdown(std::net::Shutdown::Write);
}

/// Feeds one robot and waits for its message (report or failure).
/// The feeder's side of a robot's feeder line: the feed goes out once the
/// robot said it listens ([`RobotMessage::Ready`]: a UART that is not yet
/// enabled drops what arrives), on a thread of its own, while the robot's
/// messages are read here.
pub(crate) struct FeederLine {
    conn: Option<TcpStream>,
    feed: Vec<u8>,
    writer: Option<std::thread::JoinHandle<std::io::Result<TcpStream>>>,
}

impl FeederLine {
    pub(crate) fn new(conn: TcpStream, feed: Vec<u8>) -> Self {
        FeederLine { conn: Some(conn), feed, writer: None }
    }

    /// The robot is ready: start feeding (once).
    pub(crate) fn ready(&mut self) {
        if let Some(mut conn) = self.conn.take() {
            let feed = std::mem::take(&mut self.feed);
            self.writer = Some(std::thread::spawn(move || conn.write_all(&feed).map(|_| conn)));
        }
    }

    /// Waits for the feed to be written (or to fail).
    pub(crate) fn finish(self) {
        if let Some(w) = self.writer {
            let _ = w.join();
        }
    }
}

fn feed_and_listen(conn: TcpStream, feed: Vec<u8>, deadline: Instant) -> Outcome {
    let mut reader = match conn.try_clone() {
        Ok(r) => r,
        Err(e) => return Outcome::Lost(e.to_string()),
    };
    let mut line = FeederLine::new(conn, feed);
    let mut deframer = Deframer::new();
    let mut buf = [0u8; 1024];
    let outcome = loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            break Outcome::Lost("no report before the deadline".into());
        }
        let _ = reader.set_read_timeout(Some(left.min(Duration::from_millis(500))));
        let n = match reader.read(&mut buf) {
            Ok(0) => break Outcome::Lost("the robot closed its feeder line without a report".into()),
            Ok(n) => n,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => continue,
            Err(e) => break Outcome::Lost(e.to_string()),
        };
        let mut found = None;
        for &b in &buf[..n] {
            if let Ok(Some(payload)) = deframer.push(b) {
                found = match RobotMessage::decode(payload) {
                    Ok(RobotMessage::Ready) => {
                        line.ready();
                        continue;
                    }
                    Ok(RobotMessage::Report(r)) => Some(Outcome::Report(r)),
                    Ok(RobotMessage::Failed { stage, message }) => {
                        Some(Outcome::Failed { stage: stage.as_str().into(), message: message.into() })
                    }
                    Ok(RobotMessage::Matched { .. } | RobotMessage::Placed(_) | RobotMessage::TeamEnd(_)) => {
                        Some(Outcome::Lost("a team robot's message from a pair robot".into()))
                    }
                    Err(e) => Some(Outcome::Lost(format!("undecodable report: {e}"))),
                };
                break;
            }
        }
        if let Some(o) = found {
            break o;
        }
    };
    drop(reader);
    line.finish();
    outcome
}

/// Runs both robots, robot i on `boards[i]` from firmware `elves[i]`;
/// `feeds[0]` is robot A's, `feeds[1]` robot B's. Each QEMU is killed at
/// `timeout`.
pub fn run_pair(
    elves: [&Path; 2],
    boards: [Board; 2],
    feeds: [&Feed; 2],
    fault: LineFault,
    timeout: Duration,
) -> Result<PairRun, Error> {
    let ram = [crate::board::static_ram_bytes(elves[0])?, crate::board::static_ram_bytes(elves[1])?];
    run_pair_inner(elves, boards, ram, feeds, fault, timeout).map_err(Error::Invalid)
}

fn run_pair_inner(
    elves: [&Path; 2],
    boards: [Board; 2],
    ram: [u64; 2],
    feeds: [&Feed; 2],
    fault: LineFault,
    timeout: Duration,
) -> Result<PairRun, String> {
    let started = Instant::now();
    let deadline = started + timeout;
    let bind = || TcpListener::bind("127.0.0.1:0").map_err(|e| format!("listen on 127.0.0.1: {e}"));
    let port = |l: &TcpListener| l.local_addr().map(|a| a.port()).map_err(|e| e.to_string());
    let link = bind()?;
    let feeders = [bind()?, bind()?];
    let bytes = [feeds[0].bytes().map_err(|e| e.to_string())?, feeds[1].bytes().map_err(|e| e.to_string())?];
    let mut children = Vec::new();
    for ((f, board), elf) in feeders.iter().zip(boards).zip(elves) {
        let child = board.qemu(elf, port(f)?, port(&link)?).map_err(|e| format!("qemu-system-arm: {e}"))?;
        children.push(child);
    }
    let connect_by = Instant::now() + Duration::from_secs(20);
    let result = (|| {
        // The line: whichever UART0 connects first, the pump is symmetric.
        let (l0, l1) = (accept(&link, connect_by)?, accept(&link, connect_by)?);
        let counts = [Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0))];
        let clone = |s: &TcpStream| s.try_clone().map_err(|e| e.to_string());
        let (c0, c1) = (counts[0].clone(), counts[1].clone());
        let (l0b, l1b) = (clone(&l0)?, clone(&l1)?);
        std::thread::spawn(move || pump(l0, l1b, fault, 1, c0));
        std::thread::spawn(move || pump(l1, l0b, fault, 2, c1));
        let mut listeners = Vec::new();
        for (f, b) in feeders.iter().zip(bytes) {
            let conn = accept(f, connect_by)?;
            listeners.push(std::thread::spawn(move || feed_and_listen(conn, b, deadline)));
        }
        let outcomes: Vec<Outcome> =
            listeners.into_iter().map(|h| h.join().unwrap_or(Outcome::Lost("feeder thread failed".into()))).collect();
        Ok::<_, String>((outcomes, [counts[0].load(Ordering::Relaxed), counts[1].load(Ordering::Relaxed)]))
    })();
    // Every QEMU ends by the deadline.
    let codes = reap(&mut children, deadline);
    let (outcomes, line_bytes) = result?;
    let mut runs = outcomes.into_iter().zip(codes).zip(boards.into_iter().zip(ram)).map(
        |((outcome, exit_code), (board, static_ram_bytes))| RobotRun { outcome, exit_code, board, static_ram_bytes },
    );
    let (Some(a), Some(b)) = (runs.next(), runs.next()) else { return Err("two robots expected".into()) };
    Ok(PairRun { robots: [a, b], line_bytes, wall_s: started.elapsed().as_secs_f64() })
}

/// Exit code of a firmware that panicked (its panic handler exits through
/// semihosting at once).
pub const EXIT_PANIC: i32 = cosem_core::robot::EXIT_PANIC as i32;
/// Exit code of a firmware that took a hard fault.
pub const EXIT_FAULT: i32 = cosem_core::robot::EXIT_FAULT as i32;

/// The stage a robot that said nothing stopped at: the firmware itself
/// when QEMU's exit code says it panicked or faulted, else the host.
pub(crate) fn firmware_stage(code: Option<i32>) -> &'static str {
    match code {
        Some(EXIT_PANIC | EXIT_FAULT) => "firmware",
        _ => "host",
    }
}

/// Why a robot said nothing, with what its exit code tells.
pub(crate) fn lost_reason(why: &str, code: Option<i32>) -> String {
    match code {
        Some(EXIT_PANIC) => format!("the firmware panicked (exit {EXIT_PANIC}; QEMU's stderr has the message): {why}"),
        Some(EXIT_FAULT) => {
            format!("the firmware took a hard fault (exit {EXIT_FAULT}: a stack overflow or a bad address): {why}")
        }
        None => format!("{why}; QEMU killed at the deadline"),
        Some(_) => why.to_string(),
    }
}

/// 8N1 at `baud`: seconds a number of bytes takes on the line.
pub fn line_seconds(bytes: u64, baud: u32) -> f64 {
    bytes as f64 * 10.0 / f64::from(baud.max(1))
}

/// One robot in `cosem robots --json`: its report, or where it stopped.
#[derive(Clone, Debug, Serialize)]
#[serde(untagged)]
pub enum RobotJson {
    /// It reported a match.
    Report(Box<ReportJson>),
    /// It stopped, or said nothing.
    Failed {
        /// Robot id.
        id: usize,
        /// Always null.
        status: Option<&'static str>,
        /// `{stage, message}`.
        error: BTreeMap<&'static str, String>,
        /// QEMU's exit code.
        exit_code: Option<i32>,
    },
}

/// A robot's report as JSON (field names kept for scripts).
#[derive(Clone, Debug, Serialize)]
pub struct ReportJson {
    /// Robot id (0: A, 1: B).
    pub id: usize,
    /// Its board (`mps2-an386`, `stm32f405`).
    pub board: &'static str,
    /// Static RAM of its firmware (bytes, from the ELF; the stack comes on
    /// top, `peak_stack_bytes`).
    pub static_ram_bytes: u64,
    /// Status string.
    pub status: &'static str,
    /// `T_own_peer`, row by row.
    pub transform: [f64; 16],
    /// Instructions of the prior-free alignment and the match.
    pub instructions: u64,
    /// Voxels of its own map.
    pub map_voxels: u32,
    /// Bytes it wrote to the link.
    pub bytes_sent: u64,
    /// Bytes it read from the link.
    pub bytes_received: u64,
    /// Instructions inserting points.
    pub map_instructions: u64,
    /// Instructions preparing both maps.
    pub prepare_instructions: u64,
    /// Instructions of the match.
    pub match_instructions: u64,
    /// Points fed.
    pub points: u32,
    /// Voxels received.
    pub received_voxels: u32,
    /// Frames resent on the link.
    pub retransmissions: u32,
    /// Link time on the robot's clock (ms).
    pub link_ms_onboard: u32,
    /// Link time at 115200 baud from the bytes (s).
    pub link_time_115200_s: f64,
    /// EM iterations.
    pub iterations: u16,
    /// Inlier voxels.
    pub inliers: u32,
    /// Overlap.
    pub overlap: f32,
    /// Peak stack (bytes).
    pub peak_stack_bytes: u32,
    /// Bytes that came in on the link line while the robot prepared and
    /// matched, taken by its receive interrupt (0 for a robot that does
    /// not match).
    pub link_bytes_while_matching: u32,
    /// QEMU's exit code.
    pub exit_code: Option<i32>,
    /// Instructions of the prior-free alignment.
    pub locate_instructions: u64,
    /// What the prior-free alignment found.
    pub global: Option<crate::report::GlobalJson>,
    /// Translation error against the truth (m).
    pub e_t: f64,
    /// Rotation error against the truth (degrees).
    pub e_r: f64,
}

/// The host's own run of robot A's match.
#[derive(Clone, Debug, Serialize)]
pub struct HostJson {
    /// `T_A_B`, row by row.
    pub transform: [f64; 16],
    /// Status string.
    pub status: &'static str,
    /// Translation error (m).
    pub e_t: f64,
    /// Rotation error (degrees).
    pub e_r: f64,
    /// What the prior-free alignment found.
    pub global: Option<crate::report::GlobalJson>,
    /// Wall time of the host's run of both robots (ms).
    pub time_ms: f64,
}

/// `cosem robots --json`.
#[derive(Clone, Debug, Serialize)]
pub struct RobotsJson {
    /// Version of this JSON (3: each robot's `board` and
    /// `static_ram_bytes`; 2: `global` holds the prior-free search's
    /// figures, schema 1 landmark correspondences).
    pub schema_version: u32,
    /// Robot A then B.
    pub robots: Vec<RobotJson>,
    /// The host's run of robot A.
    pub host: HostJson,
    /// Robot A's prior `T_A_B`, row by row (null: none).
    pub prior: Option<[f64; 16]>,
    /// The host's run of robot B.
    pub host_b: HostBJson,
    /// `T_A_B`, row by row.
    pub ground_truth: [f64; 16],
    /// Bytes the line carried from each robot.
    pub line_bytes: [u64; 2],
    /// Wall time of the emulated run (s).
    pub wall_time_s: f64,
    /// The label noise the fed scans carried, and its seed (absent: the
    /// ground truth's labels).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub label_noise: Option<String>,
}

/// The host's run of robot B's match.
#[derive(Clone, Debug, Serialize)]
pub struct HostBJson {
    /// `T_B_A`, row by row.
    pub transform: [f64; 16],
    /// Status string.
    pub status: &'static str,
}

fn status_str(code: u8) -> &'static str {
    MatchStatus::from_code(code).map(MatchStatus::as_str).unwrap_or("?")
}

fn robot_json(i: usize, run: &RobotRun, truth: &Isometry3<f64>) -> RobotJson {
    let failed = |stage: &str, message: &str| RobotJson::Failed {
        id: i,
        status: None,
        error: BTreeMap::from([("stage", stage.to_string()), ("message", message.to_string())]),
        exit_code: run.exit_code,
    };
    let rep = match &run.outcome {
        Outcome::Report(r) => r,
        Outcome::Failed { stage, message } => return failed(stage, message),
        Outcome::Lost(why) => return failed(firmware_stage(run.exit_code), &lost_reason(why, run.exit_code)),
    };
    let t = rep.result.transform();
    let (e_t, e_r) = errors_of(&t, truth);
    RobotJson::Report(Box::new(ReportJson {
        id: i,
        board: run.board.as_str(),
        static_ram_bytes: run.static_ram_bytes,
        status: status_str(rep.result.status),
        transform: row_major(&t.cast::<f64>()),
        instructions: rep.locate_instructions + rep.match_instructions,
        map_voxels: rep.map_voxels,
        bytes_sent: rep.bytes_sent,
        bytes_received: rep.bytes_received,
        map_instructions: rep.map_instructions,
        prepare_instructions: rep.prepare_instructions,
        match_instructions: rep.match_instructions,
        points: rep.points,
        received_voxels: rep.received_voxels,
        retransmissions: rep.retransmissions,
        link_ms_onboard: rep.link_ms,
        link_time_115200_s: line_seconds(rep.bytes_sent.max(rep.bytes_received), 115_200),
        iterations: rep.result.iterations,
        inliers: rep.result.inliers,
        overlap: rep.result.overlap,
        peak_stack_bytes: rep.peak_stack,
        link_bytes_while_matching: rep.link_bytes_while_matching,
        exit_code: run.exit_code,
        locate_instructions: rep.locate_instructions,
        global: rep.global.map(Into::into),
        e_t,
        e_r,
    }))
}

/// Everything `cosem robots` reports: the boards' runs beside the host's
/// run (`host[i]`: robot i's report computed here) and the truth `T_A_B`.
pub fn summarise(
    run: &PairRun,
    prior: Option<&[f32; 12]>,
    host: &[RobotReport; 2],
    host_ms: f64,
    gt: &Isometry3<f64>,
) -> RobotsJson {
    let truths = [*gt, gt.inverse()];
    let robots = run.robots.iter().zip(&truths).enumerate().map(|(i, (r, t))| robot_json(i, r, t)).collect();
    let (ha, hb) = (host[0].result.transform(), host[1].result.transform());
    let (e_t, e_r) = errors_of(&ha, gt);
    RobotsJson {
        schema_version: 3,
        robots,
        host: HostJson {
            transform: row_major(&ha.cast::<f64>()),
            status: status_str(host[0].result.status),
            e_t,
            e_r,
            global: host[0].global.map(Into::into),
            time_ms: host_ms,
        },
        prior: prior.map(|p| row_major(&from_rows(p).cast::<f64>())),
        host_b: HostBJson { transform: row_major(&hb.cast::<f64>()), status: status_str(host[1].result.status) },
        ground_truth: row_major(gt),
        line_bytes: run.line_bytes,
        wall_time_s: run.wall_s,
        label_noise: None,
    }
}

/// The default prior of `cosem robots`: the truth moved by 2 m and turned
/// by 10 degrees.
pub fn default_prior(gt: &Isometry3<f64>) -> Isometry3<f64> {
    pose_deg(2.0, 0.0, 0.0, 0.0, 0.0, 10.0) * gt
}

impl std::fmt::Display for ReportJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (name, peer, i) = if self.id == 0 { ("A", "B", 0) } else { ("B", "A", 1) };
        if let Some(g) = &self.global {
            let m = self.locate_instructions as f64 / 1e6;
            writeln!(f, "robot {name} (id {i}): no prior; {}; prior-free search {m:.1} M instructions", g.text())?;
        }
        let t = crate::report::pose_text(&crate::report::from_row_major(&self.transform));
        writeln!(
            f,
            "robot {name} (id {i}): {}, T_{name}_{peer} = {t} (e_t {:.3} m, e_r {:.3} deg)",
            self.status, self.e_t, self.e_r
        )?;
        let line_s = line_seconds(self.bytes_sent.max(self.bytes_received), 115_200);
        writeln!(
            f,
            "  map {} voxels from {} fed points; sent {} B, received {} B ({} retransmissions; {line_s:.1} s at 115200 baud)",
            self.map_voxels, self.points, self.bytes_sent, self.bytes_received, self.retransmissions
        )?;
        let m = |v: u64| v as f64 / 1e6;
        writeln!(
            f,
            "  instructions: mapping {:.1} M, preparation {:.1} M, match {:.1} M; peak stack {} B; \
             {} B came in on the link while matching; exit {:?}",
            m(self.map_instructions),
            m(self.prepare_instructions),
            m(self.match_instructions),
            self.peak_stack_bytes,
            self.link_bytes_while_matching,
            self.exit_code
        )
    }
}

impl std::fmt::Display for RobotsJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use crate::report::{from_row_major, pose_text};
        for robot in &self.robots {
            match robot {
                RobotJson::Report(rep) => write!(f, "{rep}")?,
                RobotJson::Failed { id, error, exit_code, .. } => {
                    let get = |k| error.get(k).map(String::as_str).unwrap_or("");
                    writeln!(f, "robot {id}: failed at {}: {}; exit {exit_code:?}", get("stage"), get("message"))?;
                }
            }
        }
        let h = &self.host;
        let t = pose_text(&from_row_major(&h.transform));
        let (e_t, e_r, ms) = (h.e_t, h.e_r, h.time_ms);
        writeln!(
            f,
            "host (same fed data): {}, T_A_B = {t} (e_t {e_t:.3} m, e_r {e_r:.3} deg); {ms:.1} ms for both robots",
            h.status
        )?;
        if let Some(g) = &h.global {
            writeln!(f, "host, no prior: {}", g.text())?;
        }
        writeln!(
            f,
            "host, robot B's match: {}, T_B_A = {}",
            self.host_b.status,
            pose_text(&from_row_major(&self.host_b.transform))
        )?;
        writeln!(
            f,
            "ground truth: T_A_B = {}; wall time {:.1} s",
            pose_text(&from_row_major(&self.ground_truth)),
            self.wall_time_s
        )
    }
}
