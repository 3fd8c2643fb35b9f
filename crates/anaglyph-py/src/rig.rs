//! `anaglyph.Rig`: a camera array, its filters and its sensing matrix; and
//! `select_filters`.

use crate::arrays::{array, F64Array};
use crate::compute::run;
use crate::errors::IntoPyResult;
use anaglyph_core::capture::CameraNoise;
use anaglyph_core::choice::Choice;
use anaglyph_core::filters::{
    builtin_candidates, select_for_sensor, SelectionCriterion, SelectionOptions, EXHAUSTIVE_LIMIT,
};
use anaglyph_core::rig::{
    resolve_curve, resolve_optional_curve, OutOfBand, RigFile, SensingMatrix,
};
use anaglyph_core::spectrum::ResponseCurve;
use numpy::PyArrayDyn;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::{Path, PathBuf};

/// A camera array: its cameras (names, positions, filters, sensors), illuminant and
/// reconstruction bands.
#[pyclass(module = "anaglyph", frozen)]
pub struct Rig {
    pub inner: anaglyph_core::rig::Rig,
}

#[pymethods]
impl Rig {
    /// Reads and checks a rig file (TOML); relative paths in it start from its folder.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        Ok(Rig {
            inner: anaglyph_core::rig::Rig::load(&path).py()?,
        })
    }

    /// A rig from TOML text; relative paths in it start from `base_dir` (default: the
    /// working folder).
    #[staticmethod]
    #[pyo3(signature = (text, base_dir=None))]
    fn from_toml(text: &str, base_dir: Option<PathBuf>) -> PyResult<Self> {
        let file = RigFile::from_toml_str(text, "rig TOML text").py()?;
        let base = base_dir.unwrap_or_else(|| PathBuf::from("."));
        Ok(Rig {
            inner: anaglyph_core::rig::Rig::from_file(file, base).py()?,
        })
    }

    /// Pickling (Dask ships a rig to its workers): the TOML text and the folder its
    /// relative paths start from, which `Rig.from_toml` reads back.
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, (String, PathBuf))> {
        let rig = &slf.get().inner;
        let base = std::path::absolute(&rig.base_dir).unwrap_or_else(|_| rig.base_dir.clone());
        let from_toml = slf.get_type().getattr("from_toml")?;
        Ok((from_toml, (rig.file.to_toml_string().py()?, base)))
    }

    /// A built-in rig: "paper-2x4", "mono-3x3" or "hexagon-7".
    #[staticmethod]
    fn preset(name: &str) -> PyResult<Self> {
        Ok(Rig {
            inner: anaglyph_core::rig::Rig::preset(name).py()?,
        })
    }

    /// The rig as TOML text (what `Rig.from_toml` reads).
    fn to_toml(&self) -> PyResult<String> {
        self.inner.file.to_toml_string().py()
    }

    /// The rig's name.
    #[getter]
    fn name(&self) -> String {
        self.inner.file.name.clone()
    }

    /// One dict per camera, in the rig's order: `name`, `position_mm` (x, y), `filter`
    /// and `sensor` (curve names; `filter` None where the rig gives none, which only a
    /// registration-only run accepts), `channels` (1 or 3), `reference` (the camera views
    /// are registered to by calibration).
    #[getter]
    fn cameras<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let list = PyList::empty(py);
        for (i, cam) in self.inner.cameras.iter().enumerate() {
            let d = PyDict::new(py);
            d.set_item("name", &cam.name)?;
            d.set_item("position_mm", (cam.position_mm[0], cam.position_mm[1]))?;
            d.set_item("filter", cam.filter.as_ref().map(|f| f.name()))?;
            d.set_item("sensor", cam.sensor.name())?;
            d.set_item("channels", cam.sensor.channel_count())?;
            d.set_item("reference", i == self.inner.reference)?;
            list.append(d)?;
        }
        Ok(list)
    }

    /// The reconstruction bands' centres, nm.
    #[getter]
    fn wavelengths<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let bands = self.inner.reconstruction_shape().py()?.wavelengths();
        array(py, &[bands.len()], bands)
    }

    /// The camera channel of each row of C, e.g. "r0c1:R".
    fn channel_labels(&self, py: Python<'_>) -> PyResult<Vec<String>> {
        let rig = &self.inner;
        Ok(run(py, || SensingMatrix::of_rig(rig))?.row_labels)
    }

    /// The sensing matrix C (rows: camera channels, columns: spectral unknowns) and the
    /// unknowns' wavelengths in nm. With `out_of_band = "extend"` (the default) the
    /// unknowns extend beyond the reconstruction bands over the curves' whole support, so
    /// that `demux(P, C)` accounts for all the light the cameras integrate; the bands are
    /// the columns whose wavelengths are in `rig.wavelengths`.
    fn sensing_matrix<'py>(&self, py: Python<'py>) -> PyResult<(F64Array<'py>, F64Array<'py>)> {
        let rig = &self.inner;
        let c = run(py, || SensingMatrix::of_rig(rig))?;
        let wavelengths = c.unknowns.wavelengths();
        let (rows, cols) = (c.rows(), c.cols());
        Ok((
            array(py, &[rows, cols], c.values().to_vec())?,
            array(py, &[wavelengths.len()], wavelengths)?,
        ))
    }

    /// cond(C), the ratio of C's largest to smallest singular value.
    #[getter]
    fn condition_number(&self, py: Python<'_>) -> PyResult<f64> {
        let rig = &self.inner;
        run(py, || SensingMatrix::of_rig(rig)?.condition_number())
    }

    fn __repr__(&self) -> String {
        format!(
            "Rig('{}', {} cameras: {})",
            self.inner.file.name,
            self.inner.cameras.len(),
            self.inner
                .cameras
                .iter()
                .map(|c| c.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )
    }
}

