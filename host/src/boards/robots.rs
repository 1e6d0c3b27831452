//! Two robots on emulated boards (`cosem robots`): the feeds made, the
//! host's twin run, both boards under QEMU with the line between their
//! UART0s, and what each robot said.
//!
//! Each robot is a QEMU `mps2-an386` (or STM32F405) running the firmware's
//! `robot` binary. Its UART1 connects to a TCP listener of this process
//! (the feeder: its scans in, its report out); its UART0 connects to
//! another listener that joins the two robots' UART0s, byte for byte in
//! both directions (and can drop or corrupt bytes, to test the firmware
//! against a bad peer).

use crate::boards::board::Board;
use crate::boards::emulator::{accept, reap, FeederLine};
use crate::boards::feeds::{feeds, Feed};
use crate::boards::firmware::firmware;
use crate::boards::pump::{pump, LineFault};
use crate::boards::twin::host_run;
use crate::error::Error;
use crate::knobs::Knob;
use crate::sources::kitti::FrameRange;
use cosem_core::geometry::{pose_deg, Isometry3};
use cosem_core::wire::feed::{RobotMessage, RobotReport};
use cosem_core::wire::frame::Deframer;
use std::io::Read;
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// What `cosem robots` runs: two robots' frames of one source, their
/// boards, the line between them and how the feeds are made.
#[derive(Clone, Debug)]
pub struct RobotsSpec {
    /// The source and its options.
    pub source: crate::sources::source::Source,
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
    pub label_noise: (crate::maps::noise::LabelNoise, u64),
}

/// What `cosem robots` ran: both boards' runs, the host's twin run of the
/// same feeds, and the truth.
#[derive(Clone, Debug)]
pub struct RobotsRun {
    /// The boards' run.
    pub pair: PairRun,
    /// Robot A's prior `T_A_B` as fed (row-major 3x4), if any.
    pub prior: Option<[f32; 12]>,
    /// Each robot's report from the host's twin run.
    pub host: [RobotReport; 2],
    /// Wall time of the twin run (ms).
    pub host_ms: f64,
    /// `T_A_B`, the truth.
    pub truth: Isometry3<f64>,
    /// The label noise on the fed scans and its seed, if any.
    pub label_noise: Option<String>,
}

/// Runs `spec`: the feeds made, the host's twin run, both boards under
/// QEMU (reported by `crate::reports::robots`).
pub fn run_robots(spec: &RobotsSpec) -> Result<RobotsRun, Error> {
    if !spec.boards.iter().any(|b| b.matches()) {
        return Err(Error::Invalid(format!(
            "{} and {}: one robot must be able to match (an mps2-an386 board)",
            Knob::BoardA,
            Knob::BoardB
        )));
    }
    let [ra, rb] = spec.ranges;
    let truth = spec.source.relative_pose(ra.start, rb.start)?;
    let prior = (!spec.no_prior).then(|| spec.prior.unwrap_or_else(|| default_prior(&truth)));
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
    let pair = run_pair([&elves[0], &elves[1]], spec.boards, [&feeds[0], &feeds[1]], spec.line, timeout)?;
    let label_noise =
        (noise != crate::maps::noise::LabelNoise::None).then(|| format!("{noise:?}, seed {seed} (+ robot id)"));
    Ok(RobotsRun { pair, prior: feeds[0].setup.prior, host, host_ms, truth, label_noise })
}

/// The default prior of `cosem robots`: the truth moved by 2 m and turned
/// by 10 degrees.
pub fn default_prior(gt: &Isometry3<f64>) -> Isometry3<f64> {
    pose_deg(2.0, 0.0, 0.0, 0.0, 0.0, 10.0) * gt
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

/// Feeds one robot and waits for its message (report or failure).
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
                    Ok(RobotMessage::Round(_) | RobotMessage::SessionEnd(_)) => {
                        Some(Outcome::Lost("a session robot's message from a pair robot".into()))
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
    let ram = [crate::boards::board::static_ram_bytes(elves[0])?, crate::boards::board::static_ram_bytes(elves[1])?];
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
