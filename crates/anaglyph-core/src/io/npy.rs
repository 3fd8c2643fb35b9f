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

/// The element type of the header's `descr`: float32, float64 or bool (for masks), its
/// size in bytes and whether it is little-endian (or single-byte); any other type is an
/// [`Error::UnsupportedFormat`] naming it as numpy does.
fn element_type(path: &Path, header: &str) -> Result<(Descriptor, u64, bool)> {
    let descr = header
        .split("'descr':")
        .nth(1)
        .map(str::trim_start)
        .ok_or_else(|| Error::decode(path, "header has no descr (expected e.g. '<f4')"))?;
    let unsupported = |found: String| Error::UnsupportedFormat {
        file: path.into(),
        what: "element type".into(),
        found,
        supported: "float32 ('<f4'), float64 ('<f8'), bool ('|b1') for masks".into(),
    };
    let Some(code) = descr.strip_prefix('\'').and_then(|d| d.split('\'').next()) else {
        return Err(unsupported("a structured dtype".into()));
    };
    let (order, rest) = match code.chars().next() {
        Some(c @ ('<' | '>' | '|' | '=')) => (c, &code[1..]),
        _ => ('=', code),
    };
    let little_endian = order != '>';
    match rest {
        "f4" => Ok((Descriptor::F32, 4, little_endian)),
        "f8" => Ok((Descriptor::F64, 8, little_endian)),
        "b1" => Ok((Descriptor::Bool, 1, true)),
        other => Err(unsupported(numpy_name(other))),
    }
}

/// numpy's name of a type code such as `c8` (complex64) or `i4` (int32).
fn numpy_name(code: &str) -> String {
    let bytes: Option<u32> = code.get(1..).and_then(|n| n.parse().ok());
    let name = match (code.chars().next(), bytes) {
        (Some('c'), Some(n)) => format!("complex{}", 8 * n),
        (Some('f'), Some(n)) => format!("float{}", 8 * n),
        (Some('i'), Some(n)) => format!("int{}", 8 * n),
        (Some('u'), Some(n)) => format!("uint{}", 8 * n),
        _ => return format!("'{code}'"),
    };
    format!("{name} ('{code}')")
}

