//! The last stage, once per requested view: every capture warped to the view along the
//! disparity maps ([`crate::register::gather_measurements`]), then the view's solve
//! through the stages of [`crate::solve`].
//!
//! In: the calibrated array, its disparity maps, the solve's plan. Out: the view's
//! reflectance cube, its reports and warnings.

use super::{CalibratedArray, PipelineSettings, ReconstructedView, RegisteredArray};
use super::{Progress, RunLog, Stage};
use super::{LOW_AGREEMENT_WARNING, LOW_VISIBILITY_WARNING};
use crate::image::Image;
use crate::register::{gather_measurements, Admission, ArrayGeometry, Gathered};
use crate::rig::Rig;
use crate::solve::{CarriedPrior, SolveContext, SolvePlan, ViewSolve};
use crate::Result;
use std::time::Instant;

/// What every view's pass shares.
pub(super) struct ViewPass<'a> {
    pub rig: &'a Rig,
    pub registered: &'a RegisteredArray,
    pub context: SolveContext<'a>,
    pub plan: &'a SolvePlan,
    pub geometry: ArrayGeometry,
    pub admission: Admission,
    pub settings: &'a PipelineSettings<'a>,
}

impl<'a> ViewPass<'a> {
    pub fn new(
        rig: &'a Rig,
        calibrated: &'a CalibratedArray,
        registered: &'a RegisteredArray,
        plan: &'a SolvePlan,
        settings: &'a PipelineSettings<'a>,
    ) -> Self {
        let options = crate::demux::DemuxOptions {
            lambda: rig.file.reconstruction.lambda,
            ..settings.demux
        };
        ViewPass {
            rig,
            registered,
            context: SolveContext::new(&calibrated.sensing, &calibrated.views, options),
            plan,
            geometry: ArrayGeometry::of_rig(rig),
            admission: match settings.solve.disputed_tolerance {
                Some(_) => Admission::DepthOrder,
                None => Admission::SourceMaps,
            },
            settings,
        }
    }

    /// Reconstructs the views of cameras `requested`, adding the warp's and each solve
    /// stage's seconds (summed over views) to `log`.
    ///
    /// `priors` (per camera, rig order) are the previous frame's scene priors of a
    /// sequence; returned with the views are the priors each view's solve used.
    pub fn run_all(
        &self,
        requested: &[usize],
        priors: Option<&[Option<CarriedPrior>]>,
        log: &mut RunLog,
        progress: &Progress<'_>,
    ) -> Result<(Vec<ReconstructedView>, Vec<Option<CarriedPrior>>)> {
        let names = self.plan.names();
        let mut seconds = vec![0.0; names.len() + 1];
        let mut views = Vec::with_capacity(requested.len());
        let mut used = Vec::with_capacity(requested.len());
        for (k, &v) in requested.iter().enumerate() {
            self.settings
                .check_cancelled(&format!("view {}", self.rig.cameras[v].name))?;
            let prior = priors.and_then(|p| p.get(v).cloned().flatten());
            let (view, prior) = self.run(v, prior, &mut seconds, &mut log.warnings)?;
            views.push(view);
            used.push(prior);
            progress(Stage::Views, k + 1, requested.len());
        }
        let names = std::iter::once("warping").chain(names);
        for (name, seconds) in names.zip(seconds) {
            log.timings.push((name.to_string(), seconds));
        }
        Ok((views, used))
    }

    /// Reconstructs camera `v`'s view; `seconds[0]` gathers the warp's time and
    /// `seconds[1..]` each solve stage's. Warnings go to `warnings`.
    pub fn run(
        &self,
        v: usize,
        prior: Option<CarriedPrior>,
        seconds: &mut [f64],
        warnings: &mut Vec<String>,
    ) -> Result<(ReconstructedView, Option<CarriedPrior>)> {
        let start = Instant::now();
        let Gathered {
            measurements,
            visibility,
            disputed,
            cameras_seeing,
        } = gather_measurements(
            v,
            self.context.views,
            &self.registered.disparities,
            &self.geometry,
            self.admission,
            self.settings.warp_kernel,
        )?;
        seconds[0] += start.elapsed().as_secs_f64();
        let image = &self.context.views[v].image;
        let (w, h) = (image.width, image.height);
        let registered = match self.settings.keep_registered {
            true => {
                let rows = measurements.len() / (w * h).max(1);
                Some(Image::new(w, h, rows, measurements.clone())?)
            }
            false => None,
        };
        let mut solve = ViewSolve::new(&self.context, v, measurements, disputed);
        solve.prior = prior;
        self.plan.run(&mut solve, &mut seconds[1..])?;
        let cam = &self.rig.cameras[v];
        let agreement = self.registered.agreement[v];
        if visibility.seen_by_all < LOW_VISIBILITY_WARNING && self.rig.cameras.len() > 1 {
            warnings.push(format!(
                "view {}: only {:.1} % of pixels are seen by every camera",
                cam.name,
                100.0 * visibility.seen_by_all
            ));
        }
        if agreement < LOW_AGREEMENT_WARNING {
            warnings.push(format!(
                "view {}: only {:.1} % of its disparities agree with a neighbouring view's \
                 map; registration is unreliable (repetitive or textureless surfaces, or a \
                 search range that misses the nearest surfaces)",
                cam.name,
                100.0 * agreement
            ));
        }
        let view = ReconstructedView {
            name: cam.name.clone(),
            reflectance: Image::new(w, h, solve.knots.len(), solve.spectra)?,
            disparity: self.registered.disparities[v].clone(),
            neighbour_agreement: agreement.is_finite().then_some(agreement),
            visibility,
            cameras_seeing,
            solve: solve.report,
            moved_to_planes: self.registered.moved_to_planes.as_ref().map(|m| m[v]),
            registered,
            pair_agreements: self.registered.pair_agreements[v].clone(),
        };
        Ok((view, solve.prior))
    }
}
