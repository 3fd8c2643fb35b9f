//! The whole pipeline, from a rig's captures to a multispectral light field (paper
//! sections 2.1, 3.3, 2.3). [`reconstruct`] reads as its list of stages:
//!
//! ```text
//! captures + white boards (+ calibrations), less their dark levels (dark_level.rs)
//!   -> checks          capture_checks.rs refuses a black, saturated or constant camera
//!   -> rectification   rectification.rs  when the cameras carry calibrations
//!   -> calibration     calibration.rs    C, and every capture in C's units
//!   -> registration    registration.rs   a disparity map per camera (or given ones)
//!   -> per view        view.rs           warp every capture to the view, then the
//!                                        view's solve, stage by stage (crate::solve)
//! ```
//!
//! In a sequence, [`reconstruct_next`] starts each frame from what the previous one
//! handed on ([`FrameCarry`]; `reuse.rs` and `view_reuse.rs`).
//!
//! A stage of the array is a function of its own file taking and returning domain values;
//! a stage of a view's solve is a type in [`crate::solve`] listed by
//! [`crate::solve::SolvePlan`].
//!
//! In: a loaded [`Rig`] and its [`ArrayCaptures`] (already rectified, or carrying each
//! camera's calibration for [`crate::rectify`]), [`PipelineSettings`]. Out: a
//! [`LightField`] with a reflectance cube and disparity map per requested view (in the
//! rectified frame), per-camera calibration, rectification, visibility, per-stage timings
//! and warnings; [`write_light_field`] writes the fixed output layout.

mod calibration;
mod capture_checks;
mod dark_level;
mod flat_field;
mod frames;
mod inputs;
mod options;
mod output;
mod preview;
mod probe_plot;
mod rectification;
mod registered_stack;
mod registration;
mod reuse;
mod settings;
mod summary;
mod view;
mod view_reuse;

pub use capture_checks::{check_signal, BLACK_LEVEL, CONSTANT_SPAN, UNUSABLE_FRACTION};
pub use dark_level::Dark;
pub(crate) use frames::summarise_numbers;
pub use frames::{FrameFiles, FrameLayout, FrameRange, FrameSequence};
pub use inputs::{
    calibrate, ArrayCaptures, CameraCalibration, CameraCapture, BRIGHTER_THAN_WHITE_WARNING,
    UNEVEN_WHITE_WARNING,
};
pub use options::{ReconstructOptions, SolveTuning};
pub use output::{write_light_field, LightFieldWriter, OutputOptions, Products};
pub use preview::{pseudo_colour, srgb_preview, RgbPreview};
pub use probe_plot::{plot_probe, plot_series, Probe};
pub use reuse::{block_correlation, FrameCarry, ReuseReport};
pub use settings::{
    Disparities, DisparitySearch, PipelineSettings, Preset, DEFAULT_MAX_DISP,
    DEFAULT_SATURATION_LEVEL, DEFAULT_WHITE_REFLECTANCE,
};
pub use summary::ViewSummary;

use crate::disparity::DisparityMap;
use crate::image::Image;
use crate::rectify::Rectification;
use crate::register::{
    check_search_range, ArrayGeometry, CommonSignal, PairAgreement, SearchRange, Visibility,
    LOW_AGREEMENT_WARNING,
};
use crate::rig::Rig;
use crate::solve::{SolvePlan, SolveReport, SolveSettings};
use crate::{Error, Result};
use calibration::{calibrate_array, CalibratedArray};
use capture_checks::check_capture_signal;
pub(crate) use inputs::{find_in, EXTENSIONS as PICTURE_EXTENSIONS};
use rectification::rectify_array;
use registration::{register_array, RegisteredArray};
use view::ViewPass;

/// Fraction of a view's pixels seen by every camera under which a warning is raised.
pub const LOW_VISIBILITY_WARNING: f64 = 0.5;
/// Fraction of a camera's values that may saturate before a warning is raised.
pub const SATURATION_WARNING: f64 = 0.01;

/// The stages reported to a progress callback.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    Rectification,
    Registration,
    /// Views whose warp and solve are done.
    Views,
}

impl Stage {
    /// The stage's name as progress displays give it.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Rectification => "rectification",
            Stage::Registration => "registration",
            Stage::Views => "views",
        }
    }
}

/// `progress(stage, done, total)`, called as work finishes.
pub type Progress<'a> = dyn Fn(Stage, usize, usize) + Sync + 'a;

