//! What reconstruction can be told, as plain data that is checked once, before any work
//! ([`PipelineSettings::validate`]).

use crate::demux::DemuxOptions;
use crate::register::{MatchingImage, RegistrationSettings, WarpKernel, DEFAULT_REGISTRATION};
use crate::solve::SolveSettings;
use crate::stereo::MatchingCost;
use crate::{Error, Result};

/// The default search range, per column step, when none is given or estimated.
pub const DEFAULT_MAX_DISP: usize = 64;
/// The default reflectance of the white board.
pub const DEFAULT_WHITE_REFLECTANCE: f64 = 0.95;
/// The default saturation level, as a fraction of full scale.
pub const DEFAULT_SATURATION_LEVEL: f32 = 0.999;

/// Everything reconstruction can be told.
#[derive(Debug, Clone)]
pub struct PipelineSettings<'a> {
    pub registration: RegistrationSettings<'a>,
    /// Choose `registration.max_disp` from the captures
    /// ([`crate::register::estimate_search_range`]).
    pub automatic_search_range: bool,
    /// What multi-baseline registration compares the views by (pairwise registration
    /// always matches luminance).
    pub matching_image: MatchingImage,
    /// Disparity maps to use instead of registration (one per camera, rig order), e.g.
    /// the simulator's truth to measure what registration costs.
    pub given_disparities: Option<Vec<Vec<f32>>>,
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
    /// Views to reconstruct as (row, col); None: every view.
    pub views: Option<Vec<(usize, usize)>>,
}

impl<'a> PipelineSettings<'a> {
    /// The default pipeline with the given matching cost: multi-baseline registration over
    /// an estimated search range, every stage of the solve on, every view.
    pub fn new(cost: MatchingCost<'a>) -> Self {
        PipelineSettings {
            registration: RegistrationSettings {
                mode: DEFAULT_REGISTRATION,
                cost,
                max_disp: DEFAULT_MAX_DISP,
            },
            automatic_search_range: true,
            matching_image: MatchingImage::default(),
            given_disparities: None,
            white_reflectance: DEFAULT_WHITE_REFLECTANCE,
            saturation_level: DEFAULT_SATURATION_LEVEL,
            warp_kernel: WarpKernel::default(),
            demux: DemuxOptions::default(),
            solve: SolveSettings::default(),
            views: None,
        }
    }

    /// Checks every number before any work.
    pub fn validate(&self) -> Result<()> {
        if !(self.white_reflectance > 0.0 && self.white_reflectance <= 1.0) {
            return Err(Error::OutOfRange {
                setting: "white reflectance",
                value: self.white_reflectance,
                expected: "in (0, 1]".into(),
            });
        }
        if !(self.saturation_level > 0.0 && self.saturation_level <= 1.0) {
            return Err(Error::OutOfRange {
                setting: "saturation level",
                value: self.saturation_level as f64,
                expected: "in (0, 1]".into(),
            });
        }
        if self.registration.max_disp == 0 && self.given_disparities.is_none() {
            return Err(Error::OutOfRange {
                setting: "search range",
                value: 0.0,
                expected: "at least 1 disparity".into(),
            });
        }
        self.solve.validate()
    }
}
