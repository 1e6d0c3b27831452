//! `cosem team --on-board`: each robot of a team on its own emulated board
//! (QEMU `mps2-an386` and the firmware's `team` binary, or an STM32F405 and
//! its `stm32f405-team`), beside the host's run of the same robots on the
//! same fed points.
//!
//! Board i's feeder line is a TCP listener of this process (its thinned
//! scans in, its messages out); its peer lines are its other UARTs, in
//! peer index order ([`Board::team_ports`]: the mps2 board's UART1 feeds
//! it, UART0, 2, 3, 4 join its peers, so a team of those has at most five
//! robots; the STM32F405's USART1 feeds it, USART2 and 3 join its peers:
//! three robots). Every pair of boards has its own line: this process
//! joins the two UARTs byte for byte, a mesh of point-to-point links like
//! the host's `cosem team`. The host's run drives the core's
//! [`TeamRobot`] with the same feeds over simulated clean lines, so the
//! boards' placements must be the host's.

use crate::boards::board::Board;
use crate::boards::emulator::{accept, qemu};
use crate::boards::feeds::Feed;
use crate::boards::pump::{pump, LineFault};
use crate::boards::twin::board_pyramids;
use crate::error::Error;
use crate::knobs::Knob;
use crate::maps::mapping::new_map;
use cosem_core::link::LinkBuffers;
use cosem_core::robot::team::{port_of, TeamRobot, TABLE_WORDS};
use cosem_core::robot::{self, RobotConfig};
use cosem_core::sim::{self, SimRobot, Wire};
use cosem_core::wire::feed::{PlacedRobot, RobotMessage, RobotReport, TeamEnd};
use cosem_core::wire::frame::Deframer;
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::sync::atomic::AtomicU64;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Most robots of a team on `board`: one more than its peer UARTs.
pub fn max_boards(board: Board) -> usize {
    board.team_ports().1.len() + 1
}

/// What one team robot said over its feeder line.
#[derive(Clone, Debug, Default)]
pub struct TeamReports {
    /// One per round met: the peer and the report (`T_own_peer`).
    pub matched: Vec<(u8, RobotReport)>,
    /// Where it placed each robot.
    pub placed: Vec<PlacedRobot>,
    /// Its last message.
    pub end: Option<TeamEnd>,
    /// Where and why it stopped (or what went wrong on the host's side).
    pub failed: Option<(String, String)>,
}

impl TeamReports {
    /// Takes one message; `true` when it was the last.
    fn take(&mut self, payload: &[u8]) -> bool {
        match RobotMessage::decode(payload) {
            Ok(RobotMessage::Matched { peer, report }) => self.matched.push((peer, report)),
            Ok(RobotMessage::Placed(p)) => self.placed.push(p),
            Ok(RobotMessage::TeamEnd(e)) => {
                self.end = Some(e);
                return true;
            }
            Ok(RobotMessage::Failed { stage, message }) => {
                self.failed = Some((stage.as_str().into(), message.into()));
                return true;
            }
            Ok(RobotMessage::Report(_)) => {
                self.failed = Some(("host".into(), "a pair robot's report from a team robot".into()));
                return true;
            }
            Ok(RobotMessage::Round(_) | RobotMessage::SessionEnd(_)) => {
                self.failed = Some(("host".into(), "a session robot's message from a team robot".into()));
                return true;
            }
            Ok(RobotMessage::Ready) => {}
            Err(e) => {
                self.failed = Some(("host".into(), format!("undecodable message: {e}")));
                return true;
            }
        }
        false
    }

    /// All the messages in `bytes` (frames).
    fn from_bytes(bytes: &[u8]) -> Self {
        let mut out = TeamReports::default();
        let mut deframer = Deframer::new();
        for &b in bytes {
            if let Ok(Some(payload)) = deframer.push(b) {
                if out.take(payload) {
                    break;
                }
            }
        }
        if out.end.is_none() && out.failed.is_none() {
            out.failed = Some(("host".into(), "no last message".into()));
        }
        out
    }
}

/// The team's framed feeds (robot i's set-up names it i of `feeds.len()`).
pub fn team_feed_bytes(feeds: &[Feed]) -> Result<Vec<Vec<u8>>, Error> {
    let n = u8::try_from(feeds.len()).map_err(|_| Error::Invalid("too many robots".into()))?;
    feeds.iter().map(|f| f.bytes_in_team(Some(n))).collect()
}

