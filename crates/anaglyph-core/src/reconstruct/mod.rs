//! The whole pipeline, from a rig's captures to a multispectral light field (paper
//! sections 2.1, 3.3, 2.3):
//!
//! ```text
//! captures + white boards -> rectify (when the cameras carry calibrations)
//!   -> calibrate (C's units, saturation masked)
//!   -> register (the search range from a coarse pass when automatic; a disparity map per
//!      view) -> warp every capture to each requested view (a measurement that a
//!      source camera's map disputes but the view's depth order allows is disputed)
//!   -> demultiplex (masked Eq. 6 with the out-of-band-aware C) -> reflectance cube per view
//!   -> disputed measurements kept where they agree with the rest
//!   -> inconsistent pixels keep only their own capture's measurements
//!   -> scene prior (pixels some camera misses, from the spectra of those all cameras see,
//!      then of those at least half the camera channels see)
//!   -> refine (guided by the view's own capture, when enabled)
//! ```
//!
//! In: a loaded [`Rig`] and its [`ArrayCaptures`] (already rectified, or carrying each
//! camera's calibration for [`crate::rectify`]). Out: a [`LightField`] with a reflectance
//! cube and disparity map per requested view (in the rectified frame), per-camera
//! calibration, rectification, visibility, per-stage timings and warnings;
//! [`write_light_field`] writes the fixed output layout.

mod inputs;
mod output;
mod preview;
mod probe_plot;

pub use inputs::{
    calibrate, ArrayCaptures, CameraCalibration, CameraCapture, UNEVEN_WHITE_WARNING,
};
pub use output::{write_light_field, OutputOptions};
pub use preview::{pseudo_colour, srgb_preview, RgbPreview};
pub use probe_plot::{plot_probe, plot_series, Probe};

use crate::demux::{demultiplex_as, DemuxOptions, DemuxReport};
use crate::rectify::{Rectification, GRID_OFFSET_WARNING};
use crate::refine::{
    confidence_weights, keep_own_where_inconsistent, measurement_residuals, refine_view,
    revert_disputed, DisputedReport, GuidedRefinement, ScenePrior, ScenePriorReport,
    ScenePriorSettings,
};
use crate::register::{
    common_signal_images, common_signals, estimate_search_range, gather_measurements,
    neighbour_agreement, register_views, Admission, ArrayGeometry, CommonSignal, Gathered,
    GridImage, MatchingImage, RegistrationMode, RegistrationSettings, SearchRange, Visibility,
    WarpKernel, COMMON_SIGNALS, LOW_AGREEMENT_WARNING,
};
use crate::rig::{Rig, SensingMatrix, ILL_CONDITIONED_WARNING};
use crate::stereo::GreyImage;
use crate::{Error, Result};
use serde::Serialize;
use std::time::Instant;

/// Fraction of a view's pixels seen by every camera under which a warning is raised.
pub const LOW_VISIBILITY_WARNING: f64 = 0.5;
/// Fraction of a camera's values that may saturate before a warning is raised.
pub const SATURATION_WARNING: f64 = 0.01;

/// The stages reported to a progress callback.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    Rectification,
    Registration,
    Warping,
    Demultiplexing,
    Refinement,
}

/// Everything reconstruction can be told.
#[derive(Debug, Clone)]
pub struct PipelineSettings<'a> {
    pub registration: RegistrationSettings<'a>,
    /// Reflectance of the white board.
    pub white_reflectance: f64,
    /// Capture values at or above this fraction of full scale are saturated.
    pub saturation_level: f32,
    pub demux: DemuxOptions,
    /// Views to reconstruct as (row, col); None: every view.
    pub views: Option<Vec<(usize, usize)>>,
    /// Disparity maps to use instead of registration (one per camera, rig order), e.g.
    /// the simulator's truth to measure what registration costs.
    pub given_disparities: Option<Vec<Vec<f32>>>,
    /// Choose `registration.max_disp` from the captures ([`estimate_search_range`]).
    pub automatic_search_range: bool,
    /// Filter each view's cube guided by its own capture ([`crate::refine`]); None: the
    /// demultiplexed cube as it is (the paper).
    pub refinement: Option<GuidedRefinement>,
    /// Estimate under-measured pixels from the spectra of the view's complete pixels
    /// ([`crate::refine::ScenePrior`]); None: Eq. 6's smoothness alone decides them.
    pub scene_prior: Option<ScenePriorSettings>,
    /// What multi-baseline registration compares the views by (pairwise registration
    /// always matches luminance).
    pub matching_image: MatchingImage,
    /// Admit the warped measurements a source camera's map disputes but the view's own
    /// depth order allows, and keep them where the residual with them stays within this
    /// factor of the residual without ([`crate::refine::revert_disputed`]); None: the
    /// source cameras' maps decide visibility alone.
    pub disputed_tolerance: Option<f64>,
    /// How the warp reads the cameras at fractional positions.
    pub warp_kernel: WarpKernel,
}

