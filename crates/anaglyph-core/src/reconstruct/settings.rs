//! What reconstruction can be told, as plain data that is checked once, before any work
//! ([`PipelineSettings::validate`]).

use crate::demux::DemuxOptions;
use crate::disparity::{DisparityMap, DisparityRange};
use crate::register::{
    CoarseToFine, MatchingImage, RegistrationMode, RegistrationSettings, WarpKernel,
    DEFAULT_REGISTRATION,
};
use crate::solve::{ScenePriorSettings, SolveSettings};
use crate::stereo::MatchingCost;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, Ordering};

/// The default search range, per column step, when none is given or estimated.
pub const DEFAULT_MAX_DISP: i32 = 64;
/// The default reflectance of the white board.
pub const DEFAULT_WHITE_REFLECTANCE: f64 = 0.95;
/// The default saturation level, as a fraction of full scale.
pub const DEFAULT_SATURATION_LEVEL: f32 = 0.999;

/// Scene prior clusters of [`Preset::Fast`]. Measured with `reconstruct --preset` on
/// the three presets at 320×240 (Intel Xeon with AVX-512 BF16, 2 cores): fast takes
/// 6.6–6.9 s against 7.4–8.4 s, r0c0 PSNR 0.0–0.7 dB lower, all views 0.1–0.5 dB lower.
/// The bilinear warp saves 0.3 s for 0.2–0.65 dB and luminance matching loses the periodic
/// scene (16.6 against 29.4 dB), so neither is part of it.
pub const FAST_PRIOR_CLUSTERS: usize = 8;

/// A named choice of stages and tuning (`reconstruct --preset`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// Every stage on, with the measured defaults.
    #[default]
    Default,
    /// The default with a lighter scene prior ([`FAST_PRIOR_CLUSTERS`] clusters, no
    /// propagation rounds): its stage is the longest of a view's solve.
    Fast,
    /// The paper's pipeline: Eq. 6 alone on bilinearly warped measurements, the source
    /// cameras' maps deciding visibility; no prior, no refinement.
    Paper,
}

crate::choice::named_choices!(Preset, "preset" {
    Default = "default" "Every stage on, with the measured defaults.",
    Fast = "fast" "The default with a lighter scene prior.",
    Paper = "paper" "The paper's pipeline after registration: Eq. 6 on bilinearly warped measurements; no prior, no refinement.",
});

impl Preset {
    /// The stages of each view's solve.
    pub fn solve(self) -> SolveSettings {
        match self {
            Preset::Default => SolveSettings::default(),
            Preset::Fast => SolveSettings {
                scene_prior: Some(ScenePriorSettings {
                    clusters: FAST_PRIOR_CLUSTERS,
                    propagation_rounds: 0,
                    ..ScenePriorSettings::default()
                }),
                ..SolveSettings::default()
            },
            Preset::Paper => SolveSettings::paper(),
        }
    }

    /// How the warp reads the cameras.
    pub fn warp_kernel(self) -> WarpKernel {
        match self {
            Preset::Default | Preset::Fast => WarpKernel::Lanczos3,
            Preset::Paper => WarpKernel::Bilinear,
        }
    }

    /// What multi-baseline registration compares the views by: the common signals in
    /// every preset (luminance, the paper's input, loses the periodic preset's grating).
    pub fn matching_image(self) -> MatchingImage {
        MatchingImage::CommonSignals
    }
}

/// The disparities registration searches, per column step of the array.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DisparitySearch {
    /// Chosen from the captures ([`crate::register::estimate_search_range`]).
    #[default]
    Auto,
    Fixed(DisparityRange),
}

impl Serialize for DisparitySearch {
    /// `"auto"` or `{"min": .., "max": ..}`, as manifests record it.
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            DisparitySearch::Auto => s.serialize_str("auto"),
            DisparitySearch::Fixed(range) => range.serialize(s),
        }
    }
}

/// Where every view's disparity map comes from.
#[derive(Debug, Clone)]
pub enum Disparities {
    /// Registration of the captures.
    Search(DisparitySearch),
    /// Maps to use instead of registration (one per camera, rig order, per column step),
    /// e.g. the simulator's truth to measure what registration costs.
    Given(Vec<DisparityMap>),
}

