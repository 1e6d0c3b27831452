//! One pipeline configuration: what a robot, or the host, maps and matches
//! with (voxel size, crop, pyramid levels, footprint cell, EM iterations,
//! the verdict's thresholds, the prior-free search's budget). Named presets
//! say what each place runs ([`Pipeline::HOST`], [`Pipeline::MPS2`],
//! [`Pipeline::STM32F405`], [`Pipeline::STM32F405_TEAM`]); a front end
//! (the command line, a board's capacities, the Python bindings) starts
//! from one and checks every setting it changes with the one validator,
//! [`Setting::check`] (all of them: [`Pipeline::validate`]).

use crate::map::{MapConfig, VOXEL_SIZES};
use crate::matching::search::GlobalSearch;
use crate::matching::{Alignment, MatchSettings, MAX_LEVELS};

/// What a robot (or the host) maps and matches with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pipeline {
    /// Voxel size of the map (m), in [`VOXEL_SIZES`].
    pub voxel: f32,
    /// Points farther than this from their sensor are left out (m);
    /// `None`: every point.
    pub crop: Option<f32>,
    /// Pyramid levels a map is prepared with (at least; the host adds
    /// levels until its coarsest cell reaches 3.2 m).
    pub levels: usize,
    /// First footprint cell of the coarse search (m; doubled until the
    /// grids fit).
    pub footprint_cell: f32,
    /// The matcher (EM iterations, the verdict's thresholds) and the
    /// prior-free search (its budget of nodes).
    pub alignment: Alignment,
}

impl Pipeline {
    /// The host's: the paper's 0.2 m maps, every point, five levels, 50 EM
    /// iterations, an unbounded prior-free search.
    pub const HOST: Pipeline =
        Pipeline { voxel: 0.2, crop: None, levels: 5, footprint_cell: 1.0, alignment: Alignment::DEFAULT };

    /// The mps2-an386 robot's (512 KiB): 0.5 m maps of points within 25 m,
    /// three levels, 30 EM iterations, 40,000 search nodes (see
    /// `robot::SEARCH_NODES` and `robot::EM_ITERATIONS` for why).
    pub const MPS2: Pipeline = Pipeline {
        voxel: 0.5,
        crop: Some(25.0),
        levels: 3,
        footprint_cell: 1.0,
        alignment: Alignment {
            settings: MatchSettings { max_iterations: 30, ..MatchSettings::DEFAULT },
            search: GlobalSearch { max_evaluations: 40_000, ..GlobalSearch::DEFAULT },
        },
    };

    /// The STM32F405 pair robot's (192 KiB): 0.7 m maps (3,008 voxels hold
    /// a robot's 25 m), 40 EM iterations, otherwise the mps2 robot's.
    pub const STM32F405: Pipeline = Pipeline {
        voxel: 0.7,
        alignment: Alignment {
            settings: MatchSettings { max_iterations: 40, ..MatchSettings::DEFAULT },
            ..Pipeline::MPS2.alignment
        },
        ..Pipeline::MPS2
    };

    /// The STM32F405 team robot's: 1 m maps, otherwise the STM32F405
    /// pair robot's.
    pub const STM32F405_TEAM: Pipeline = Pipeline { voxel: 1.0, ..Pipeline::STM32F405 };

    /// Every setting checked ([`Setting::check`]): the first out of range.
    pub fn validate(&self) -> Result<(), PipelineError> {
        let s = &self.alignment.settings;
        let checks = [
            (Setting::Voxel, f64::from(self.voxel)),
            (Setting::Crop, self.crop.map_or(1.0, f64::from)),
            (Setting::Levels, self.levels as f64),
            (Setting::FootprintCell, f64::from(self.footprint_cell)),
            (Setting::Iterations, f64::from(s.max_iterations)),
            (Setting::SearchNodes, f64::from(self.alignment.search.max_evaluations)),
            (Setting::MinOverlap, f64::from(s.min_overlap)),
            (Setting::MinAgreement, f64::from(s.min_agreement)),
            (Setting::Degeneracy, f64::from(s.degeneracy_threshold)),
        ];
        checks.into_iter().try_for_each(|(setting, value)| setting.check(value).map(|_| ()))
    }

    /// This pipeline with one setting changed, through the validator
    /// ([`Setting::check`]): what every front end sets a setting with.
    pub fn with(self, setting: Setting, value: f64) -> Result<Pipeline, PipelineError> {
        let v = setting.check(value)?;
        let mut p = self;
        let s = &mut p.alignment.settings;
        match setting {
            Setting::Voxel => p.voxel = v as f32,
            Setting::Crop => p.crop = Some(v as f32),
            Setting::Levels => p.levels = v as usize,
            Setting::FootprintCell => p.footprint_cell = v as f32,
            Setting::Iterations => s.max_iterations = v as u32,
            Setting::SearchNodes => p.alignment.search.max_evaluations = v as u32,
            Setting::MinOverlap => s.min_overlap = v as f32,
            Setting::MinAgreement => s.min_agreement = v as f32,
            Setting::Degeneracy => s.degeneracy_threshold = v as f32,
        }
        Ok(p)
    }

