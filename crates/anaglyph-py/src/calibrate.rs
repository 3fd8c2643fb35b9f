//! `anaglyph.calibrate`: each camera's map onto the reference camera through the plane of
//! a checkerboard.

use crate::arrays::{array, image};
use crate::compute::run;
use crate::errors::{to_py, IntoPyResult};
use crate::rig::Rig;
use anaglyph_core::choice::Choice;
use anaglyph_core::plane_calibration::{
    calibrate_to_plane, detect_board, BoardCapture, BoardPattern, PlaneModel,
};
use anaglyph_core::Error;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Calibrates the array to the plane of the checkerboard every camera sees in `boards`
/// (one capture per camera of `rig`). Returns a dict per camera: `homography` (3x3 onto
/// the reference camera, what `reconstruct(calibration=...)` takes), `residual_rms_px`,
/// `residual_max_px`, `rotation_deg` (the map's turn at the image centre: beyond 90° for
/// a camera mounted otherwise than the reference), `seen` (how
/// the camera sees the board: "upright", "turned 180°", ...) and `corners`
/// (`(rows * cols, 2)` pixel positions, in the reference's order).
#[pyfunction]
#[pyo3(signature = (boards, rig, pattern, reference=None, model="homography"))]
pub fn calibrate<'py>(
    py: Python<'py>,
    boards: &Bound<'py, PyDict>,
    rig: &Rig,
    pattern: (usize, usize),
    reference: Option<String>,
    model: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let rig = &rig.inner;
    let model = PlaneModel::parse_choice(model).py()?;
    let pattern = board_pattern(pattern)?;
    let reference = match reference {
        Some(name) => rig.cameras[rig.camera_index(&name).py()?].name.clone(),
        None => rig.cameras[rig.reference].name.clone(),
    };
    let mut captures = Vec::with_capacity(rig.cameras.len());
    for cam in &rig.cameras {
        let board = boards.get_item(&cam.name)?.ok_or_else(|| {
            to_py(Error::captures(
                "boards",
                format!("no checkerboard capture of camera {}", cam.name),
                "one per camera of the rig",
            ))
        })?;
        let picture = image(
            &board,
            &format!("checkerboard capture of camera {}", cam.name),
            None,
        )?;
        captures.push(BoardCapture::from_capture(&cam.name, &picture));
    }
    let calibration = run(py, || {
        calibrate_to_plane(&captures, pattern, &reference, model)
    })?;
    let out = PyDict::new(py);
    for fit in calibration.cameras {
        let d = PyDict::new(py);
        let h: Vec<f64> = fit.homography.iter().flatten().copied().collect();
        d.set_item("homography", array(py, &[3, 3], h)?)?;
        d.set_item("residual_rms_px", fit.residual_rms_px)?;
        d.set_item("residual_max_px", fit.residual_max_px)?;
        d.set_item("rotation_deg", fit.rotation_deg)?;
        d.set_item("seen", fit.orientation.seen)?;
        let corners: Vec<f64> = fit.corners.iter().flatten().copied().collect();
        d.set_item("corners", array(py, &[fit.corners.len(), 2], corners)?)?;
        out.set_item(&fit.name, d)?;
    }
    Ok(out)
}

/// `(cols, rows)` as a [`BoardPattern`], checked.
fn board_pattern(pattern: (usize, usize)) -> PyResult<BoardPattern> {
    format!("{}x{}", pattern.0, pattern.1)
        .parse()
        .map_err(|e: String| {
            to_py(Error::setting(
                "pattern",
                e,
                "(cols, rows) inner corners, 2 to 100 each",
            ))
        })
}

/// The inner corners of a checkerboard with `pattern=(cols, rows)` inner corners in one
/// picture (`(H, W)` or `(H, W, C)`, grey as the mean of its channels), as `calibrate`
/// finds them: `(rows * cols, 2)` pixel positions (x, y; pixel centres at integers), row
/// by row as the image shows the board. Raises UnusableError naming what was seen where
/// the board is not found.
#[pyfunction]
#[pyo3(signature = (image, pattern))]
pub fn find_board<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    pattern: (usize, usize),
) -> PyResult<Bound<'py, numpy::PyArrayDyn<f64>>> {
    let pattern = board_pattern(pattern)?;
    let picture = crate::arrays::image(image, "image", None)?;
    let capture = BoardCapture::from_capture("image", &picture);
    let board = run(py, || detect_board(&capture.image, pattern, "image"))?;
    let corners: Vec<f64> = board.corners.iter().flatten().copied().collect();
    array(py, &[board.corners.len(), 2], corners)
}
