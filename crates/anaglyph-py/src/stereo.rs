//! `anaglyph.match`: the disparity of one rectified pair.

use crate::arrays::{array, image};
use crate::compute::run;
use crate::errors::IntoPyResult;
use anaglyph_core::choice::Choice;
use anaglyph_core::disparity::DisparityRange;
use anaglyph_core::reconstruct::check_signal;
use anaglyph_core::stereo::{match_pair, Contrast, GreyChannel, MatchMethod, MatchSettings};
use numpy::PyArrayDyn;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// The disparity of a rectified pair (`x_right = x_left - d`, `min <= d < max`) through the
/// full stereo chain; NaN where unknown. Returns the map and a dict of what ran: the
/// contrast vote (when `contrast="auto"`) and each stage's seconds.
#[pyfunction]
#[pyo3(signature = (left, right, disp_min, disp_max, method="mccnn", contrast="auto",
                    channel="luminance", model=None))]
#[allow(clippy::too_many_arguments)]
pub fn match_pair_arrays<'py>(
    py: Python<'py>,
    left: &Bound<'py, PyAny>,
    right: &Bound<'py, PyAny>,
    disp_min: i32,
    disp_max: i32,
    method: &str,
    contrast: &str,
    channel: &str,
    model: Option<PathBuf>,
) -> PyResult<(Bound<'py, PyArrayDyn<f32>>, Bound<'py, PyDict>)> {
    let range = DisparityRange::new(disp_min, disp_max).py()?;
    let method = MatchMethod::parse_choice(method).py()?;
    let contrast = Contrast::parse_choice(contrast).py()?;
    let channel = GreyChannel::parse_choice(channel).py()?;
    let left = channel
        .of(&image(left, "left image", None)?, "left image")
        .py()?;
    let right = channel
        .of(&image(right, "right image", None)?, "right image")
        .py()?;
    check_signal(&left, f32::INFINITY, "left image").py()?;
    check_signal(&right, f32::INFINITY, "right image").py()?;
    let output = run(py, || {
        let network = method.network(model.as_deref())?;
        let cost = method.cost(network.as_ref())?;
        let mut settings = MatchSettings::for_cost(&cost, range);
        settings.contrast = contrast;
        match_pair(&left, &right, &cost, &settings)
    })?;
    let info = PyDict::new(py);
    info.set_item("method", method.name())?;
    if let Some(vote) = &output.contrast {
        let d = PyDict::new(py);
        d.set_item("inverted", vote.inverted)?;
        d.set_item("inverted_share", vote.inverted_share)?;
        d.set_item("windows", vote.windows)?;
        info.set_item("contrast", d)?;
    }
    let timings = PyDict::new(py);
    for (stage, seconds) in &output.timings {
        timings.set_item(*stage, *seconds)?;
    }
    info.set_item("timings_s", timings)?;
    let map = output.disparity;
    Ok((array(py, &[map.height, map.width], map.data)?, info))
}