/// The default of [`PipelineSettings::disputed_tolerance`].
pub const DISPUTED_TOLERANCE: f64 = 2.0;

/// One reconstructed view.
#[derive(Debug, Clone)]
pub struct ReconstructedView {
    pub row: usize,
    pub col: usize,
    /// Reflectance, `height × width × bands`, NaN where nothing was measured.
    pub reflectance: Vec<f32>,
    /// Disparity per column step (the simulator's convention), NaN where unknown.
    pub disparity: Vec<f32>,
    /// Fraction of the view's disparities that a row or column neighbour's map confirms
    /// ([`crate::register::neighbour_agreement`]; None: no finite disparity). It needs no
    /// truth: a failed registration lowers it.
    pub neighbour_agreement: Option<f64>,
    pub visibility: Visibility,
    pub demux: DemuxReport,
    /// Median rms residual `‖P − Cŝ‖` of the view's pixels in reflectance units, after the
    /// scene prior and before the guided filter (None: not computed). It needs no truth:
    /// misregistration raises it.
    pub median_residual: Option<f64>,
    /// What the scene prior did to the view (None: not applied, or too few complete
    /// pixels to learn it).
    pub scene_prior: Option<ScenePriorReport>,
    /// How many pixels had disputed measurements and how many dropped them (None: the
    /// source cameras' maps decided visibility alone).
    pub disputed: Option<DisputedReport>,
    /// Pixels whose disparity registration moved to the plane of their ambiguous
    /// (repetitive) region ([`crate::register::resolve_ambiguous_planes`]; None: given
    /// disparities, or a registration mode without that step).
    pub moved_to_planes: Option<usize>,
}

/// The multispectral light field of an array.
#[derive(Debug, Clone)]
pub struct LightField {
    pub width: usize,
    pub height: usize,
    /// Band centres, nm.
    pub bands: Vec<f64>,
    pub views: Vec<ReconstructedView>,
    pub calibration: Vec<CameraCalibration>,
    /// How the array was rectified (None: the captures were already rectified).
    pub rectification: Option<Rectification>,
    /// The search range chosen from the captures (None: given, or no registration).
    pub search_range: Option<SearchRange>,
    /// The refinement applied to every view (None: none).
    pub refinement: Option<GuidedRefinement>,
    /// The scene prior's settings (None: not used).
    pub scene_prior: Option<ScenePriorSettings>,
    /// The common signals registration matched by (None: luminance, or no registration).
    pub common_signals: Option<Vec<CommonSignal>>,
    pub condition_number: f64,
    /// (stage, seconds) in the order run.
    pub timings: Vec<(String, f64)>,
    pub warnings: Vec<String>,
}

