//! ENVI spectral cubes: a text header (`.hdr`) beside a raw binary file (`.img`).
//! We write float32, band-interleaved-by-pixel, little-endian, with `wavelength`,
//! `wavelength units = Nanometers` and `band names`, which Spectral Python and GDAL
//! open as they are. The reader accepts what other tools write: byte, int16, uint16,
//! float32 and float64 data, BSQ/BIL/BIP interleave, either byte order, header offset.

use super::{write_atomically, MAX_RASTER_VALUES};
use crate::{Error, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Largest ENVI header read (a header with 10 000 band names is about 200 kB).
pub const MAX_ENVI_HEADER_BYTES: u64 = 4 << 20;

/// A spectral cube in memory, band-interleaved by pixel: `data[(y * width + x) * bands + b]`.
#[derive(Debug, Clone, PartialEq)]
pub struct EnviCube {
    pub width: usize,
    pub height: usize,
    pub bands: usize,
    /// Band centres in nm, when known.
    pub wavelengths: Option<Vec<f64>>,
    pub data: Vec<f32>,
}

impl EnviCube {
    /// Value of band `b` at pixel `(x, y)`.
    pub fn at(&self, x: usize, y: usize, b: usize) -> f32 {
        self.data[(y * self.width + x) * self.bands + b]
    }

    /// One band as a row-major plane.
    pub fn band(&self, b: usize) -> Vec<f32> {
        self.data
            .iter()
            .skip(b)
            .step_by(self.bands)
            .copied()
            .collect()
    }
}

/// The raw data path of a header path (`x.hdr` -> `x.img`).
fn data_path(header: &Path) -> PathBuf {
    header.with_extension("img")
}

/// Writes `cube` as `path` (.hdr) and the `.img` beside it, both atomically.
pub fn write_envi(path: &Path, cube: &EnviCube, description: &str) -> Result<()> {
    if cube.data.len() != cube.width * cube.height * cube.bands || cube.bands == 0 {
        return Err(Error::Shape {
            op: "write_envi".into(),
            got: vec![cube.data.len()],
            expected: vec![cube.width * cube.height * cube.bands],
        });
    }
    if let Some(w) = &cube.wavelengths {
        if w.len() != cube.bands {
            return Err(Error::Shape {
                op: "write_envi wavelengths".into(),
                got: vec![w.len()],
                expected: vec![cube.bands],
            });
        }
    }
    let mut header = format!(
        "ENVI\ndescription = {{{}}}\nsamples = {}\nlines = {}\nbands = {}\nheader offset = 0\n\
         file type = ENVI Standard\ndata type = 4\ninterleave = bip\nbyte order = 0\n",
        description.replace(['{', '}'], ""),
        cube.width,
        cube.height,
        cube.bands
    );
    if let Some(w) = &cube.wavelengths {
        let list =
            |f: &dyn Fn(f64) -> String| w.iter().map(|&v| f(v)).collect::<Vec<_>>().join(", ");
        header.push_str("wavelength units = Nanometers\n");
        header.push_str(&format!("wavelength = {{{}}}\n", list(&|v| format!("{v}"))));
        header.push_str(&format!(
            "band names = {{{}}}\n",
            list(&|v| format!("{v} nm"))
        ));
    }
    write_atomically(&data_path(path), |w| {
        for chunk in cube.data.chunks(1 << 16) {
            let bytes: Vec<u8> = chunk.iter().flat_map(|v| v.to_le_bytes()).collect();
            w.write_all(&bytes)?;
        }
        Ok(())
    })?;
    write_atomically(path, |w| w.write_all(header.as_bytes()))
}

/// Parses `key = value` pairs; `{...}` values may span lines.
fn parse_header(text: &str) -> std::result::Result<HashMap<String, String>, String> {
    let mut lines = text.lines();
    if lines.next().map(str::trim) != Some("ENVI") {
        return Err("first line is not 'ENVI'".into());
    }
    let mut fields = HashMap::new();
    let mut pending: Option<(String, String)> = None;
    for line in lines {
        if let Some((key, mut value)) = pending.take() {
            value.push(' ');
            value.push_str(line.trim());
            if value.contains('}') {
                fields.insert(key, value);
            } else {
                pending = Some((key, value));
            }
            continue;
        }
        let line = line.trim();
        if line.is_empty() || line.starts_with(';') {
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            return Err(format!("line '{line}' is not 'key = value'"));
        };
        let key = key.trim().to_ascii_lowercase();
        let value = value.trim().to_string();
        if value.starts_with('{') && !value.contains('}') {
            pending = Some((key, value));
        } else {
            fields.insert(key, value);
        }
    }
    if let Some((key, _)) = pending {
        return Err(format!("unterminated '{{' in '{key}'"));
    }
    Ok(fields)
}

/// Reads an ENVI cube given its header path; the data file is `.img`, `.dat`, `.raw`
/// or the header path without extension.
pub fn read_envi(path: &Path) -> Result<EnviCube> {
    let bad = |message: String| Error::Parse {
        context: path.display().to_string(),
        line: 0,
        message,
    };
    let size = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    if size > MAX_ENVI_HEADER_BYTES {
        return Err(Error::TooLarge {
            op: format!("reading {}", path.display()),
            what: "header size".into(),
            size,
            limit: MAX_ENVI_HEADER_BYTES,
        });
    }
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let fields = parse_header(&text).map_err(bad)?;
    let int = |key: &str| -> Result<usize> {
        fields
            .get(key)
            .ok_or_else(|| bad(format!("missing '{key}'")))?
            .parse::<usize>()
            .map_err(|_| bad(format!("'{key}' is not a non-negative integer")))
    };
    let (width, height, bands) = (int("samples")?, int("lines")?, int("bands")?);
    let offset = fields
        .get("header offset")
        .map(|v| {
            v.parse::<u64>()
                .map_err(|_| bad("'header offset' is not an integer".into()))
        })
        .transpose()?
        .unwrap_or(0);
    let data_type = int("data type")?;
    let bytes_per = match data_type {
        1 => 1,
        2 | 12 => 2,
        4 => 4,
        5 => 8,
        other => {
            return Err(bad(format!(
                "data type {other} (supported: 1, 2, 4, 5, 12)"
            )))
        }
    };
    let interleave = fields
        .get("interleave")
        .map(|s| s.to_ascii_lowercase())
        .unwrap_or_else(|| "bsq".into());
    if !["bsq", "bil", "bip"].contains(&interleave.as_str()) {
        return Err(bad(format!(
            "interleave '{interleave}' (expected bsq, bil or bip)"
        )));
    }
    let big_endian = match fields.get("byte order").map(String::as_str) {
        None | Some("0") => false,
        Some("1") => true,
        Some(other) => return Err(bad(format!("byte order '{other}' (expected 0 or 1)"))),
    };
    let values = width as u64 * height as u64 * bands as u64;
    if values == 0 || values > MAX_RASTER_VALUES {
        return Err(bad(format!(
            "size {width}x{height}x{bands} is empty or over the limit"
        )));
    }
    let wavelengths = match fields.get("wavelength") {
        None => None,
        Some(list) => {
            let inner = list.trim().trim_start_matches('{').trim_end_matches('}');
            let w = inner
                .split(',')
                .map(|s| s.trim().parse::<f64>())
                .collect::<std::result::Result<Vec<_>, _>>()
                .map_err(|_| bad("'wavelength' holds a non-number".into()))?;
            if w.len() != bands {
                return Err(bad(format!("{} wavelengths for {bands} bands", w.len())));
            }
            let micrometres = fields
                .get("wavelength units")
                .is_some_and(|u| u.to_ascii_lowercase().starts_with("micro"));
            Some(if micrometres {
                w.iter().map(|v| v * 1000.0).collect()
            } else {
                w
            })
        }
    };
    let candidates = [
        path.with_extension("img"),
        path.with_extension("dat"),
        path.with_extension("raw"),
        path.with_extension(""),
    ];
    let data_file = candidates.iter().find(|p| p.is_file()).ok_or_else(|| {
        bad("no data file beside the header (.img, .dat, .raw or no extension)".into())
    })?;
    let need = offset + values * bytes_per as u64;
    let have = std::fs::metadata(data_file)
        .map_err(|e| Error::io(data_file, e))?
        .len();
    if have < need {
        return Err(bad(format!(
            "{} holds {have} bytes (expected {need})",
            data_file.display()
        )));
    }
    let raw = std::fs::read(data_file).map_err(|e| Error::io(data_file, e))?;
    let raw = &raw[offset as usize..need as usize];
    let decode = |i: usize| -> f32 {
        let b = &raw[i * bytes_per..(i + 1) * bytes_per];
        macro_rules! num {
            ($t:ty) => {{
                let arr = b.try_into().unwrap_or_default();
                (if big_endian {
                    <$t>::from_be_bytes(arr)
                } else {
                    <$t>::from_le_bytes(arr)
                }) as f32
            }};
        }
        match data_type {
            1 => b[0] as f32,
            2 => num!(i16),
            12 => num!(u16),
            4 => num!(f32),
            _ => num!(f64),
        }
    };
    let (w, h, n) = (width, height, bands);
    let mut data = vec![0f32; values as usize];
    for y in 0..h {
        for x in 0..w {
            for b in 0..n {
                let src = match interleave.as_str() {
                    "bip" => (y * w + x) * n + b,
                    "bil" => (y * n + b) * w + x,
                    _ => (b * h + y) * w + x,
                };
                data[(y * w + x) * n + b] = decode(src);
            }
        }
    }
    Ok(EnviCube {
        width,
        height,
        bands,
        wavelengths,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_wavelengths() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cube.hdr");
        let cube = EnviCube {
            width: 3,
            height: 2,
            bands: 4,
            wavelengths: Some(vec![450.0, 458.0, 466.0, 474.0]),
            data: (0..24).map(|v| v as f32 * 0.25).collect(),
        };
        write_envi(&path, &cube, "test").unwrap();
        let header = std::fs::read_to_string(&path).unwrap();
        assert!(header.contains("wavelength units = Nanometers"));
        assert!(header.contains("band names = {450 nm, 458 nm, 466 nm, 474 nm}"));
        assert_eq!(
            std::fs::metadata(dir.path().join("cube.img"))
                .unwrap()
                .len(),
            96
        );
        assert_eq!(read_envi(&path).unwrap(), cube);
    }

    #[test]
    fn reads_bsq_big_endian_uint16_with_multiline_lists() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.hdr");
        std::fs::write(
            &path,
            "ENVI\nsamples = 2\nlines = 1\nbands = 2\ndata type = 12\ninterleave = bsq\n\
             byte order = 1\nwavelength = {\n 0.5,\n 0.6}\nwavelength units = Micrometers\n",
        )
        .unwrap();
        // BSQ: band 0 = [1, 2], band 1 = [3, 4].
        let raw: Vec<u8> = [1u16, 2, 3, 4]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        std::fs::write(dir.path().join("x.img"), raw).unwrap();
        let cube = read_envi(&path).unwrap();
        assert_eq!(cube.data, vec![1.0, 3.0, 2.0, 4.0]);
        assert_eq!(cube.wavelengths, Some(vec![500.0, 600.0]));
    }

    #[test]
    fn malformed_headers_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("y.hdr");
        for (text, needle) in [
            ("NOT ENVI\n", "first line"),
            ("ENVI\nsamples = 2\n", "missing 'lines'"),
            (
                "ENVI\nsamples = 2\nlines = 2\nbands = 1\ndata type = 3\n",
                "data type 3",
            ),
            (
                "ENVI\nsamples = 2\nlines = 2\nbands = 1\ndata type = 4\nwavelength = {1,\n",
                "unterminated",
            ),
            (
                "ENVI\nsamples = 2\nlines = 2\nbands = 1\ndata type = 4\n",
                "no data file",
            ),
        ] {
            std::fs::write(&path, text).unwrap();
            let err = read_envi(&path).unwrap_err().to_string();
            assert!(err.contains(needle), "{text:?}: {err}");
        }
        std::fs::write(
            &path,
            "ENVI\nsamples = 2\nlines = 2\nbands = 1\ndata type = 4\n",
        )
        .unwrap();
        std::fs::write(dir.path().join("y.img"), [0u8; 8]).unwrap();
        assert!(read_envi(&path)
            .unwrap_err()
            .to_string()
            .contains("expected 16"));
    }
}