/// The team run on this host, exactly as on the boards: the core's team
/// robot with `board`'s team capacities, each pair joined by a clean
/// simulated 115200-baud line, one millisecond per round of polls.
pub fn host_team_run(feeds: &[Feed], board: Board) -> Result<Vec<TeamReports>, Error> {
    let c = board.team_capacity();
    let n = feeds.len();
    let bytes = team_feed_bytes(feeds)?;
    let config = robot::map_config(feeds.first().map_or(0.5, |f| f.setup.resolution));
    struct Buffers {
        own: crate::maps::mapping::HostMap,
        received: crate::boards::twin::Received,
        scratch: Vec<u32>,
        link: Box<LinkBuffers>,
    }
    let mut buffers = (0..n)
        .map(|_| {
            Ok(Buffers {
                own: new_map(c.voxels, config)?,
                received: crate::boards::twin::received_scene(c.voxels, config.resolution)?,
                scratch: vec![0u32; c.voxels.max(TABLE_WORDS)],
                link: Box::new(LinkBuffers::new()),
            })
        })
        .collect::<Result<Vec<_>, Error>>()?;
    let (model_storage, scene_storage) = board_pyramids(c);
    let mut robots: Vec<_> = buffers
        .iter_mut()
        .map(|b| {
            TeamRobot::new(
                RobotConfig::default(),
                &mut b.own,
                &mut b.received,
                &mut b.scratch,
                &mut b.link,
                model_storage(),
                scene_storage(),
            )
            .with_em_iterations(c.em_iterations)
        })
        .collect();
    let mut polled: Vec<&mut SimRobot<'_, '_, TeamEnd>> =
        robots.iter_mut().map(|r| r as &mut SimRobot<'_, '_, _>).collect();
    let feeds: Vec<&[u8]> = bytes.iter().map(Vec::as_slice).collect();
    // One clean line per pair of robots, the boards' mesh.
    let out = sim::run(&mut polled, &feeds, &Wire::mesh(n, 115_200), 3_600_000);
    Ok(out.iter().map(|o| TeamReports::from_bytes(&o.told)).collect())
}

/// One board's run.
#[derive(Clone, Debug)]
pub struct BoardRun {
    /// What it said.
    pub reports: TeamReports,
    /// QEMU's exit code (`None`: killed at the deadline).
    pub exit_code: Option<i32>,
}

/// Feeds one board and collects its messages until its last.
fn feed_and_collect(conn: TcpStream, feed: Vec<u8>, deadline: Instant, progress: Option<usize>) -> TeamReports {
    let mut out = TeamReports::default();
    let ended = crate::boards::emulator::feed_and_collect(conn, feed, deadline, |payload| {
        if let Some(i) = progress {
            eprintln!("board {i}: {}", describe(payload));
        }
        out.take(payload)
    });
    if let Err(why) = ended {
        out.failed = Some(("host".into(), why));
    }
    out
}

/// One line on what a board said, for progress on stderr.
fn describe(payload: &[u8]) -> String {
    match RobotMessage::decode(payload) {
        Ok(RobotMessage::Matched { peer, report }) => format!(
            "met robot {peer}: status {}, overlap {:.2}, {} B sent, {} B received, {} ms on the line",
            report.result.status, report.result.overlap, report.bytes_sent, report.bytes_received, report.link_ms
        ),
        Ok(RobotMessage::Placed(p)) => format!("robot {} in the frame of robot {}", p.index, p.anchor),
        Ok(RobotMessage::TeamEnd(e)) => {
            format!("finished: {} candidates, heard {:#b}, shared in {} ms", e.candidates, e.heard, e.share_ms)
        }
        Ok(RobotMessage::Failed { stage, message }) => format!("stopped at {}: {message}", stage.as_str()),
        Ok(RobotMessage::Report(_)) => "a pair robot's report".into(),
        Ok(RobotMessage::Round(_) | RobotMessage::SessionEnd(_)) => "a session robot's message".into(),
        Ok(RobotMessage::Ready) => "listening".into(),
        Err(e) => format!("undecodable message: {e}"),
    }
}

/// Runs the team on boards: `elf` is the firmware's `team` binary. Every
/// QEMU is killed at `timeout`. With `progress`, each board's messages are
/// told on stderr as they come.
pub fn run_boards(
    board: Board,
    elf: &Path,
    feeds: &[Feed],
    timeout: Duration,
    progress: bool,
) -> Result<(Vec<BoardRun>, f64), Error> {
    run_boards_inner(board, elf, feeds, timeout, progress).map_err(Error::Invalid)
}

