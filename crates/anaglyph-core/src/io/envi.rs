//! ENVI spectral cubes: a text header (`.hdr`) beside a raw binary file (`.img`).
//! We write float32, band-interleaved-by-pixel, little-endian, with `wavelength`,
//! `wavelength units = Nanometers` and `band names`, which Spectral Python and GDAL
//! open as they are. The reader accepts what other tools write: byte, int16, uint16,
//! float32 and float64 data, BSQ/BIL/BIP interleave, either byte order, header offset.

use super::{write_atomically, MAX_RASTER_VALUES};
use crate::image::Image;
use crate::{Error, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Largest ENVI header read (a header with 10 000 band names is about 200 kB).
pub const MAX_ENVI_HEADER_BYTES: u64 = 4 << 20;

/// A spectral cube in memory: an image whose channels are the bands, band-interleaved by
/// pixel (`image.data[(y * width + x) * bands + b]`).
#[derive(Debug, Clone, PartialEq)]
pub struct EnviCube {
    pub image: Image<f32>,
    /// Band centres in nm, when known.
    pub wavelengths: Option<Vec<f64>>,
    /// Band names (None: "W nm" from the wavelengths, when known).
    pub band_names: Option<Vec<String>>,
}

impl EnviCube {
    /// Number of bands.
    pub fn bands(&self) -> usize {
        self.image.channels
    }

    /// Value of band `b` at pixel `(x, y)`.
    pub fn at(&self, x: usize, y: usize, b: usize) -> f32 {
        self.image.pixel(x, y)[b]
    }

    /// One band as a row-major plane.
    pub fn band(&self, b: usize) -> Vec<f32> {
        let bands = self.bands();
        self.image
            .data
            .iter()
            .skip(b)
            .step_by(bands)
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
    if cube.image.data.len() != cube.image.width * cube.image.height * cube.image.channels
        || cube.image.channels == 0
    {
        return Err(Error::Shape {
            op: "write_envi".into(),
            got: vec![cube.image.data.len()],
            expected: vec![cube.image.width * cube.image.height * cube.image.channels],
        });
    }
    if let Some(w) = &cube.wavelengths {
        if w.len() != cube.image.channels {
            return Err(Error::Shape {
                op: "write_envi wavelengths".into(),
                got: vec![w.len()],
                expected: vec![cube.image.channels],
            });
        }
    }
    let mut header = format!(
        "ENVI\ndescription = {{{}}}\nsamples = {}\nlines = {}\nbands = {}\nheader offset = 0\n\
         file type = ENVI Standard\ndata type = 4\ninterleave = bip\nbyte order = 0\n",
        description.replace(['{', '}'], ""),
        cube.image.width,
        cube.image.height,
        cube.image.channels
    );
    if let Some(names) = &cube.band_names {
        if names.len() != cube.image.channels {
            return Err(Error::Shape {
                op: "write_envi band names".into(),
                got: vec![names.len()],
                expected: vec![cube.image.channels],
            });
        }
    }
    let names = cube.band_names.clone().or_else(|| {
        let w = cube.wavelengths.as_ref()?;
        Some(w.iter().map(|v| format!("{v} nm")).collect())
    });
    if let Some(w) = &cube.wavelengths {
        let list = w
            .iter()
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join(", ");
        header.push_str("wavelength units = Nanometers\n");
        header.push_str(&format!("wavelength = {{{list}}}\n"));
    }
    if let Some(names) = names {
        let clean: Vec<String> = names
            .iter()
            .map(|n| n.replace([',', '{', '}'], " "))
            .collect();
        header.push_str(&format!("band names = {{{}}}\n", clean.join(", ")));
    }
    write_atomically(&data_path(path), |w| {
        for chunk in cube.image.data.chunks(1 << 16) {
            let bytes: Vec<u8> = chunk.iter().flat_map(|v| v.to_le_bytes()).collect();
            w.write_all(&bytes)?;
        }
        Ok(())
    })?;
    write_atomically(path, |w| w.write_all(header.as_bytes()))
}

/// Parses `key = value` pairs; `{...}` values may span lines. An error carries the
/// line (from 1) it was found on.
fn parse_header(text: &str) -> std::result::Result<HashMap<String, String>, (usize, String)> {
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
    if lines.next().map(|(_, l)| l.trim()) != Some("ENVI") {
        return Err((1, "the first line is not 'ENVI'".into()));
    }
    let mut fields = HashMap::new();
    let mut pending: Option<(usize, String, String)> = None;
    for (number, line) in lines {
        if let Some((start, key, mut value)) = pending.take() {
            value.push(' ');
            value.push_str(line.trim());
            if value.contains('}') {
                fields.insert(key, value);
            } else {
                pending = Some((start, key, value));
            }
            continue;
        }
        let line = line.trim();
        if line.is_empty() || line.starts_with(';') {
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            return Err((number, format!("'{line}' is not 'key = value'")));
        };
        let key = key.trim().to_ascii_lowercase();
        let value = value.trim().to_string();
        if value.starts_with('{') && !value.contains('}') {
            pending = Some((number, key, value));
        } else {
            fields.insert(key, value);
        }
    }
    if let Some((start, key, _)) = pending {
        return Err((start, format!("unterminated '{{' in '{key}'")));
    }
    Ok(fields)
}

/// What an ENVI header says about its cube, checked: sizes within limits, a known data
/// type and interleave.
#[derive(Debug, Clone)]
struct EnviHeader {
    width: usize,
    height: usize,
    bands: usize,
    /// Bytes before the first value in the data file.
    offset: u64,
    data_type: usize,
    bytes_per_value: usize,
    interleave: Interleave,
    big_endian: bool,
    wavelengths: Option<Vec<f64>>,
    band_names: Option<Vec<String>>,
}

/// How an ENVI file orders its values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Interleave {
    /// Band sequential: `[band][y][x]`.
    Bsq,
    /// Band interleaved by line: `[y][band][x]`.
    Bil,
    /// Band interleaved by pixel: `[y][x][band]`.
    Bip,
}

impl EnviHeader {
    /// Reads and checks the header at `path`.
    fn read(path: &Path) -> Result<EnviHeader> {
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
        let fields = parse_header(&text).map_err(|(line, message)| Error::Parse {
            context: path.display().to_string(),
            line,
            message,
        })?;
        Self::from_fields(path, &fields)
    }

    fn from_fields(path: &Path, fields: &HashMap<String, String>) -> Result<EnviHeader> {
        let int = |key: &str| -> Result<usize> {
            let value = fields
                .get(key)
                .ok_or_else(|| Error::bad_field(path, key, "missing", "a non-negative integer"))?;
            value.parse::<usize>().map_err(|_| {
                Error::bad_field(path, key, format!("'{value}'"), "a non-negative integer")
            })
        };
        let (width, height, bands) = (int("samples")?, int("lines")?, int("bands")?);
        let values = (width as u64)
            .checked_mul(height as u64)
            .and_then(|v| v.checked_mul(bands as u64))
            .filter(|&v| v > 0 && v <= MAX_RASTER_VALUES)
            .ok_or_else(|| {
                Error::bad_field(
                    path,
                    "samples × lines × bands",
                    format!("{width} × {height} × {bands}"),
                    format!("between 1 and {MAX_RASTER_VALUES} values"),
                )
            })?;
        let offset = match fields.get("header offset") {
            None => 0,
            Some(v) => v.parse::<u64>().map_err(|_| {
                Error::bad_field(
                    path,
                    "header offset",
                    format!("'{v}'"),
                    "a non-negative integer",
                )
            })?,
        };
        let data_type = int("data type")?;
        let bytes_per_value = match data_type {
            1 => 1,
            2 | 12 => 2,
            4 => 4,
            5 => 8,
            other => {
                return Err(Error::UnsupportedFormat {
                    file: path.into(),
                    what: "data type".into(),
                    found: other.to_string(),
                    supported: "1, 2, 4, 5, 12".into(),
                })
            }
        };
        // The data's end must be representable: offset + values × bytes.
        values
            .checked_mul(bytes_per_value as u64)
            .and_then(|bytes| bytes.checked_add(offset))
            .ok_or_else(|| {
                Error::bad_field(
                    path,
                    "header offset",
                    offset,
                    "an offset the data fits after",
                )
            })?;
        Ok(EnviHeader {
            width,
            height,
            bands,
            offset,
            data_type,
            bytes_per_value,
            interleave: interleave_of(path, fields)?,
            big_endian: match fields.get("byte order").map(String::as_str) {
                None | Some("0") => false,
                Some("1") => true,
                Some(other) => {
                    return Err(Error::bad_field(
                        path,
                        "byte order",
                        format!("'{other}'"),
                        "0 or 1",
                    ))
                }
            },
            wavelengths: wavelengths_of(path, fields, bands)?,
            band_names: band_names_of(fields, bands),
        })
    }

    /// Values in the cube.
    fn values(&self) -> usize {
        self.width * self.height * self.bands
    }

    /// Bytes the data file must hold: the offset and every value.
    fn data_bytes(&self) -> u64 {
        self.offset + (self.values() * self.bytes_per_value) as u64
    }

    /// Value `i` of `raw` (the data after the offset) in the header's type and byte order.
    fn decode(&self, raw: &[u8], i: usize) -> f32 {
        let b = &raw[i * self.bytes_per_value..(i + 1) * self.bytes_per_value];
        macro_rules! num {
            ($t:ty) => {{
                let arr = b.try_into().unwrap_or_default();
                (if self.big_endian {
                    <$t>::from_be_bytes(arr)
                } else {
                    <$t>::from_le_bytes(arr)
                }) as f32
            }};
        }
        match self.data_type {
            1 => b[0] as f32,
            2 => num!(i16),
            12 => num!(u16),
            4 => num!(f32),
            _ => num!(f64),
        }
    }
}

fn interleave_of(path: &Path, fields: &HashMap<String, String>) -> Result<Interleave> {
    match fields
        .get("interleave")
        .map(|s| s.to_ascii_lowercase())
        .as_deref()
    {
        None | Some("bsq") => Ok(Interleave::Bsq),
        Some("bil") => Ok(Interleave::Bil),
        Some("bip") => Ok(Interleave::Bip),
        Some(other) => Err(Error::UnsupportedFormat {
            file: path.into(),
            what: "interleave".into(),
            found: format!("'{other}'"),
            supported: "bsq, bil, bip".into(),
        }),
    }
}

/// The `wavelength` list in nm (micrometres converted), one per band; None when absent.
/// The `band names` list when it names every band (a list of another length is ignored:
/// names are labels, not data).
fn band_names_of(fields: &HashMap<String, String>, bands: usize) -> Option<Vec<String>> {
    let list = fields.get("band names")?;
    let inner = list.trim().trim_start_matches('{').trim_end_matches('}');
    let names: Vec<String> = inner.split(',').map(|s| s.trim().to_string()).collect();
    (names.len() == bands).then_some(names)
}

fn wavelengths_of(
    path: &Path,
    fields: &HashMap<String, String>,
    bands: usize,
) -> Result<Option<Vec<f64>>> {
    let Some(list) = fields.get("wavelength") else {
        return Ok(None);
    };
    let inner = list.trim().trim_start_matches('{').trim_end_matches('}');
    let w = inner
        .split(',')
        .map(|s| s.trim().parse::<f64>())
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|_| Error::bad_field(path, "wavelength", "a non-number", "numbers"))?;
    if w.len() != bands {
        return Err(Error::bad_field(
            path,
            "wavelength",
            format!("{} values", w.len()),
            format!("one per band ({bands})"),
        ));
    }
    let micrometres = fields
        .get("wavelength units")
        .is_some_and(|u| u.to_ascii_lowercase().starts_with("micro"));
    Ok(Some(if micrometres {
        w.iter().map(|v| v * 1000.0).collect()
    } else {
        w
    }))
}

