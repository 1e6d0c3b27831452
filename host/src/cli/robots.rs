//! `cosem robots`: two robots on emulated Cortex-M4F boards map, exchange
//! maps over their UART0s and match on board; printed beside the host's own
//! run of the same pipeline on the same fed data and the ground truth.

use super::Error;
use cosem_core::geometry::{from_rows, rows};
use cosem_core::robot::{GlobalReport, Setup};
use cosem_host::align::{errors, to_matrix};
use cosem_host::kitti::{FrameRange, Sequence};
use cosem_host::mapping::PointFilter;
use cosem_host::pose;
use cosem_host::robots::{host_align, run_pair, thin_scan, Feed, LineFault, Outcome};
use nalgebra::Matrix4;
use serde_json::json;
use std::path::PathBuf;
use std::time::Duration;

/// Where `cargo build --release` in firmware/ puts the robot binary.
const DEFAULT_FIRMWARE: &str = "firmware/target/thumbv7em-none-eabihf/release/robot";

#[derive(clap::Args, Debug)]
pub struct Args {
    /// SemanticKITTI-layout folder.
    #[arg(long)]
    data: PathBuf,
    /// Robot A's frames.
    #[arg(long)]
    a: FrameRange,
    /// Robot B's frames.
    #[arg(long)]
    b: FrameRange,
    /// Voxel size on board (m); each scan is fed as one point per voxel.
    #[arg(long, default_value_t = 0.5)]
    voxel: f32,
    /// Points farther than this from their sensor are not fed (m).
    #[arg(long, default_value_t = 25.0)]
    crop: f32,
    /// Robot A's prior `T_A_B` as x,y,z,roll,pitch,yaw (m, degrees); robot B
    /// gets its inverse. Default: the ground truth moved by 2 m and turned
    /// by 10 degrees.
    #[arg(long, allow_hyphen_values = true, conflicts_with = "no_prior")]
    prior: Option<String>,
    /// Give the robots no prior: each aligns from both maps' semantic
    /// landmarks first (prior-free global alignment), on board.
    #[arg(long)]
    no_prior: bool,
    /// Print JSON.
    #[arg(long)]
    json: bool,
    /// The firmware's robot binary (at the default path, built or brought
    /// up to date first).
    #[arg(long, default_value = DEFAULT_FIRMWARE)]
    firmware: PathBuf,
    /// What the line between the UART0s does: none, silent, or corrupt=P
    /// (each byte flipped with probability P).
    #[arg(long, default_value = "none")]
    line: String,
    /// A robot gives up on the link after this long without a valid frame (s).
    #[arg(long, default_value_t = 30.0)]
    silence: f64,
    /// Kill both emulators after this long (s).
    #[arg(long, default_value_t = 900.0)]
    timeout: f64,
}

fn parse_line(s: &str) -> Result<LineFault, String> {
    match s {
        "none" => Ok(LineFault::None),
        "silent" => Ok(LineFault::Silent),
        _ => match s.strip_prefix("corrupt=").map(str::parse::<f64>) {
            Some(Ok(p)) if (0.0..=1.0).contains(&p) => Ok(LineFault::Corrupt(p)),
            _ => Err(format!("--line `{s}`: expected none, silent or corrupt=P with P in [0, 1]")),
        },
    }
}

/// At the default path, brings the robot firmware up to date (a no-op when
/// it is), so a run never uses a stale build; elsewhere it must exist.
fn ensure_firmware(path: &std::path::Path) -> Result<(), Error> {
    let dir = PathBuf::from("firmware");
    let default = path == std::path::Path::new(DEFAULT_FIRMWARE);
    if !default || !dir.join("Cargo.toml").exists() {
        return if path.exists() {
            Ok(())
        } else {
            Err(format!("{}: no such firmware (build it with `cargo build --release` in firmware/)", path.display())
                .into())
        };
    }
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args(["build", "--release", "--bin", "robot"])
        .current_dir(&dir)
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("RUSTFLAGS")
        .output()?;
    if !out.status.success() || !path.exists() {
        return Err(format!("building the firmware failed:\n{}", String::from_utf8_lossy(&out.stderr)).into());
    }
    Ok(())
}

/// The landmark alignment's figures as JSON.
fn global_json(g: GlobalReport) -> serde_json::Value {
    json!({"landmarks": g.landmarks, "agreeing": g.agreeing, "runner_up": g.runner_up, "unique": g.unique})
}

