//! `cosem match`: align a scene map to a model map.

use super::args::MatchOpts;
use super::{print_json, Error};
use cosem_host::maps::ply;
use cosem_host::matching::align::prepare_and_align;
use cosem_host::reports::report::{exit_code, result_text, GlobalJson, MatchJson};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Model map (kept fixed).
    model: PathBuf,
    /// Scene map (moved into the model frame).
    scene: PathBuf,
    #[command(flatten)]
    opts: MatchOpts,
    /// Print JSON.
    #[arg(long)]
    pub(super) json: bool,
    /// Write both maps in the model frame, coloured by robot, to this PLY.
    #[arg(long, value_name = "OUT")]
    merged: Option<PathBuf>,
    /// Write the match as a ROS 2 recording (MCAP) to view in Foxglove: both
    /// maps as PointCloud2 coloured by class (/cosem/model, /cosem/scene),
    /// T_model_scene on /tf (model -> scene), the result on /cosem/status.
    #[arg(long, value_name = "OUT")]
    mcap_out: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<u8, Error> {
    let (how, prior) = a.opts.resolve();
    let outputs: Vec<(&str, &std::path::Path)> = [("--merged", &a.merged), ("--mcap-out", &a.mcap_out)]
        .into_iter()
        .filter_map(|(n, p)| Some((n, p.as_deref()?)))
        .collect();
    cosem_host::paths::check_outputs_apart(&outputs)?;
    for (arg, out) in outputs {
        cosem_host::paths::check_output(arg, out, &[("MODEL", &a.model), ("SCENE", &a.scene)])?;
    }
    let (_, model) = cosem_host::maps::cmap::read(&a.model)?;
    let (_, scene) = cosem_host::maps::cmap::read(&a.scene)?;
    if (model.resolution() - scene.resolution()).abs() > 1e-6 {
        let (m, s) = (a.model.display(), a.scene.display());
        return Err(
            format!("resolutions differ: {} m ({m}) vs {} m ({s})", model.resolution(), scene.resolution()).into()
        );
    }
    let (model_name, scene_name) = (a.model.display().to_string(), a.scene.display().to_string());
    let m = prepare_and_align(&model, &scene, [&model_name, &scene_name], how, prior.as_ref())?;
    let (r, global, time_ms, prep_ms) = (m.result, m.global, m.match_ms, m.prepare_ms);
    if let Some(path) = &a.merged {
        ply::write_merged(path, &model, &scene, &r.transform)?;
    }
    let mut j = MatchJson::new(&r, time_ms, prep_ms);
    j.method = Some(how.settings.method.name());
    j.global = global.as_ref().map(GlobalJson::from);
    if let Some(path) = &a.mcap_out {
        cosem_host::reports::match_recording::write_match(path, &model, &scene, &r.transform, &j)?;
    }
    if a.json {
        print_json(&j)?;
        return Ok(exit_code(r.status));
    }
    print!("{}", result_text(&r, global.as_ref()));
    println!("time        {time_ms:.1} ms (preparation {prep_ms:.1} ms)");
    Ok(exit_code(r.status))
}
