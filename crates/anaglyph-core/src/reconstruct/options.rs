//! What a user asks of reconstruction, as the CLI's options and the Python package's
//! keyword arguments give it ([`ReconstructOptions`]), and the one conversion of it into
//! [`PipelineSettings`], validated once, before any work. Both front ends fill the same
//! struct and call the same conversion, so that they run the same pipeline.

use super::settings::{
    Disparities, DisparitySearch, PipelineSettings, Preset, DEFAULT_SATURATION_LEVEL,
    DEFAULT_WHITE_REFLECTANCE,
};
use super::Products;
use crate::demux::Solver;
use crate::io::StoreLayout;
use crate::refine::GuidedRefinement;
use crate::register::{
    CoarseToFine, MatchingImage, RegistrationMode, WarpKernel, DEFAULT_REGISTRATION,
};
use crate::rig::Rig;
use crate::solve::{ScenePriorSettings, SolveSettings};
use crate::stereo::{MatchMethod, MatchingCost, MatchingNetwork};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// The solve's tuning over a preset: each option set overrides the preset's value, a
/// stage's option switches the stage on, and 0 switches it off where noted.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SolveTuning {
    /// See [`SolveSettings::disputed_tolerance`]; 0: off.
    pub disputed_tolerance: Option<f64>,
    /// See [`SolveSettings::inconsistency_factor`]; 0: off.
    pub scene_prior_inconsistency: Option<f64>,
    /// No scene prior (and no inconsistent-pixel stage, whose pixels it estimates).
    pub no_scene_prior: bool,
    /// See [`ScenePriorSettings::noise_scale`].
    pub scene_prior_noise: Option<f64>,
    /// See [`ScenePriorSettings::clusters`].
    pub scene_prior_clusters: Option<usize>,
    /// See [`ScenePriorSettings::propagation_rounds`].
    pub scene_prior_rounds: Option<usize>,
    /// No guided refinement.
    pub no_refine: bool,
    /// See [`GuidedRefinement::radius`].
    pub refine_radius: Option<usize>,
    /// See [`GuidedRefinement::epsilon`].
    pub refine_epsilon: Option<f64>,
    /// See [`GuidedRefinement::confidence_scale`]; 0: equal weights.
    pub refine_confidence: Option<f64>,
}

impl SolveTuning {
    /// Tuning from a JSON object of the fields above (`{"no_refine": true}`); an unknown
    /// field is an error naming the fields.
    pub fn from_json(text: &str) -> Result<Self> {
        serde_json::from_str(text).map_err(|e| Error::Parse {
            context: "tuning".into(),
            line: e.line(),
            message: e.to_string(),
        })
    }

    /// `preset`'s solve with this tuning applied.
    pub fn apply(&self, preset: SolveSettings) -> SolveSettings {
        let mut solve = preset;
        if let Some(t) = self.disputed_tolerance {
            solve.disputed_tolerance = (t > 0.0).then_some(t);
        }
        let prior_asked = self.scene_prior_noise.is_some()
            || self.scene_prior_clusters.is_some()
            || self.scene_prior_rounds.is_some();
        if prior_asked && solve.scene_prior.is_none() {
            solve.scene_prior = Some(ScenePriorSettings::default());
        }
        if let Some(prior) = &mut solve.scene_prior {
            prior.noise_scale = self.scene_prior_noise.unwrap_or(prior.noise_scale);
            prior.clusters = self.scene_prior_clusters.unwrap_or(prior.clusters);
            prior.propagation_rounds = self.scene_prior_rounds.unwrap_or(prior.propagation_rounds);
        }
        if let Some(k) = self.scene_prior_inconsistency {
            solve.inconsistency_factor = (k > 0.0).then_some(k);
        }
        if self.no_scene_prior {
            solve.scene_prior = None;
            solve.inconsistency_factor = None;
        }
        let refine_asked = self.refine_radius.is_some()
            || self.refine_epsilon.is_some()
            || self.refine_confidence.is_some();
        if refine_asked && solve.refinement.is_none() {
            solve.refinement = Some(GuidedRefinement::default());
        }
        if let Some(refinement) = &mut solve.refinement {
            refinement.radius = self.refine_radius.unwrap_or(refinement.radius);
            refinement.epsilon = self.refine_epsilon.unwrap_or(refinement.epsilon);
            if let Some(scale) = self.refine_confidence {
                refinement.confidence_scale = (scale > 0.0).then_some(scale);
            }
        }
        if self.no_refine {
            solve.refinement = None;
        }
        solve
    }
}

