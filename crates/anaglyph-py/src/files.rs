//! The file formats at the edges: ENVI cubes, PFM maps and linear captures.

use crate::arrays::{c_order, image_array};
use crate::compute::run;
use crate::errors::{to_py, IntoPyResult};
use anaglyph_core::image::Image;
use anaglyph_core::io::{
    read_envi as core_read_envi, read_image_header, read_linear_image, read_pfm as core_read_pfm,
};
use anaglyph_core::io::{write_envi as core_write_envi, write_pfm as core_write_pfm, EnviCube};
use anaglyph_core::Error;
use numpy::{PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use std::path::PathBuf;

/// Reads an ENVI cube (`.hdr` and its data file): `(cube (H, W, bands) float32,
/// wavelengths in nm or None, band names or None)`.
#[pyfunction]
#[allow(clippy::type_complexity)]
pub fn read_envi<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(
    Bound<'py, PyArrayDyn<f32>>,
    Option<Vec<f64>>,
    Option<Vec<String>>,
)> {
    let cube = run(py, || core_read_envi(&path))?;
    let Image {
        width,
        height,
        channels,
        data,
    } = cube.image;
    let array = crate::arrays::array(py, &[height, width, channels], data)?;
    Ok((array, cube.wavelengths, cube.band_names))
}

/// Writes a `(H, W, bands)` cube as ENVI float32 (band-interleaved by pixel), with its
/// wavelengths (nm) and band names when given. Written atomically.
#[pyfunction]
#[pyo3(signature = (path, cube, wavelengths=None, band_names=None, description="anaglyph cube"))]
pub fn write_envi(
    py: Python<'_>,
    path: PathBuf,
    cube: &Bound<'_, PyAny>,
    wavelengths: Option<Vec<f64>>,
    band_names: Option<Vec<String>>,
    description: &str,
) -> PyResult<()> {
    let cube_array = cube
        .extract::<PyReadonlyArrayDyn<'_, f32>>()
        .or_else(|_| {
            cube.call_method1("astype", ("float32",))?
                .extract::<PyReadonlyArrayDyn<'_, f32>>()
        })
        .map_err(|_| crate::errors::type_error("cube: expected a numeric numpy array"))?;
    let [height, width, bands] = cube_array.shape()[..] else {
        return Err(to_py(Error::raster(
            "cube",
            format!("shape {:?}", cube_array.shape()),
            "(H, W, bands)",
        )));
    };
    let data = c_order(&cube_array).into_owned();
    for (what, len) in [
        ("wavelengths", wavelengths.as_ref().map(Vec::len)),
        ("band_names", band_names.as_ref().map(Vec::len)),
    ] {
        if let Some(len) = len.filter(|&l| l != bands) {
            return Err(to_py(Error::raster(
                what,
                format!("{len} values"),
                format!("one per band ({bands})"),
            )));
        }
    }
    let cube = EnviCube {
        image: Image::new(width, height, bands, data).py()?,
        wavelengths,
        band_names,
    };
    run(py, || core_write_envi(&path, &cube, description))
}

/// Reads a PFM file as float32 `(H, W)` or `(H, W, 3)`, top row first. Values are as
/// stored: anaglyph's disparity files hold +inf where unknown.
#[pyfunction]
pub fn read_pfm<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let image = run(py, || core_read_pfm(&path))?;
    image_array(py, image)
}

/// Writes a float32 `(H, W)` or `(H, W, 3)` array as PFM (atomically).
#[pyfunction]
pub fn write_pfm(py: Python<'_>, path: PathBuf, array: &Bound<'_, PyAny>) -> PyResult<()> {
    let shape = crate::arrays::shape_of(array).unwrap_or_default();
    let values = array
        .extract::<PyReadonlyArrayDyn<'_, f32>>()
        .map_err(|_| crate::errors::type_error("array: expected a float32 numpy array"))?;
    let (height, width, channels) = match shape[..] {
        [h, w] => (h, w, 1),
        [h, w, 3] => (h, w, 3),
        _ => {
            return Err(to_py(Error::raster(
                "PFM array",
                format!("shape {shape:?}"),
                "(H, W) or (H, W, 3)",
            )))
        }
    };
    let data = c_order(&values).into_owned();
    let image = Image::new(width, height, channels, data).py()?;
    run(py, || core_write_pfm(&path, &image))
}

/// Reads an 8- or 16-bit PNG or TIFF capture as its samples, `uint8` or `uint16`, `(H, W)`
/// or `(H, W, 3)`: what the file stores, which `reconstruct` scales by the type's full
/// scale exactly as the CLI reads the file (a rig's `black_level` is in these units).
#[pyfunction]
pub fn read_capture<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyAny>> {
    let (image, full_scale) = run(py, || {
        let header = read_image_header(&path)?;
        Ok((read_linear_image(&path)?, header.full_scale))
    })?;
    let Image {
        width,
        height,
        channels,
        data,
    } = image;
    let sample = |v: f32| (v * full_scale as f32).round();
    if full_scale <= 255 {
        let values = data.into_iter().map(|v| sample(v) as u8).collect();
        Ok(image_array(py, Image::new(width, height, channels, values).py()?)?.into_any())
    } else {
        let values = data.into_iter().map(|v| sample(v) as u16).collect();
        Ok(image_array(py, Image::new(width, height, channels, values).py()?)?.into_any())
    }
}

/// Reads an 8- or 16-bit PNG or TIFF capture as linear float32 values in [0, 1] (full
/// scale), `(H, W)` or `(H, W, 3)`: what `reconstruct` reads from a capture file.
#[pyfunction]
pub fn read_image<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let image = run(py, || read_linear_image(&path))?;
    image_array(py, image)
}
