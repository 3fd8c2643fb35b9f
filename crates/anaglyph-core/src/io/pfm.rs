//! Portable Float Map, the Middlebury disparity format: header `Pf` (one channel) or
//! `PF` (three), `width height`, a scale whose sign gives the byte order (negative =
//! little-endian), then rows stored bottom to top. `+inf` marks unknown disparity.

use super::{write_atomically, MAX_RASTER_VALUES};
use crate::{Error, Result};
use std::path::Path;

/// A PFM image: 1 (grey) or 3 (colour) channels, rows top first (the file stores them
/// bottom first).
pub type PfmImage = crate::image::Image<f32>;

/// Writes a little-endian PFM (scale −1), bottom row first.
pub fn write_pfm(path: &Path, image: &PfmImage) -> Result<()> {
    if !(image.channels == 1 || image.channels == 3)
        || image.data.len() != image.width * image.height * image.channels
    {
        return Err(Error::Shape {
            op: "write_pfm".into(),
            got: vec![image.data.len(), image.channels],
            expected: vec![image.width * image.height * image.channels, 1],
        });
    }
    let magic = if image.channels == 1 { "Pf" } else { "PF" };
    let row_len = image.width * image.channels;
    write_atomically(path, |w| {
        write!(w, "{magic}\n{} {}\n-1\n", image.width, image.height)?;
        for row in image.data.chunks_exact(row_len.max(1)).rev() {
            for v in row {
                w.write_all(&v.to_le_bytes())?;
            }
        }
        Ok(())
    })
}

/// Reads a PFM of either byte order; rows come back top to bottom.
pub fn read_pfm(path: &Path) -> Result<PfmImage> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_pfm(&bytes).map_err(|message| Error::decode(path, message))
}

fn parse_pfm(bytes: &[u8]) -> std::result::Result<PfmImage, String> {
    // Three whitespace-separated header tokens after the magic, then one whitespace byte.
    let mut pos = 0;
    let mut token = || -> std::result::Result<String, String> {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() && pos - start < 32 {
            pos += 1;
        }
        if start == pos {
            return Err("truncated header".into());
        }
        Ok(String::from_utf8_lossy(&bytes[start..pos]).into_owned())
    };
    let magic = token()?;
    let channels = match magic.as_str() {
        "Pf" => 1,
        "PF" => 3,
        other => return Err(format!("magic '{other}' (expected 'Pf' or 'PF')")),
    };
    let width: usize = token()?
        .parse()
        .map_err(|_| "width is not an integer".to_string())?;
    let height: usize = token()?
        .parse()
        .map_err(|_| "height is not an integer".to_string())?;
    let scale: f32 = token()?
        .parse()
        .map_err(|_| "scale is not a number".to_string())?;
    if scale == 0.0 || !scale.is_finite() {
        return Err(format!("scale {scale} (expected non-zero)"));
    }
    pos += 1; // the single whitespace byte that ends the header
    let values = (width as u64) * (height as u64) * channels as u64;
    if width == 0 || height == 0 || values > MAX_RASTER_VALUES {
        return Err(format!(
            "size {width}x{height}x{channels} is empty or over the limit"
        ));
    }
    let need = values as usize * 4;
    let body = bytes.get(pos..).unwrap_or_default();
    if body.len() != need {
        return Err(format!("{} data bytes (expected {need})", body.len()));
    }
    let little = scale < 0.0;
    let row_len = width * channels;
    let mut data = vec![0f32; values as usize];
    for (r, src) in body.chunks_exact(row_len * 4).enumerate() {
        let dst_row = height - 1 - r;
        for (i, b) in src.chunks_exact(4).enumerate() {
            let b = [b[0], b[1], b[2], b[3]];
            data[dst_row * row_len + i] = if little {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            };
        }
    }
    Ok(PfmImage {
        width,
        height,
        channels,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_row_order_and_infinity() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.pfm");
        let image = PfmImage {
            width: 3,
            height: 2,
            channels: 1,
            data: vec![1.0, 2.0, 3.0, 4.0, f32::INFINITY, 6.5],
        };
        write_pfm(&path, &image).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.starts_with(b"Pf\n3 2\n-1\n"));
        // The first stored row is the bottom row (4, inf, 6.5).
        assert_eq!(&bytes[10..14], &4.0f32.to_le_bytes());
        assert_eq!(read_pfm(&path).unwrap(), image);
    }

    #[test]
    fn big_endian_and_malformed_files() {
        let mut be = b"Pf\n1 1\n1.0\n".to_vec();
        be.extend_from_slice(&2.5f32.to_be_bytes());
        assert_eq!(parse_pfm(&be).unwrap().data, vec![2.5]);
        assert!(parse_pfm(b"P5\n1 1\n-1\n").unwrap_err().contains("magic"));
        assert!(parse_pfm(b"Pf\n2 2\n-1\n\0\0\0\0")
            .unwrap_err()
            .contains("bytes"));
        assert!(parse_pfm(b"Pf\n99999999 99999999\n-1\n")
            .unwrap_err()
            .contains("limit"));
        assert!(parse_pfm(b"Pf\n1 1\n0\n\0\0\0\0")
            .unwrap_err()
            .contains("scale"));
    }
}
