//! Linear captures as pictures: 8- or 16-bit PNG/TIFF, grey or RGB(A), read as values in
//! [0, 1] without any gamma curve (the files hold linear sensor values), and written as
//! 16-bit PNG. The `image` crate decodes; we only check sizes and lay out the channels.

use super::{write_atomically, MAX_RASTER_VALUES};
use crate::{Error, Result};
use std::path::Path;

/// An interleaved linear raster with values in [0, 1].
pub type LinearImage = crate::image::Image<f32>;

/// Largest picture decoded, in pixels, unless `ANAGLYPH_MAX_PIXELS` says otherwise:
/// 2^26 (67 Mpx, 8192 × 8192).
pub const DEFAULT_MAX_IMAGE_PIXELS: u64 = 1 << 26;

/// The pixel limit in force: `ANAGLYPH_MAX_PIXELS` where set to a number, else
/// [`DEFAULT_MAX_IMAGE_PIXELS`]; never above [`MAX_RASTER_VALUES`] / 3.
pub fn max_image_pixels() -> u64 {
    std::env::var("ANAGLYPH_MAX_PIXELS")
        .ok()
        .and_then(|v| v.trim().parse::<u64>().ok())
        .unwrap_or(DEFAULT_MAX_IMAGE_PIXELS)
        .min(MAX_RASTER_VALUES / 3)
}

/// What a picture's header says, read without decoding its pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageHeader {
    pub width: usize,
    pub height: usize,
    /// Channels once read: 1 (grey) or 3 (RGB); alpha is dropped.
    pub channels: usize,
    /// The largest value the file can store (255 or 65535), which reads as 1.
    pub full_scale: u32,
}

fn open_picture(path: &Path) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
    image::ImageReader::open(path)
        .map_err(|e| Error::io(path, e))?
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))
}

/// Among pictures that must share one size, the first of another size than most of them
/// share, and that size (on a tie, the first picture's): the odd one out is blamed
/// whichever camera comes first. None when all agree.
pub fn odd_size_out(sizes: &[(usize, usize)]) -> Option<(usize, (usize, usize))> {
    let count = |size: &(usize, usize)| sizes.iter().filter(|s| *s == size).count();
    let common = sizes
        .iter()
        .fold(None, |best: Option<&(usize, usize)>, s| match best {
            Some(b) if count(b) >= count(s) => Some(b),
            _ => Some(s),
        })?;
    sizes
        .iter()
        .position(|s| s != common)
        .map(|odd| (odd, *common))
}

/// Reads the size and channels of a PNG or TIFF from its header and checks them against
/// [`max_image_pixels`], decoding no pixel: what a command checks before its work.
pub fn read_image_header(path: &Path) -> Result<ImageHeader> {
    use image::ImageDecoder;
    super::tiff_directory::check_tiff_directory(path)?;
    let mut reader = open_picture(path)?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(HEADER_ALLOCATION);
    reader.limits(limits);
    let decoder = reader.into_decoder().map_err(|e| Error::decode(path, e))?;
    let (width, height) = decoder.dimensions();
    let channels = match decoder.color_type().channel_count() {
        1 | 2 => 1,
        3 | 4 => 3,
        other => {
            return Err(Error::UnsupportedFormat {
                file: path.into(),
                what: "pixel type".into(),
                found: format!("{other} channels"),
                supported: "8- or 16-bit grey or RGB".into(),
            })
        }
    };
    let pixels = width as u64 * height as u64;
    let limit = max_image_pixels();
    if pixels > limit {
        return Err(Error::TooLarge {
            op: format!("reading {}", path.display()),
            what: format!(
                "a {width}x{height} picture, in pixels (ANAGLYPH_MAX_PIXELS raises the limit)"
            ),
            size: pixels,
            limit,
        });
    }
    check_compression(path, decoder.total_bytes())?;
    let colour = decoder.color_type();
    let bytes_per_sample = colour.bytes_per_pixel() / colour.channel_count().max(1);
    Ok(ImageHeader {
        width: width as usize,
        height: height as usize,
        channels,
        full_scale: if bytes_per_sample == 1 { 255 } else { 65535 },
    })
}

/// What reading a header may allocate (tags, palettes, offsets): 16 MiB.
const HEADER_ALLOCATION: u64 = 16 << 20;
/// Pixels a file may declare beyond its own size before its ratio is checked: 16 MiB.
const UNCHECKED_PIXEL_BYTES: u64 = 16 << 20;
/// The most a capture's pixels outgrow its file: noisy sensor data compresses about 2×,
/// a smooth rendering some 20×; only a truncated, hostile or constant picture reaches
/// this (and a constant capture is refused anyway).
const MAX_COMPRESSION_RATIO: u64 = 256;

