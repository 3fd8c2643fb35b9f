//! The second stage: the sensing matrix of the rig and every capture calibrated into its
//! units ([`calibrate`]), with warnings about saturation, uneven white boards and an
//! ill-conditioned C.
//!
//! In: the rig and its (rectified) captures. Out: C, its condition number, each camera's
//! calibrated capture and calibration record.

use super::{calibrate, ArrayCaptures, CameraCalibration, PipelineSettings, RunLog};
use super::{BRIGHTER_THAN_WHITE_WARNING, SATURATION_WARNING, UNEVEN_WHITE_WARNING};
use crate::register::NormalisedView;
use crate::rig::{Rig, SensingMatrix, ILL_CONDITIONED_WARNING};
use crate::Result;

/// The array in C's units.
pub(super) struct CalibratedArray {
    pub sensing: SensingMatrix,
    pub condition_number: f64,
    /// Every camera's calibrated capture, rig order.
    pub views: Vec<NormalisedView>,
    pub calibration: Vec<CameraCalibration>,
}

pub(super) fn calibrate_array(
    rig: &Rig,
    captures: &ArrayCaptures,
    settings: &PipelineSettings<'_>,
    log: &mut RunLog,
) -> Result<CalibratedArray> {
    let clock = std::time::Instant::now();
    let sensing = match settings.spectra {
        true => SensingMatrix::of_rig(rig)?,
        false => {
            let (sensing, set_aside) = SensingMatrix::for_registration(rig)?;
            if !set_aside.is_empty() {
                log.warnings.push(format!(
                    "the filter curves of {} let none of the sensor's light through \
                     (sensor × filter × illuminant is zero): this registration-only run \
                     matches those cameras as unfiltered, and a run with cubes would refuse them",
                    set_aside.join(", ")
                ));
            }
            sensing
        }
    };
    let condition_number = sensing.condition_number()?;
    if settings.spectra
        && condition_number > ILL_CONDITIONED_WARNING
        && rig.file.reconstruction.lambda == 0.0
    {
        log.warnings.push(format!(
            "cond(C) = {condition_number:.3e} with lambda = 0: the solve amplifies noise; use lambda > 0"
        ));
    }
    let (views, calibration) = calibrate(
        captures,
        &sensing,
        settings.white_reflectance,
        settings.saturation_level,
        settings.spectra,
    )?;
    for (record, cam) in calibration.iter().zip(&captures.cameras) {
        log.warnings
            .extend(camera_warnings(record, cam.capture.data.len()));
    }
    log.timings
        .push(("calibration".to_string(), clock.elapsed().as_secs_f64()));
    Ok(CalibratedArray {
        sensing,
        condition_number,
        views,
        calibration,
    })
}

/// Saturation over [`SATURATION_WARNING`], a white board that varies by more than
/// [`UNEVEN_WHITE_WARNING`], and more than [`BRIGHTER_THAN_WHITE_WARNING`] of the values
/// brighter than a perfect white.
fn camera_warnings(record: &CameraCalibration, values: usize) -> Vec<String> {
    let mut warnings = Vec::new();
    let fraction = record.saturated_values as f64 / values.max(1) as f64;
    if fraction > SATURATION_WARNING {
        warnings.push(format!(
            "camera {}: {:.1} % of values saturated (masked)",
            record.name,
            100.0 * fraction
        ));
    }
    let worst = record
        .white_variation
        .as_ref()
        .and_then(|cv| cv.iter().cloned().reduce(f64::max));
    if let Some(worst) = worst.filter(|&w| w > UNEVEN_WHITE_WARNING) {
        warnings.push(format!(
            "camera {}: white board varies by {:.1} % across the frame (vignetting or uneven light): divided out pixel by pixel, right for the lens, wrong if the board was lit unlike the scene",
            record.name,
            100.0 * worst
        ));
    }
    if record.brighter_than_white > BRIGHTER_THAN_WHITE_WARNING {
        warnings.push(format!(
            "camera {}: {:.1} % of values brighter than a perfect white ({}): was it \
             captured at another exposure or under other light than the scene?",
            record.name,
            100.0 * record.brighter_than_white,
            record.method
        ));
    }
    warnings
}