/// Reconstructs the requested views of `rig` from `captures`. `progress(stage, done,
/// total)` is called as work finishes.
pub fn reconstruct(
    rig: &Rig,
    captures: &ArrayCaptures,
    settings: &PipelineSettings<'_>,
    progress: &(dyn Fn(Stage, usize, usize) + Sync),
) -> Result<LightField> {
    let (w, h) = (captures.width, captures.height);
    if captures.cameras.len() != rig.cameras.len()
        || captures
            .cameras
            .iter()
            .zip(&rig.cameras)
            .any(|(a, b)| (a.row, a.col) != (b.row, b.col))
    {
        return Err(Error::invalid(
            "reconstruction",
            "the captures do not follow the rig's cameras (one per camera, row-major)",
        ));
    }
    let requested: Vec<usize> = match &settings.views {
        None => (0..rig.cameras.len()).collect(),
        Some(list) => list
            .iter()
            .map(|&(r, c)| {
                rig.cameras
                    .iter()
                    .position(|cam| (cam.row, cam.col) == (r, c))
                    .ok_or_else(|| {
                        Error::invalid(
                            "reconstruction",
                            format!(
                                "view r{r}c{c} is not in the {}x{} rig",
                                rig.file.rows, rig.file.cols
                            ),
                        )
                    })
            })
            .collect::<Result<_>>()?,
    };
    let mut timings = Vec::new();
    let mut warnings = Vec::new();
    let clock = Instant::now();
    let rectified = rectify_array(rig, captures, settings.saturation_level, progress)?;
    let (captures, rectification) = match rectified {
        Some((rectified_captures, plan, notes)) => {
            warnings.extend(notes);
            timings.push(("rectification".to_string(), clock.elapsed().as_secs_f64()));
            (std::borrow::Cow::Owned(rectified_captures), Some(plan))
        }
        None => (std::borrow::Cow::Borrowed(captures), None),
    };
    let captures = captures.as_ref();
    let clock = Instant::now();

    let sensing = SensingMatrix::of_rig(rig)?;
    let condition_number = sensing.condition_number()?;
    if condition_number > ILL_CONDITIONED_WARNING && settings.demux.lambda == 0.0 {
        warnings.push(format!(
            "cond(C) = {condition_number:.3e} with lambda = 0: the solve amplifies noise; use lambda > 0"
        ));
    }
    let (views, calibration) = calibrate(
        captures,
        &sensing,
        settings.white_reflectance,
        settings.saturation_level,
    )?;
    for (record, cam) in calibration.iter().zip(&captures.cameras) {
        let fraction = record.saturated_values as f64 / cam.capture.data.len().max(1) as f64;
        if fraction > SATURATION_WARNING {
            warnings.push(format!(
                "camera r{}c{}: {:.1} % of values saturated (masked)",
                record.row,
                record.col,
                100.0 * fraction
            ));
        }
        if let Some(cv) = &record.white_variation {
            if let Some(worst) = cv.iter().cloned().reduce(f64::max) {
                if worst > UNEVEN_WHITE_WARNING {
                    warnings.push(format!(
                        "camera r{}c{}: white board varies by {:.1} % (uneven light or vignetting; one gain per channel is applied)",
                        record.row,
                        record.col,
                        100.0 * worst
                    ));
                }
            }
        }
    }
    timings.push(("calibration".to_string(), clock.elapsed().as_secs_f64()));

    let geometry = ArrayGeometry::of_rig(rig);
    let mut search_range = None;
    let mut common = None;
    let mut moved_to_planes = None;
    let disparities = match &settings.given_disparities {
        Some(given) => {
            if given.len() != rig.cameras.len() || given.iter().any(|d| d.len() != w * h) {
                return Err(Error::invalid(
                    "reconstruction",
                    format!(
                        "given disparities: expected {} maps of {w}x{h}",
                        rig.cameras.len()
                    ),
                ));
            }
            given.clone()
        }
        None => {
            let matching = match settings.matching_image {
                MatchingImage::CommonSignals
                    if settings.registration.mode == RegistrationMode::MultiBaseline =>
                {
                    let channels: Vec<usize> = views.iter().map(|v| v.channels).collect();
                    let signals = common_signals(&sensing, &channels, COMMON_SIGNALS)?;
                    let images: Vec<Vec<GreyImage>> = signals
                        .iter()
                        .map(|signal| common_signal_images(&views, signal))
                        .collect();
                    common = Some(signals);
                    (0..views.len())
                        .map(|k| images.iter().map(|per_view| per_view[k].clone()).collect())
                        .collect()
                }
                _ => vec![Vec::new(); views.len()],
            };
            let images: Vec<GridImage> = captures
                .grey_images()
                .into_iter()
                .zip(matching)
                .zip(&captures.cameras)
                .map(|((image, matching), cam)| GridImage {
                    row: cam.row,
                    col: cam.col,
                    image,
                    matching,
                    measured: cam.capture.data.iter().any(|v| v.is_nan()).then(|| {
                        cam.capture
                            .data
                            .chunks_exact(cam.capture.channels)
                            .map(|p| p.iter().all(|v| !v.is_nan()))
                            .collect()
                    }),
                })
                .collect();
            let mut registration_settings = settings.registration;
            if settings.automatic_search_range {
                let range = estimate_search_range(&images, &geometry, &registration_settings)?;
                registration_settings.max_disp = range.max_disp;
                timings.push(("search range".to_string(), range.seconds));
                search_range = Some(range);
            }
            let registration = register_views(
                &images,
                &geometry,
                &registration_settings,
                &|done, total| progress(Stage::Registration, done, total),
            )?;
            for (name, seconds) in &registration.timings {
                timings.push((format!("registration: {name}"), *seconds));
            }
            moved_to_planes = registration.moved_to_planes;
            registration.disparities
        }
    };

    let positions: Vec<(usize, usize)> = rig.cameras.iter().map(|c| (c.row, c.col)).collect();
    let agreement = neighbour_agreement(&disparities, &positions, &geometry, w, h);

    let bands = rig.reconstruction_shape()?;
    let output = sensing.reported_offset..sensing.reported_offset + bands.count;
    let options = DemuxOptions {
        lambda: rig.file.reconstruction.lambda,
        ..settings.demux
    };
    let (mut warp_seconds, mut demux_seconds) = (0.0, 0.0);
    let (mut prior_seconds, mut refine_seconds) = (0.0, 0.0);
    let camera_rows: Vec<std::ops::Range<usize>> = views
        .iter()
        .scan(0, |row, view| {
            let first = *row;
            *row += view.channels;
            Some(first..*row)
        })
        .collect();
    let mut reconstructed = Vec::with_capacity(requested.len());
    for (k, &v) in requested.iter().enumerate() {
        let start = Instant::now();
        let admission = match settings.disputed_tolerance {
            Some(_) => Admission::DepthOrder,
            None => Admission::SourceMaps,
        };
        let Gathered {
            mut measurements,
            visibility,
            disputed,
        } = gather_measurements(
            v,
            &views,
            &disparities,
            &geometry,
            admission,
            settings.warp_kernel,
        )?;
        warp_seconds += start.elapsed().as_secs_f64();
        progress(Stage::Warping, k + 1, requested.len());
        let start = Instant::now();
        // The residuals (for the disputed measurements and the confidence weights) and the
        // scene prior need every knot of C; the reported bands are cut out afterwards.
        let confidence = settings.refinement.and_then(|r| r.confidence_scale);
        let full_knots = confidence.is_some()
            || settings.scene_prior.is_some()
            || settings.disputed_tolerance.is_some();
        let solved = if full_knots {
            0..sensing.cols()
        } else {
            output.clone()
        };
        let (mut spectra, demux) = demultiplex_as::<f32, f32>(
            sensing.values(),
            sensing.rows(),
            &measurements,
            None,
            solved.clone(),
            &options,
        )?;
        // The residuals (for the disputed measurements, the confidence weights and the
        // inconsistent pixels) are computed once and kept up to date by each step.
        let mut residuals = if full_knots {
            Some(measurement_residuals(
                sensing.values(),
                sensing.rows(),
                &measurements,
                &spectra,
            )?)
        } else {
            None
        };
        let disputed_report = match (settings.disputed_tolerance, residuals.as_mut()) {
            (Some(tolerance), Some(residuals)) => Some(revert_disputed(
                sensing.values(),
                sensing.rows(),
                &camera_rows,
                &disputed,
                &mut measurements,
                &mut spectra,
                residuals,
                tolerance,
                (solved.clone(), &options),
            )?),
            _ => None,
        };
        demux_seconds += start.elapsed().as_secs_f64();
        progress(Stage::Demultiplexing, k + 1, requested.len());
        let (mut reflectance, weights, median_residual, prior_report) =
            if let Some(mut residuals) = residuals {
                let start = Instant::now();
                let prior_report = match &settings.scene_prior {
                    Some(prior_settings) => {
                        let inconsistent = if prior_settings.inconsistency_factor > 0.0 {
                            keep_own_where_inconsistent(
                                sensing.values(),
                                sensing.rows(),
                                camera_rows[v].clone(),
                                &mut measurements,
                                &mut spectra,
                                &mut residuals,
                                prior_settings.inconsistency_factor,
                                (solved.clone(), &options),
                            )?
                        } else {
                            0
                        };
                        ScenePrior::fill_view(
                            sensing.values(),
                            sensing.rows(),
                            &measurements,
                            &mut spectra,
                            &mut residuals,
                            prior_settings,
                        )?
                        .map(|report| ScenePriorReport {
                            inconsistent_pixels: inconsistent,
                            ..report
                        })
                    }
                    None => None,
                };
                prior_seconds += start.elapsed().as_secs_f64();
                let start = Instant::now();
                let (weights, median) = match confidence {
                    Some(scale) => {
                        let (weights, median) = confidence_weights(&residuals, scale)?;
                        (Some(weights), Some(median))
                    }
                    None => (None, None),
                };
                let knots = solved.len();
                let reflectance: Vec<f32> = spectra
                    .chunks_exact(knots)
                    .flat_map(|s| s[output.clone()].iter().copied())
                    .collect();
                refine_seconds += start.elapsed().as_secs_f64();
                (reflectance, weights, median, prior_report)
            } else {
                (spectra, None, None, None)
            };
        if let Some(refinement) = settings.refinement {
            let start = Instant::now();
            let white_response: Vec<f64> = (0..views[v].channels)
                .map(|c| sensing.row(camera_rows[v].start + c).iter().sum())
                .collect();
            refine_view(
                &mut reflectance,
                bands.count,
                &views[v],
                &white_response,
                weights.as_deref(),
                refinement,
            )?;
            refine_seconds += start.elapsed().as_secs_f64();
            progress(Stage::Refinement, k + 1, requested.len());
        }
        let cam = &rig.cameras[v];
        if visibility.seen_by_all < LOW_VISIBILITY_WARNING && rig.cameras.len() > 1 {
            warnings.push(format!(
                "view r{}c{}: only {:.1} % of pixels are seen by every camera",
                cam.row,
                cam.col,
                100.0 * visibility.seen_by_all
            ));
        }
        if agreement[v] < LOW_AGREEMENT_WARNING {
            warnings.push(format!(
                "view r{}c{}: only {:.1} % of its disparities agree with a neighbouring view's \
                 map; registration is unreliable (repetitive or textureless surfaces, or a \
                 search range that misses the nearest surfaces)",
                cam.row,
                cam.col,
                100.0 * agreement[v]
            ));
        }
        reconstructed.push(ReconstructedView {
            row: cam.row,
            col: cam.col,
            reflectance,
            disparity: disparities[v].clone(),
            neighbour_agreement: agreement[v].is_finite().then_some(agreement[v]),
            visibility,
            demux,
            median_residual,
            scene_prior: prior_report,
            disputed: disputed_report,
            moved_to_planes: moved_to_planes.as_ref().map(|moved| moved[v]),
        });
    }
    timings.push(("warping".to_string(), warp_seconds));
    timings.push(("demultiplexing".to_string(), demux_seconds));
    if settings.scene_prior.is_some() {
        timings.push(("scene prior".to_string(), prior_seconds));
    }
    if settings.refinement.is_some() {
        timings.push(("refinement".to_string(), refine_seconds));
    }
    Ok(LightField {
        width: w,
        height: h,
        bands: bands.wavelengths(),
        views: reconstructed,
        calibration,
        rectification,
        search_range,
        refinement: settings.refinement,
        scene_prior: settings.scene_prior,
        common_signals: common,
        condition_number,
        timings,
        warnings,
    })
}