/// Everything reconstruction can be told.
#[derive(Debug, Clone)]
pub struct PipelineSettings<'a> {
    /// How views are registered.
    pub registration: RegistrationMode,
    /// The matching cost registration uses.
    pub cost: MatchingCost<'a>,
    /// Where the disparity maps come from.
    pub disparities: Disparities,
    /// What multi-baseline registration compares the views by (pairwise registration
    /// always matches luminance).
    pub matching_image: MatchingImage,
    /// Whether multi-baseline registration goes coarse to fine.
    pub coarse_to_fine: CoarseToFine,
    /// Reflectance of the white board.
    pub white_reflectance: f64,
    /// Capture values at or above this fraction of full scale are saturated.
    pub saturation_level: f32,
    /// How the warp reads the cameras at fractional positions.
    pub warp_kernel: WarpKernel,
    /// The solver of Eq. 6 (λ comes from the rig).
    pub demux: DemuxOptions,
    /// The stages of each view's solve after demultiplexing ([`crate::solve`]).
    pub solve: SolveSettings,
    /// Views to reconstruct, by camera name; None: every view.
    pub views: Option<Vec<String>>,
    /// Keep each view's registered stack: every camera's normalised capture warped into
    /// the view, NaN where the camera does not see the point
    /// ([`super::ReconstructedView::registered`]).
    pub keep_registered: bool,
    /// Solve each view's reflectance. Off, the run registers only: a camera without a
    /// white board or exposure keeps its capture as recorded (less its dark level), and no
    /// spectral stage (demultiplexing, scene prior, refinement) runs.
    pub spectra: bool,
    /// Set by the caller (another thread, or the progress callback) to stop the run at the
    /// next stage boundary (before rectification, calibration, registration and each
    /// view) with [`Error::Cancelled`]; nothing is returned half done.
    pub cancel: Option<&'a AtomicBool>,
}

impl<'a> PipelineSettings<'a> {
    /// The default pipeline with the given matching cost: multi-baseline registration over
    /// an estimated search range, every stage of the solve on, every view.
    pub fn new(cost: MatchingCost<'a>) -> Self {
        Self::with_preset(cost, Preset::Default)
    }

    /// [`PipelineSettings::new`] with the stages and tuning of `preset`.
    pub fn with_preset(cost: MatchingCost<'a>, preset: Preset) -> Self {
        PipelineSettings {
            registration: DEFAULT_REGISTRATION,
            cost,
            disparities: Disparities::Search(DisparitySearch::Auto),
            matching_image: preset.matching_image(),
            coarse_to_fine: CoarseToFine::default(),
            white_reflectance: DEFAULT_WHITE_REFLECTANCE,
            saturation_level: DEFAULT_SATURATION_LEVEL,
            warp_kernel: preset.warp_kernel(),
            demux: DemuxOptions::default(),
            solve: preset.solve(),
            views: None,
            keep_registered: false,
            spectra: true,
            cancel: None,
        }
    }

    /// [`Error::Cancelled`] when the caller asked the run to stop; `stage` names what
    /// would have run next.
    pub fn check_cancelled(&self, stage: &str) -> Result<()> {
        match self.cancel {
            Some(flag) if flag.load(Ordering::Relaxed) => Err(Error::Cancelled {
                stage: stage.to_string(),
            }),
            _ => Ok(()),
        }
    }

    /// The registration settings over `range`.
    pub fn registration_over(&self, range: DisparityRange) -> RegistrationSettings<'a> {
        RegistrationSettings {
            mode: self.registration,
            cost: self.cost,
            range,
            coarse_to_fine: self.coarse_to_fine,
            previous: None,
        }
    }

    /// Checks every number before any work.
    pub fn validate(&self) -> Result<()> {
        if !(self.white_reflectance > 0.0 && self.white_reflectance <= 1.0) {
            return Err(Error::OutOfRange {
                setting: "white reflectance".into(),
                value: self.white_reflectance,
                expected: "in (0, 1]".into(),
            });
        }
        if !(self.saturation_level > 0.0 && self.saturation_level <= 1.0) {
            return Err(Error::OutOfRange {
                setting: "saturation level".into(),
                value: self.saturation_level as f64,
                expected: "in (0, 1]".into(),
            });
        }
        if let Disparities::Search(DisparitySearch::Fixed(range)) = self.disparities {
            DisparityRange::new(range.min, range.max)?;
        }
        if !self.spectra && !self.keep_registered {
            return Err(Error::setting(
                "output",
                "neither spectra nor registered stacks",
                "spectra, registered stacks or both",
            ));
        }
        self.solve.validate()
    }
}
