//! Argument types shared by the subcommands: parsed by clap into typed
//! values, never matched as strings later.

use cosem_core::geometry::{parse_pose, Isometry3};
use cosem_core::matching::{Alignment, Dof, MatchSettings, Method};

/// An association method by its name (`--method`): cosem, cosem-hard or
/// geometric.
pub fn method(s: &str) -> Result<Method, String> {
    Method::from_name(s).ok_or_else(|| format!("`{s}`: expected cosem, cosem-hard or geometric"))
}

/// Degrees of freedom (`--dof`): 6, or 4 (x, y, z, yaw: level anchor frames).
pub fn dof(s: &str) -> Result<Dof, String> {
    s.parse().ok().and_then(Dof::from_count).ok_or_else(|| format!("`{s}`: expected 6 or 4"))
}

/// Match settings of a method and degrees of freedom.
pub fn settings(method: Method, dof: Dof) -> MatchSettings {
    MatchSettings { method, dof, ..MatchSettings::default() }
}

/// Parses the conventions' pose `x,y,z,roll,pitch,yaw` (m, degrees).
pub fn pose(s: &str) -> Result<Isometry3<f64>, String> {
    parse_pose(s).map_err(|e| format!("pose `{s}`: {e}"))
}

/// How to match: shared by `cosem match` and `cosem link`.
#[derive(clap::Args, Debug)]
pub struct MatchOpts {
    /// Start `T_model_scene` as x,y,z,roll,pitch,yaw (m, degrees); default:
    /// none (prior-free alignment).
    #[arg(long, allow_hyphen_values = true, value_parser = pose)]
    pub init: Option<Isometry3<f64>>,
    /// Association method: cosem, cosem-hard (the paper's hard label
    /// rejection) or geometric (labels ignored).
    #[arg(long, default_value = "cosem", value_parser = method)]
    pub method: Method,
    /// Degrees of freedom: 6, or 4 (x, y, z, yaw).
    #[arg(long, default_value = "6", value_parser = dof)]
    pub dof: Dof,
    /// EM iterations, the verdict's thresholds, the search's budget.
    #[command(flatten)]
    pub tuning: Tuning,
}

impl MatchOpts {
    /// The alignment and the prior (in the matcher's precision).
    pub fn resolve(&self) -> (Alignment, Option<Isometry3<f32>>) {
        let how = self.tuning.apply(HOST.alignment);
        let how = Alignment { settings: MatchSettings { method: self.method, dof: self.dof, ..how.settings }, ..how };
        (how, self.init.map(|p| p.cast::<f32>()))
    }
}

/// The matcher's numbers, each through the pipeline's one validator
/// ([`cosem_core::pipeline::Setting`]); unset: the host pipeline's.
#[derive(clap::Args, Debug, Clone, Copy, Default)]
pub struct Tuning {
    /// EM iterations at most (default 50; `cosem session`: 80).
    #[arg(long, value_parser = em_iterations)]
    pub em_iterations: Option<u32>,
    /// The verdict's least overlap: the share of the smaller map's voxels
    /// with a match (default 0.2; `cosem session`: 0.25).
    #[arg(long, value_parser = min_overlap)]
    pub min_overlap: Option<f32>,
    /// The verdict's least agreement of what both maps saw (default 0.40):
    /// to measure other operating points.
    #[arg(long, value_parser = min_agreement)]
    pub min_agreement: Option<f32>,
    /// The prior-free search's budget of nodes (default: unbounded;
    /// `cosem session`: 60,000).
    #[arg(long, value_parser = search_nodes)]
    pub search_nodes: Option<u32>,
}

impl Tuning {
    /// `base` with what was set (each value already through the
    /// validator, set by the pipeline's one setter).
    pub fn apply(&self, base: Alignment) -> Alignment {
        use cosem_core::pipeline::Setting;
        let set = [
            (Setting::Iterations, self.em_iterations.map(f64::from)),
            (Setting::MinOverlap, self.min_overlap.map(f64::from)),
            (Setting::MinAgreement, self.min_agreement.map(f64::from)),
            (Setting::SearchNodes, self.search_nodes.map(f64::from)),
        ];
        let pipeline = cosem_core::pipeline::Pipeline { alignment: base, ..HOST };
        set.into_iter()
            .filter_map(|(s, v)| Some((s, v?)))
            .fold(pipeline, |p, (s, v)| p.with(s, v).unwrap_or(p))
            .alignment
    }
}

/// `--em-iterations`, through the validator.
fn em_iterations(s: &str) -> Result<u32, String> {
    setting(cosem_core::pipeline::Setting::Iterations, s).map(|v| v as u32)
}

/// `--min-overlap`, through the validator.
fn min_overlap(s: &str) -> Result<f32, String> {
    setting(cosem_core::pipeline::Setting::MinOverlap, s).map(|v| v as f32)
}

/// `--min-agreement`, through the validator.
fn min_agreement(s: &str) -> Result<f32, String> {
    setting(cosem_core::pipeline::Setting::MinAgreement, s).map(|v| v as f32)
}