/// Rectifies `captures` when their cameras carry calibrations (all or none must): returns
/// the rectified captures, the plan and warnings about what rectification cannot correct.
fn rectify_array(
    rig: &Rig,
    captures: &ArrayCaptures,
    saturation_level: f32,
    progress: &(dyn Fn(Stage, usize, usize) + Sync),
) -> Result<Option<(ArrayCaptures, Rectification, Vec<String>)>> {
    let (with, without): (Vec<&CameraCapture>, Vec<&CameraCapture>) = captures
        .cameras
        .iter()
        .partition(|c| c.calibration.is_some());
    if with.is_empty() {
        return Ok(None);
    }
    if !without.is_empty() {
        let names = |list: &[&CameraCapture]| {
            list.iter()
                .map(|c| format!("r{}c{}", c.row, c.col))
                .collect::<Vec<_>>()
                .join(", ")
        };
        return Err(Error::invalid(
            "rectification",
            format!(
                "cameras {} have a calibration but {} have none: give every camera one (or \
                 none, for captures that are already rectified)",
                names(&with),
                names(&without)
            ),
        ));
    }
    let models = captures
        .cameras
        .iter()
        .filter_map(|c| c.calibration.clone().map(|m| (c.row, c.col, m)))
        .collect();
    let plan = Rectification::plan(models, captures.width, captures.height)?;
    let total = captures.cameras.len();
    let mut cameras = Vec::with_capacity(total);
    for (k, cam) in captures.cameras.iter().enumerate() {
        cameras.push(CameraCapture {
            row: cam.row,
            col: cam.col,
            capture: plan.resample(k, &cam.capture, saturation_level)?,
            white: cam.white.clone(),
            exposure: cam.exposure,
            calibration: cam.calibration.clone(),
        });
        progress(Stage::Rectification, k + 1, total);
    }
    let mut warnings = Vec::new();
    let offset = plan.worst_grid_offset();
    if offset > GRID_OFFSET_WARNING {
        warnings.push(format!(
            "rectification: an optical centre lies {:.1} % of the baseline off the camera \
             grid; no image warp removes that parallax (about that fraction of each disparity)",
            100.0 * offset
        ));
    }
    let [bx, by] = plan.baseline_mm;
    let (rig_bx, rig_by) = (
        rig.file.baseline_mm.horizontal,
        rig.file.baseline_mm.vertical,
    );
    if bx > 0.0 && by > 0.0 && rig_bx > 0.0 && rig_by > 0.0 {
        let ratio = (by / bx) / (rig_by / rig_bx);
        if (ratio - 1.0).abs() > GRID_OFFSET_WARNING {
            warnings.push(format!(
                "rectification: the calibrated baselines are {bx:.2} x {by:.2} but the rig \
                 says {rig_bx} x {rig_by}; registration uses the rig's ratio"
            ));
        }
    }
    let cropped: f64 = cameras
        .iter()
        .map(|c| {
            c.capture.data.iter().filter(|v| v.is_nan()).count() as f64
                / c.capture.data.len().max(1) as f64
        })
        .fold(0.0, f64::max);
    if cropped > SATURATION_WARNING {
        warnings.push(format!(
            "rectification: up to {:.1} % of a camera's rectified frame lies outside its \
             capture (not measured)",
            100.0 * cropped
        ));
    }
    Ok(Some((
        ArrayCaptures {
            width: captures.width,
            height: captures.height,
            cameras,
        },
        plan,
        warnings,
    )))
}

