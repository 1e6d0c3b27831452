//! Two robots on emulated boards (`cosem robots`): what the host feeds each
//! robot, the line between their UART0s, and the host's own run of the
//! robots' pipeline on the same data.
//!
//! Each robot is a QEMU `mps2-an386` running the firmware's `robot` binary.
//! Its UART1 connects to a TCP listener of this process (the feeder: its
//! scans in, its report out); its UART0 connects to another listener that
//! joins the two robots' UART0s, byte for byte in both directions (and can
//! drop or corrupt bytes, to test the firmware against a bad peer).

use crate::kitti::Frame;
use crate::mapping::{new_map, HostMap, PointFilter};
use cosem_core::classes::{Class, NUM_CLASSES};
use cosem_core::geometry::Isometry3;
use cosem_core::matching::global::Located;
use cosem_core::matching::MatchResult;
use cosem_core::robot::{
    self, FeedMessage, RobotMessage, RobotReport, Setup, COARSE, MAX_POINTS_PER_MESSAGE, MODEL_WORDS, POINT_BYTES,
    SCENE_WORDS, VOXELS,
};
use cosem_core::wire::codec::MapDecoder;
use cosem_core::wire::frame::{encode_frame, Deframer, MAX_FRAME, MAX_PAYLOAD};
use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
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
        let Some(class) = filter.keep(r, l) else { continue };
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
            Some(robot::pack_point(mean, class))
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
    pub fn bytes(&self) -> Result<Vec<u8>, String> {
        let mut out = Vec::new();
        let mut push = |msg: FeedMessage<'_>| -> Result<(), String> {
            let mut payload = [0u8; MAX_PAYLOAD];
            let mut frame = [0u8; MAX_FRAME];
            let n = msg.encode(&mut payload).map_err(|e| e.to_string())?;
            let len = encode_frame(&payload[..n], &mut frame).map_err(|e| format!("{e:?}"))?;
            out.extend_from_slice(&frame[..len]);
            Ok(())
        };
        push(FeedMessage::Setup(self.setup))?;
        for (i, scan) in self.scans.iter().enumerate() {
            for part in scan.chunks(MAX_POINTS_PER_MESSAGE) {
                let data: Vec<u8> = part.iter().flatten().copied().collect();
                push(FeedMessage::Points { scan: i as u16, data: &data })?;
            }
        }
        push(FeedMessage::EndOfFeed { scans: self.scans.len() as u16, points: self.points() as u32 })?;
        Ok(out)
    }

    /// The robot's map, built here as the robot builds it.
    pub fn map(&self) -> Result<HostMap, String> {
        let mut map = new_map(VOXELS, robot::map_config(self.setup.resolution)).map_err(|e| e.to_string())?;
        for scan in &self.scans {
            let data: Vec<u8> = scan.iter().flatten().copied().collect();
            robot::insert_points(&mut map, &data).map_err(|e| e.to_string())?;
        }
        Ok(map)
    }
}

/// `map` as the peer holds it after the link: through the wire encoding.
pub fn through_wire(map: &HostMap) -> Result<HostMap, String> {
    let mut out = new_map(VOXELS, *map.config()).map_err(|e| e.to_string())?;
    let mut decoder = MapDecoder::new(map.len());
    for chunk in crate::cmap::encode_chunks(map, 240) {
        decoder.decode_chunk(&chunk, &mut out).map_err(|e| e.to_string())?;
    }
    if !decoder.is_complete() {
        return Err("the map did not pass through the encoding whole".into());
    }
    Ok(out)
}

/// The robot's alignment computed on this host: its own map against the
/// peer's (through the wire), with the firmware's capacities; from `prior`,
/// or with none from the maps' landmarks (then what they found comes back).
pub fn host_align(
    own: &HostMap,
    peer: &HostMap,
    prior: Option<&Isometry3<f32>>,
) -> Result<(MatchResult, Option<Located>), String> {
    let received = through_wire(peer)?;
    let model = crate::align::HeapPyramidStorage::with_capacity(VOXELS, COARSE, MODEL_WORDS);
    let scene = crate::align::HeapPyramidStorage::with_capacity(VOXELS, COARSE, SCENE_WORDS);
    let mut scratch = vec![0u32; VOXELS];
    robot::align(own, &received, prior, &mut scratch, model, scene, |_| {}).map_err(|e| e.to_string())
}