fn run_boards_inner(
    board: Board,
    elf: &Path,
    feeds: &[Feed],
    timeout: Duration,
    progress: bool,
) -> Result<(Vec<BoardRun>, f64), String> {
    let n = feeds.len();
    let most = max_boards(board);
    if !(2..=most).contains(&n) {
        return Err(format!("a team on {} boards has 2 to {most} robots, not {n}", board.as_str()));
    }
    let started = Instant::now();
    let deadline = started + timeout;
    let bind = || TcpListener::bind("127.0.0.1:0").map_err(|e| format!("listen on 127.0.0.1: {e}"));
    let port = |l: &TcpListener| l.local_addr().map(|a| a.port()).map_err(|e| e.to_string());
    let bytes = team_feed_bytes(feeds).map_err(|e| e.to_string())?;
    let pairs: Vec<(usize, usize)> = (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).collect();
    let links = pairs.iter().map(|_| bind()).collect::<Result<Vec<_>, _>>()?;
    let feeders = (0..n).map(|_| bind()).collect::<Result<Vec<_>, _>>()?;
    let mut children = Vec::new();
    for (i, f) in feeders.iter().enumerate() {
        let serials = serial_ports(board, i, port(f)?, &pairs, &links)?;
        let child = qemu(board, elf, &serials).map_err(|e| format!("qemu-system-arm: {e}"))?;
        children.push(child);
    }
    let connect_by = Instant::now() + Duration::from_secs(30);
    let result = (|| {
        for l in &links {
            let (x, y) = (accept(l, connect_by)?, accept(l, connect_by)?);
            let clone = |s: &TcpStream| s.try_clone().map_err(|e| e.to_string());
            let (xb, yb) = (clone(&x)?, clone(&y)?);
            let (cx, cy) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
            std::thread::spawn(move || pump(x, yb, LineFault::None, 1, cx));
            std::thread::spawn(move || pump(y, xb, LineFault::None, 2, cy));
        }
        let mut listeners = Vec::new();
        for (i, (f, b)) in feeders.iter().zip(bytes).enumerate() {
            let conn = accept(f, connect_by)?;
            let progress = progress.then_some(i);
            listeners.push(std::thread::spawn(move || feed_and_collect(conn, b, deadline, progress)));
        }
        Ok::<_, String>(
            listeners
                .into_iter()
                .map(|h| {
                    h.join().unwrap_or_else(|_| TeamReports {
                        failed: Some(("host".into(), "feeder thread failed".into())),
                        ..TeamReports::default()
                    })
                })
                .collect::<Vec<_>>(),
        )
    })();
    let codes = crate::boards::emulator::reap(&mut children, deadline);
    let reports = result?;
    let runs = reports
        .into_iter()
        .zip(codes)
        .map(|(mut reports, exit_code)| {
            // A board that stopped without a word: say what its exit code tells.
            if let Some((stage, message)) = reports.failed.as_mut().filter(|(s, _)| s == "host") {
                *message = crate::boards::emulator::lost_reason(message, exit_code);
                *stage = crate::boards::emulator::firmware_stage(exit_code).to_string();
            }
            BoardRun { reports, exit_code }
        })
        .collect();
    Ok((runs, started.elapsed().as_secs_f64()))
}

/// Board `i`'s serial ports in QEMU's order ([`Board::team_ports`]): its
/// feeder's TCP port `feeder`, and for each pair of boards it is in, the
/// pair's line; up to the last one used (QEMU connects them in order).
fn serial_ports(
    board: Board,
    i: usize,
    feeder: u16,
    pairs: &[(usize, usize)],
    links: &[TcpListener],
) -> Result<Vec<Option<u16>>, String> {
    let (feeder_port, peer_ports) = board.team_ports();
    let mut serials: Vec<Option<u16>> = vec![None; peer_ports.len() + 1];
    serials[feeder_port] = Some(feeder);
    for (&(a, b), l) in pairs.iter().zip(links) {
        if a == i || b == i {
            let peer = if a == i { b } else { a };
            let at = peer_ports.get(port_of(i as u8, peer as u8)).ok_or("more peers than UARTs")?;
            serials[*at] = Some(l.local_addr().map_err(|e| e.to_string())?.port());
        }
    }
    let last = serials.iter().rposition(Option::is_some).unwrap_or(feeder_port);
    serials.truncate(last + 1);
    Ok(serials)
}

/// Each robot's feed: its frames (label noise applied, robot i's seeded by
/// `seed + i`) thinned to one point per `voxel` within `crop` m, no prior.
pub fn team_feeds(spec: &crate::evaluation::team::TeamSpec, crop: f32, silence_ms: u32) -> Result<Vec<Feed>, Error> {
    let filter = crate::maps::mapping::PointFilter::default();
    let mut out = Vec::new();
    for (i, r) in spec.robots.iter().enumerate() {
        let seq = crate::sources::source::Source::open(&r.data, &spec.source)?;
        let (mut frames, _, _) = seq.load(Some(r.frames))?;
        crate::maps::noise::corrupt_all(&mut frames, spec.label_noise, spec.seed.wrapping_add(i as u64));
        let scans = frames.iter().map(|f| crate::boards::feeds::thin_scan(f, spec.voxel, crop, &filter)).collect();
        let setup =
            cosem_core::wire::feed::Setup { robot_id: i as u8, resolution: spec.voxel, prior: None, silence_ms };
        out.push(Feed { setup, scans });
    }
    Ok(out)
}

