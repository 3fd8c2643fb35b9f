//! A view's per-pixel solve as an ordered list of stages (paper section 2.3, Eq. 6, and
//! what anaglyph adds after it). The warped measurements of one view come in; its
//! reflectance cube on the rig's reported bands goes out.
//!
//! ```text
//! measurements (pixels × rows of C, NaN where not seen) + disputed flags
//!   -> Demultiplex            masked Eq. 6 on the knots later stages need   demultiplex.rs
//!   -> DisputedMeasurements   kept only where they agree with the rest      disputed.rs
//!   -> InconsistentPixels     keep only their own capture's measurements    inconsistent.rs
//!   -> ScenePrior             under-measured pixels from the scene's spectra scene_prior/
//!   -> Confidence             per-pixel weights from the residuals          confidence.rs
//!   -> ReportedBands          the spectra cut to the rig's reported bands   reported_bands.rs
//!   -> GuidedRefinement       filtered, guided by the view's own capture    guided_refinement.rs
//! ```
//!
//! Every stage is a type implementing [`SolveStage`]; [`SolvePlan::new`] lists the ones a
//! [`SolveSettings`] switches on, in this order, and [`SolvePlan::run`] passes one
//! [`ViewSolve`] through them. A new stage is a new file, a field of [`SolveSettings`]
//! and one line in [`SolvePlan::new`].

mod confidence;
mod demultiplex;
mod disputed;
mod guided_refinement;
mod inconsistent;
mod reported_bands;
mod residuals;
mod scene_prior;

pub use confidence::{confidence_weights, Confidence};
pub use demultiplex::Demultiplex;
pub use disputed::{revert_disputed, DisputedMeasurements, DisputedReport};
pub use guided_refinement::GuidedRefinementStage;
pub use inconsistent::{keep_own_where_inconsistent, InconsistentPixels};
pub use reported_bands::ReportedBands;
pub use residuals::{measurement_residuals, median_of_complete};
pub use scene_prior::{
    fill_view, CarriedPrior, ScenePrior, ScenePriorReport, ScenePriorSettings, ScenePriorStage,
};

use crate::demux::{DemuxOptions, DemuxReport};
use crate::refine::GuidedRefinement;
use crate::register::NormalisedView;
use crate::rig::SensingMatrix;
use crate::{Error, Result};
use serde::Serialize;
use std::ops::Range;
use std::time::Instant;

/// Which stages of a view's solve run, each switched by its own field (None: off).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SolveSettings {
    /// Keep disputed measurements where a pixel's residual with them stays within this
    /// factor of its residual without them ([`DisputedMeasurements`]); None: the warp
    /// admitted none (the source cameras' maps decided visibility alone).
    pub disputed_tolerance: Option<f64>,
    /// Pixels whose residual exceeds this multiple of the complete pixels' median keep
    /// only their own capture's measurements ([`InconsistentPixels`]). It hands those
    /// pixels to the scene prior, so it needs `scene_prior`.
    pub inconsistency_factor: Option<f64>,
    /// The spectral prior learned from the view's complete pixels ([`ScenePriorStage`]).
    pub scene_prior: Option<ScenePriorSettings>,
    /// The guided filter and its confidence weights ([`Confidence`],
    /// [`GuidedRefinementStage`]).
    pub refinement: Option<GuidedRefinement>,
}

/// The default of [`SolveSettings::disputed_tolerance`].
pub const DISPUTED_TOLERANCE: f64 = 2.0;
/// The default of [`SolveSettings::inconsistency_factor`]. Measured on the presets at
/// 640×480 (docs/reconstruction.md, "Inconsistent pixels"): factors 3, 4 and 6 gain alike
/// (within 0.2 dB on the clutter and periodic presets).
pub const INCONSISTENCY_FACTOR: f64 = 4.0;

impl Default for SolveSettings {
    /// Every stage on, with the measured defaults.
    fn default() -> Self {
        SolveSettings {
            disputed_tolerance: Some(DISPUTED_TOLERANCE),
            inconsistency_factor: Some(INCONSISTENCY_FACTOR),
            scene_prior: Some(ScenePriorSettings::default()),
            refinement: Some(GuidedRefinement::default()),
        }
    }
}

