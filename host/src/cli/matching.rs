//! `cosem match`: align a scene map to a model map.

use super::Error;
use cosem_core::matching::global::{locate, refine, GlobalSettings, Located};
use cosem_core::matching::landmarks::{extract, Landmark, MAX_LANDMARKS};
use cosem_core::matching::{Dof, MatchResult, MatchSettings, Matcher, Method};
use cosem_host::align::{prepare, to_matrix, DEFAULT_LEVELS};
use cosem_host::ply::{self, PlyPoint};
use cosem_host::pose;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

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
    json: bool,
    /// Write both maps in the model frame, coloured by robot, to this PLY.
    #[arg(long)]
    merged: Option<PathBuf>,
}

/// How to match: shared by `cosem match` and `cosem link`.
#[derive(clap::Args, Debug)]
pub struct MatchOpts {
    /// Start `T_model_scene` as x,y,z,roll,pitch,yaw (m, degrees); default identity.
    #[arg(long, allow_hyphen_values = true)]
    pub init: Option<String>,
    /// Association: cosem (soft semantic), cosem-hard, geometric.
    #[arg(long, default_value = "cosem")]
    pub method: String,
    /// Degrees of freedom: 6, or 4 (x, y, z, yaw).
    #[arg(long, default_value_t = 6)]
    pub dof: u8,
}

impl MatchOpts {
    /// The settings and the start.
    pub fn resolve(&self) -> Result<(MatchSettings, nalgebra::Isometry3<f32>), Error> {
        let init = match &self.init {
            Some(s) => pose::to_isometry(&pose::parse(s)?),
            None => nalgebra::Isometry3::identity(),
        };
        Ok((settings(&self.method, self.dof)?, init))
    }
}

/// Settings from the command-line names.
pub fn settings(method: &str, dof: u8) -> Result<MatchSettings, Error> {
    let method =
        Method::from_name(method).ok_or_else(|| format!("unknown method `{method}` (cosem, cosem-hard, geometric)"))?;
    let dof = match dof {
        6 => Dof::Six,
        4 => Dof::Four,
        d => return Err(format!("--dof {d}: expected 6 or 4").into()),
    };
    Ok(MatchSettings { method, dof, ..MatchSettings::default() })
}

/// The JSON form of a result (shared with eval and link).
pub fn result_json(r: &MatchResult, time_ms: f64) -> serde_json::Value {
    let m = to_matrix(&r.transform);
    let info: Vec<f32> = (0..6).flat_map(|i| (0..6).map(move |j| (i, j))).map(|(i, j)| r.information[(i, j)]).collect();
    json!({
        "status": r.status.as_str(),
        "transform": pose::to_row_major(&m),
        "xyz_rpy_deg": pose::to_xyz_rpy_deg(&m),
        "iterations": r.iterations,
        "iterations_per_level": r.iterations_per_level,
        "inliers": r.inliers,
        "overlap": r.overlap,
        "rmse": r.rmse,
        "information": info,
        "min_eigenvalue": r.min_eigenvalue,
        "degeneracy": r.degeneracy,
        "time_ms": time_ms,
    })
}

/// A map's semantic landmarks.
pub fn landmarks(map: &cosem_host::mapping::HostMap) -> Result<heapless::Vec<Landmark, MAX_LANDMARKS>, Error> {
    let mut out = heapless::Vec::new();
    extract(map, &mut vec![0u32; map.len()], &mut out)?;
    Ok(out)
}

/// Aligns two prepared maps: from `init` when `--init` was given, else by
/// global alignment from semantic landmarks first (the conventions), with
/// the core's [`locate`] and [`refine`], as the robots do.
pub fn align_maps(
    opts: &MatchOpts,
    settings: MatchSettings,
    init: &nalgebra::Isometry3<f32>,
    maps: (&cosem_host::mapping::HostMap, &cosem_host::mapping::HostMap),
    pyramids: (&cosem_host::align::HostPyramid<'_>, &cosem_host::align::HostPyramid<'_>),
) -> Result<(MatchResult, Option<Located>), Error> {
    let matcher = Matcher::new(settings);
    if opts.init.is_some() {
        return Ok((matcher.align(pyramids.0, pyramids.1, init)?, None));
    }
    let mut scratch = vec![0u32; maps.0.len().max(maps.1.len())];
    let located = locate(maps.0, maps.1, &mut scratch, &GlobalSettings::default())?;
    let r = refine(&matcher, pyramids.0, pyramids.1, located.outcome.as_ref())?;
    Ok((r, Some(located)))
}