/// Largest distance (m) between the translations two robots' reports give
/// for the same robot, and whether every robot has the same anchor in
/// both (`None` when either placed nothing).
pub fn placement_difference(a: &TeamReports, b: &TeamReports) -> Option<(f64, bool)> {
    if a.placed.is_empty() || a.placed.len() != b.placed.len() {
        return None;
    }
    let mut worst = 0.0f64;
    let mut same = true;
    for (p, q) in a.placed.iter().zip(&b.placed) {
        same &= p.index == q.index && p.anchor == q.anchor;
        let d = (0..3).map(|k| f64::from(p.transform[4 * k + 3] - q.transform[4 * k + 3]).powi(2)).sum::<f64>();
        worst = worst.max(d.sqrt());
    }
    Some((worst, same))
}

/// What a team on boards ran: each board's run, the host's run of the same
/// robots, the truth (reported by `crate::reports::team::TeamBoardJson`).
pub struct TeamBoardsRun {
    /// Each board's run.
    pub boards: Vec<BoardRun>,
    /// The host's run of each robot.
    pub host: Vec<TeamReports>,
    /// The truth.
    pub truth: crate::evaluation::team::Truth,
    /// Wall time of the boards' run (s).
    pub wall_s: f64,
}

/// A team on `board`s, end to end: each robot's feed, the host's run of
/// the same robots, the boards under QEMU (`firmware`, default the board's
/// team binary; killed after `timeout`).
pub fn run_on_boards(
    spec: &crate::evaluation::team::TeamSpec,
    crop: f32,
    silence_ms: u32,
    (board, firmware): (Board, Option<&Path>),
    timeout: Duration,
) -> Result<TeamBoardsRun, Error> {
    let (n, most) = (spec.robots.len(), max_boards(board));
    if !(2..=most).contains(&n) {
        return Err(Error::Invalid(format!(
            "{}: 2 to {most} robots on {} boards (one per peer UART and one), not {n}",
            Knob::OnBoard,
            board.as_str()
        )));
    }
    let truth = crate::evaluation::team::Truth::of(spec)?;
    let feeds = team_feeds(spec, crop, silence_ms)?;
    let host = host_team_run(&feeds, board)?;
    let elf = crate::boards::firmware::firmware(firmware.unwrap_or(Path::new(board.team_firmware())))?;
    let (boards, wall_s) = run_boards(board, &elf, &feeds, timeout, true)?;
    Ok(TeamBoardsRun { boards, host, truth, wall_s })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluation::team::{RobotSpec, TeamSpec};

    fn data() -> Option<std::path::PathBuf> {
        let root = std::env::var_os("COSEM_DATA").map_or_else(|| "../../shared/data".into(), std::path::PathBuf::from);
        let dir = root.join("kitti00");
        if dir.is_dir() {
            Some(dir)
        } else {
            eprintln!("skipped: no {}", dir.display());
            None
        }
    }

    #[test]
    fn host_team_run_places_three_robots_of_one_drive() {
        let Some(dir) = data() else { return };
        let robot = |a, b| RobotSpec {
            data: dir.clone(),
            frames: crate::sources::kitti::FrameRange { start: a, end: b, stride: 1 },
        };
        let spec = TeamSpec {
            robots: vec![robot(0, 3), robot(3, 6), robot(6, 10)],
            voxel: 0.5,
            prior_noise: None,
            inject_false_match: Vec::new(),
            source: Default::default(),
            label_noise: crate::maps::noise::LabelNoise::None,
            seed: 1,
            settings: Default::default(),
        };
        let feeds = team_feeds(&spec, 25.0, 60_000).unwrap();
        let reports = host_team_run(&feeds, Board::Mps2An386).unwrap();
        for r in &reports {
            assert!(r.end.is_some(), "{:?}", r.failed);
            assert_eq!(r.matched.len(), 2, "{r:?}");
            assert!(r.placed.iter().all(|p| p.anchor == 0) && r.placed.len() == 3, "{r:?}");
            // Every robot holds every estimate and places the team alike.
            assert_eq!(placement_difference(r, &reports[0]), Some((0.0, true)));
        }
        // Robot 2 started about 4.3 m ahead of robot 0 (kitti00 frames 0 and 6).
        let x = reports[0].placed[2].transform[3];
        assert!((4.0..4.6).contains(&x), "{x}");
    }
}
