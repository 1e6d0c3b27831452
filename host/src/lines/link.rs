//! `cosem link` on the host: one robot's end of the map exchange over TCP
//! or a serial port, with the core's link endpoint.

use crate::error::Error;
use crate::lines::transport::{HostClock, Paced, Tcp};
use crate::maps::mapping::{new_map, HostMap};
use cosem_core::link::{Endpoint, LinkBuffers, LinkConfig, LinkStats, Progress};
use std::time::Duration;

/// Voxels a received map may have (64 MB of staging).
pub const STAGING_VOXELS: usize = 2 << 20;

/// Which line to exchange over.
#[derive(Clone, Debug)]
pub enum Line {
    /// Listen on 127.0.0.1:port (0: any free port) for the peer, waiting at
    /// most this long for it.
    Listen(u16, Duration),
    /// Connect to a peer at HOST:PORT, retrying for this long while it starts.
    Connect(String, Duration),
    /// A serial device at a baud rate (feature `serial`).
    Serial(String, u32),
}

/// Exchanges `ours` for the peer's map over `line` as robot `robot_id`;
/// `on_listen` learns the address when listening. Returns the peer's map
/// (accepted only whole: count and digest checked) and what moved.
/// How to run the exchange.
#[derive(Clone, Copy, Debug)]
pub struct Exchange {
    /// Our robot id (robot 0 sends first on a half-duplex line).
    pub robot_id: u8,
    /// Timestamp of our map's anchor scan (µs).
    pub anchor_us: u64,
    /// The line carries one direction at a time.
    pub half_duplex: bool,
    /// Writes paced to this baud rate (8N1), as a UART: 0 unpaced (a serial
    /// port paces itself).
    pub baud: u32,
    /// Give up with an error after this long, whatever the state.
    pub deadline: Duration,
}

pub fn exchange(
    line: &Line,
    ours: &HostMap,
    how: &Exchange,
    on_listen: impl FnOnce(std::net::SocketAddr),
) -> Result<(HostMap, LinkStats), Error> {
    let (robot_id, anchor_us, half_duplex) = (how.robot_id, how.anchor_us, how.half_duplex);
    let mut staging: HostMap = new_map(STAGING_VOXELS, *ours.config())?;
    let mut scratch = vec![0u32; ours.len()];
    let map_id = (u32::from(robot_id) << 24) ^ (ours.len() as u32);
    let config = LinkConfig { half_duplex, ..LinkConfig::default() };
    let mut buffers = Box::new(LinkBuffers::new());
    let mine = Some((ours, &mut scratch[..]));
    let endpoint = Endpoint::new(config, robot_id, map_id, anchor_us, mine, Some(&mut staging), &mut *buffers)
        .map_err(link_err)?;
    let stats = run(line, endpoint, how, on_listen)?;
    Ok((staging, stats))
}

fn link_err(e: cosem_core::link::LinkError) -> Error {
    Error::Invalid(format!("link: {e}"))
}

/// Runs `endpoint` to its end over `line`.
fn run(
    line: &Line,
    mut endpoint: Endpoint<'_, cosem_core::map::VecStorage, cosem_core::map::VecMap>,
    how: &Exchange,
    on_listen: impl FnOnce(std::net::SocketAddr),
) -> Result<LinkStats, Error> {
    let io_err = |what: String| move |source| Error::Io { path: what.into(), source };
    let started = std::time::Instant::now();
    match line {
        Line::Listen(port, wait) => {
            let listener = std::net::TcpListener::bind(("127.0.0.1", *port))
                .map_err(io_err(format!("listen on 127.0.0.1:{port}")))?;
            on_listen(listener.local_addr().map_err(io_err("listener".into()))?);
            let tcp = Tcp::accept(&listener, *wait).map_err(io_err(format!("accept on port {port}")))?;
            drive(&mut endpoint, &mut Paced::new(tcp, how.baud), started, how.deadline)
        }
        Line::Connect(addr, wait) => {
            let tcp = Tcp::connect(addr, *wait).map_err(io_err(addr.clone()))?;
            drive(&mut endpoint, &mut Paced::new(tcp, how.baud), started, how.deadline)
        }
        #[cfg(feature = "serial")]
        Line::Serial(dev, baud) => {
            let mut io = crate::lines::transport::Serial::open(dev, *baud)
                .map_err(|e| Error::Io { path: dev.into(), source: std::io::Error::other(e) })?;
            drive(&mut endpoint, &mut io, started, how.deadline)
        }
        #[cfg(not(feature = "serial"))]
        Line::Serial(dev, _) => Err(Error::Invalid(format!("{dev}: serial ports need the `serial` feature"))),
    }
}

/// Steps the endpoint until it is done, fails, or the deadline passes.
fn drive<IO: embedded_io::Read + embedded_io::Write + embedded_io::ReadReady + embedded_io::WriteReady>(
    endpoint: &mut Endpoint<'_, cosem_core::map::VecStorage, cosem_core::map::VecMap>,
    io: &mut IO,
    started: std::time::Instant,
    deadline: Duration,
) -> Result<LinkStats, Error> {
    let clock = HostClock::default();
    loop {
        if endpoint.step(io, cosem_core::link::Clock::now_ms(&clock)).map_err(link_err)? == Progress::Done {
            return Ok(endpoint.stats());
        }
        if started.elapsed() > deadline {
            return Err(Error::Invalid(format!(
                "link: no result within the deadline of {:.0} s ({} bytes sent, {} received)",
                deadline.as_secs_f64(),
                endpoint.stats().bytes_sent,
                endpoint.stats().bytes_received
            )));
        }
        std::thread::sleep(Duration::from_micros(300));
    }
}