    /// The map's configuration at this voxel size (the map's other
    /// defaults).
    pub fn map_config(&self) -> MapConfig {
        MapConfig::with_resolution(self.voxel)
    }
}

/// A setting of a [`Pipeline`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Setting {
    /// Voxel size (m).
    Voxel,
    /// Crop range (m).
    Crop,
    /// Pyramid levels.
    Levels,
    /// Footprint cell (m).
    FootprintCell,
    /// EM iterations.
    Iterations,
    /// Prior-free search nodes.
    SearchNodes,
    /// The verdict's least overlap.
    MinOverlap,
    /// The verdict's least agreement.
    MinAgreement,
    /// The verdict's degeneracy threshold.
    Degeneracy,
}

impl Setting {
    /// What the setting is called in messages.
    pub fn name(self) -> &'static str {
        match self {
            Setting::Voxel => "voxel size",
            Setting::Crop => "crop range",
            Setting::Levels => "pyramid levels",
            Setting::FootprintCell => "footprint cell",
            Setting::Iterations => "EM iterations",
            Setting::SearchNodes => "search nodes",
            Setting::MinOverlap => "least overlap",
            Setting::MinAgreement => "least agreement",
            Setting::Degeneracy => "degeneracy threshold",
        }
    }

    /// The setting's range, lowest and highest (both allowed).
    pub fn range(self) -> (f64, f64) {
        match self {
            Setting::Voxel => (f64::from(*VOXEL_SIZES.start()), f64::from(*VOXEL_SIZES.end())),
            // Beyond 10 km no LiDAR sees; a key range holds 6.5 km at 0.2 m.
            Setting::Crop => (1e-3, 1e4),
            Setting::Levels => (1.0, MAX_LEVELS as f64),
            Setting::FootprintCell => (0.1, 100.0),
            Setting::Iterations => (1.0, 10_000.0),
            Setting::SearchNodes => (1.0, f64::from(u32::MAX)),
            Setting::MinOverlap | Setting::MinAgreement | Setting::Degeneracy => (0.0, 1.0),
        }
    }

    /// The one validator: `value` if it is a finite number in the
    /// setting's range (whole for counts), else an error naming the setting
    /// and the value.
    pub fn check(self, value: f64) -> Result<f64, PipelineError> {
        let (lo, hi) = self.range();
        let whole = !matches!(self, Setting::Levels | Setting::Iterations | Setting::SearchNodes)
            || libm::trunc(value) == value;
        if value.is_finite() && (lo..=hi).contains(&value) && whole {
            Ok(value)
        } else {
            Err(PipelineError { setting: self, value })
        }
    }
}

/// A setting out of its range: which, and the value given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PipelineError {
    /// The setting.
    pub setting: Setting,
    /// The value given.
    pub value: f64,
}

impl core::fmt::Display for PipelineError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        // Whole numbers as such, the rest as the f32 they are set as.
        let number = |f: &mut core::fmt::Formatter<'_>, v: f64| {
            if v.is_finite() && libm::trunc(v) == v && libm::fabs(v) < 1e15 {
                write!(f, "{}", v as i64)
            } else {
                write!(f, "{}", v as f32)
            }
        };
        let (lo, hi) = self.setting.range();
        write!(f, "{} ", self.setting.name())?;
        number(f, self.value)?;
        f.write_str(": expected ")?;
        number(f, lo)?;
        f.write_str(" to ")?;
        number(f, hi)?;
        if self.setting == Setting::Voxel {
            f.write_str(" m (a robot's map)")?;
        }
        Ok(())
    }
}

impl core::error::Error for PipelineError {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_is_valid() {
        for p in [Pipeline::HOST, Pipeline::MPS2, Pipeline::STM32F405, Pipeline::STM32F405_TEAM] {
            assert_eq!(p.validate(), Ok(()), "{p:?}");
        }
        assert_eq!(Pipeline::HOST.alignment, Alignment::default());
    }

    #[test]
    fn the_validator_names_the_setting_and_the_value() {
        let bad = Pipeline { voxel: 0.01, ..Pipeline::HOST };
        let e = bad.validate().unwrap_err();
        assert_eq!(e, PipelineError { setting: Setting::Voxel, value: f64::from(0.01f32) });
        assert_eq!(Setting::Levels.check(2.5), Err(PipelineError { setting: Setting::Levels, value: 2.5 }));
        assert!(Setting::Crop.check(f64::NAN).is_err() && Setting::Crop.check(1e308).is_err());
        assert_eq!(Setting::Crop.check(25.0), Ok(25.0));
        let p = Pipeline::HOST.with(Setting::MinAgreement, 0.5).unwrap();
        assert_eq!(p.alignment.settings.min_agreement, 0.5);
        assert_eq!(Pipeline::HOST.with(Setting::SearchNodes, 0.0).unwrap_err().setting, Setting::SearchNodes);
        assert_eq!(Pipeline::HOST.with(Setting::Iterations, 7.0).unwrap().alignment.settings.max_iterations, 7);
        let mut s = alloc::string::String::new();
        core::fmt::write(&mut s, format_args!("{}", PipelineError { setting: Setting::Voxel, value: 11.0 })).unwrap();
        assert_eq!(s, "voxel size 11: expected 0.02 to 10 m (a robot's map)");
    }
}