/// What a view's products need to know of the whole field, known before the first view is
/// done: the size, the bands and the channels of a registered stack.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldLayout {
    pub width: usize,
    pub height: usize,
    /// Band centres, nm (empty: a registration-only run).
    pub bands: Vec<f64>,
    /// The camera channel of each channel of a registered stack, e.g. `r0c1:R`.
    pub channel_labels: Vec<String>,
}

/// `sink(layout, view)`, called with each view as soon as it is done
/// ([`reconstruct_streaming`]). A sink that writes the view's images out may take them
/// ([`ReconstructedView::reflectance`], [`ReconstructedView::registered`]), so that the
/// run holds one view's at a time.
pub type ViewSink<'a> = dyn FnMut(&FieldLayout, &mut ReconstructedView) -> Result<()> + 'a;

/// One reconstructed view.
#[derive(Debug, Clone)]
pub struct ReconstructedView {
    /// The camera's name (see [`crate::rig::Camera::name`]).
    pub name: String,
    /// Reflectance, a channel per band, NaN where nothing was measured (None: a
    /// registration-only run, [`PipelineSettings::spectra`] off).
    pub reflectance: Option<Image<f32>>,
    /// Disparity per column step of the array (the simulator's convention), NaN where
    /// unknown.
    pub disparity: DisparityMap,
    /// Fraction of the view's disparities that a row or column neighbour's map confirms
    /// ([`crate::register::neighbour_agreement`]; None: no finite disparity). It needs no
    /// truth: a failed registration lowers it.
    pub neighbour_agreement: Option<f64>,
    pub visibility: Visibility,
    /// Per pixel, how many cameras (the view's own included) measured it: 0 where nothing
    /// was measured, the number of cameras where every camera sees the point.
    pub cameras_seeing: Image<u8>,
    /// What each stage of the view's solve did.
    pub solve: SolveReport,
    /// Pixels whose disparity registration moved to the plane of their ambiguous
    /// (repetitive) region ([`crate::register::resolve_ambiguous_planes`]; None: given
    /// disparities, or a registration mode without that step).
    pub moved_to_planes: Option<usize>,
    /// With [`PipelineSettings::keep_registered`]: every camera's white-normalised capture
    /// warped into this view, `height × width × Σ channels` in the order of
    /// [`LightField::channel_labels`], NaN where that camera does not see the point.
    pub registered: Option<Image<f32>>,
    /// The view's agreement with each row and column neighbour's map, pixel by pixel.
    pub pair_agreements: Vec<PairAgreement>,
}

impl LightField {
    /// The field's size, bands and registered-stack channels.
    pub fn layout(&self) -> FieldLayout {
        FieldLayout {
            width: self.width,
            height: self.height,
            bands: self.bands.clone(),
            channel_labels: self.channel_labels.clone(),
        }
    }
}

impl ReconstructedView {
    /// The reflectance cube; an error in a registration-only run, which solves none.
    pub fn cube(&self) -> Result<&Image<f32>> {
        self.reflectance.as_ref().ok_or(Error::StageDependency {
            stage: "reflectance output",
            needs: "the view's spectral solve",
            why: "the run registered only (output registered)",
        })
    }

    /// The registered stack; an error in a run without
    /// [`PipelineSettings::keep_registered`].
    pub fn registered_stack(&self) -> Result<&Image<f32>> {
        self.registered.as_ref().ok_or(Error::StageDependency {
            stage: "registered-stack output",
            needs: "the warped captures",
            why: "the pipeline ran without keep_registered",
        })
    }
}

/// The multispectral light field of an array.
#[derive(Debug, Clone)]
pub struct LightField {
    pub width: usize,
    pub height: usize,
    /// Band centres, nm (empty: a registration-only run).
    pub bands: Vec<f64>,
    pub views: Vec<ReconstructedView>,
    /// The camera channel of each row of C, e.g. `r0c1:R` (the bands of a registered
    /// stack).
    pub channel_labels: Vec<String>,
    pub calibration: Vec<CameraCalibration>,
    /// How the array was rectified (None: the captures were already rectified).
    pub rectification: Option<Rectification>,
    /// The search range chosen from the captures (None: given, or no registration).
    pub search_range: Option<SearchRange>,
    /// The stages of every view's solve and their settings.
    pub solve: SolveSettings,
    /// The names of the solve's stages that ran, in order (none in a registration-only
    /// run).
    pub solve_stages: Vec<&'static str>,
    /// The stages of the array that ran, in order: rectification (for calibrated
    /// cameras), calibration, registration, warping, then the solve's stages.
    pub stages: Vec<&'static str>,
    /// The common signals registration matched by (None: luminance, or no registration).
    pub common_signals: Option<Vec<CommonSignal>>,
    pub condition_number: f64,
    /// (stage, seconds) in the order run.
    pub timings: Vec<(String, f64)>,
    pub warnings: Vec<String>,
    /// What the frame took from the previous frame of a sequence ([`reconstruct_next`];
    /// None: a single frame, [`reconstruct`]).
    pub reuse: Option<ReuseReport>,
}

