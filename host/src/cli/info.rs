//! `cosem info`: what a map file holds.

use super::Error;
use cosem_host::reports::report::InfoJson;
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
    super::show(a.json, &InfoJson::of(&a.file)?)
}