/// The landmark alignment's figures as JSON.
pub fn global_json(g: &Located) -> serde_json::Value {
    let o = g.outcome;
    json!({
        "landmarks": g.landmarks,
        "agreeing": o.map(|o| o.agreeing),
        "runner_up": o.map(|o| o.runner_up),
        "unique": o.map(|o| o.unique),
        "start": o.map(|o| pose::to_row_major(&to_matrix(&o.transform))),
    })
}

pub fn run(a: Args) -> Result<(), Error> {
    let (settings, init) = a.opts.resolve()?;
    let (_, model) = cosem_host::cmap::read(&a.model)?;
    let (_, scene) = cosem_host::cmap::read(&a.scene)?;
    if (model.resolution() - scene.resolution()).abs() > 1e-6 {
        return Err(format!(
            "resolutions differ: {} m ({}) vs {} m ({})",
            model.resolution(),
            a.model.display(),
            scene.resolution(),
            a.scene.display()
        )
        .into());
    }
    let t_prep = Instant::now();
    let pm = prepare(&model, DEFAULT_LEVELS).map_err(|e| format!("{}: {e}", a.model.display()))?;
    let ps = prepare(&scene, DEFAULT_LEVELS).map_err(|e| format!("{}: {e}", a.scene.display()))?;
    let prep_ms = t_prep.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let (r, global) = align_maps(&a.opts, settings, &init, (&model, &scene), (&pm, &ps))?;
    let time_ms = t.elapsed().as_secs_f64() * 1e3;
    if let Some(path) = &a.merged {
        let mut pts: Vec<PlyPoint> = Vec::with_capacity(model.len() + scene.len());
        for v in model.iter() {
            let c = v.class();
            pts.push(PlyPoint {
                position: v.position(model.resolution()),
                color: [40, 110, 255],
                class: c.map(|c| c.index()).unwrap_or(255),
                label: c.map(|c| c.semantic_kitti_id()).unwrap_or(0),
            });
        }
        for v in scene.iter() {
            let c = v.class();
            pts.push(PlyPoint {
                position: cosem_core::geometry::transform_point(&r.transform, v.position(scene.resolution())),
                color: [255, 120, 30],
                class: c.map(|c| c.index()).unwrap_or(255),
                label: c.map(|c| c.semantic_kitti_id()).unwrap_or(0),
            });
        }
        ply::write(path, &pts).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    if a.json {
        let mut j = result_json(&r, time_ms);
        j["prepare_ms"] = json!(prep_ms);
        j["method"] = json!(settings.method.name());
        if let Some(g) = &global {
            j["global"] = global_json(g);
        }
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        let m = to_matrix(&r.transform);
        let x = pose::to_xyz_rpy_deg(&m);
        println!("status      {}", r.status.as_str());
        if let Some(Located { landmarks: [nm, ns], outcome }) = &global {
            match outcome {
                Some(o) => println!(
                    "global      {nm} / {ns} landmarks, {} agree (runner-up {}): {}",
                    o.agreeing,
                    o.runner_up,
                    if o.unique { "unique" } else { "not unique, no answer" }
                ),
                None => println!("global      {nm} / {ns} landmarks, too few agree: no answer"),
            }
        }
        println!("T_model_scene");
        for i in 0..4 {
            println!("  {:>12.6} {:>12.6} {:>12.6} {:>12.6}", m[(i, 0)], m[(i, 1)], m[(i, 2)], m[(i, 3)]);
        }
        println!("x,y,z,roll,pitch,yaw  {:.4},{:.4},{:.4},{:.4},{:.4},{:.4}", x[0], x[1], x[2], x[3], x[4], x[5]);
        println!(
            "iterations  {} (per level, fine to coarse: {:?})",
            r.iterations,
            &r.iterations_per_level[..DEFAULT_LEVELS]
        );
        println!("inliers     {}   overlap {:.1}%   rmse {:.4} m", r.inliers, 100.0 * r.overlap, r.rmse);
        println!("information min eigenvalue {:.4e}, normalised {:.4}", r.min_eigenvalue, r.degeneracy);
        println!("time        {time_ms:.1} ms (preparation {prep_ms:.1} ms)");
    }
    Ok(())
}
