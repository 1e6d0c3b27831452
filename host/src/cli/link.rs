//! `cosem link`: exchange maps with a peer over a line, then match.

use super::args::MatchOpts;
use super::{print_json, Error};
use cosem_host::lines::link::{exchange, Exchange, Line};
use cosem_host::matching::align::prepare_and_align;
use cosem_host::reports::report::{exit_code, result_text, GlobalJson, LinkJson, MatchJson};
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
    /// Baud rate: of the serial port; with TCP, our writes are paced to it
    /// as a UART would send (default: unpaced, line times reported at 115200).
    #[arg(long, value_parser = super::args::baud)]
    baud: Option<u32>,
    /// Give up after this long, whatever the state (s; long enough for a
    /// robot's map on a 115200-baud line with 5% byte errors).
    #[arg(long, default_value = "600", value_parser = super::args::seconds)]
    deadline: f64,
    /// With --listen: give up when no peer connected in this long (s).
    #[arg(long, default_value = "60", value_parser = super::args::seconds)]
    accept_timeout: f64,
    /// With --tcp: keep trying to connect for this long while the peer starts (s).
    #[arg(long, default_value = "10", value_parser = super::args::seconds)]
    connect_timeout: f64,
    /// Our robot id (default 0 when listening, 1 when connecting).
    #[arg(long)]
    robot_id: Option<u8>,
    /// Our match: our map is the model, the peer's the scene (`--init` is
    /// `T_ours_peers`).
    #[command(flatten)]
    opts: MatchOpts,
    /// The line carries one direction at a time: robot 0 sends its map
    /// first, the other after receiving it (both sides must say so).
    #[arg(long)]
    half_duplex: bool,
    /// Print JSON.
    #[arg(long)]
    pub(super) json: bool,
}

fn line(a: &Args) -> Line {
    match (&a.listen, &a.tcp, &a.serial) {
        (Some(port), _, _) => Line::Listen(*port, Duration::from_secs_f64(a.accept_timeout.min(86_400.0))),
        (None, Some(addr), _) => Line::Connect(addr.clone(), Duration::from_secs_f64(a.connect_timeout.min(3600.0))),
        (None, None, dev) => Line::Serial(dev.clone().unwrap_or_default(), a.baud.unwrap_or(115_200)),
    }
}

pub fn run(a: Args) -> Result<u8, Error> {
    let (alignment, prior) = a.opts.resolve();
    let (header, ours) = cosem_host::maps::cmap::read(&a.map)?;
    let robot_id = a.robot_id.unwrap_or(if a.listen.is_some() { 0 } else { 1 });
    let anchor_us = header.anchor_time.map(|t| (t * 1e6) as u64).unwrap_or(0);
    let started = Instant::now();
    let how = Exchange {
        robot_id,
        anchor_us,
        half_duplex: a.half_duplex,
        baud: if a.serial.is_some() { 0 } else { a.baud.unwrap_or(0) },
        deadline: Duration::from_secs_f64(a.deadline.min(86_400.0)),
    };
    let (theirs, stats) = exchange(&line(&a), &ours, &how, |at| eprintln!("listening on {at}"))?;
    let link_s = started.elapsed().as_secs_f64();
    let our_name = format!("our map {}", a.map.display());
    let m = prepare_and_align(&ours, &theirs, [&our_name, "the peer's map"], alignment, prior.as_ref())?;
    let (r, global, match_ms, prep_ms) = (m.result, m.global, m.match_ms, m.prepare_ms);
    let mut result = MatchJson::new(&r, match_ms, prep_ms);
    result.global = global.as_ref().map(GlobalJson::from);
    let figures =
        LinkJson::new(robot_id, &stats, (ours.len(), theirs.len()), link_s, a.baud.unwrap_or(115_200), result);
    if a.json {
        print_json(&figures)?;
        return Ok(exit_code(r.status));
    }
    print!("{figures}");
    println!("match (ours = model, peer's = scene):");
    print!("{}", result_text(&r, global.as_ref()));
    println!("time        {match_ms:.1} ms (preparation {prep_ms:.1} ms)");
    Ok(exit_code(r.status))
}
