//! `anaglyph.simulate`: a scene rendered through a rig, in memory.

use crate::arrays::array;
use crate::compute::run;
use crate::errors::IntoPyResult;
use crate::rig::Rig;
use anaglyph_core::io::to_u16_sample;
use anaglyph_core::scene::{Scene, SceneFile};
use anaglyph_core::simulate::{DarkSignal, Simulation, SimulationSettings};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Renders `scene` (a preset, "random" or a scene file) through `rig` at `width x height`.
/// Returns a dict: `captures`, `whites` (and `darks` with a dark signal) as uint16 arrays
/// per camera, exactly what the CLI writes as 16-bit PNG files; `reflectance` (float32
/// `(H, W, bands)`), `disparity` and `depth` (float32 `(H, W)`, NaN where nothing is hit)
/// per camera; `wavelengths` (nm), `exposures` and `saturated_values` per camera.
#[pyfunction]
#[pyo3(signature = (scene, rig, width, height, seed=0, noise=true, supersampling=2,
                    vignetting=0.0, dark=None, frame=0))]
#[allow(clippy::too_many_arguments)]
pub fn simulate<'py>(
    py: Python<'py>,
    scene: &str,
    rig: &Rig,
    width: usize,
    height: usize,
    seed: u64,
    noise: bool,
    supersampling: usize,
    vignetting: f64,
    dark: Option<(f64, f64)>,
    frame: u64,
) -> PyResult<Bound<'py, PyDict>> {
    let (file, base) = SceneFile::named(scene, seed).py()?;
    let file = file.at_frame(frame);
    let mut settings = SimulationSettings {
        width,
        height,
        supersampling,
        seed,
        frame,
        vignetting,
        dark: dark.map(|(level, pattern)| DarkSignal { level, pattern }),
        ..SimulationSettings::default()
    };
    if !noise {
        settings.noise = None;
    }
    let rig = &rig.inner;
    let simulation = run(py, || {
        let scene = Scene::resolve(file, &base)?;
        Simulation::run(rig, &scene, settings)
    })?;
    let out = PyDict::new(py);
    let groups = [
        "captures",
        "whites",
        "darks",
        "reflectance",
        "disparity",
        "depth",
        "exposures",
        "saturated_values",
    ];
    for group in groups {
        out.set_item(group, PyDict::new(py))?;
    }
    let group = |name: &str| -> PyResult<Bound<'py, PyDict>> {
        Ok(out
            .get_item(name)?
            .expect("made above")
            .cast_into::<PyDict>()?)
    };
    let (w, h, bands) = (width, height, simulation.bands.len());
    for view in simulation.views {
        let picture_shape: Vec<usize> = match view.channels {
            1 => vec![h, w],
            c => vec![h, w, c],
        };
        let quantised = |values: &[f32]| values.iter().map(|&v| to_u16_sample(v)).collect();
        let name = view.name.as_str();
        group("captures")?.set_item(
            name,
            array::<u16>(py, &picture_shape, quantised(&view.capture))?,
        )?;
        group("whites")?.set_item(
            name,
            array::<u16>(py, &picture_shape, quantised(&view.white))?,
        )?;
        if let Some(dark) = &view.dark {
            group("darks")?.set_item(name, array::<u16>(py, &picture_shape, quantised(dark))?)?;
        }
        group("reflectance")?.set_item(name, array(py, &[h, w, bands], view.truth)?)?;
        group("disparity")?.set_item(name, array(py, &[h, w], view.disparity)?)?;
        group("depth")?.set_item(name, array(py, &[h, w], view.depth)?)?;
        group("exposures")?.set_item(name, view.exposure)?;
        group("saturated_values")?.set_item(name, view.saturated)?;
    }
    out.set_item(
        "wavelengths",
        array(py, &[bands], simulation.bands.clone())?,
    )?;
    Ok(out)
}
