//! The last stage, once per requested view: every capture warped to the view along the
//! disparity maps ([`crate::register::gather_measurements`]), then the view's solve
//! through the stages of [`crate::solve`].
//!
//! In: the calibrated array, its disparity maps, the solve's plan. Out: the view's
//! reflectance cube, its reports and warnings.

use super::view_reuse::{scatter, select, CameraChanges, CarriedView, PixelState, ViewNow};
use super::{CalibratedArray, PipelineSettings, ReconstructedView, RegisteredArray};
use super::{FieldLayout, Progress, RunLog, Stage, ViewSink};
use super::{LOW_AGREEMENT_WARNING, LOW_VISIBILITY_WARNING};
use crate::image::Image;
use crate::register::{gather_measurements, Admission, ArrayGeometry, Gathered};
use crate::rig::Rig;
use crate::solve::{KeptPixels, SolveContext, SolvePlan, SolveReport, ViewSolve};
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
    /// In a sequence's frame that is no cut: where each camera's capture moved since the
    /// references the previous frame kept (temporal reuse).
    pub changes: Option<&'a CameraChanges>,
    /// Build what each view hands to the next frame (a sequence; a single frame builds
    /// none).
    pub hand_on: bool,
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
            changes: None,
            hand_on: false,
        }
    }

    /// Reconstructs the views of cameras `requested`, adding the warp's and each solve
    /// stage's seconds (summed over views) to `log`.
    ///
    /// `carried` (per camera, rig order) is what the previous frame of a sequence handed
    /// on ([`CarriedView`]); returned with the views is what each hands to the next. Each
    /// view goes to the sink, when there is one, as soon as it is done.
    pub fn run_all(
        &self,
        requested: &[usize],
        carried: Option<&[Option<CarriedView>]>,
        (layout, mut sink): (&FieldLayout, Option<&mut ViewSink<'_>>),
        log: &mut RunLog,
        progress: &Progress<'_>,
    ) -> Result<(Vec<ReconstructedView>, Vec<CarriedView>)> {
        let names = match self.settings.spectra {
            true => self.plan.names(),
            false => Vec::new(),
        };
        let mut seconds = vec![0.0; self.plan.names().len() + 1];
        let mut views = Vec::with_capacity(requested.len());
        let mut used = Vec::with_capacity(requested.len());
        for (k, &v) in requested.iter().enumerate() {
            self.settings
                .check_cancelled(&format!("view {}", self.rig.cameras[v].name))?;
            let previous = carried.and_then(|c| c.get(v).cloned().flatten());
            let (mut view, next) = self.run(v, previous, &mut seconds, &mut log.warnings)?;
            if let Some(sink) = sink.as_mut() {
                sink(layout, &mut view)?;
            }
            views.push(view);
            used.push(next);
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
        previous: Option<CarriedView>,
        seconds: &mut [f64],
        warnings: &mut Vec<String>,
    ) -> Result<(ReconstructedView, CarriedView)> {
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
        let rows = measurements.len() / (w * h).max(1);
        // A registration-only run stops here: no spectral stage, and the stack takes the
        // measurements themselves.
        let (registered, measurements) =
            match (self.settings.keep_registered, self.settings.spectra) {
                (true, true) => (
                    Some(Image::new(w, h, rows, measurements.clone())?),
                    measurements,
                ),
                (true, false) => (Some(Image::new(w, h, rows, measurements)?), Vec::new()),
                (false, _) => (None, measurements),
            };
        let (reflectance, report, next) = match self.settings.spectra {
            true => {
                let (solve, next) =
                    self.solve(v, measurements, disputed, previous, &mut seconds[1..])?;
                let cube = Image::new(w, h, solve.knots.len(), solve.spectra)?;
                (Some(cube), solve.report, next)
            }
            false => (
                None,
                SolveReport::default(),
                CarriedView {
                    prior: None,
                    pixels: None,
                },
            ),
        };
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
            reflectance,
            disparity: self.registered.disparities[v].clone(),
            neighbour_agreement: agreement.is_finite().then_some(agreement),
            visibility,
            cameras_seeing,
            solve: report,
            moved_to_planes: self.registered.moved_to_planes.as_ref().map(|m| m[v]),
            registered,
            pair_agreements: self.registered.pair_agreements[v].clone(),
        };
        Ok((view, next))
    }

    /// View `v`'s solve: the per-pixel stages on the pixels that changed since the
    /// previous frame (all of them without one; see `view_reuse.rs`), the others keeping
    /// its spectra, then the spatial stages on the whole view. Returns the solve and what
    /// it hands to the next frame.
    fn solve(
        &self,
        v: usize,
        measurements: Vec<f32>,
        disputed: Vec<bool>,
        previous: Option<CarriedView>,
        seconds: &mut [f64],
    ) -> Result<(ViewSolve<'_>, CarriedView)> {
        let rows = self.context.sensing.rows();
        let cameras = self.context.camera_rows.len();
        let disparity = &self.registered.disparities[v].data;
        let (prior, state) = previous.map_or((None, None), |p| (p.prior, p.pixels));
        let unchanged = match (&prior, &state, self.changes) {
            (Some(_), Some(state), Some(changes)) => {
                let shifts: Vec<(f64, f64)> =
                    (0..cameras).map(|k| self.geometry.shift(v, k)).collect();
                state.unchanged(&ViewNow {
                    measurements: &measurements,
                    disputed: &disputed,
                    rows,
                    disparity,
                    camera_rows: &self.context.camera_rows,
                    shifts: &shifts,
                    changes,
                })
            }
            _ => None,
        };
        if let (Some(unchanged), Some(state)) = (unchanged, state) {
            let changed: Vec<bool> = unchanged.iter().map(|u| !u).collect();
            let flags = if disputed.is_empty() { 0 } else { cameras };
            let (gathered, gathered_flags) = (
                select(&measurements, rows, &changed),
                select(&disputed, flags, &changed),
            );
            let mut part =
                ViewSolve::new(&self.context, v, gathered.clone(), gathered_flags.clone());
            part.prior = prior.clone();
            part.statistics = state.statistics;
            let mut part_seconds = vec![0.0; seconds.len()];
            self.plan.run_per_pixel(&mut part, &mut part_seconds)?;
            // A carried prior that met a new material was learned again from the
            // changed pixels alone: solve the whole view instead.
            let prior_held = part.report.scene_prior.is_none_or(|p| p.carried);
            if prior_held && part.knots == state.knots {
                seconds
                    .iter_mut()
                    .zip(&part_seconds)
                    .for_each(|(s, p)| *s += p);
                let width = part.knots.len();
                let mut spectra = state.spectra;
                scatter(&mut spectra, width, &changed, &part.spectra);
                let weights = match (state.weights, &part.weights) {
                    (Some(mut all), Some(some)) => {
                        scatter(&mut all, 1, &changed, some);
                        Some(all)
                    }
                    _ => None,
                };
                // Unchanged pixels keep what their spectra came from (the stages may
                // mask measurements: the reference is what was gathered).
                let mut reference = state.measurements;
                scatter(&mut reference, rows, &changed, &gathered);
                let mut reference_flags = state.disputed;
                scatter(&mut reference_flags, flags, &changed, &gathered_flags);
                let mut reference_disparity = state.disparity;
                scatter(
                    &mut reference_disparity,
                    1,
                    &changed,
                    &select(disparity, 1, &changed),
                );
                let mut report = part.report;
                report.reused_pixels = unchanged.iter().filter(|&&u| u).count();
                let mut solve = ViewSolve::new(&self.context, v, measurements, disputed);
                solve.knots = part.knots;
                solve.spectra = spectra;
                solve.weights = weights;
                solve.prior = part.prior;
                solve.statistics = part.statistics;
                solve.report = report;
                let mut next = PixelState {
                    measurements: reference,
                    disputed: reference_flags,
                    disparity: reference_disparity,
                    spectra: solve.spectra.clone(),
                    weights: solve.weights.clone(),
                    knots: solve.knots.clone(),
                    statistics: solve.statistics,
                    refined: Vec::new(),
                };
                solve.kept = Some(KeptPixels {
                    changed,
                    refined: state.refined,
                });
                self.plan.run_spatial(&mut solve, seconds)?;
                solve.kept = None;
                next.refined = solve.spectra.clone();
                let carried = CarriedView {
                    prior: solve.prior.clone(),
                    pixels: Some(next),
                };
                return Ok((solve, carried));
            }
        }
        // What the next frame compares with (the stages may mask measurements).
        let gathered = self
            .hand_on
            .then(|| (measurements.clone(), disputed.clone()));
        let mut solve = ViewSolve::new(&self.context, v, measurements, disputed);
        solve.prior = prior;
        self.plan.run_per_pixel(&mut solve, seconds)?;
        // Pixels are reused only under a scene prior's mixture: it is what lets a part of
        // the view be solved alone (a new material among the changed pixels is caught by
        // the carried prior's own check).
        let mut next = gathered.filter(|_| solve.prior.is_some()).map(|gathered| {
            let (measurements, disputed) = gathered;
            PixelState {
                measurements,
                disputed,
                disparity: disparity.clone(),
                spectra: solve.spectra.clone(),
                weights: solve.weights.clone(),
                knots: solve.knots.clone(),
                statistics: solve.statistics,
                refined: Vec::new(),
            }
        });
        self.plan.run_spatial(&mut solve, seconds)?;
        if let Some(next) = &mut next {
            next.refined = solve.spectra.clone();
        }
        let carried = CarriedView {
            prior: solve.prior.clone(),
            pixels: next,
        };
        Ok((solve, carried))
    }
}
