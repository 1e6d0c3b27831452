//! `cosem link` on the host: one robot's end of the map exchange over TCP
//! or a serial port, with the core's link endpoint.

use crate::error::Error;
use crate::mapping::{new_map, HostMap};
use crate::transport::{HostClock, Tcp};
use cosem_core::link::{Endpoint, LinkConfig, LinkStats};
use std::time::Duration;

/// Voxels a received map may have (64 MB of staging).
pub const STAGING_VOXELS: usize = 2 << 20;

/// Which line to exchange over.
#[derive(Clone, Debug)]
pub enum Line {
    /// Listen on 127.0.0.1:port (0: any free port) for the peer.
    Listen(u16),
    /// Connect to a peer at HOST:PORT, retrying for this long while it starts.
    Connect(String, Duration),
    /// A serial device at a baud rate (feature `serial`).
    Serial(String, u32),
}

/// Exchanges `ours` for the peer's map over `line` as robot `robot_id`;
/// `on_listen` learns the address when listening. Returns the peer's map
/// (accepted only whole: count and digest checked) and what moved.
pub fn exchange(
    line: &Line,
    robot_id: u8,
    ours: &HostMap,
    anchor_us: u64,
    half_duplex: bool,
    on_listen: impl FnOnce(std::net::SocketAddr),
) -> Result<(HostMap, LinkStats), Error> {
    let mut staging: HostMap = new_map(STAGING_VOXELS, *ours.config())?;
    let mut scratch = vec![0u32; ours.len()];
    let map_id = (u32::from(robot_id) << 24) ^ (ours.len() as u32);
    let config = LinkConfig { half_duplex, ..LinkConfig::default() };
    let endpoint = Endpoint::new(config, robot_id, map_id, anchor_us, Some((ours, &mut scratch)), Some(&mut staging))
        .map_err(link_err)?;
    let stats = run(line, endpoint, on_listen)?;
    Ok((staging, stats))
}

fn link_err(e: cosem_core::link::LinkError) -> Error {
    Error::Invalid(format!("link: {e}"))
}

/// Runs `endpoint` to its end over `line`.
fn run(
    line: &Line,
    mut endpoint: Endpoint<'_, cosem_core::map::VecStorage, cosem_core::map::VecStorage>,
    on_listen: impl FnOnce(std::net::SocketAddr),
) -> Result<LinkStats, Error> {
    let clock = HostClock::default();
    let idle = || std::thread::sleep(Duration::from_micros(300));
    let io_err = |what: String| move |source| Error::Io { path: what.into(), source };
    match line {
        Line::Listen(port) => {
            let listener = std::net::TcpListener::bind(("127.0.0.1", *port))
                .map_err(io_err(format!("listen on 127.0.0.1:{port}")))?;
            on_listen(listener.local_addr().map_err(io_err("listener".into()))?);
            let mut io = Tcp::accept(&listener).map_err(io_err(format!("accept on port {port}")))?;
            endpoint.run(&mut io, &clock, idle).map_err(link_err)
        }
        Line::Connect(addr, wait) => {
            let mut io = Tcp::connect(addr, *wait).map_err(io_err(addr.clone()))?;
            endpoint.run(&mut io, &clock, idle).map_err(link_err)
        }
        #[cfg(feature = "serial")]
        Line::Serial(dev, baud) => {
            let mut io = crate::transport::Serial::open(dev, *baud)
                .map_err(|e| Error::Io { path: dev.into(), source: std::io::Error::other(e) })?;
            endpoint.run(&mut io, &clock, idle).map_err(link_err)
        }
        #[cfg(not(feature = "serial"))]
        Line::Serial(dev, _) => Err(Error::Invalid(format!("{dev}: serial ports need the `serial` feature"))),
    }
}