/// The result of [`reconstruct`] as JSON-friendly records (everything but the images).
#[derive(Debug, Clone, Serialize)]
pub struct ViewSummary {
    pub row: usize,
    pub col: usize,
    pub visibility: Visibility,
    pub demux: DemuxReport,
    pub disparity_range: [f32; 2],
    pub neighbour_agreement: Option<f64>,
    pub unmeasured_pixels: usize,
    pub median_residual: Option<f64>,
    pub scene_prior: Option<ScenePriorReport>,
    pub disputed: Option<DisputedReport>,
    pub moved_to_planes: Option<usize>,
}

impl ReconstructedView {
    pub fn summary(&self) -> ViewSummary {
        let finite = self.disparity.iter().filter(|v| v.is_finite());
        let range = finite.fold([f32::INFINITY, f32::NEG_INFINITY], |[a, b], &v| {
            [a.min(v), b.max(v)]
        });
        ViewSummary {
            row: self.row,
            col: self.col,
            visibility: self.visibility.clone(),
            demux: self.demux.clone(),
            disparity_range: range,
            neighbour_agreement: self.neighbour_agreement,
            unmeasured_pixels: self.demux.unmeasured_pixels,
            median_residual: self.median_residual,
            scene_prior: self.scene_prior,
            disputed: self.disputed,
            moved_to_planes: self.moved_to_planes,
        }
    }
}