/// Checks the header's shape against the file length; returns what it declares.
fn check_header(path: &Path) -> Result<Header> {
    use std::io::Read;
    let bad = |message: String| Error::decode(path, message);
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
    let (descriptor, item, little_endian) = element_type(path, &header)?;
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
        little_endian,
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
    Error::decode(path, e)
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
        _ => Err(Error::UnsupportedFormat {
            file: path.into(),
            what: "element type".into(),
            found: "bool".into(),
            supported: "float32, float64".into(),
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

/// A little-endian, C-order float `.npy` file opened for reading in blocks of rows (all
/// axes but the last are rows), so that large files stream through bounded buffers.
#[derive(Debug)]
pub struct NpyRowReader {
    file: std::fs::File,
    pub shape: Vec<usize>,
    pub stored_as_f32: bool,
    row_len: usize,
    rows_left: usize,
}

/// Opens `path` for streaming when it holds native (little-endian, C-order) f32 or f64
/// data; `None` for other layouts, which [`read_npy_float`] handles whole.
pub fn open_npy_rows(path: &Path) -> Result<Option<NpyRowReader>> {
    use std::io::{Seek, SeekFrom};
    let header = check_header(path)?;
    let native = header.little_endian && !header.fortran_order && cfg!(target_endian = "little");
    let stored_as_f32 = match header.descriptor {
        Descriptor::F32 => true,
        Descriptor::F64 => false,
        _ => return Ok(None),
    };
    if !native || header.shape.is_empty() {
        return Ok(None);
    }
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    file.seek(SeekFrom::Start(header.data_offset))
        .map_err(|e| Error::io(path, e))?;
    let row_len = *header.shape.last().unwrap_or(&1);
    let rows = header.shape[..header.shape.len() - 1].iter().product();
    Ok(Some(NpyRowReader {
        file,
        shape: header.shape,
        stored_as_f32,
        row_len,
        rows_left: if row_len == 0 { 0 } else { rows },
    }))
}

impl NpyRowReader {
    /// Fills `buffer` with as many whole rows as fit and remain; returns the row count
    /// (0 at the end). `T` must be the stored type (f32 or f64).
    pub fn read_rows<T: bytemuck::Pod>(&mut self, buffer: &mut [T]) -> Result<usize> {
        use std::io::Read;
        let item = if self.stored_as_f32 { 4 } else { 8 };
        if std::mem::size_of::<T>() != item {
            return Err(Error::raster(
                "npy stream buffer element",
                format!("{} bytes", std::mem::size_of::<T>()),
                format!("{item} bytes, the stored type"),
            ));
        }
        let rows = (buffer.len() / self.row_len.max(1)).min(self.rows_left);
        let values = rows * self.row_len;
        self.file
            .read_exact(bytemuck::cast_slice_mut(&mut buffer[..values]))
            .map_err(|e| Error::io("npy stream", e))?;
        self.rows_left -= rows;
        Ok(rows)
    }
}

/// The `.npy` (version 1.0) header for a C-order array of `descr` (e.g. `<f4`) and `shape`,
/// padded so that the data starts on a 64-byte boundary.
pub fn npy_header(descr: &str, shape: &[usize]) -> Vec<u8> {
    let dims = match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {dims}, }}");
    let unpadded = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
    dict.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
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
    let array =
        ArrayD::from_shape_vec(IxDyn(shape), data).map_err(|e| Error::output(".npy array", e))?;
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
    fn streamed_reads_and_our_header_round_trip_through_ndarray_npy() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.npy");
        let values: Vec<f32> = (0..30).map(|v| v as f32 * 0.5).collect();
        let mut bytes = npy_header("<f4", &[2, 5, 3]);
        assert_eq!(bytes.len() % 64, 0);
        bytes.extend(values.iter().flat_map(|v| v.to_le_bytes()));
        std::fs::write(&path, &bytes).unwrap();
        // ndarray-npy accepts our header...
        let whole = read_npy_f64(&path).unwrap();
        assert_eq!(whole.shape, vec![2, 5, 3]);
        assert_eq!(whole.data[29], 14.5);
        // ...and the stream returns the same rows in blocks.
        let mut reader = open_npy_rows(&path).unwrap().unwrap();
        let mut buffer = vec![0f32; 12];
        let mut streamed = Vec::new();
        loop {
            let rows = reader.read_rows(&mut buffer).unwrap();
            if rows == 0 {
                break;
            }
            streamed.extend_from_slice(&buffer[..rows * 3]);
        }
        assert_eq!(streamed, values);
        assert_eq!(
            reader.read_rows(&mut [0f64; 3]).err().map(|e| e.kind()),
            Some("Raster")
        );
    }

    #[test]
    fn big_endian_and_fortran_files_are_not_streamed_but_read_whole() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.npy");
        // A 2×2 Fortran-order big-endian f8 array [[1, 2], [3, 4]]: stored column by column.
        let mut dict = "{'descr': '>f8', 'fortran_order': True, 'shape': (2, 2), }".to_string();
        let unpadded = 10 + dict.len() + 1;
        dict.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
        dict.push('\n');
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        bytes.extend_from_slice(dict.as_bytes());
        for v in [1.0f64, 3.0, 2.0, 4.0] {
            bytes.extend_from_slice(&v.to_be_bytes());
        }
        std::fs::write(&path, &bytes).unwrap();
        assert!(open_npy_rows(&path).unwrap().is_none());
        assert_eq!(read_npy_f64(&path).unwrap().data, vec![1.0, 2.0, 3.0, 4.0]);
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
        assert_eq!(read_npy_f64(&p).err().map(|e| e.kind()), Some("Decode"));
        std::fs::write(&p, b"hello").unwrap();
        assert!(read_npy_f64(&p).unwrap_err().to_string().contains("magic"));
    }

    #[test]
    fn other_element_types_are_named_as_numpy_names_them() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        for (descr, name) in [
            ("<c8", "complex64 ('c8')"),
            ("<i4", "int32 ('i4')"),
            ("|u1", "uint8 ('u1')"),
        ] {
            let mut bytes = npy_header(descr, &[2]);
            bytes.extend_from_slice(&[0u8; 16]);
            std::fs::write(&p, &bytes).unwrap();
            let refused = read_npy_f64(&p).err();
            let message = refused.as_ref().map(|e| e.to_string()).unwrap_or_default();
            assert_eq!(refused.map(|e| e.kind()), Some("UnsupportedFormat"));
            assert!(message.contains(name), "{message}");
        }
        let dict = "{'descr': [('a', '<f4')], 'fortran_order': False, 'shape': (2,), }";
        let mut bytes = b"\x93NUMPY\x01\x00\x76\x00".to_vec();
        bytes.extend_from_slice(format!("{dict:<117}\n").as_bytes());
        bytes.extend_from_slice(&[0u8; 8]);
        std::fs::write(&p, &bytes).unwrap();
        let message = read_npy_f64(&p).unwrap_err().to_string();
        assert!(message.contains("structured"), "{message}");
    }
}