/// What the line between the robots' UART0s does to bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LineFault {
    /// Passes every byte.
    None,
    /// Passes nothing: each robot's peer is silent.
    Silent,
    /// Flips each byte with this probability (seeded).
    Corrupt(f64),
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

fn qemu(elf: &Path, link_port: u16, feed_port: u16) -> std::io::Result<Child> {
    Command::new("qemu-system-arm")
        .args(["-machine", "mps2-an386", "-cpu", "cortex-m4", "-display", "none", "-icount", "shift=0"])
        .args(["-semihosting-config", "enable=on,target=native", "-monitor", "none"])
        .arg("-serial")
        .arg(format!("tcp:127.0.0.1:{link_port}"))
        .arg("-serial")
        .arg(format!("tcp:127.0.0.1:{feed_port}"))
        .arg("-kernel")
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
}

fn accept(listener: &TcpListener, deadline: Instant) -> Result<TcpStream, String> {
    listener.set_nonblocking(true).map_err(|e| e.to_string())?;
    loop {
        match listener.accept() {
            Ok((s, _)) => {
                s.set_nonblocking(false).map_err(|e| e.to_string())?;
                s.set_nodelay(true).ok();
                return Ok(s);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if Instant::now() > deadline {
                    return Err("QEMU did not connect its serial port".into());
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(e.to_string()),
        }
    }
}

/// Copies `from` to `to` through `fault` until either side closes; counts bytes.
fn pump(mut from: TcpStream, mut to: TcpStream, fault: LineFault, seed: u64, count: Arc<AtomicU64>) {
    let mut rng = crate::rng::Rng::new(seed);
    let mut buf = [0u8; 4096];
    loop {
        let n = match from.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        count.fetch_add(n as u64, Ordering::Relaxed);
        match fault {
            LineFault::Silent => continue,
            LineFault::Corrupt(p) => {
                for b in &mut buf[..n] {
                    if rng.chance(p) {
                        *b ^= 1 << (rng.below(8) as u8);
                    }
                }
            }
            LineFault::None => {}
        }
        if to.write_all(&buf[..n]).is_err() {
            break;
        }
    }
    let _ = to.shutdown(std::net::Shutdown::Write);
}

/// Feeds one robot and waits for its message (report or failure).
fn feed_and_listen(mut conn: TcpStream, feed: Vec<u8>, deadline: Instant) -> Outcome {
    let mut reader = match conn.try_clone() {
        Ok(r) => r,
        Err(e) => return Outcome::Lost(e.to_string()),
    };
    let writer = std::thread::spawn(move || conn.write_all(&feed).map(|_| conn));
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
                found = Some(match RobotMessage::decode(payload) {
                    Ok(RobotMessage::Report(r)) => Outcome::Report(r),
                    Ok(RobotMessage::Failed { stage, message }) => {
                        Outcome::Failed { stage: stage.as_str().into(), message: message.into() }
                    }
                    Err(e) => Outcome::Lost(format!("undecodable report: {e}")),
                });
                break;
            }
        }
        if let Some(o) = found {
            break o;
        }
    };
    drop(reader);
    let _ = writer.join();
    outcome
}

/// Runs both robots: `elf` is the firmware's `robot` binary; `feeds[0]` is
/// robot A's, `feeds[1]` robot B's. Each QEMU is killed at `timeout`.
pub fn run_pair(elf: &Path, feeds: [&Feed; 2], fault: LineFault, timeout: Duration) -> Result<PairRun, String> {
    let started = Instant::now();
    let deadline = started + timeout;
    let bind = || TcpListener::bind("127.0.0.1:0").map_err(|e| format!("listen on 127.0.0.1: {e}"));
    let port = |l: &TcpListener| l.local_addr().map(|a| a.port()).map_err(|e| e.to_string());
    let link = bind()?;
    let feeders = [bind()?, bind()?];
    let bytes = [feeds[0].bytes()?, feeds[1].bytes()?];
    let mut children = Vec::new();
    for f in &feeders {
        let child = qemu(elf, port(&link)?, port(f)?).map_err(|e| format!("qemu-system-arm: {e}"))?;
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
    let mut codes = Vec::new();
    for c in &mut children {
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
    let (outcomes, line_bytes) = result?;
    let mut runs = outcomes.into_iter().zip(codes).map(|(outcome, exit_code)| RobotRun { outcome, exit_code });
    let (Some(a), Some(b)) = (runs.next(), runs.next()) else { return Err("two robots expected".into()) };
    Ok(PairRun { robots: [a, b], line_bytes, wall_s: started.elapsed().as_secs_f64() })
}