impl SolveSettings {
    /// The paper's solve: Eq. 6 alone.
    pub fn paper() -> Self {
        SolveSettings {
            disputed_tolerance: None,
            inconsistency_factor: None,
            scene_prior: None,
            refinement: None,
        }
    }

    /// Checks each stage's numbers and the stages' dependencies.
    pub fn validate(&self) -> Result<()> {
        if let Some(tolerance) = self.disputed_tolerance {
            check_at_least("disputed tolerance", tolerance, 1.0)?;
        }
        if let Some(factor) = self.inconsistency_factor {
            check_at_least("inconsistency factor", factor, f64::MIN_POSITIVE)?;
            if self.scene_prior.is_none() {
                return Err(Error::StageDependency {
                    stage: "inconsistent pixels",
                    needs: "scene prior",
                    why: "the pixels it strips to their own capture are estimated by the prior",
                });
            }
        }
        if let Some(prior) = &self.scene_prior {
            prior.validate()?;
        }
        if let Some(refinement) = &self.refinement {
            refinement.validate()?;
        }
        Ok(())
    }
}

fn check_at_least(setting: &'static str, value: f64, least: f64) -> Result<()> {
    if value.is_finite() && value >= least {
        Ok(())
    } else {
        Err(Error::out_of_range(
            setting,
            value,
            format!("a finite value >= {least}"),
        ))
    }
}

/// What every view's solve shares: the sensing matrix, each camera's rows of it, the
/// solver and the calibrated captures that guide the refinement.
#[derive(Debug)]
pub struct SolveContext<'a> {
    pub sensing: &'a SensingMatrix,
    /// Camera k's rows of C.
    pub camera_rows: Vec<Range<usize>>,
    pub options: DemuxOptions,
    /// Every camera's calibrated capture, in rig order.
    pub views: &'a [NormalisedView],
}

impl<'a> SolveContext<'a> {
    pub fn new(
        sensing: &'a SensingMatrix,
        views: &'a [NormalisedView],
        options: DemuxOptions,
    ) -> Self {
        let camera_rows = views
            .iter()
            .scan(0, |row, view| {
                let first = *row;
                *row += view.image.channels;
                Some(first..*row)
            })
            .collect();
        SolveContext {
            sensing,
            camera_rows,
            options,
            views,
        }
    }

    /// The reported bands as a range of C's knots.
    pub fn reported_knots(&self) -> Range<usize> {
        let offset = self.sensing.reported_offset;
        offset..offset + self.sensing.reported.count
    }
}

/// One view's solve as it passes through the stages.
#[derive(Debug)]
pub struct ViewSolve<'a> {
    pub context: &'a SolveContext<'a>,
    /// The view's camera (rig order).
    pub camera: usize,
    /// `pixels × rows of C`, NaN where not measured.
    pub measurements: Vec<f32>,
    /// `pixels × cameras`: the warp admitted this measurement against the source camera's
    /// own map.
    pub disputed: Vec<bool>,
    /// The knots of C that `spectra` holds.
    pub knots: Range<usize>,
    /// `pixels × knots.len()`, NaN where nothing was measured.
    pub spectra: Vec<f32>,
    /// The rms residual `‖P − Cŝ‖` per pixel in reflectance units, kept up to date by
    /// every stage that changes `spectra` (None: no stage needs them).
    pub residuals: Option<Vec<f32>>,
    /// Per-pixel weights of the guided filter (None: every pixel weighs the same).
    pub weights: Option<Vec<f32>>,
    /// The view's scene prior: on entry the previous frame's of a sequence (temporal
    /// reuse; None: learn it), after the solve the one the scene prior stage used.
    pub prior: Option<CarriedPrior>,
    /// The view-wide yardsticks of the per-pixel stages: None fields are computed from
    /// these pixels (and recorded), given ones are used as they are.
    pub statistics: ViewStatistics,
    /// In a sequence, the pixels that kept the previous frame's spectra (temporal reuse):
    /// the spatial stages compute again only near the others.
    pub kept: Option<KeptPixels>,
    pub report: SolveReport,
}

