//! `cosem team --on-board`: each robot on its own emulated board (see
//! `cosem_host::team_board`), beside the host's run of the same robots.

use super::team::Args;
use super::{show, Error};
use std::time::Duration;

/// Exit code: 0 when every board finished and placed every robot in robot
/// 0's frame; 5 when a robot is unplaced; 1 when a board stopped.
pub fn run(a: Args) -> Result<u8, Error> {
    // No prior and no injected match on board (clap refuses them).
    let spec = super::team::spec(&a, 0.5);
    let silence_ms = (a.silence * 1000.0).min(f64::from(u32::MAX)) as u32;
    let timeout = Duration::from_secs_f64(a.timeout.min(86_400.0));
    let out = cosem_host::team_board::run_on_boards(&spec, a.crop, silence_ms, &a.firmware, timeout)?;
    show(a.json, &out)?;
    Ok(out.exit_code())
}