/// Refuses a file that declares far more pixel bytes than it could hold, before the
/// decoder allocates them: a few hundred bytes declaring a picture of hundreds of MB.
fn check_compression(path: &Path, declared: u64) -> Result<()> {
    let file_bytes = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    if declared > UNCHECKED_PIXEL_BYTES
        && declared > file_bytes.saturating_mul(MAX_COMPRESSION_RATIO)
    {
        return Err(Error::decode(
            path,
            format!(
                "{file_bytes} bytes declaring {declared} bytes of pixels (expected at most \
                 {MAX_COMPRESSION_RATIO} times the file's size: a truncated or corrupt file?)"
            ),
        ));
    }
    Ok(())
}

/// Reads a PNG or TIFF as linear values in [0, 1]; alpha is dropped. The header is
/// checked first ([`read_image_header`]), and the decoder may allocate no more than the
/// picture it declares.
pub fn read_linear_image(path: &Path) -> Result<LinearImage> {
    let header = read_image_header(path)?;
    let mut reader = open_picture(path)?;
    let mut limits = image::Limits::default();
    let pixels = (header.width * header.height) as u64;
    // Four 16-bit samples per pixel at most, and room for the decoder's own rows.
    limits.max_alloc = Some(pixels * 8 + (64 << 20));
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| Error::Decode {
        file: path.into(),
        message: e.to_string(),
    })?;
    use image::DynamicImage as D;
    let (width, height) = (decoded.width() as usize, decoded.height() as usize);
    let (channels, data): (usize, Vec<f32>) = match decoded {
        D::ImageLuma8(i) => (1, i.into_raw().into_iter().map(from_u8_sample).collect()),
        D::ImageLuma16(i) => (1, i.into_raw().into_iter().map(from_u16_sample).collect()),
        D::ImageLumaA8(i) => (
            1,
            i.into_raw()
                .chunks_exact(2)
                .map(|p| from_u8_sample(p[0]))
                .collect(),
        ),
        D::ImageLumaA16(i) => (
            1,
            i.into_raw()
                .chunks_exact(2)
                .map(|p| from_u16_sample(p[0]))
                .collect(),
        ),
        D::ImageRgb8(i) => (3, i.into_raw().into_iter().map(from_u8_sample).collect()),
        D::ImageRgb16(i) => (3, i.into_raw().into_iter().map(from_u16_sample).collect()),
        D::ImageRgba8(i) => (
            3,
            i.into_raw()
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .map(from_u8_sample)
                .collect(),
        ),
        D::ImageRgba16(i) => (
            3,
            i.into_raw()
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .map(from_u16_sample)
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

/// A linear value in [0, 1] as a 16-bit sample (clipped, rounded): what a 16-bit capture
/// file stores.
#[inline]
pub fn to_u16_sample(v: f32) -> u16 {
    (v.clamp(0.0, 1.0) * 65535.0).round() as u16
}

/// A 16-bit sample as a linear value in [0, 1].
#[inline]
pub fn from_u16_sample(v: u16) -> f32 {
    v as f32 / 65535.0
}

/// An 8-bit sample as a linear value in [0, 1].
#[inline]
pub fn from_u8_sample(v: u8) -> f32 {
    v as f32 / 255.0
}

/// Writes a 16-bit grey or RGB PNG from values in [0, 1] (clipped, rounded).
pub fn write_png16(path: &Path, image: &LinearImage) -> Result<()> {
    let color = match image.channels {
        1 => image::ExtendedColorType::L16,
        3 => image::ExtendedColorType::Rgb16,
        c => {
            return Err(Error::raster(
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
        .flat_map(|&v| to_u16_sample(v).to_ne_bytes())
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
    #[test]
    fn the_odd_size_out_is_the_one_most_pictures_do_not_share() {
        let (a, b) = ((320, 240), (1, 1));
        assert_eq!(odd_size_out(&[a, a, a]), None);
        assert_eq!(odd_size_out(&[b, a, a]), Some((0, a)));
        assert_eq!(odd_size_out(&[a, b, a]), Some((1, a)));
        assert_eq!(odd_size_out(&[a, b]), Some((1, a)));
        assert_eq!(odd_size_out(&[]), None);
    }

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