/// The landmark alignment's figures in words.
fn global_text(g: &GlobalReport) -> String {
    if g.agreeing == 0 {
        return format!("{} / {} landmarks, too few agree: no answer", g.landmarks[0], g.landmarks[1]);
    }
    format!(
        "{} / {} landmarks, {} agree (runner-up {}): {}",
        g.landmarks[0],
        g.landmarks[1],
        g.agreeing,
        g.runner_up,
        if g.unique { "unique" } else { "no unique answer" }
    )
}

/// `x,y,z,roll,pitch,yaw` (m, degrees) of a transform, for printing.
fn pose_text(m: &Matrix4<f64>) -> String {
    let x = pose::to_xyz_rpy_deg(m);
    format!("{:.4},{:.4},{:.4},{:.3},{:.3},{:.3}", x[0], x[1], x[2], x[3], x[4], x[5])
}

pub fn run(a: Args) -> Result<(), Error> {
    let line = parse_line(&a.line)?;
    let positive = |v: f32| v.is_finite() && v > 0.0;
    if !(positive(a.voxel) && positive(a.crop)) {
        return Err("--voxel and --crop must be positive".into());
    }
    if !(a.silence.is_finite() && a.silence > 0.0 && a.timeout.is_finite() && a.timeout > 0.0) {
        return Err("--silence and --timeout must be positive".into());
    }
    let seq = Sequence::open(&a.data)?;
    let gt = seq.relative_pose(a.a.start, a.b.start)?;
    let prior_ab = match &a.prior {
        Some(p) => pose::parse(p)?,
        None => pose::from_xyz_rpy_deg(2.0, 0.0, 0.0, 0.0, 0.0, 10.0) * gt,
    };
    let prior_ab = (!a.no_prior).then(|| pose::to_isometry(&prior_ab));
    let filter = PointFilter::default();
    let mut feeds = Vec::new();
    for (id, range, prior) in [(0u8, a.a, prior_ab), (1u8, a.b, prior_ab.map(|p| p.inverse()))] {
        let frames = seq.load_range(range)?;
        let scans = frames.iter().map(|f| thin_scan(f, a.voxel, a.crop, &filter)).collect();
        let setup = Setup {
            robot_id: id,
            resolution: a.voxel,
            prior: prior.map(|p| rows(&p)),
            silence_ms: (a.silence * 1000.0) as u32,
        };
        feeds.push(Feed { setup, scans });
    }
    let (map_a, map_b) = (feeds[0].map()?, feeds[1].map()?);
    // The host runs each robot's alignment too: A's is the reference the
    // conventions name (`host`), B's the check of robot B.
    // Each from the prior exactly as its robot decodes it.
    let prior_of = |f: &Feed| f.setup.prior.as_ref().map(from_rows);
    let t = std::time::Instant::now();
    let (host, host_global) = host_align(&map_a, &map_b, prior_of(&feeds[0]).as_ref())?;
    let host_ms = t.elapsed().as_secs_f64() * 1e3;
    let (host_b, _) = host_align(&map_b, &map_a, prior_of(&feeds[1]).as_ref())?;
    ensure_firmware(&a.firmware)?;
    let run = run_pair(&a.firmware, [&feeds[0], &feeds[1]], line, Duration::from_secs_f64(a.timeout))?;
    // 8N1 at 115200 baud: 11,520 bytes per second each way.
    let line_s = |bytes: u64| bytes as f64 * 10.0 / 115_200.0;
    let truth = [gt, cosem_host::kitti::rigid_inverse(&gt)];
    let mut all_reported = true;
    let mut robots_json = Vec::new();
    let mut lines = Vec::new();
    for (i, r) in run.robots.iter().enumerate() {
        let name = if i == 0 { "A" } else { "B" };
        let feed_points = feeds[i].points();
        match &r.outcome {
            Outcome::Report(rep) => {
                let m = to_matrix(&rep.result.transform());
                let status = rep.result.status().map(|s| s.as_str()).unwrap_or("?");
                let (e_t, e_r) = errors(&m, &truth[i]);
                robots_json.push(json!({
                    "id": i, "status": status, "transform": pose::to_row_major(&m),
                    "instructions": rep.locate_instructions + rep.match_instructions, "map_voxels": rep.map_voxels,
                    "bytes_sent": rep.bytes_sent, "bytes_received": rep.bytes_received,
                    "map_instructions": rep.map_instructions, "prepare_instructions": rep.prepare_instructions,
                    "match_instructions": rep.match_instructions, "points": rep.points,
                    "received_voxels": rep.received_voxels, "retransmissions": rep.retransmissions,
                    "link_ms_onboard": rep.link_ms, "link_time_115200_s": line_s(rep.bytes_sent.max(rep.bytes_received)),
                    "iterations": rep.result.iterations, "inliers": rep.result.inliers, "overlap": rep.result.overlap,
                    "peak_stack_bytes": rep.peak_stack, "exit_code": r.exit_code,
                    "locate_instructions": rep.locate_instructions, "global": rep.global.map(global_json),
                    "e_t": e_t, "e_r": e_r,
                }));
                if let Some(g) = &rep.global {
                    lines.push(format!(
                        "robot {name} (id {i}): no prior; {}; landmark alignment {:.1} M instructions",
                        global_text(g),
                        rep.locate_instructions as f64 / 1e6
                    ));
                }
                lines.push(format!(
                    "robot {name} (id {i}): {status}, T_{name}_{} = {} (e_t {e_t:.3} m, e_r {e_r:.3} deg)\n  \
                     map {} voxels from {} fed points; sent {} B, received {} B ({} retransmissions; {:.1} s at 115200 baud)\n  \
                     instructions: mapping {:.1} M, preparation {:.1} M, match {:.1} M; peak stack {} B; exit {:?}",
                    if i == 0 { "B" } else { "A" },
                    pose_text(&m),
                    rep.map_voxels, feed_points, rep.bytes_sent, rep.bytes_received, rep.retransmissions,
                    line_s(rep.bytes_sent.max(rep.bytes_received)),
                    rep.map_instructions as f64 / 1e6, rep.prepare_instructions as f64 / 1e6,
                    rep.match_instructions as f64 / 1e6, rep.peak_stack, r.exit_code,
                ));
            }
            Outcome::Failed { stage, message } => {
                all_reported = false;
                robots_json.push(json!({"id": i, "status": null, "error": {"stage": stage, "message": message}, "exit_code": r.exit_code}));
                lines.push(format!("robot {name} (id {i}): failed at {stage}: {message}; exit {:?}", r.exit_code));
            }
            Outcome::Lost(why) => {
                all_reported = false;
                robots_json.push(json!({"id": i, "status": null, "error": {"stage": "host", "message": why}, "exit_code": r.exit_code}));
                lines.push(format!("robot {name} (id {i}): no report: {why}; exit {:?}", r.exit_code));
            }
        }
    }
    let host_m = to_matrix(&host.transform);
    let (he_t, he_r) = errors(&host_m, &gt);
    let host_bm = to_matrix(&host_b.transform);
    if a.json {
        let out = json!({
            "robots": robots_json,
            "host": {
                "transform": pose::to_row_major(&host_m), "status": host.status.as_str(), "e_t": he_t, "e_r": he_r,
                "global": host_global.as_ref().map(|l| global_json(GlobalReport::from(l))), "time_ms": host_ms,
            },
            "prior": feeds[0].setup.prior.as_ref().map(|p| pose::to_row_major(&to_matrix(&from_rows(p)))),
            "host_b": {"transform": pose::to_row_major(&host_bm), "status": host_b.status.as_str()},
            "ground_truth": pose::to_row_major(&gt),
            "line_bytes": run.line_bytes,
            "wall_time_s": run.wall_s,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        for l in &lines {
            println!("{l}");
        }
        println!(
            "host (same fed data): {}, T_A_B = {} (e_t {he_t:.3} m, e_r {he_r:.3} deg); {host_ms:.1} ms",
            host.status.as_str(),
            pose_text(&host_m)
        );
        if let Some(l) = &host_global {
            println!("host, no prior: {}", global_text(&GlobalReport::from(l)));
        }
        println!("host, robot B's match: {}, T_B_A = {}", host_b.status.as_str(), pose_text(&host_bm));
        println!("ground truth: T_A_B = {}; wall time {:.1} s", pose_text(&gt), run.wall_s);
    }
    if all_reported {
        Ok(())
    } else {
        Err("a robot did not report a match".into())
    }
}