/// The data file beside `header`: `.img`, `.dat`, `.raw` or no extension.
fn data_file_of(header: &Path) -> Result<PathBuf> {
    let candidates = [
        header.with_extension("img"),
        header.with_extension("dat"),
        header.with_extension("raw"),
        header.with_extension(""),
    ];
    candidates
        .into_iter()
        .find(|p| p.is_file() && p != header)
        .ok_or_else(|| Error::MissingFile {
            path: header.with_extension("img"),
            what: "the ENVI data file (.img, .dat, .raw or no extension) beside the header".into(),
        })
}

/// The shape of an ENVI cube, from its header, with the data file's size checked.
#[derive(Debug, Clone, PartialEq)]
pub struct EnviShape {
    pub width: usize,
    pub height: usize,
    pub bands: usize,
    /// Band centres in nm, where the header gives them.
    pub wavelengths: Option<Vec<f64>>,
}

/// Reads the header at `path` and checks that its data file holds exactly what the
/// header declares, without reading the data: what a command checks before its work.
pub fn read_envi_shape(path: &Path) -> Result<EnviShape> {
    let (header, _) = checked_header(path)?;
    Ok(EnviShape {
        width: header.width,
        height: header.height,
        bands: header.bands,
        wavelengths: header.wavelengths,
    })
}

