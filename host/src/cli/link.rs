//! `cosem link`: exchange maps with a peer over a line, then match.

use super::Error;
use cosem_core::link::{Endpoint, LinkConfig, LinkStats};
use cosem_host::align::{prepare, DEFAULT_LEVELS};
use cosem_host::mapping::{new_map, HostMap};
use cosem_host::pose;
use cosem_host::transport::{HostClock, Serial, Tcp};
use serde_json::json;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(clap::Args, Debug)]
#[command(group(clap::ArgGroup::new("line").required(true).args(["tcp", "listen", "serial"])))]
pub struct Args {
    /// Our map (the model of our match).
    #[arg(long)]
    map: PathBuf,
    /// Connect to a peer listening at HOST:PORT.
    #[arg(long)]
    tcp: Option<String>,
    /// Listen on 127.0.0.1:PORT for the peer (0: any free port, printed).
    #[arg(long)]
    listen: Option<u16>,
    /// Serial device (e.g. /dev/ttyUSB0).
    #[arg(long, requires = "baud")]
    serial: Option<String>,
    /// Baud rate: of the serial port; with TCP, the rate the link time is
    /// also reported at (default 115200).
    #[arg(long)]
    baud: Option<u32>,
    /// With --tcp: keep trying to connect for this long while the peer starts (s).
    #[arg(long, default_value_t = 10.0)]
    connect_timeout: f64,
    /// Our robot id (default 0 when listening, 1 when connecting).
    #[arg(long)]
    robot_id: Option<u8>,
    /// Our match: our map is the model, the peer's the scene (`--init` is
    /// `T_ours_peers`).
    #[command(flatten)]
    opts: super::matching::MatchOpts,
    /// The line carries one direction at a time: robot 0 sends its map
    /// first, the other after receiving it (both sides must say so).
    #[arg(long)]
    half_duplex: bool,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// Voxels a received map may have (64 MB of staging).
const STAGING_VOXELS: usize = 2 << 20;

pub fn run(a: Args) -> Result<(), Error> {
    let (settings, init) = a.opts.resolve()?;
    let (header, ours) = cosem_host::cmap::read(&a.map)?;
    let robot_id = a.robot_id.unwrap_or(if a.listen.is_some() { 0 } else { 1 });
    let mut staging: HostMap = new_map(STAGING_VOXELS, *ours.config())?;
    let mut scratch = vec![0u32; ours.len()];
    let map_id = (u32::from(robot_id) << 24) ^ (ours.len() as u32);
    let anchor_us = header.anchor_time.map(|t| (t * 1e6) as u64).unwrap_or(0);
    let clock = HostClock::default();
    let started = Instant::now();
    let config = LinkConfig { half_duplex: a.half_duplex, ..LinkConfig::default() };
    let mut endpoint =
        Endpoint::new(config, robot_id, map_id, anchor_us, Some((&ours, &mut scratch)), Some(&mut staging))?;
    let idle = || std::thread::sleep(Duration::from_micros(300));
    let stats: LinkStats = if let Some(port) = a.listen {
        let listener = std::net::TcpListener::bind(("127.0.0.1", port))?;
        eprintln!("listening on {}", listener.local_addr()?);
        let mut io = Tcp::accept(&listener)?;
        endpoint.run(&mut io, &clock, idle)?
    } else if let Some(addr) = &a.tcp {
        let wait = Duration::from_secs_f64(a.connect_timeout.clamp(0.0, 3600.0));
        let mut io = Tcp::connect(addr, wait).map_err(|e| format!("{addr}: {e}"))?;
        endpoint.run(&mut io, &clock, idle)?
    } else if let Some(dev) = &a.serial {
        let baud = a.baud.unwrap_or(115_200);
        let mut io = Serial::open(dev, baud).map_err(|e| format!("{dev}: {e}"))?;
        endpoint.run(&mut io, &clock, idle)?
    } else {
        return Err("one of --tcp, --listen, --serial is required".into());
    };
    let link_s = started.elapsed().as_secs_f64();
    let theirs = staging;
    let baud = a.baud.unwrap_or(115_200);
    // 8N1: ten bits per byte on the line.
    let line_s = |bytes: u64| bytes as f64 * 10.0 / f64::from(baud);
    let t0 = Instant::now();
    let pm = prepare(&ours, DEFAULT_LEVELS)?;
    let ps = prepare(&theirs, DEFAULT_LEVELS)?;
    let prep_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = Instant::now();
    let (r, global) = super::matching::align_maps(&a.opts, settings, &init, (&ours, &theirs), (&pm, &ps))?;
    let match_ms = t1.elapsed().as_secs_f64() * 1e3;
    let wire_per_voxel = stats.chunk_bytes_sent as f64 / ours.len().max(1) as f64;
    if a.json {
        let mut m = super::matching::result_json(&r, match_ms);
        m["prepare_ms"] = json!(prep_ms);
        if let Some(g) = &global {
            m["global"] = super::matching::global_json(g);
        }
        let out = json!({
            "robot_id": robot_id,
            "bytes_sent": stats.bytes_sent,
            "bytes_received": stats.bytes_received,
            "frames": stats.frames_sent,
            "frames_received": stats.frames_received,
            "retransmissions": stats.retransmissions,
            "bad_frames": stats.bad_frames,
            "voxels_sent": ours.len(),
            "voxels_received": theirs.len(),
            "wire_bytes_per_voxel": wire_per_voxel,
            "link_time_s": link_s,
            "baud": baud,
            "line_time_s": {"sent": line_s(stats.bytes_sent), "received": line_s(stats.bytes_received)},
            "match": m,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "robot {robot_id}: sent {} voxels in {} bytes ({:.2} bytes/voxel of encoding), received {} voxels in {} bytes",
            ours.len(),
            stats.bytes_sent,
            wire_per_voxel,
            theirs.len(),
            stats.bytes_received
        );
        println!(
            "frames {} sent, {} received, {} retransmitted, {} broken; {:.2} s here; at {baud} baud: {:.1} s out, {:.1} s in",
            stats.frames_sent,
            stats.frames_received,
            stats.retransmissions,
            stats.bad_frames,
            link_s,
            line_s(stats.bytes_sent),
            line_s(stats.bytes_received)
        );
        let x = pose::to_xyz_rpy_deg(&cosem_host::align::to_matrix(&r.transform));
        println!(
            "match (ours = model, peer's = scene): {} x,y,z,roll,pitch,yaw {:.4},{:.4},{:.4},{:.4},{:.4},{:.4}; {} iterations, overlap {:.1}%, {:.1} ms",
            r.status.as_str(),
            x[0],
            x[1],
            x[2],
            x[3],
            x[4],
            x[5],
            r.iterations,
            100.0 * r.overlap,
            match_ms
        );
    }
    Ok(())
}