/// Timings and warnings as the stages add them.
#[derive(Debug, Default)]
pub(crate) struct RunLog {
    pub timings: Vec<(String, f64)>,
    pub warnings: Vec<String>,
}

/// Reconstructs the requested views of `rig` from `captures`.
pub fn reconstruct(
    rig: &Rig,
    captures: &ArrayCaptures,
    settings: &PipelineSettings<'_>,
    progress: &Progress<'_>,
) -> Result<LightField> {
    let (mut field, _) = reconstruct_frame(rig, captures, settings, progress, None, false, None)?;
    field.reuse = None;
    Ok(field)
}

/// [`reconstruct`], handing each view to `sink` as soon as it is done. A sink that writes
/// each view's images and takes them out of the view (as [`LightFieldWriter::view`] does)
/// keeps one view's images in memory instead of every view's: on arrays of many cameras
/// at full resolution, the registered stacks are most of a run's memory.
pub fn reconstruct_streaming(
    rig: &Rig,
    captures: &ArrayCaptures,
    settings: &PipelineSettings<'_>,
    progress: &Progress<'_>,
    sink: &mut ViewSink<'_>,
) -> Result<LightField> {
    let (mut field, _) =
        reconstruct_frame(rig, captures, settings, progress, None, false, Some(sink))?;
    field.reuse = None;
    Ok(field)
}

/// [`reconstruct`] of one frame of a sequence, starting from what the previous frame
/// handed on (`previous`; None: the first frame) where that is sound (temporal reuse,
/// see `reuse.rs`): the search range narrowed by the previous maps, each view's scene
/// prior, unless the frame is a cut. Returns the field, whose [`LightField::reuse`] says
/// what was reused, and what this frame hands to the next.
pub fn reconstruct_next(
    rig: &Rig,
    captures: &ArrayCaptures,
    settings: &PipelineSettings<'_>,
    progress: &Progress<'_>,
    previous: Option<&FrameCarry>,
) -> Result<(LightField, FrameCarry)> {
    let (field, carry) =
        reconstruct_frame(rig, captures, settings, progress, previous, true, None)?;
    let carry =
        carry.ok_or_else(|| Error::setting("temporal reuse", "nothing handed on", "a carry"))?;
    Ok((field, carry))
}

