//! `cosem relay`: a paced, lossy line between two `cosem link` processes.

use super::Error;
use cosem_host::lines::relay::{flip_mix, run, Fault, LineModel, Mix};
use std::time::Duration;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The two ports on 127.0.0.1 the link processes connect to (0: any free one; printed).
    #[arg(long, num_args = 2, default_values_t = [0, 0])]
    ports: Vec<u16>,
    /// Line speed (baud, 8N1) each direction is paced to; 0: unpaced.
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// Probability that a byte is damaged (flipped, dropped or duplicated).
    #[arg(long, default_value_t = 0.0, value_parser = super::args::probability)]
    error_rate: f64,
    /// Seed of the errors.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// What a flip does: `bit` flips one bit, `byte` XORs a random non-zero byte.
    #[arg(long, value_enum, default_value = "bit", conflicts_with = "mix")]
    flip: Flip,
    /// Shares of the damage instead: bit=S,byte=S,drop=S,dup=S.
    #[arg(long, value_parser = cosem_host::lines::relay::parse_mix)]
    mix: Option<Mix>,
    /// Give up when the two sides have not connected in this long (s).
    #[arg(long, default_value = "60", value_parser = super::args::seconds)]
    accept_timeout: f64,
}

/// What a flip does to a byte: a UART's bit error flips one bit; noise
/// across a whole character (or a clock slip) garbles it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Flip {
    /// One bit flipped.
    #[default]
    Bit,
    /// XOR with a random non-zero byte.
    Byte,
}

pub fn run_relay(a: Args) -> Result<(), Error> {
    let bind =
        |p: u16| std::net::TcpListener::bind(("127.0.0.1", p)).map_err(|e| format!("listen on 127.0.0.1:{p}: {e}"));
    let listeners = [bind(a.ports[0])?, bind(a.ports[1])?];
    if a.mix.is_some() && a.error_rate == 0.0 {
        eprintln!("warning: --mix without --error-rate: the line stays clean (--error-rate 0), the mix is not used");
    }
    let mix = a.mix.unwrap_or(flip_mix(a.flip == Flip::Byte));
    let fault = Fault::new(a.error_rate, mix).map_err(|e| format!("--error-rate {} --mix: {e}", a.error_rate))?;
    let model = LineModel { baud: a.baud, fault, seed: a.seed };
    let wait = Duration::from_secs_f64(a.accept_timeout.min(86_400.0));
    let stats = run(listeners, model, wait, |[x, y]| eprintln!("relay on {x} {y}"))?;
    println!(
        "relay: {} bytes one way ({} damaged), {} the other ({} damaged)",
        stats.bytes_in[0], stats.damaged[0], stats.bytes_in[1], stats.damaged[1]
    );
    Ok(())
}
