//! `anaglyph.demux`: the paper's Eq. 6 for every pixel of an array in memory.

use crate::arrays::{array, c_order, shape_of};
use crate::compute::run;
use crate::errors::{shape_error, to_py, type_error, IntoPyResult};
use anaglyph_core::choice::Choice;
use anaglyph_core::demux::{demultiplex_as, DemuxOptions, Sample, Solver};
use anaglyph_core::Error;
use numpy::{Element, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

/// Solves Eq. 6 for one dtype of P.
#[allow(clippy::too_many_arguments)]
fn solve<'py, T: Sample + Element>(
    py: Python<'py>,
    p: &PyReadonlyArrayDyn<'py, T>,
    c: &[f64],
    rows: usize,
    n: usize,
    mask: Option<&[bool]>,
    options: &DemuxOptions,
) -> PyResult<Bound<'py, PyAny>> {
    let mut shape = p.shape().to_vec();
    let measurements = c_order(p);
    let spectra = run(py, || {
        demultiplex_as::<T, T>(c, rows, &measurements, mask, 0..n, options).map(|(s, _)| s)
    })?;
    if let Some(last) = shape.last_mut() {
        *last = n;
    }
    Ok(array(py, &shape, spectra)?.into_any())
}

/// Solves the paper's Eq. 6, `min ||C s - p||² + λ ||D s||²` with `s >= 0` (D: second
/// differences), for every pixel of `P`.
#[pyfunction]
#[pyo3(signature = (p, c, lam=0.01, solver="exact", mask=None, tolerance=1e-10))]
pub fn demux<'py>(
    py: Python<'py>,
    p: &Bound<'py, PyAny>,
    c: &Bound<'py, PyAny>,
    lam: f64,
    solver: &str,
    mask: Option<&Bound<'py, PyAny>>,
    tolerance: f64,
) -> PyResult<Bound<'py, PyAny>> {
    let options = DemuxOptions {
        lambda: lam,
        solver: Solver::parse_choice(solver).py()?,
        tolerance,
        ..DemuxOptions::default()
    };
    let c_shape = shape_of(c).ok_or_else(|| type_error("C: expected a 2-D numpy array"))?;
    let [rows, n] = c_shape[..] else {
        return Err(to_py(Error::raster(
            "C",
            format!("shape {c_shape:?}"),
            "a 2-D matrix (measurements x unknowns)",
        )));
    };
    let c: Vec<f64> = c
        .call_method1("astype", ("float64",))?
        .extract::<PyReadonlyArrayDyn<'_, f64>>()?
        .as_array()
        .iter()
        .copied()
        .collect();
    let p_shape = shape_of(p).ok_or_else(|| type_error("P: expected a numpy array"))?;
    if p_shape.last() != Some(&rows) {
        let mut expected = p_shape.clone();
        match expected.last_mut() {
            Some(last) => *last = rows,
            None => expected.push(rows),
        }
        return Err(shape_error(
            format!("P against C's {rows} rows (the last axis holds the measurements)"),
            &p_shape,
            &expected,
        ));
    }
    let mask_values: Option<Vec<bool>> = match mask {
        None => None,
        Some(m) => {
            let m = m
                .extract::<PyReadonlyArrayDyn<'_, bool>>()
                .map_err(|_| type_error("mask: expected a numpy array of bool with P's shape"))?;
            if m.shape() != p_shape.as_slice() {
                return Err(shape_error("mask against P", m.shape(), &p_shape));
            }
            Some(m.as_array().iter().copied().collect())
        }
    };
    let mask = mask_values.as_deref();
    if let Ok(p) = p.extract::<PyReadonlyArrayDyn<'py, f32>>() {
        solve(py, &p, &c, rows, n, mask, &options)
    } else if let Ok(p) = p.extract::<PyReadonlyArrayDyn<'py, f64>>() {
        solve(py, &p, &c, rows, n, mask, &options)
    } else {
        Err(type_error(
            "P: expected a numpy array of float32 or float64 (convert with P.astype(np.float32))",
        ))
    }
}