/// `--search-nodes`, through the validator.
fn search_nodes(s: &str) -> Result<u32, String> {
    setting(cosem_core::pipeline::Setting::SearchNodes, s).map(|v| v as u32)
}

/// A positive finite number (m, s, ...).
pub fn positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("`{s}`: expected a positive number")),
    }
}

/// A finite number, zero or more (m, s, ...).
pub fn non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!("`{s}`: expected a number, zero or more")),
    }
}

/// A baud rate: a positive whole number of bits a second.
pub fn baud(s: &str) -> Result<u32, String> {
    match s.parse::<u32>() {
        Ok(v) if v > 0 => Ok(v),
        _ => Err(format!("`{s}`: expected a baud rate, a positive whole number (e.g. 115200)")),
    }
}

/// The host's pipeline: the defaults of the commands that map on the host.
pub const HOST: cosem_core::pipeline::Pipeline = cosem_core::pipeline::Pipeline::HOST;
/// A robot's pipeline (mps2-an386): the defaults of what robots are fed.
pub const ROBOT: cosem_core::pipeline::Pipeline = cosem_core::pipeline::Pipeline::MPS2;
/// A robot's crop (m): what it is fed of each scan.
pub const ROBOT_CROP: f32 = match ROBOT.crop {
    Some(c) => c,
    None => f32::INFINITY,
};

/// `--voxel`: a voxel size of a robot's map, checked by the pipeline's one
/// validator ([`cosem_core::pipeline::Setting::Voxel`]): what every
/// command maps, sends, feeds and matches alike.
pub fn voxel(s: &str) -> Result<f32, String> {
    setting(cosem_core::pipeline::Setting::Voxel, s).map(|v| v as f32)
}

/// `--crop` / `--max-range`: how far from its sensor a point is kept (m),
/// checked by the pipeline's validator ([`cosem_core::pipeline::Setting::Crop`]).
pub fn crop(s: &str) -> Result<f32, String> {
    setting(cosem_core::pipeline::Setting::Crop, s).map(|v| v as f32)
}

/// A pipeline setting from the command line, through the one validator.
fn setting(which: cosem_core::pipeline::Setting, s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("`{s}`: expected a number ({})", which.name()))?;
    // As the setting is kept (f32 where it is one).
    let v = if matches!(which, cosem_core::pipeline::Setting::Voxel | cosem_core::pipeline::Setting::Crop) {
        f64::from(v as f32)
    } else {
        v
    };
    which.check(v).map_err(|e| e.to_string())
}

/// Segmentation images to render, or none (a type alias: clap takes it as
/// one value, not as an optional argument).
pub type SegChoice = Option<cosem_core::camera::SegClasses>;

/// `--seg`: cityscapes, semantickitti or none.
pub fn seg(s: &str) -> Result<SegChoice, String> {
    use cosem_core::camera::SegClasses;
    match s {
        "cityscapes" => Ok(Some(SegClasses::Cityscapes)),
        "semantickitti" => Ok(Some(SegClasses::SemanticKitti)),
        "none" => Ok(None),
        _ => Err(format!("`{s}`: expected cityscapes, semantickitti or none")),
    }
}

/// `--fit`: squash, tile or tile:SCALE.
pub fn fit(s: &str) -> Result<cosem_host::camera::seg_files::Fit, String> {
    s.parse()
}

/// A library enum read by name: its `NAMES` for clap's help and checks,
/// its `FromStr` (the one parser the Python bindings use too).
pub trait Named: std::str::FromStr<Err = String> + Clone + Send + Sync + 'static {
    /// The names.
    const NAMES: &'static [&'static str];
}

impl Named for cosem_host::maps::mapping::Unlabeled {
    const NAMES: &'static [&'static str] = Self::NAMES;
}
impl Named for cosem_host::sources::cloud::CloudFormat {
    const NAMES: &'static [&'static str] = Self::NAMES;
}
impl Named for cosem_host::sources::recording::ChunkCompression {
    const NAMES: &'static [&'static str] = Self::NAMES;
}
impl Named for cosem_host::camera::seg_files::VoidChannel {
    const NAMES: &'static [&'static str] = Self::NAMES;
}

/// The value parser of a [`Named`] enum.
pub fn named<T: Named>() -> impl clap::builder::TypedValueParser<Value = T> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(T::NAMES).try_map(|s| s.parse::<T>())
}

/// A whole number of at least `N`.
pub fn at_least<const N: usize>(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(v) if v >= N => Ok(v),
        _ => Err(format!("`{s}`: expected a whole number of at least {N}")),
    }
}

/// A thread count (`--threads`): 1 to 4 x the machine's cores.
pub fn threads(s: &str) -> Result<usize, String> {
    let n = s.parse::<usize>().map_err(|_| format!("`{s}`: expected a whole number of threads"))?;
    cosem_host::limits::threads("--threads", n)
}

/// `--max-pixels`: a whole number of at least 1.
pub fn max_pixels(s: &str) -> Result<u64, String> {
    match s.parse::<u64>() {
        Ok(v) if v >= 1 => Ok(v),
        _ => Err(format!("`{s}`: expected a whole number of pixels, at least 1")),
    }
}