/// The best subsets of candidate filters for a sensor (paper section 3.2), best first:
/// one dict per subset with `filters` (names), `condition_number` and `expected_rmse`.
#[pyfunction]
#[pyo3(signature = (
    count, sensor="builtin:canon_eos_5d_mark_ii", illuminant="builtin:cie_a",
    criterion="condition", candidates=None, lam=0.01, full_well=10_000.0, read_noise=5.0,
    keep=5, out_of_band="extend"
))]
#[allow(clippy::too_many_arguments)]
pub fn select_filters<'py>(
    py: Python<'py>,
    count: usize,
    sensor: &str,
    illuminant: Option<&str>,
    criterion: &str,
    candidates: Option<Vec<String>>,
    lam: f64,
    full_well: f64,
    read_noise: f64,
    keep: usize,
    out_of_band: &str,
) -> PyResult<Bound<'py, PyList>> {
    let here = Path::new(".");
    let criterion = SelectionCriterion::parse_choice(criterion).py()?;
    let out_of_band = OutOfBand::parse_choice(out_of_band).py()?;
    let sensor = resolve_curve(sensor, here).py()?;
    let illuminant = match illuminant {
        Some(name) => resolve_optional_curve(name, here).py()?,
        None => None,
    };
    let candidates: Vec<ResponseCurve> = match candidates {
        None => builtin_candidates().py()?,
        Some(names) => names
            .iter()
            .map(|n| resolve_curve(n, here))
            .collect::<anaglyph_core::Result<_>>()
            .py()?,
    };
    let options = SelectionOptions {
        count,
        criterion,
        noise: CameraNoise {
            full_well_electrons: full_well,
            read_noise_electrons: read_noise,
            ..CameraNoise::default()
        },
        lambda: lam,
        keep,
        exhaustive_limit: EXHAUSTIVE_LIMIT,
    };
    let report = run(py, || {
        select_for_sensor(
            &candidates,
            &sensor,
            illuminant.as_ref(),
            &options,
            out_of_band,
        )
    })?;
    let list = PyList::empty(py);
    for subset in &report.best {
        let d = PyDict::new(py);
        let names: Vec<&str> = subset
            .filters
            .iter()
            .map(|&f| report.candidates[f].as_str())
            .collect();
        d.set_item("filters", names)?;
        d.set_item("condition_number", subset.condition_number)?;
        d.set_item("expected_rmse", subset.expected_rmse)?;
        list.append(d)?;
    }
    Ok(list)
}