/// Everything a user can ask of `reconstruct`, by the CLI's names.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReconstructOptions {
    pub preset: Preset,
    pub registration: RegistrationMode,
    pub method: MatchMethod,
    /// Weights of the learned method (None: the built-in fast network).
    pub model: Option<PathBuf>,
    /// The disparities searched, per column step of the array.
    pub disp_range: DisparitySearch,
    pub output: Products,
    /// Views to reconstruct, by camera name; None: every view.
    pub views: Option<Vec<String>>,
    pub white_reflectance: f64,
    /// Capture values at or above this fraction of full scale are saturated.
    pub saturation: f32,
    pub solver: Solver,
    /// None: the preset's.
    pub matching_image: Option<MatchingImage>,
    /// None: the preset's.
    pub warp_kernel: Option<WarpKernel>,
    pub coarse_to_fine: CoarseToFine,
    pub tuning: SolveTuning,
    /// In a sequence, each frame starts from what the previous one learned where that is
    /// sound ([`super::reconstruct_next`]); false: every frame is reconstructed alone.
    pub temporal_reuse: bool,
}

impl Default for ReconstructOptions {
    fn default() -> Self {
        ReconstructOptions {
            preset: Preset::Default,
            registration: DEFAULT_REGISTRATION,
            method: MatchMethod::Mccnn,
            model: None,
            disp_range: DisparitySearch::Auto,
            output: Products::Cubes,
            views: None,
            white_reflectance: DEFAULT_WHITE_REFLECTANCE,
            saturation: DEFAULT_SATURATION_LEVEL,
            solver: Solver::Exact,
            matching_image: None,
            warp_kernel: None,
            coarse_to_fine: CoarseToFine::default(),
            tuning: SolveTuning::default(),
            temporal_reuse: true,
        }
    }
}

impl ReconstructOptions {
    /// The network the matching method needs (None for the classical costs); the settings
    /// borrow it.
    pub fn network(&self) -> Result<Option<MatchingNetwork>> {
        self.method.network(self.model.as_deref())
    }

    /// The pipeline's settings: the preset's, with every option applied over them,
    /// validated. `network` is what [`ReconstructOptions::network`] gave.
    pub fn settings<'a>(
        &self,
        network: Option<&'a MatchingNetwork>,
    ) -> Result<PipelineSettings<'a>> {
        self.settings_with_cost(self.method.cost(network)?)
    }

    /// Checks every option before any work, without loading the network (the cost plays
    /// no part in the checks).
    pub fn validate(&self) -> Result<()> {
        self.settings_with_cost(MatchingCost::Census).map(|_| ())
    }

    fn settings_with_cost<'a>(&self, cost: MatchingCost<'a>) -> Result<PipelineSettings<'a>> {
        let mut settings = PipelineSettings::with_preset(cost, self.preset);
        settings.registration = self.registration;
        settings.disparities = Disparities::Search(self.disp_range);
        settings.keep_registered = self.output.registered();
        settings.spectra = self.output.cubes();
        settings.white_reflectance = self.white_reflectance;
        settings.saturation_level = self.saturation;
        settings.demux.solver = self.solver;
        settings.views = self.views.clone();
        if let Some(image) = self.matching_image {
            settings.matching_image = image;
        }
        if let Some(kernel) = self.warp_kernel {
            settings.warp_kernel = kernel;
        }
        settings.coarse_to_fine = self.coarse_to_fine;
        settings.solve = self.tuning.apply(settings.solve);
        settings.validate()?;
        Ok(settings)
    }
}

impl ReconstructOptions {
    /// The layout of a Zarr store of this run's `frames` at `width × height`: the views
    /// asked for (in the rig's order), the rig's bands and channels as the products need
    /// them, and as the run the rig and the recorded settings (a reopened store must match).
    pub fn store_layout(
        &self,
        settings: &PipelineSettings<'_>,
        rig: &Rig,
        frames: Vec<i64>,
        (width, height): (usize, usize),
    ) -> Result<StoreLayout> {
        let views = rig
            .cameras
            .iter()
            .map(|c| c.name.clone())
            .filter(|name| self.views.as_ref().is_none_or(|v| v.contains(name)))
            .collect();
        let wavelengths = match self.output.cubes() {
            true => rig.reconstruction_shape()?.wavelengths(),
            false => Vec::new(),
        };
        let channels = match self.output.registered() {
            true => crate::rig::SensingMatrix::of_rig(rig)?.row_labels,
            false => Vec::new(),
        };
        Ok(StoreLayout {
            frames,
            views,
            width,
            height,
            wavelengths,
            channels,
            run: serde_json::json!({
                "rig": rig.file.to_toml_string()?,
                "parameters": self.record(settings, rig),
            }),
        })
    }