/// A frame, starting from `previous`; with `hand_on`, what the next frame takes (a
/// single frame builds none: it costs a copy of every view's measurements and spectra);
/// each view goes to `sink` when it is done.
fn reconstruct_frame(
    rig: &Rig,
    captures: &ArrayCaptures,
    settings: &PipelineSettings<'_>,
    progress: &Progress<'_>,
    previous: Option<&FrameCarry>,
    hand_on: bool,
    sink: Option<&mut ViewSink<'_>>,
) -> Result<(LightField, Option<FrameCarry>)> {
    settings.validate()?;
    if rig.cameras.len() < 2 {
        return Err(Error::rig_layout(
            format!("rig '{}'", rig.file.name),
            format!(
                "one camera ({})",
                rig.cameras.first().map_or("none", |c| c.name.as_str())
            ),
            "an array of at least two cameras (a light field needs views to register)",
        ));
    }
    check_captures_follow_rig(rig, captures)?;
    if settings.spectra {
        crate::rig::check_filters(rig)?;
    }
    if let Disparities::Search(DisparitySearch::Fixed(range)) = settings.disparities {
        let geometry = ArrayGeometry::of_rig(rig);
        check_search_range(range, &geometry, captures.width, captures.height)?;
    }
    check_capture_signal(captures, settings.saturation_level)?;
    let requested = requested_views(rig, settings.views.as_deref())?;
    let plan = SolvePlan::new(&settings.solve)?;
    let mut log = RunLog::default();

    settings.check_cancelled("rectification")?;
    let rectified = rectify_array(rig, captures, settings.saturation_level, &mut log, progress)?;
    let captures = rectified.as_ref().map_or(captures, |r| &r.captures);
    settings.check_cancelled("calibration")?;
    let calibrated = calibrate_array(rig, captures, settings, &mut log)?;
    // The grey captures judge this frame against the previous one and go to the next;
    // a single frame needs neither.
    let clock = std::time::Instant::now();
    let greys = match previous.is_some() || hand_on {
        true => captures.grey_images(),
        false => Vec::new(),
    };
    let (reuse, correlation) = match previous {
        Some(carry) => carry.judge(&greys),
        None => (None, None),
    };
    let cut = previous.is_some() && reuse.is_none();
    let mut report = ReuseReport::fresh(previous.is_some(), cut, correlation);
    // Where each camera's capture moved since the references the previous frame kept;
    // the references follow the captures where they moved.
    let now: Vec<&Image<f32>> = calibrated.views.iter().map(|v| &v.image).collect();
    let (changes, references) = match reuse {
        Some(r) => r.carry.camera_changes(&now),
        None if hand_on => (None, now.iter().map(|&i| i.clone()).collect()),
        None => (None, Vec::new()),
    };
    log.timings
        .push(("frame changes".to_string(), clock.elapsed().as_secs_f64()));
    settings.check_cancelled("registration")?;
    let registered = register_array(
        rig,
        captures,
        &calibrated,
        settings,
        (reuse, changes.as_ref(), &mut report),
        &mut log,
        progress,
    )?;
    let mut pass = ViewPass::new(rig, &calibrated, &registered, &plan, settings);
    pass.changes = changes.as_ref();
    pass.hand_on = hand_on;
    let carried_views = reuse.map(|r| r.carry.views.as_slice());
    let layout = FieldLayout {
        width: captures.width,
        height: captures.height,
        bands: match settings.spectra {
            true => rig.reconstruction_shape()?.wavelengths(),
            false => Vec::new(),
        },
        channel_labels: calibrated.sensing.row_labels.clone(),
    };
    let (views, handed_on) = pass.run_all(
        &requested,
        carried_views,
        (&layout, sink),
        &mut log,
        progress,
    )?;
    report.priors_carried = views
        .iter()
        .filter(|v| v.solve.scene_prior.is_some_and(|p| p.carried))
        .count();
    report.priors_learned = views
        .iter()
        .filter(|v| v.solve.scene_prior.is_some_and(|p| !p.carried))
        .count();
    report.reused_pixels = views.iter().map(|v| v.solve.reused_pixels).sum();
    let mut carried_views = vec![None; rig.cameras.len()];
    for (&v, view) in requested.iter().zip(handed_on) {
        carried_views[v] = Some(view);
    }
    let carry = hand_on.then(|| FrameCarry {
        greys,
        references,
        maps: registered.disparities.clone(),
        range: registered.whole_range,
        views: carried_views,
    });

    let solve_stages = match settings.spectra {
        true => plan.names(),
        false => Vec::new(),
    };
    let stages = [
        rectified.is_some().then_some("rectification"),
        Some("calibration"),
        Some("registration"),
        Some("warping"),
    ]
    .into_iter()
    .flatten()
    .chain(solve_stages.iter().copied())
    .collect();
    for (stage, seconds) in &log.timings {
        tracing::debug!("stage {stage}: {seconds:.3} s");
    }
    let field = LightField {
        width: layout.width,
        height: layout.height,
        bands: layout.bands,
        views,
        channel_labels: layout.channel_labels,
        calibration: calibrated.calibration,
        rectification: rectified.map(|r| r.plan),
        search_range: registered.search_range,
        solve: settings.solve,
        solve_stages,
        stages,
        common_signals: registered.common_signals,
        condition_number: calibrated.condition_number,
        timings: log.timings,
        warnings: log.warnings,
        reuse: Some(report),
    };
    Ok((field, carry))
}

/// Checks that the captures hold one capture per camera of the rig, in its order.
fn check_captures_follow_rig(rig: &Rig, captures: &ArrayCaptures) -> Result<()> {
    let follows = captures.cameras.len() == rig.cameras.len()
        && captures
            .cameras
            .iter()
            .zip(&rig.cameras)
            .all(|(a, b)| a.name == b.name);
    if follows {
        Ok(())
    } else {
        Err(Error::captures(
            "captures",
            "a different set or order of cameras than the rig's",
            "one capture per camera of the rig, in its order",
        ))
    }
}

/// The cameras (rig order) of the requested views; None: every camera.
fn requested_views(rig: &Rig, views: Option<&[String]>) -> Result<Vec<usize>> {
    let Some(list) = views else {
        return Ok((0..rig.cameras.len()).collect());
    };
    list.iter().map(|name| rig.camera_index(name)).collect()
}
