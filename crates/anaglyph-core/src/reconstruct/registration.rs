//! The third stage: a disparity map per camera, from registration of the calibrated
//! captures ([`crate::register`]) or given (e.g. the simulator's truth), and how well each
//! view's map agrees with its neighbours' (no truth needed).
//!
//! In: the rig, its captures in C's units and the settings. Out: the maps (disparity per
//! column step, NaN where unknown), the search range when it was estimated, the common
//! signals matched by, the pixels moved to planes of ambiguous regions, the agreement.

use super::reuse::{at_narrowed_ends, previous_maps, Reuse, ReuseReport};
use super::view_reuse::CameraChanges;
use super::{
    ArrayCaptures, CalibratedArray, Disparities, DisparitySearch, PipelineSettings, RunLog, Stage,
};
use crate::disparity::{DisparityConvention, DisparityMap, DisparityRange};
use crate::register::{
    common_signal_images, common_signals, estimate_search_range, neighbour_agreement,
    pair_agreements, register_views, ArrayGeometry, CommonSignal, MatchingImage, PairAgreement,
    RegistrationMode, RegistrationSettings, SearchRange, ViewImage, COMMON_SIGNALS,
};
use crate::rig::Rig;
use crate::stereo::GreyImage;
use crate::{Error, Result};

/// The array's disparity maps and what registration reports about them.
#[derive(Default)]
pub(super) struct RegisteredArray {
    /// Per camera (rig order), per column step of the array.
    pub disparities: Vec<DisparityMap>,
    pub search_range: Option<SearchRange>,
    /// The whole range of a sequence's search (estimated, carried or given; None: given
    /// disparities), which the next frame narrows.
    pub whole_range: Option<DisparityRange>,
    pub common_signals: Option<Vec<CommonSignal>>,
    pub moved_to_planes: Option<Vec<usize>>,
    /// Per camera: the fraction of its disparities a neighbour's map confirms (NaN: none
    /// finite).
    pub agreement: Vec<f64>,
    /// Per camera: its agreement with each neighbour.
    pub pair_agreements: Vec<Vec<PairAgreement>>,
}