    /// The options and what they resolved to in `settings`, as a run's manifest records
    /// them (`parameters`; the front end adds its inputs).
    pub fn record(&self, settings: &PipelineSettings<'_>, rig: &Rig) -> serde_json::Value {
        use crate::choice::Choice;
        serde_json::json!({
            "preset": self.preset.name(),
            "output": self.output.name(),
            "registration": match settings.disparities {
                Disparities::Given(_) => "true disparities",
                Disparities::Search(_) => settings.registration.name(),
            },
            "matching_image": settings.matching_image.name(),
            "coarse_to_fine": settings.coarse_to_fine.name(),
            "method": self.method.name(),
            "model": self.model.as_ref().map(|p| p.display().to_string()),
            "disp_range": self.disp_range,
            "views": self.views,
            "white_reflectance": self.white_reflectance,
            "saturation": self.saturation,
            "solver": self.solver.name(),
            "lambda": rig.file.reconstruction.lambda,
            "refinement": settings.solve.refinement,
            "scene_prior": settings.solve.scene_prior,
            "disputed_tolerance": settings.solve.disputed_tolerance,
            "inconsistency_factor": settings.solve.inconsistency_factor,
            "warp_kernel": settings.warp_kernel.name(),
            "temporal_reuse": self.temporal_reuse,
            "out_of_band": rig.file.reconstruction.out_of_band,
            "rig_name": rig.file.name,
            "cameras": rig
                .cameras
                .iter()
                .map(|c| {
                    serde_json::json!({"name": c.name, "filter": c.filter.as_ref().map(|f| f.name())})
                })
                .collect::<Vec<_>>(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::disparity::DisparityRange;

    fn settings(options: &ReconstructOptions) -> PipelineSettings<'static> {
        assert!(!options.method.is_learned());
        options.settings(None).unwrap()
    }

    fn census() -> ReconstructOptions {
        ReconstructOptions {
            method: MatchMethod::Census,
            ..ReconstructOptions::default()
        }
    }

    #[test]
    fn presets_choose_the_stages_and_options_override_them() {
        let default = settings(&census());
        assert_eq!(default.solve, SolveSettings::default());
        assert_eq!(default.warp_kernel, WarpKernel::Lanczos3);
        assert!(matches!(default.cost, MatchingCost::Census));
        assert!(matches!(
            default.disparities,
            Disparities::Search(DisparitySearch::Auto)
        ));

        let paper = settings(&ReconstructOptions {
            preset: Preset::Paper,
            ..census()
        });
        assert_eq!(paper.solve, SolveSettings::paper());
        assert_eq!(paper.warp_kernel, WarpKernel::Bilinear);

        let fast = settings(&ReconstructOptions {
            preset: Preset::Fast,
            ..census()
        });
        let prior = fast.solve.scene_prior.unwrap();
        assert_eq!((prior.clusters, prior.propagation_rounds), (8, 0));

        // A stage's option switches it on over a preset without it.
        let mut refined = ReconstructOptions {
            preset: Preset::Paper,
            ..census()
        };
        refined.tuning.refine_radius = Some(3);
        let refined = settings(&refined);
        assert_eq!(refined.solve.refinement.unwrap().radius, 3);
        assert!(refined.solve.scene_prior.is_none());

        // No scene prior also switches off the stage that hands its pixels to the prior.
        let mut no_prior = census();
        no_prior.tuning.no_scene_prior = true;
        no_prior.disp_range = DisparitySearch::Fixed(DisparityRange { min: -24, max: 8 });
        let no_prior = settings(&no_prior);
        assert!(no_prior.solve.scene_prior.is_none());
        assert!(no_prior.solve.inconsistency_factor.is_none());
        assert!(matches!(
            no_prior.disparities,
            Disparities::Search(DisparitySearch::Fixed(DisparityRange { min: -24, max: 8 }))
        ));

        let mut off = census();
        off.tuning.disputed_tolerance = Some(0.0);
        off.tuning.refine_confidence = Some(0.0);
        let off = settings(&off);
        assert!(off.solve.disputed_tolerance.is_none());
        assert!(off.solve.refinement.unwrap().confidence_scale.is_none());
    }

    #[test]
    fn tuning_reads_json_and_names_unknown_fields() {
        let tuning = SolveTuning::from_json(r#"{"no_refine": true, "refine_radius": 3}"#).unwrap();
        assert!(tuning.no_refine);
        assert_eq!(tuning.refine_radius, Some(3));
        let error = SolveTuning::from_json(r#"{"refine_radios": 3}"#).unwrap_err();
        assert!(error.to_string().contains("refine_radios"), "{error}");
        assert!(error.to_string().contains("refine_radius"), "{error}");
    }

    #[test]
    fn bad_values_are_refused_by_the_conversion() {
        let bad_white = ReconstructOptions {
            white_reflectance: 1.5,
            ..census()
        };
        assert_eq!(bad_white.settings(None).unwrap_err().kind(), "OutOfRange");
        let reversed = ReconstructOptions {
            disp_range: DisparitySearch::Fixed(DisparityRange { min: 8, max: 8 }),
            ..census()
        };
        assert!(reversed.settings(None).is_err());
        assert!(reversed.validate().is_err());
        // A learned method without its network.
        assert!(ReconstructOptions::default().settings(None).is_err());
    }
}