/// The header at `path` and its data file, whose size matches the header.
fn checked_header(path: &Path) -> Result<(EnviHeader, PathBuf)> {
    let header = EnviHeader::read(path)?;
    let data_file = data_file_of(path)?;
    let expected = header.data_bytes();
    let found = std::fs::metadata(&data_file)
        .map_err(|e| Error::io(&data_file, e))?
        .len();
    if found != expected {
        return Err(Error::FileSize {
            path: data_file,
            found,
            expected,
        });
    }
    Ok((header, data_file))
}

/// Reads an ENVI cube given its header path; the data file is `.img`, `.dat`, `.raw`
/// or the header path without extension, and must hold exactly what the header declares.
pub fn read_envi(path: &Path) -> Result<EnviCube> {
    let (header, data_file) = checked_header(path)?;
    let raw = std::fs::read(&data_file).map_err(|e| Error::io(&data_file, e))?;
    let raw = &raw[header.offset as usize..];
    let (w, h, n) = (header.width, header.height, header.bands);
    let mut data = vec![0f32; header.values()];
    for y in 0..h {
        for x in 0..w {
            for b in 0..n {
                let src = match header.interleave {
                    Interleave::Bip => (y * w + x) * n + b,
                    Interleave::Bil => (y * n + b) * w + x,
                    Interleave::Bsq => (b * h + y) * w + x,
                };
                data[(y * w + x) * n + b] = header.decode(raw, src);
            }
        }
    }
    Ok(EnviCube {
        image: Image {
            width: w,
            height: h,
            channels: n,
            data,
        },
        wavelengths: header.wavelengths,
        band_names: header.band_names,
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
            image: Image::new(3, 2, 4, (0..24).map(|v| v as f32 * 0.25).collect()).unwrap(),
            wavelengths: Some(vec![450.0, 458.0, 466.0, 474.0]),
            band_names: None,
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
        let back = read_envi(&path).unwrap();
        assert_eq!(
            (&back.image, &back.wavelengths),
            (&cube.image, &cube.wavelengths)
        );
        assert_eq!(back.band_names.unwrap()[1], "458 nm");
        // Named bands without wavelengths (a registered stack of cameras).
        let named = EnviCube {
            wavelengths: None,
            band_names: Some(
                ["r0c0:R", "r0c0:G", "r0c1", "r1c0"]
                    .map(String::from)
                    .to_vec(),
            ),
            ..cube
        };
        write_envi(&path, &named, "test").unwrap();
        let header = std::fs::read_to_string(&path).unwrap();
        assert!(
            header.contains("band names = {r0c0:R, r0c0:G, r0c1, r1c0}"),
            "{header}"
        );
        assert!(!header.contains("wavelength"));
        assert_eq!(read_envi(&path).unwrap(), named);
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
        assert_eq!(cube.image.data, vec![1.0, 3.0, 2.0, 4.0]);
        assert_eq!(cube.wavelengths, Some(vec![500.0, 600.0]));
    }

    #[test]
    fn malformed_headers_are_errors_naming_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("y.hdr");
        let base = "ENVI\nsamples = 2\nlines = 2\nbands = 1\n";
        // (header, the error variant expected, a phrase of its message)
        type Case = (String, fn(&Error) -> bool, &'static str);
        let cases: [Case; 7] = [
            (
                "NOT ENVI\n".into(),
                |e| matches!(e, Error::Parse { .. }),
                "first line",
            ),
            (
                "ENVI\nsamples = 2\n".into(),
                |e| matches!(e, Error::BadField { field, .. } if field == "lines"),
                "lines is missing",
            ),
            (
                format!("{base}data type = 3\n"),
                |e| matches!(e, Error::UnsupportedFormat { .. }),
                "unsupported data type 3",
            ),
            (
                format!("{base}data type = 4\nwavelength = {{1,\n"),
                |e| matches!(e, Error::Parse { .. }),
                "unterminated",
            ),
            (
                format!("{base}data type = 4\n"),
                |e| matches!(e, Error::MissingFile { .. }),
                "data file",
            ),
            (
                format!("{base}data type = 4\nheader offset = 18446744073709551615\n"),
                |e| matches!(e, Error::BadField { field, .. } if field == "header offset"),
                "header offset",
            ),
            (
                "ENVI\nsamples = 9223372036854775809\nlines = 2\nbands = 1\ndata type = 4\n".into(),
                |e| matches!(e, Error::BadField { .. }),
                "samples × lines × bands",
            ),
        ];
        for (text, variant, needle) in cases {
            std::fs::write(&path, &text).unwrap();
            let err = read_envi(&path).unwrap_err();
            assert!(variant(&err), "{text:?}: {err:?}");
            assert!(err.to_string().contains(needle), "{text:?}: {err}");
        }
        // A data file shorter or longer than the header declares (a partial or stale
        // file): 16 bytes expected.
        std::fs::write(&path, format!("{base}data type = 4\n")).unwrap();
        for bytes in [8usize, 24] {
            std::fs::write(dir.path().join("y.img"), vec![0u8; bytes]).unwrap();
            let err = read_envi(&path).unwrap_err();
            assert!(
                matches!(err, Error::FileSize { found, expected: 16, .. } if found == bytes as u64),
                "{err:?}"
            );
        }
    }
}
