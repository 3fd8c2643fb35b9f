//! The compiled part of the `anaglyph` Python package (`anaglyph._core`): thin bindings
//! of the core's public API. Arrays come in from numpy and go out as numpy arrays moved
//! from the core's buffers; every compute call releases the GIL and runs on the pool
//! `set_num_threads` chose; core errors become exceptions of one class per cause. The
//! pure-Python part (`python/anaglyph/`) adds progress bars, logging and result objects.

mod arrays;
mod calibrate;
mod compute;
mod errors;
mod files;
mod reconstruct;
mod rig;
mod simulate;
mod spectral;
mod stereo;

use anaglyph_core::choice::Choice;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Every named choice and its spellings, as the functions accept them.
#[pyfunction]
fn choices(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    fn names<T: Choice>() -> Vec<&'static str> {
        T::ALL.iter().map(|v| v.name()).collect()
    }
    use anaglyph_core::{demux, filters, plane_calibration, reconstruct, register, rig, stereo};
    let d = PyDict::new(py);
    d.set_item("solver", names::<demux::Solver>())?;
    d.set_item("criterion", names::<filters::SelectionCriterion>())?;
    d.set_item("out_of_band", names::<rig::OutOfBand>())?;
    d.set_item("method", names::<stereo::MatchMethod>())?;
    d.set_item("contrast", names::<stereo::Contrast>())?;
    d.set_item("channel", names::<stereo::GreyChannel>())?;
    d.set_item("preset", names::<reconstruct::Preset>())?;
    d.set_item("output", names::<reconstruct::Products>())?;
    d.set_item("registration", names::<register::RegistrationMode>())?;
    d.set_item("matching_image", names::<register::MatchingImage>())?;
    d.set_item("warp_kernel", names::<register::WarpKernel>())?;
    d.set_item("coarse_to_fine", names::<register::CoarseToFine>())?;
    d.set_item("model", names::<plane_calibration::PlaneModel>())?;
    Ok(d)
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    errors::register(m)?;
    m.add_class::<rig::Rig>()?;
    m.add_class::<reconstruct::FrameCarry>()?;
    m.add_class::<reconstruct::PendingWrite>()?;
    m.add_function(wrap_pyfunction!(choices, m)?)?;
    m.add_function(wrap_pyfunction!(compute::set_num_threads, m)?)?;
    m.add_function(wrap_pyfunction!(compute::get_num_threads, m)?)?;
    m.add_function(wrap_pyfunction!(compute::_panic_for_tests, m)?)?;
    m.add_function(wrap_pyfunction!(rig::select_filters, m)?)?;
    m.add_function(wrap_pyfunction!(spectral::demux, m)?)?;
    m.add_function(wrap_pyfunction!(stereo::match_pair_arrays, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::simulate, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate::find_board, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct::reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(files::read_envi, m)?)?;
    m.add_function(wrap_pyfunction!(files::write_envi, m)?)?;
    m.add_function(wrap_pyfunction!(files::read_pfm, m)?)?;
    m.add_function(wrap_pyfunction!(files::write_pfm, m)?)?;
    m.add_function(wrap_pyfunction!(files::read_image, m)?)?;
    m.add_function(wrap_pyfunction!(files::read_capture, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct::discover_frames, m)?)?;
    Ok(())
}
