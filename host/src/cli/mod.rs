//! The subcommands, one module each: each parses its arguments (clap) and
//! prints; the work is in the `cosem_host` library.

pub mod args;
mod bench;
mod demo;
mod eval;
mod export;
mod info;
mod label;
mod link;
mod map;
mod matching;
mod relay;
mod robots;
mod ros;
mod segment;
mod session;
mod synth;
mod team;
mod tree;

use clap::{Parser, Subcommand};

/// Errors of the CLI: a message, possibly wrapping a typed error.
pub type Error = Box<dyn std::error::Error + Send + Sync>;

/// cosem: two robots, two semantic maps, one relative pose.
#[derive(Parser, Debug)]
#[command(name = "cosem", version, about)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
    /// The most pixels an image (or a network's input) may have; a larger
    /// one is refused before anything is allocated for it.
    #[arg(long, global = true, default_value_t = cosem_host::limits::DEFAULT_MAX_PIXELS, value_parser = args::max_pixels)]
    max_pixels: u64,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Build a local semantic map from a range of SemanticKITTI frames.
    Map(map::Args),
    /// Align a scene map to a model map: prints T_model_scene and its figures.
    Match(matching::Args),
    /// The paper's robustness protocol: many starts, success rates, errors.
    Eval(eval::Args),
    /// Exchange maps with a peer over TCP or a serial line, then match.
    Link(link::Args),
    /// A paced, lossy line between two `cosem link` processes (for tests and measurements).
    Relay(relay::Args),
    /// Two robots on emulated Cortex-M4F boards: onboard mapping, map
    /// exchange over UART0, onboard matching.
    Robots(robots::Args),
    /// A team of 2 to 8 robots: maps over a mesh of links, every pair
    /// matched both ways, matches checked around cycles, every robot placed
    /// in robot 0's frame.
    Team(team::Args),
    /// Robots that keep driving: rounds of mapping, map updates as deltas,
    /// each peer's pose tracked and re-checked under odometry drift.
    Session(session::Args),
    /// cosem beside a robot's ROS 2 stack, over DDS (pure Rust, no ROS
    /// installation).
    Ros {
        #[command(subcommand)]
        what: ros::What,
    },
    /// Describe a map file.
    Info(info::Args),
    /// Export a map to another format.
    Export {
        #[command(subcommand)]
        format: export::Format,
    },
    /// Label LiDAR scans from camera segmentation images (SemanticKITTI layout out).
    Label(label::Args),
    /// Segment camera images with a network (ONNX, pure Rust; feature `segment`).
    Segment(segment::Args),
    /// Synthesise a SemanticKITTI-layout sequence (street scene + simulated LiDAR).
    Synth(synth::Args),
    /// Benchmarks that print numbers.
    Bench {
        /// Also write the figures as JSON to this file (map, wire, link, label).
        #[arg(long, global = true, value_name = "OUT")]
        json: Option<std::path::PathBuf>,
        #[command(subcommand)]
        what: bench::What,
    },
    /// The main job on built-in data: synthesise, map two robots, match.
    Demo(demo::Args),
    /// The command tree as JSON (for the misuse table test).
    #[command(hide = true)]
    CliTree,
}

/// Runs a parsed command line; returns the exit code (docs/commands.md, "Exit
/// codes": `match`, `link` and `robots` say the match's status, the others
/// 0 when they did their job).
pub fn run(cli: Cli) -> Result<u8, Error> {
    // With --json, an error is JSON too (on standard output, beside the
    // message on standard error): scripts always get an object to read.
    let json = match &cli.command {
        Command::Match(a) => a.json.then_some("match"),
        Command::Link(a) => a.json.then_some("link"),
        Command::Robots(a) => a.json.then_some("robots"),
        Command::Team(a) => a.json.then_some("team"),
        Command::Info(a) => a.json.then_some("info"),
        Command::Label(a) => a.json.then_some("label"),
        _ => None,
    };
    let r = run_command(cli);
    let printed = JSON_PRINTED.load(std::sync::atomic::Ordering::Relaxed);
    if let (Err(e), Some(command), false) = (&r, json, printed) {
        let _ = print_json(&serde_json::json!({ "command": command, "error": e.to_string() }));
    }
    r
}

fn run_command(cli: Cli) -> Result<u8, Error> {
    cosem_host::limits::set_max_pixels(cli.max_pixels);
    let done = |r: Result<(), Error>| r.map(|()| 0);
    match cli.command {
        Command::Map(a) => done(map::run(a)),
        Command::Match(a) => matching::run(a),
        Command::Eval(a) => done(eval::run(a)),
        Command::Link(a) => link::run(a),
        Command::Robots(a) => robots::run(a),
        Command::Team(a) => team::run(a),
        Command::Session(a) => done(session::run_session(a)),
        Command::Relay(a) => done(relay::run_relay(a)),
        Command::Ros { what } => done(ros::run(what)),
        Command::Info(a) => done(info::run(a)),
        Command::Export { format } => done(export::run(format)),
        Command::Label(a) => done(label::run(a)),
        Command::Segment(a) => done(segment::run(a)),
        Command::Synth(a) => done(synth::run(a)),
        Command::Bench { json, what } => done(bench::run(what, json.as_deref())),
        Command::Demo(a) => done(demo::run(a)),
        Command::CliTree => done(tree::run()),
    }
}

/// Whether the command printed its JSON already (an error after it, such
/// as a robot that did not report, adds no second object).
static JSON_PRINTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Prints `value` as JSON with `json`, else as its text.
pub fn show(json: bool, value: &(impl serde::Serialize + std::fmt::Display)) -> Result<(), Error> {
    if json {
        return print_json(value);
    }
    print!("{value}");
    Ok(())
}

/// Prints `value` as pretty JSON.
pub fn print_json(value: &impl serde::Serialize) -> Result<(), Error> {
    println!("{}", serde_json::to_string_pretty(value)?);
    JSON_PRINTED.store(true, std::sync::atomic::Ordering::Relaxed);
    Ok(())
}
