//! `cosem cli-tree` (hidden): the command tree as clap knows it, as JSON,
//! for the misuse table test (tests/tests/misuse.rs), which makes its
//! cases from it so that no option is forgotten: every command, every
//! argument, its kind (number, frame range, input or output path, text,
//! flag) and its values.

use serde_json::{json, Value};
use std::any::TypeId;
use std::path::PathBuf;

/// An argument's kind, from the type its parser makes: paths are outputs
/// when their value name says OUT (`--out <OUT>`, `-o <OUT>`), else inputs.
fn kind(arg: &clap::Arg) -> &'static str {
    if !arg.get_action().takes_values() {
        return "flag";
    }
    let id = arg.get_value_parser().type_id();
    let is = |t: TypeId| id == t;
    let numbers = [
        TypeId::of::<f64>(),
        TypeId::of::<f32>(),
        TypeId::of::<u64>(),
        TypeId::of::<u32>(),
        TypeId::of::<u16>(),
        TypeId::of::<u8>(),
        TypeId::of::<usize>(),
        TypeId::of::<i64>(),
        TypeId::of::<i32>(),
    ];
    if numbers.into_iter().any(is) {
        "number"
    } else if is(TypeId::of::<cosem_host::sources::kitti::FrameRange>()) {
        "range"
    } else if is(TypeId::of::<PathBuf>()) {
        let out = arg.get_value_names().is_some_and(|n| n.iter().any(|n| n.as_str().starts_with("OUT")));
        if out {
            "output"
        } else {
            "input"
        }
    } else {
        "text"
    }
}

fn command(cmd: &clap::Command, path: &[String]) -> Vec<Value> {
    let mut here: Vec<String> = path.to_vec();
    here.push(cmd.get_name().to_string());
    let subs: Vec<&clap::Command> = cmd.get_subcommands().filter(|c| c.get_name() != "help").collect();
    if !subs.is_empty() {
        return subs.into_iter().flat_map(|s| command(s, &here)).collect();
    }
    let args: Vec<Value> = cmd
        .get_arguments()
        .filter(|a| !matches!(a.get_id().as_str(), "help" | "version"))
        .map(|a| {
            json!({
                "id": a.get_id().as_str(),
                "long": a.get_long(),
                "short": a.get_short().map(String::from),
                "positional": a.is_positional(),
                "required": a.is_required_set(),
                "kind": kind(a),
                "default": a.get_default_values().iter().map(|v| v.to_string_lossy().into_owned()).collect::<Vec<_>>(),
                "values": a.get_possible_values().iter().map(|v| v.get_name().to_string()).collect::<Vec<_>>(),
                "multiple": a.get_num_args().is_some_and(|n| n.max_values() > 1),
                "global": a.is_global_set(),
            })
        })
        .collect();
    vec![json!({ "command": here[1..].to_vec(), "args": args })]
}

/// Prints the tree.
pub fn run() -> Result<(), super::Error> {
    use clap::CommandFactory;
    let mut cli = super::Cli::command();
    cli.build();
    let commands: Vec<Value> = command(&cli, &[]).into_iter().filter(|c| c["command"][0] != "cli-tree").collect();
    println!("{}", serde_json::to_string_pretty(&commands)?);
    Ok(())
}
