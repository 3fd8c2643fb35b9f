//! NumPy `.npy` arrays through `ndarray-npy`: float arrays of any rank are read as f64
//! (from `<f4` or `<f8`), boolean masks as bool; arrays are written as f32 or f64. Before
//! anything is allocated, the header's shape is checked against the file size.

use super::{write_atomically, MAX_RASTER_VALUES};
use crate::{Error, Result};
use ndarray::{ArrayD, IxDyn};
use ndarray_npy::{ReadNpyExt, WriteNpyExt};
use std::path::Path;

/// A dense array in row-major (C) order.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray<T> {
    pub shape: Vec<usize>,
    pub data: Vec<T>,
    /// True when the file held 32-bit floats (so outputs can match it).
    pub stored_as_f32: bool,
}

/// Element types an `.npy` header can declare that we read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Descriptor {
    F32,
    F64,
    Bool,
    Other,
}

/// What a checked header declares.
#[derive(Debug, Clone)]
struct Header {
    descriptor: Descriptor,
    /// Little-endian (or single-byte) elements.
    little_endian: bool,
    fortran_order: bool,
    shape: Vec<usize>,
    /// Byte offset of the data.
    data_offset: u64,
}

/// Checks the header's shape against the file length; returns what it declares.
fn check_header(path: &Path) -> Result<Header> {
    use std::io::Read;
    let bad = |message: String| Error::Parse {
        context: path.display().to_string(),
        line: 0,
        message,
    };
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut head = vec![0u8; 12.min(file_len as usize)];
    file.read_exact(&mut head).map_err(|e| Error::io(path, e))?;
    if head.len() < 10 || &head[..6] != b"\x93NUMPY" {
        return Err(bad("not an .npy file (bad magic)".into()));
    }
    let (header_len, prefix) = match head[6] {
        1 => (u16::from_le_bytes([head[8], head[9]]) as u64, 10u64),
        2 | 3 if head.len() == 12 => (
            u32::from_le_bytes([head[8], head[9], head[10], head[11]]) as u64,
            12,
        ),
        v => return Err(bad(format!("unsupported .npy version {v}"))),
    };
    if header_len > 1 << 20 || prefix + header_len > file_len {
        return Err(bad(format!(
            "header length {header_len} does not fit the file"
        )));
    }
    let mut header = vec![0u8; header_len as usize];
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    std::io::copy(&mut (&mut file).take(prefix), &mut std::io::sink())
        .map_err(|e| Error::io(path, e))?;
    file.read_exact(&mut header)
        .map_err(|e| Error::io(path, e))?;
    let header = String::from_utf8_lossy(&header);
    let descriptor = if header.contains("f8'") {
        Descriptor::F64
    } else if header.contains("f4'") {
        Descriptor::F32
    } else if header.contains("b1'") {
        Descriptor::Bool
    } else {
        Descriptor::Other
    };
    let item = if header.contains("f8") || header.contains("i8") || header.contains("u8") {
        8
    } else if header.contains("f4") || header.contains("i4") || header.contains("u4") {
        4
    } else if header.contains("f2") || header.contains("i2") || header.contains("u2") {
        2
    } else {
        1
    };
    let shape_text = header
        .split("'shape':")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| bad("header has no shape".into()))?;
    let mut values: u64 = 1;
    let mut shape = Vec::new();
    for dim in shape_text
        .trim()
        .trim_start_matches('(')
        .split(',')
        .map(str::trim)
    {
        if dim.is_empty() {
            continue;
        }
        let d: u64 = dim
            .parse()
            .map_err(|_| bad(format!("shape entry '{dim}' is not an integer")))?;
        values = values.saturating_mul(d);
        shape.push(d as usize);
    }
    if values > MAX_RASTER_VALUES {
        return Err(Error::TooLarge {
            op: format!("reading {}", path.display()),
            what: "array elements".into(),
            size: values,
            limit: MAX_RASTER_VALUES,
        });
    }
    let need = prefix + header_len + values * item;
    if file_len != need {
        return Err(bad(format!("{file_len} bytes (header declares {need})")));
    }
    Ok(Header {
        descriptor,
        little_endian: header.contains("'<") || header.contains("'|"),
        fortran_order: header.contains("'fortran_order': True"),
        shape,
        data_offset: prefix + header_len,
    })
}

/// Reads the data of a little-endian, C-order float array straight into a huge-page
/// buffer (no ndarray intermediate).
fn read_native<T: bytemuck::Pod + bytemuck::Zeroable>(
    path: &Path,
    header: &Header,
) -> Result<Vec<T>> {
    use std::io::{Read, Seek, SeekFrom};
    let len: usize = header.shape.iter().product();
    let mut data = super::zeroed_large::<T>(len);
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    file.seek(SeekFrom::Start(header.data_offset))
        .map_err(|e| Error::io(path, e))?;
    file.read_exact(bytemuck::cast_slice_mut(&mut data))
        .map_err(|e| Error::io(path, e))?;
    Ok(data)
}

fn read_error(path: &Path, e: ndarray_npy::ReadNpyError) -> Error {
    Error::Parse {
        context: path.display().to_string(),
        line: 0,
        message: e.to_string(),
    }
}