/// A number of frames to synthesise: 1 to 100,000.
pub fn frames_count(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(v) if (1..=100_000).contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: expected a whole number of frames from 1 to 100000")),
    }
}

/// A finite number from `LO` to `HI`.
pub fn within<const LO: i64, const HI: i64>(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= LO as f64 && v <= HI as f64 => Ok(v),
        _ => Err(format!("`{s}`: expected a number from {LO} to {HI}")),
    }
}

/// Repetitions of a benchmark: 1 to 1,000.
pub fn repeat(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(v) if (1..=1000).contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: expected a whole number of repetitions from 1 to 1000")),
    }
}

/// A time in seconds: positive, at most a day (86,400 s).
pub fn seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 86_400.0 => Ok(v),
        _ => Err(format!("`{s}`: expected a positive number of seconds, at most 86400 (a day)")),
    }
}

/// A label accuracy: a probability in (1/19, 1).
pub fn accuracy(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if v > 1.0 / 19.0 && v < 1.0 => Ok(v),
        _ => Err(format!("`{s}`: expected a probability in (1/19, 1)")),
    }
}

/// A probability in [0, 1].
pub fn probability(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: expected a probability in [0, 1]")),
    }
}

/// How scans are read from a recording or a user's files (`--data` may
/// name a SemanticKITTI folder, a `.mcap` recording or a folder of PCD/PLY
/// scans with poses.txt): shared by every command that reads scans.
#[derive(clap::Args, Debug, Clone)]
pub struct SourceArgs {
    /// With a recording (.mcap): the point cloud topic.
    #[arg(long, default_value = "/velodyne_points")]
    pub points: String,
    /// With a recording or PCD/PLY scans: the label field's name.
    #[arg(long, default_value = "label")]
    pub label_field: String,
    /// With a recording: the frame the scans' poses are chained from.
    #[arg(long, default_value = "world")]
    pub pose_frame: String,
    /// With a recording: an odometry topic (nav_msgs/msg/Odometry) whose
    /// poses join /tf and /tf_static.
    #[arg(long)]
    pub odom: Option<String>,
    /// A class table (TOML) mapping the scans' label ids to classes.
    #[arg(long)]
    pub classes: Option<std::path::PathBuf>,
    /// With a recording: one cut short (no footer) is an error; without,
    /// it is read up to its last whole record, with a warning.
    #[arg(long)]
    pub strict: bool,
}

impl SourceArgs {
    /// The library's options.
    pub fn options(&self) -> cosem_host::sources::source::SourceOptions {
        cosem_host::sources::source::SourceOptions {
            points: self.points.clone(),
            label_field: self.label_field.clone(),
            pose_frame: self.pose_frame.clone(),
            odom: self.odom.clone(),
            classes: self.classes.clone(),
            strict: self.strict,
        }
    }
}

/// How the command line spells each of the library's knobs: its flags
/// (installed once by `main`, so the library's messages name them).
pub fn flag(k: cosem_host::knobs::Knob) -> &'static str {
    use cosem_host::knobs::Knob;
    match k {
        Knob::Classes => "--classes",
        Knob::MaxRange => "--max-range",
        Knob::KeepMoving => "--keep-moving",
        Knob::MaxPixels => "--max-pixels",
        Knob::Strict => "--strict",
        Knob::ImageSize => "--image-size",
        Knob::Frames => "--frames",
        Knob::Model => "--model",
        Knob::Images => "--images",
        Knob::Seg => "--seg",
        Knob::Data => "--data",
        Knob::Out => "--out",
        Knob::Output => "--output",
        Knob::CheckDir => "--check-dir",
        Knob::Force => "--force",
        Knob::NoPrior => "--no-prior",
        Knob::InjectFalseMatch => "--inject-false-match",
        Knob::OnBoard => "--on-board",
        Knob::BoardA => "--board-a",
        Knob::BoardB => "--board-b",
        Knob::File => "FILE",
        Knob::VoidChannel => "--void-channel",
        Knob::ScaleToImages => "--scale-to-images",
        Knob::Domain => "--domain",
        Knob::Rate => "--rate",
        Knob::Speed => "--speed",
        Knob::WaitReaders => "--wait-readers",
    }
}

#[cfg(test)]
mod tests {
    use cosem_host::knobs::Knob;

    /// Every knob's flag is one the command line has (a long option, or a
    /// positional's value name), so no message points to a flag that is not.
    #[test]
    fn every_knob_is_a_flag_of_some_command() {
        use clap::CommandFactory;
        fn names(c: &clap::Command, out: &mut Vec<String>) {
            for a in c.get_arguments() {
                out.extend(a.get_long().map(|l| format!("--{l}")));
                out.extend(a.get_value_names().into_iter().flatten().map(|v| v.to_string()));
            }
            c.get_subcommands().for_each(|s| names(s, out));
        }
        let mut all = Vec::new();
        names(&super::super::Cli::command(), &mut all);
        for k in Knob::ALL {
            assert!(all.iter().any(|n| n == super::flag(k)), "{k:?}: {} is no flag of cosem", super::flag(k));
        }
    }
}
