//! numpy arrays in and out.
//!
//! In: images as `(H, W)` or `(H, W, C)` arrays of `uint8`, `uint16` (scaled by their full
//! scale, as the CLI reads 8- and 16-bit files) or `float32` / `float64` (linear values,
//! 1.0 = full scale). They are read through numpy's buffer without a Python-side copy and
//! converted once into the core's image; NaN or infinite values are refused. Out: arrays
//! made from the core's buffers without copying (`into_pyarray` moves the `Vec`).

use crate::errors::{shape_error, to_py, type_error};
use anaglyph_core::image::Image;
use anaglyph_core::io::{from_u16_sample, from_u8_sample};
use anaglyph_core::Error;
use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{Element, IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use std::borrow::Cow;

/// A numpy array of f64 made here.
pub type F64Array<'py> = Bound<'py, PyArrayDyn<f64>>;

/// The dtypes an image may have, as messages name them.
pub const IMAGE_DTYPES: &str = "uint8, uint16, float32 or float64";

/// The values of a numpy array in C order: borrowed where numpy lays them out so, else
/// gathered once. (An F-contiguous array is contiguous too, but in the other order: its
/// memory is not its C-order values.)
pub fn c_order<'a, T: Element + Copy>(array: &'a PyReadonlyArrayDyn<'_, T>) -> Cow<'a, [T]> {
    if array.is_c_contiguous() {
        if let Ok(slice) = array.as_slice() {
            return Cow::Borrowed(slice);
        }
    }
    Cow::Owned(array.as_array().iter().copied().collect())
}

/// The shape of a numpy array, if `object` is one.
pub fn shape_of(object: &Bound<'_, PyAny>) -> Option<Vec<usize>> {
    object
        .cast::<numpy::PyUntypedArray>()
        .ok()
        .map(|a| a.shape().to_vec())
}

/// The dtype's name of a numpy array (or the Python type's name).
fn dtype_name(object: &Bound<'_, PyAny>) -> String {
    match object.cast::<numpy::PyUntypedArray>() {
        Ok(a) => a.dtype().to_string(),
        Err(_) => format!(
            "a {} (not a numpy array)",
            object
                .get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default()
        ),
    }
}

/// `object` as an image in linear units; `what` names it in errors (e.g. "capture of
/// camera r0c1"), `channels` is what it must have when known.
pub fn image(
    object: &Bound<'_, PyAny>,
    what: &str,
    channels: Option<usize>,
) -> PyResult<Image<f32>> {
    let shape = shape_of(object).ok_or_else(|| {
        type_error(format!(
            "{what}: expected a numpy array of {IMAGE_DTYPES}, got {}",
            dtype_name(object)
        ))
    })?;
    let (height, width, c) = match shape[..] {
        [h, w] => (h, w, 1),
        [h, w, c] => (h, w, c),
        _ => {
            let expected = match channels {
                Some(1) | None => "(H, W)",
                Some(_) => "(H, W, C)",
            };
            return Err(to_py(Error::raster(
                what,
                format!("an array of shape {shape:?}"),
                format!("an image of shape {expected}"),
            )));
        }
    };
    if let Some(expected) = channels {
        if c != expected {
            let expected_shape: Vec<usize> = match expected {
                1 => vec![height, width],
                _ => vec![height, width, expected],
            };
            return Err(shape_error(
                format!("{what} (channels of its sensor)"),
                &shape,
                &expected_shape,
            ));
        }
    }
    let data: Vec<f32> = if let Ok(a) = object.extract::<PyReadonlyArrayDyn<'_, u16>>() {
        c_order(&a).iter().map(|&v| from_u16_sample(v)).collect()
    } else if let Ok(a) = object.extract::<PyReadonlyArrayDyn<'_, u8>>() {
        c_order(&a).iter().map(|&v| from_u8_sample(v)).collect()
    } else if let Ok(a) = object.extract::<PyReadonlyArrayDyn<'_, f32>>() {
        c_order(&a).into_owned()
    } else if let Ok(a) = object.extract::<PyReadonlyArrayDyn<'_, f64>>() {
        c_order(&a).iter().map(|&v| v as f32).collect()
    } else {
        return Err(type_error(format!(
            "{what}: dtype {} (expected {IMAGE_DTYPES})",
            dtype_name(object)
        )));
    };
    if let Some(bad) = data.iter().find(|v| !v.is_finite()) {
        return Err(to_py(Error::NonFinite {
            what: format!("a value of the {what}"),
            value: f64::from(*bad),
        }));
    }
    Image::new(width, height, c, data).map_err(to_py)
}

/// The full scale of an image's samples: 65535 for uint16, 255 for uint8, 1 for floats
/// (the units a rig's `black_level` is given in).
pub fn full_scale(object: &Bound<'_, PyAny>) -> f64 {
    if object.extract::<PyReadonlyArrayDyn<'_, u16>>().is_ok() {
        65535.0
    } else if object.extract::<PyReadonlyArrayDyn<'_, u8>>().is_ok() {
        255.0
    } else {
        1.0
    }
}

/// A numpy array of `shape` over `data` (moved, not copied).
pub fn array<'py, T: Element>(
    py: Python<'py>,
    shape: &[usize],
    data: Vec<T>,
) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    let array = ArrayD::from_shape_vec(IxDyn(shape), data)
        .map_err(|e| crate::errors::internal(format!("array of shape {shape:?}: {e}")))?;
    Ok(array.into_pyarray(py))
}

/// An image as `(H, W)` (one channel) or `(H, W, C)`.
pub fn image_array<'py, T: Element>(
    py: Python<'py>,
    image: Image<T>,
) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    let shape: Vec<usize> = match image.channels {
        1 => vec![image.height, image.width],
        c => vec![image.height, image.width, c],
    };
    array(py, &shape, image.data)
}

/// A cube or stack as `(H, W, C)`, three dimensions even for one channel.
pub fn cube_array<'py, T: Element>(
    py: Python<'py>,
    image: Image<T>,
) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    array(py, &[image.height, image.width, image.channels], image.data)
}