pub(super) fn register_array(
    rig: &Rig,
    captures: &ArrayCaptures,
    calibrated: &CalibratedArray,
    settings: &PipelineSettings<'_>,
    reuse: (Option<Reuse<'_>>, Option<&CameraChanges>, &mut ReuseReport),
    log: &mut RunLog,
    progress: &super::Progress<'_>,
) -> Result<RegisteredArray> {
    let geometry = ArrayGeometry::of_rig(rig);
    let mut registered = match &settings.disparities {
        Disparities::Given(given) => given_maps(given, rig, captures)?,
        Disparities::Search(search) => {
            let search = (*search, &geometry);
            estimate_maps(captures, calibrated, search, settings, reuse, log, progress)?
        }
    };
    let maps = &registered.disparities;
    registered.agreement = neighbour_agreement(maps, &geometry);
    registered.pair_agreements = (0..maps.len())
        .map(|i| pair_agreements(maps, &geometry, i))
        .collect();
    Ok(registered)
}

/// The given maps, checked against the rig and the captures' size.
fn given_maps(
    given: &[DisparityMap],
    rig: &Rig,
    captures: &ArrayCaptures,
) -> Result<RegisteredArray> {
    if given.len() != rig.cameras.len() {
        return Err(Error::Shape {
            op: "given disparities: one map per camera".into(),
            got: vec![given.len()],
            expected: vec![rig.cameras.len()],
        });
    }
    for map in given {
        map.check(
            captures.width,
            captures.height,
            DisparityConvention::ColumnStep,
        )?;
    }
    Ok(RegisteredArray {
        disparities: given.to_vec(),
        ..Default::default()
    })
}

/// Registration of the captures over `search`'s range, estimated when asked; in a
/// sequence, the carried range narrowed by the previous frame's maps (again over the
/// whole range when the maps pile up at a narrowed end).
fn estimate_maps(
    captures: &ArrayCaptures,
    calibrated: &CalibratedArray,
    (search, geometry): (DisparitySearch, &ArrayGeometry),
    settings: &PipelineSettings<'_>,
    (reuse, changes, report): (Option<Reuse<'_>>, Option<&CameraChanges>, &mut ReuseReport),
    log: &mut RunLog,
    progress: &super::Progress<'_>,
) -> Result<RegisteredArray> {
    let (matching, common) = matching_images(calibrated, settings)?;
    let images = view_images(captures, matching);
    let carried = reuse.and_then(|r| r.carry.range);
    let (whole, search_range) = match (search, carried) {
        (DisparitySearch::Fixed(range), _) => (range, None),
        (DisparitySearch::Auto, Some(range)) => (range, None),
        (DisparitySearch::Auto, None) => {
            // The estimate searches a coarse range of its own.
            let coarse = settings.registration_over(DisparityRange::up_to(2)?);
            let range = estimate_search_range(&images, geometry, &coarse)?;
            log.timings
                .push(("search range".to_string(), range.seconds));
            (range.range, Some(range))
        }
    };
    let narrowed = reuse.and_then(|r| r.carry.narrowed(whole));
    // Each tile searches around the previous frame's maps.
    let previous = reuse.map(|r| previous_maps(r.carry, changes, whole));
    let register = |range: DisparityRange, previous| {
        register_views(
            &images,
            geometry,
            &RegistrationSettings {
                previous,
                ..settings.registration_over(range)
            },
            &|done, total| progress(Stage::Registration, done, total),
        )
    };
    let mut registration = register(narrowed.unwrap_or(whole), previous)?;
    if let Some(narrowed) = narrowed {
        report.narrowed_range = Some(narrowed);
        if at_narrowed_ends(&registration.disparities, narrowed, whole) {
            report.range_fallback = true;
            for (name, seconds) in &registration.timings {
                log.timings
                    .push((format!("registration (narrowed): {name}"), *seconds));
            }
            // The previous maps missed the surfaces: registered as a frame alone is.
            registration = register(whole, None)?;
        }
    }
    for (name, seconds) in &registration.timings {
        log.timings
            .push((format!("registration: {name}"), *seconds));
    }
    if previous.is_some() && !report.range_fallback {
        report.banded = registration.banded;
    }
    Ok(RegisteredArray {
        disparities: registration.disparities,
        search_range,
        whole_range: Some(whole),
        common_signals: common,
        moved_to_planes: registration.moved_to_planes,
        ..RegisteredArray::default()
    })
}

/// Per camera, the images multi-baseline registration compares by (empty: luminance),
/// and the common signals they come from (None: luminance).
type MatchingImages = (Vec<Vec<GreyImage>>, Option<Vec<CommonSignal>>);

/// The [`MatchingImages`] of the calibrated views.
fn matching_images(
    calibrated: &CalibratedArray,
    settings: &PipelineSettings<'_>,
) -> Result<MatchingImages> {
    let views = &calibrated.views;
    let by_common_signals = settings.matching_image == MatchingImage::CommonSignals
        && settings.registration == RegistrationMode::MultiBaseline;
    if !by_common_signals {
        return Ok((vec![Vec::new(); views.len()], None));
    }
    let channels: Vec<usize> = views.iter().map(|v| v.image.channels).collect();
    let signals = common_signals(&calibrated.sensing, &channels, COMMON_SIGNALS)?;
    let images: Vec<Vec<GreyImage>> = signals
        .iter()
        .map(|signal| common_signal_images(views, signal))
        .collect();
    let mut per_camera: Vec<Vec<GreyImage>> = (0..views.len())
        .map(|_| Vec::with_capacity(signals.len()))
        .collect();
    for per_view in images {
        for (camera, image) in per_camera.iter_mut().zip(per_view) {
            camera.push(image);
        }
    }
    Ok((per_camera, Some(signals)))
}

/// Each camera's grey image, with its matching images and the pixels it measured (None:
/// all).
fn view_images(captures: &ArrayCaptures, matching: Vec<Vec<GreyImage>>) -> Vec<ViewImage> {
    captures
        .grey_images()
        .into_iter()
        .zip(matching)
        .zip(&captures.cameras)
        .map(|((image, matching), cam)| ViewImage {
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
        .collect()
}