/// Which pixels of a view were solved anew in a sequence's frame, and the spatial
/// stages' output of the frame the others were kept from.
#[derive(Debug, Clone)]
pub struct KeptPixels {
    /// Per pixel: solved anew (the others kept their spectra and weights).
    pub changed: Vec<bool>,
    /// The previous frame's output of the spatial stages, `pixels × knots`.
    pub refined: Vec<f32>,
}

/// The view-wide statistics the per-pixel stages compare each pixel with: computed from
/// the whole view, or carried from the frame that last solved the whole view when a
/// sequence solves only the pixels that changed (temporal reuse), so that those pixels
/// meet the same yardsticks as a whole view's.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ViewStatistics {
    /// [`DisputedMeasurements`]' floor: the complete pixels' median residual after
    /// demultiplexing.
    pub disputed_floor: Option<f32>,
    /// [`InconsistentPixels`]' median residual of the complete pixels.
    pub inconsistent_median: Option<f32>,
    /// [`Confidence`]'s median residual.
    pub confidence_median: Option<f64>,
}

/// What the stages did to a view.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SolveReport {
    pub demux: DemuxReport,
    pub disputed: Option<DisputedReport>,
    /// Pixels that kept only their own capture's measurements.
    pub inconsistent_pixels: Option<usize>,
    pub scene_prior: Option<ScenePriorReport>,
    /// Median residual of the view's pixels after the scene prior, reflectance units.
    pub median_residual: Option<f64>,
    /// Pixels whose measurements had not changed since the previous frame of a sequence
    /// and kept its spectra (temporal reuse); the other counts are of the rest.
    pub reused_pixels: usize,
}

impl<'a> ViewSolve<'a> {
    /// A view's gathered measurements, before any stage.
    pub fn new(
        context: &'a SolveContext<'a>,
        camera: usize,
        measurements: Vec<f32>,
        disputed: Vec<bool>,
    ) -> Self {
        ViewSolve {
            context,
            camera,
            measurements,
            disputed,
            knots: 0..0,
            spectra: Vec::new(),
            residuals: None,
            weights: None,
            prior: None,
            statistics: ViewStatistics::default(),
            kept: None,
            report: SolveReport::default(),
        }
    }

    /// The residuals, for a stage that needs them.
    pub(crate) fn residuals_mut(&mut self, stage: &'static str) -> Result<&mut Vec<f32>> {
        self.residuals
            .as_mut()
            .ok_or_else(|| missing_residuals(stage))
    }
}

/// One stage of a view's solve.
pub trait SolveStage: std::fmt::Debug + Send + Sync {
    /// The stage's name in timings and reports.
    fn name(&self) -> &'static str;
    /// Whether it reads the spectra on every knot of C and their residuals.
    fn needs_residuals(&self) -> bool;
    /// Whether a pixel's result depends on its neighbours' (such stages come last; the
    /// others' results at a pixel depend on that pixel's measurements and the view's
    /// [`ViewStatistics`] alone).
    fn spatial(&self) -> bool {
        false
    }
    fn run(&self, solve: &mut ViewSolve<'_>) -> Result<()>;
}

/// The stages [`SolveSettings`] switches on, in pipeline order.
#[derive(Debug)]
pub struct SolvePlan {
    stages: Vec<Box<dyn SolveStage>>,
}

impl SolvePlan {
    pub fn new(settings: &SolveSettings) -> Result<Self> {
        settings.validate()?;
        let mut later: Vec<Box<dyn SolveStage>> = Vec::new();
        if let Some(tolerance) = settings.disputed_tolerance {
            later.push(Box::new(DisputedMeasurements { tolerance }));
        }
        if let Some(factor) = settings.inconsistency_factor {
            later.push(Box::new(InconsistentPixels { factor }));
        }
        if let Some(prior) = settings.scene_prior {
            later.push(Box::new(ScenePriorStage { settings: prior }));
        }
        if let Some(scale) = settings.refinement.and_then(|r| r.confidence_scale) {
            later.push(Box::new(Confidence { scale }));
        }
        later.push(Box::new(ReportedBands));
        if let Some(refinement) = settings.refinement {
            later.push(Box::new(GuidedRefinementStage { refinement }));
        }
        let all_knots = later.iter().any(|stage| stage.needs_residuals());
        let mut stages: Vec<Box<dyn SolveStage>> = vec![Box::new(Demultiplex { all_knots })];
        stages.extend(later);
        Ok(SolvePlan { stages })
    }

