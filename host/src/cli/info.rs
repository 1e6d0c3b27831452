//! `cosem info`: what a map file holds.

use super::{print_json, Error};
use cosem_host::report::InfoJson;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Map file.
    file: PathBuf,
    /// Print JSON.
    #[arg(long)]
    pub(super) json: bool,
}

pub fn run(a: Args) -> Result<(), Error> {
    let info = InfoJson::of(&a.file)?;
    if a.json {
        return print_json(&info);
    }
    print!("{info}");
    Ok(())
}
