//! Images in memory: a width × height grid of pixels of `channels` values each, row-major
//! with channels interleaved (kornia's `Image`, with the channel count known at run time:
//! an array mixes RGB and monochrome cameras, and a cube has as many bands as the rig asks).
//!
//! In: the values and their layout, checked on construction. Out: per-pixel access.

use crate::{Error, Result};

/// `height × width × channels` values of type `T`: `data[(y * width + x) * channels + c]`.
///
/// The one raster of the library: captures and matching images (`Image<f32>`), feature
/// maps ([`crate::stereo::FeatureMap`], `Image<f32>` with a channel per feature), their
/// bfloat16 form ([`crate::register::CompactFeatures`], `Image<u16>`), cubes and
/// registered stacks (`Image<f32>` with a channel per band) and previews
/// ([`crate::reconstruct::RgbPreview`], `Image<u8>`, three channels).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Image<T> {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<T>,
}

impl<T> Image<T> {
    /// An image of the given layout over `data`, whose length must be
    /// `width × height × channels` (channels ≥ 1).
    pub fn new(width: usize, height: usize, channels: usize, data: Vec<T>) -> Result<Self> {
        let expected = width
            .checked_mul(height)
            .and_then(|n| n.checked_mul(channels))
            .filter(|_| channels > 0);
        if expected != Some(data.len()) {
            return Err(Error::Shape {
                op: "image: values against width × height × channels".into(),
                got: vec![data.len()],
                expected: vec![width, height, channels],
            });
        }
        Ok(Image {
            width,
            height,
            channels,
            data,
        })
    }

    /// Pixels in the image.
    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// The values of pixel (x, y).
    pub fn pixel(&self, x: usize, y: usize) -> &[T] {
        let start = (y * self.width + x) * self.channels;
        &self.data[start..start + self.channels]
    }
}

impl<T: Clone> Image<T> {
    /// An image whose every value is `value`.
    pub fn filled(width: usize, height: usize, channels: usize, value: T) -> Self {
        Image {
            width,
            height,
            channels,
            data: vec![value; width * height * channels],
        }
    }
}

/// A one-channel image (`channels == 1`) of `f32` values: what stereo matching compares.
pub type GreyImage = Image<f32>;

impl<T: Copy> Image<T> {
    /// The pixels of columns `xs` and rows `ys`, as an image of their own.
    pub fn crop(&self, xs: std::ops::Range<usize>, ys: std::ops::Range<usize>) -> Result<Self> {
        if xs.start >= xs.end || ys.start >= ys.end || xs.end > self.width || ys.end > self.height {
            return Err(Error::raster(
                "crop",
                format!("columns {xs:?} and rows {ys:?}"),
                format!("non-empty ranges within {}x{}", self.width, self.height),
            ));
        }
        let c = self.channels;
        let data = ys
            .clone()
            .flat_map(|y| {
                self.data[(y * self.width + xs.start) * c..(y * self.width + xs.end) * c]
                    .iter()
                    .copied()
            })
            .collect();
        Image::new(xs.len(), ys.len(), c, data)
    }

    /// The value at (x, y) of a one-channel image.
    pub fn at(&self, x: usize, y: usize) -> T {
        debug_assert_eq!(self.channels, 1, "at() reads one-channel images");
        self.data[y * self.width + x]
    }
}

/// A `width × height` plane of values blurred by a Gaussian of `sigma` pixels
/// (`image::imageops::blur`); returned as it is if the sizes do not match.
pub fn gaussian_blur_plane(width: usize, height: usize, values: Vec<f32>, sigma: f32) -> Vec<f32> {
    let buffer = image::ImageBuffer::<image::Luma<f32>, Vec<f32>>::from_raw(
        width as u32,
        height as u32,
        values,
    );
    match buffer {
        Some(buffer) if sigma > 0.0 => image::imageops::blur(&buffer, sigma).into_raw(),
        Some(buffer) => buffer.into_raw(),
        None => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layout_is_checked_and_pixels_are_interleaved() {
        let image = Image::new(2, 1, 3, vec![1, 2, 3, 4, 5, 6]).unwrap();
        assert_eq!(image.pixel(1, 0), &[4, 5, 6]);
        assert_eq!(image.pixels(), 2);
        assert!(matches!(
            Image::new(2, 2, 3, vec![0; 6]),
            Err(Error::Shape { .. })
        ));
        assert_eq!(
            Image::<u8>::new(2, 2, 0, vec![]).err().map(|e| e.kind()),
            Some("Shape")
        );
        assert_eq!(
            Image::<u8>::new(usize::MAX, 2, 1, vec![])
                .err()
                .map(|e| e.kind()),
            Some("Shape")
        );
    }
}