fn into_row_major<T: Clone>(array: ArrayD<T>) -> NpyArray<T> {
    let shape = array.shape().to_vec();
    // Moving the buffer out avoids a per-element walk of a dynamic-rank array.
    let standard = if array.is_standard_layout() {
        array
    } else {
        array.as_standard_layout().into_owned()
    };
    let (data, _) = standard.into_raw_vec_and_offset();
    NpyArray {
        shape,
        data,
        stored_as_f32: false,
    }
}

/// A float array as stored: f32 or f64.
#[derive(Debug, Clone, PartialEq)]
pub enum FloatArray {
    F32(NpyArray<f32>),
    F64(NpyArray<f64>),
}

impl FloatArray {
    pub fn shape(&self) -> &[usize] {
        match self {
            FloatArray::F32(a) => &a.shape,
            FloatArray::F64(a) => &a.shape,
        }
    }
}

/// Reads a float array (`f4` or `f8`, either byte order, C or Fortran order) in its own type.
pub fn read_npy_float(path: &Path) -> Result<FloatArray> {
    let header = check_header(path)?;
    let native = header.little_endian && !header.fortran_order && cfg!(target_endian = "little");
    match header.descriptor {
        Descriptor::F32 if native => {
            return Ok(FloatArray::F32(NpyArray {
                data: read_native(path, &header)?,
                shape: header.shape,
                stored_as_f32: true,
            }))
        }
        Descriptor::F64 if native => {
            return Ok(FloatArray::F64(NpyArray {
                data: read_native(path, &header)?,
                shape: header.shape,
                stored_as_f32: false,
            }))
        }
        _ => {}
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    match header.descriptor {
        Descriptor::F64 => {
            let a = ArrayD::<f64>::read_npy(file).map_err(|e| read_error(path, e))?;
            Ok(FloatArray::F64(into_row_major(a)))
        }
        Descriptor::F32 => {
            let a = ArrayD::<f32>::read_npy(file).map_err(|e| read_error(path, e))?;
            let mut array = into_row_major(a);
            array.stored_as_f32 = true;
            Ok(FloatArray::F32(array))
        }
        _ => Err(Error::Parse {
            context: path.display().to_string(),
            line: 0,
            message: "element type is not float32 or float64".into(),
        }),
    }
}

/// Reads a float array as f64 (converting f32).
pub fn read_npy_f64(path: &Path) -> Result<NpyArray<f64>> {
    Ok(match read_npy_float(path)? {
        FloatArray::F64(a) => a,
        FloatArray::F32(a) => NpyArray {
            shape: a.shape,
            data: a.data.iter().map(|&v| f64::from(v)).collect(),
            stored_as_f32: true,
        },
    })
}

/// Reads a boolean array.
pub fn read_npy_bool(path: &Path) -> Result<NpyArray<bool>> {
    check_header(path)?;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let a = ArrayD::<bool>::read_npy(file).map_err(|e| read_error(path, e))?;
    Ok(into_row_major(a))
}

fn write_array<T: ndarray_npy::WritableElement + Clone>(
    path: &Path,
    shape: &[usize],
    data: Vec<T>,
) -> Result<()> {
    let array = ArrayD::from_shape_vec(IxDyn(shape), data)
        .map_err(|e| Error::invalid("write_npy", e.to_string()))?;
    write_atomically(path, |w| array.write_npy(w).map_err(std::io::Error::other))
}

/// Writes a row-major f32 array.
pub fn write_npy_f32(path: &Path, shape: &[usize], data: Vec<f32>) -> Result<()> {
    write_array(path, shape, data)
}

/// Writes a row-major f64 array.
pub fn write_npy_f64(path: &Path, shape: &[usize], data: Vec<f64>) -> Result<()> {
    write_array(path, shape, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f32_and_f64_round_trip_and_bool_masks() {
        let dir = tempfile::tempdir().unwrap();
        let p32 = dir.path().join("a.npy");
        write_npy_f32(&p32, &[2, 3], vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.5]).unwrap();
        let a = read_npy_f64(&p32).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(a.data[5], 6.5);
        let p64 = dir.path().join("b.npy");
        write_npy_f64(&p64, &[3], vec![0.1, 0.2, 0.3]).unwrap();
        assert_eq!(read_npy_f64(&p64).unwrap().data, vec![0.1, 0.2, 0.3]);

        let pb = dir.path().join("m.npy");
        let mask = ArrayD::from_shape_vec(IxDyn(&[2]), vec![true, false]).unwrap();
        ndarray_npy::write_npy(&pb, &mask).unwrap();
        assert_eq!(read_npy_bool(&pb).unwrap().data, vec![true, false]);
    }

    #[test]
    fn truncated_or_lying_headers_are_rejected_before_allocation() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        write_npy_f32(&p, &[4], vec![1.0; 4]).unwrap();
        let mut bytes = std::fs::read(&p).unwrap();
        bytes.truncate(bytes.len() - 4);
        std::fs::write(&p, &bytes).unwrap();
        assert!(read_npy_f64(&p)
            .unwrap_err()
            .to_string()
            .contains("header declares"));
        let text = String::from_utf8_lossy(&bytes).replace("(4,)", "(9999999999999,)");
        std::fs::write(&p, text.as_bytes()).unwrap();
        assert!(read_npy_f64(&p).is_err());
        std::fs::write(&p, b"hello").unwrap();
        assert!(read_npy_f64(&p).unwrap_err().to_string().contains("magic"));
    }
}