    /// The stages' names, in order.
    pub fn names(&self) -> Vec<&'static str> {
        self.stages.iter().map(|stage| stage.name()).collect()
    }

    /// Runs every stage on `solve`, adding each one's seconds to `seconds` (same order
    /// as [`SolvePlan::names`]).
    pub fn run(&self, solve: &mut ViewSolve<'_>, seconds: &mut [f64]) -> Result<()> {
        self.run_per_pixel(solve, seconds)?;
        self.run_spatial(solve, seconds)
    }

    /// Runs the stages whose result at a pixel depends on that pixel alone (all but the
    /// last, spatial ones; `seconds` as for [`SolvePlan::run`]).
    pub fn run_per_pixel(&self, solve: &mut ViewSolve<'_>, seconds: &mut [f64]) -> Result<()> {
        self.run_where(solve, seconds, false)
    }

    /// Runs the spatial stages (after [`SolvePlan::run_per_pixel`]).
    pub fn run_spatial(&self, solve: &mut ViewSolve<'_>, seconds: &mut [f64]) -> Result<()> {
        self.run_where(solve, seconds, true)
    }

    fn run_where(
        &self,
        solve: &mut ViewSolve<'_>,
        seconds: &mut [f64],
        spatial: bool,
    ) -> Result<()> {
        for (stage, total) in self.stages.iter().zip(seconds) {
            if stage.spatial() == spatial {
                let start = Instant::now();
                stage.run(solve)?;
                *total += start.elapsed().as_secs_f64();
            }
        }
        Ok(())
    }
}

impl ViewSolve<'_> {
    /// Checks that the solve holds every knot of C, residuals, and consistent shapes: what
    /// `stage` needs.
    pub(crate) fn check_full(&self, stage: &'static str) -> Result<()> {
        let (rows, cols) = (self.context.sensing.rows(), self.context.sensing.cols());
        let Some(residuals) = &self.residuals else {
            return Err(missing_residuals(stage));
        };
        let pixels = residuals.len();
        if self.knots != (0..cols)
            || self.measurements.len() != pixels * rows
            || self.spectra.len() != pixels * cols
        {
            return Err(Error::Shape {
                op: format!("{stage}: measurements, spectra and residuals"),
                got: vec![self.measurements.len(), self.spectra.len(), pixels],
                expected: vec![pixels * rows, pixels * cols, pixels],
            });
        }
        Ok(())
    }
}

fn missing_residuals(stage: &'static str) -> Error {
    Error::StageDependency {
        stage,
        needs: "residuals",
        why: "demultiplexing computes them on every knot only when a later stage asks",
    }
}

#[cfg(test)]
pub(crate) mod test_support {
    //! Small solves for the stages' unit tests.
    use super::*;
    use crate::spectrum::SpectralShape;

    /// C of `rows` rows from row-major values, on knots 400, 410, … nm.
    pub fn matrix(rows: usize, values: Vec<f64>) -> SensingMatrix {
        let knots = values.len() / rows;
        let shape = SpectralShape::new(400.0, 10.0, knots).unwrap();
        SensingMatrix::from_dense(rows, shape, values).unwrap()
    }

    /// A context without captures (no guided refinement) and the default solver.
    pub fn context(sensing: &SensingMatrix, camera_rows: Vec<Range<usize>>) -> SolveContext<'_> {
        SolveContext {
            sensing,
            camera_rows,
            options: DemuxOptions::default(),
            views: &[],
        }
    }

    /// Camera 0's solve of `measurements` after demultiplexing on every knot.
    pub fn demultiplexed<'a>(
        context: &'a SolveContext<'a>,
        measurements: Vec<f32>,
        disputed: Vec<bool>,
    ) -> ViewSolve<'a> {
        let mut solve = ViewSolve::new(context, 0, measurements, disputed);
        Demultiplex { all_knots: true }.run(&mut solve).unwrap();
        solve
    }
}
