//! The first stage: rectification of the array when its cameras carry calibrations
//! ([`crate::rectify`]), with warnings about what no image warp can correct.
//!
//! In: the rig and its captures. Out: the rectified captures and the plan (None: the
//! captures carry no calibrations, so they are taken as already rectified).

use super::{ArrayCaptures, CameraCapture, RunLog, Stage, SATURATION_WARNING};
use crate::rectify::{Calibration, Rectification, GRID_OFFSET_WARNING};
use crate::rig::Rig;
use crate::{Error, Result};

/// Rectified captures and how they were rectified.
pub(super) struct RectifiedArray {
    pub captures: ArrayCaptures,
    pub plan: Rectification,
}

/// Rectifies `captures` when their cameras carry calibrations (all or none must).
pub(super) fn rectify_array(
    rig: &Rig,
    captures: &ArrayCaptures,
    saturation_level: f32,
    log: &mut RunLog,
    progress: &super::Progress<'_>,
) -> Result<Option<RectifiedArray>> {
    let (with, without): (Vec<&CameraCapture>, Vec<&CameraCapture>) = captures
        .cameras
        .iter()
        .partition(|c| c.calibration.is_some());
    if with.is_empty() {
        return Ok(None);
    }
    if !without.is_empty() {
        return Err(Error::calibration(
            "rectification",
            format!(
                "cameras {} have a calibration but {} have none",
                camera_names(&with),
                camera_names(&without)
            ),
            "a calibration for every camera, or none for captures already rectified",
        ));
    }
    let clock = std::time::Instant::now();
    let plan = plan_of(rig, captures)?;
    let total = captures.cameras.len();
    let mut cameras = Vec::with_capacity(total);
    for (k, cam) in captures.cameras.iter().enumerate() {
        cameras.push(CameraCapture {
            name: cam.name.clone(),
            capture: plan.resample(k, &cam.capture, saturation_level)?,
            white: cam.white.clone(),
            exposure: cam.exposure,
            calibration: cam.calibration.clone(),
        });
        progress(Stage::Rectification, k + 1, total);
    }
    let rectified = ArrayCaptures {
        width: captures.width,
        height: captures.height,
        cameras,
    };
    log.warnings
        .extend(rectification_warnings(rig, &plan, &rectified));
    log.timings
        .push(("rectification".to_string(), clock.elapsed().as_secs_f64()));
    Ok(Some(RectifiedArray {
        captures: rectified,
        plan,
    }))
}

/// The plan of captures (in `rig`'s order) that all carry calibrations of one kind (poses
/// or homographies).
fn plan_of(rig: &Rig, captures: &ArrayCaptures) -> Result<Rectification> {
    let (mut poses, mut planes) = (Vec::new(), Vec::new());
    for (c, cam) in captures.cameras.iter().zip(&rig.cameras) {
        match &c.calibration {
            Some(Calibration::Pose(model)) => {
                poses.push((c.name.clone(), cam.position_mm, model.clone()))
            }
            Some(Calibration::Plane {
                homography,
                image_size,
            }) => {
                let size = (captures.width, captures.height);
                if let Some((w, h)) = image_size.filter(|s| *s != size) {
                    return Err(Error::calibration(
                        format!("calibration of camera {}", c.name),
                        format!("a homography made for {w}x{h} px images"),
                        format!("one for the captures' {}x{} px", size.0, size.1),
                    ));
                }
                planes.push((c.name.clone(), *homography))
            }
            None => {}
        }
    }
    let (w, h) = (captures.width, captures.height);
    match (poses.is_empty(), planes.is_empty()) {
        (false, true) => Rectification::plan(poses, w, h),
        (true, false) => Rectification::through_plane(planes, w, h),
        _ => Err(Error::calibration(
            "rectification",
            format!(
                "{} cameras calibrated with poses and {} with homographies",
                poses.len(),
                planes.len()
            ),
            "one kind of calibration for the whole array",
        )),
    }
}

fn camera_names(list: &[&CameraCapture]) -> String {
    list.iter()
        .map(|c| c.name.clone())
        .collect::<Vec<_>>()
        .join(", ")
}

/// What rectification cannot correct: optical centres off the rig's layout, a layout
/// stretched against the rig's, frames that reach outside the captures.
fn rectification_warnings(
    rig: &Rig,
    plan: &Rectification,
    rectified: &ArrayCaptures,
) -> Vec<String> {
    let mut warnings = Vec::new();
    let [sx, sy] = plan.common.map_or([0.0; 2], |c| c.scale);
    let scale = if sx > 0.0 { sx } else { sy };
    let offset = plan.worst_grid_offset_mm() / (scale * rig.disparity_baseline_mm);
    if offset > GRID_OFFSET_WARNING {
        warnings.push(format!(
            "rectification: an optical centre lies {:.1} % of the baseline off the rig's \
             layout; no image warp removes that parallax (about that fraction of each \
             disparity)",
            100.0 * offset
        ));
    }
    if sx > 0.0 && sy > 0.0 && ((sy / sx) - 1.0).abs() > GRID_OFFSET_WARNING {
        warnings.push(format!(
            "rectification: the calibrated camera positions are {sx:.3} x {sy:.3} times the \
             rig's along x and y; registration uses the rig's layout"
        ));
    }
    let cropped: f64 = rectified
        .cameras
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
    warnings
}
