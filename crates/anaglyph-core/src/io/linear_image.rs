//! Linear captures as pictures: 8- or 16-bit PNG/TIFF, grey or RGB(A), read as values in
//! [0, 1] without any gamma curve (the files hold linear sensor values), and written as
//! 16-bit PNG. The `image` crate decodes; we only check sizes and lay out the channels.

use super::{write_atomically, MAX_RASTER_VALUES};
use crate::{Error, Result};
use std::path::Path;

/// An interleaved linear raster with values in [0, 1].
pub type LinearImage = crate::image::Image<f32>;

/// Reads a PNG or TIFF as linear values in [0, 1]; alpha is dropped.
pub fn read_linear_image(path: &Path) -> Result<LinearImage> {
    let reader = image::ImageReader::open(path)
        .map_err(|e| Error::io(path, e))?
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    let mut reader = reader;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_RASTER_VALUES * 2);
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| Error::Decode {
        file: path.into(),
        message: e.to_string(),
    })?;
    use image::DynamicImage as D;
    let (width, height) = (decoded.width() as usize, decoded.height() as usize);
    let (channels, data): (usize, Vec<f32>) = match decoded {
        D::ImageLuma8(i) => (1, i.into_raw().iter().map(|&v| v as f32 / 255.0).collect()),
        D::ImageLuma16(i) => (
            1,
            i.into_raw().iter().map(|&v| v as f32 / 65535.0).collect(),
        ),
        D::ImageLumaA8(i) => (
            1,
            i.into_raw()
                .chunks_exact(2)
                .map(|p| p[0] as f32 / 255.0)
                .collect(),
        ),
        D::ImageLumaA16(i) => (
            1,
            i.into_raw()
                .chunks_exact(2)
                .map(|p| p[0] as f32 / 65535.0)
                .collect(),
        ),
        D::ImageRgb8(i) => (3, i.into_raw().iter().map(|&v| v as f32 / 255.0).collect()),
        D::ImageRgb16(i) => (
            3,
            i.into_raw().iter().map(|&v| v as f32 / 65535.0).collect(),
        ),
        D::ImageRgba8(i) => (
            3,
            i.into_raw()
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .map(|v| v as f32 / 255.0)
                .collect(),
        ),
        D::ImageRgba16(i) => (
            3,
            i.into_raw()
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .map(|v| v as f32 / 65535.0)
                .collect(),
        ),
        other => {
            return Err(Error::UnsupportedFormat {
                file: path.into(),
                what: "pixel type".into(),
                found: format!("{:?}", other.color()),
                supported: "8- or 16-bit grey or RGB".into(),
            })
        }
    };
    Ok(LinearImage {
        width,
        height,
        channels,
        data,
    })
}

/// Writes a 16-bit grey or RGB PNG from values in [0, 1] (clipped, rounded).
pub fn write_png16(path: &Path, image: &LinearImage) -> Result<()> {
    let color = match image.channels {
        1 => image::ExtendedColorType::L16,
        3 => image::ExtendedColorType::Rgb16,
        c => {
            return Err(Error::mismatch(
                "16-bit PNG output",
                format!("{c} channels"),
                "1 or 3",
            ))
        }
    };
    if image.data.len() != image.width * image.height * image.channels {
        return Err(Error::Shape {
            op: "write_png16".into(),
            got: vec![image.data.len()],
            expected: vec![image.width * image.height * image.channels],
        });
    }
    let bytes: Vec<u8> = image
        .data
        .iter()
        .flat_map(|&v| ((v.clamp(0.0, 1.0) * 65535.0).round() as u16).to_ne_bytes())
        .collect();
    write_atomically(path, |w| {
        use image::ImageEncoder;
        image::codecs::png::PngEncoder::new(w)
            .write_image(&bytes, image.width as u32, image.height as u32, color)
            .map_err(std::io::Error::other)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sixteen_bit_png_round_trip_is_linear() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.png");
        let img = LinearImage {
            width: 2,
            height: 1,
            channels: 3,
            data: vec![0.0, 0.5, 1.0, 0.25, 1.0 / 65535.0, 0.75],
        };
        write_png16(&path, &img).unwrap();
        let back = read_linear_image(&path).unwrap();
        assert_eq!((back.width, back.height, back.channels), (2, 1, 3));
        for (a, b) in back.data.iter().zip(&img.data) {
            assert!((a - b).abs() <= 0.5 / 65535.0, "{a} vs {b}");
        }
    }

    #[test]
    fn sixteen_bit_tiff_and_eight_bit_grey_png_are_read_linearly() {
        let dir = tempfile::tempdir().unwrap();
        let tiff = dir.path().join("c.tif");
        let pixels: Vec<u16> = vec![0, 1000, 65535, 32768, 7, 9];
        image::ImageBuffer::<image::Rgb<u16>, _>::from_raw(2, 1, pixels.clone())
            .unwrap()
            .save(&tiff)
            .unwrap();
        let back = read_linear_image(&tiff).unwrap();
        assert_eq!(back.channels, 3);
        for (a, &b) in back.data.iter().zip(&pixels) {
            assert_eq!(*a, b as f32 / 65535.0);
        }
        let png = dir.path().join("g.png");
        image::GrayImage::from_raw(3, 1, vec![0, 51, 255])
            .unwrap()
            .save(&png)
            .unwrap();
        let grey = read_linear_image(&png).unwrap();
        assert_eq!(grey.channels, 1);
        assert_eq!(grey.data, vec![0.0, 0.2, 1.0]);
    }

    #[test]
    fn garbage_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        std::fs::write(&path, b"not a png").unwrap();
        assert_eq!(
            read_linear_image(&path).err().map(|e| e.kind()),
            Some("Decode")
        );
    }
}
