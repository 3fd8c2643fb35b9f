//! Dark subtraction, the first correction of a real sensor's values: what a camera
//! records with no light (its black level, or a dark frame that also holds fixed-pattern
//! offsets) is removed from its capture and its white board before they are calibrated.
//!
//! In: a picture read as values in [0, 1] and the camera's [`Dark`]. Out: the picture less
//! the dark values, clamped at 0; values at full scale stay at full scale, so that clipped
//! pixels remain saturated (the saturation level applies to the dark-subtracted values).

use crate::io::LinearImage;
use crate::{Error, Result};
use std::path::Path;

/// What a camera records without light.
#[derive(Debug, Clone)]
pub enum Dark {
    /// One level for every pixel, as a fraction of full scale.
    Level(f32),
    /// A dark frame of the capture's size and channels.
    Frame(LinearImage),
}

impl Dark {
    /// The black level `level`, given in the units of a file whose full scale is
    /// `full_scale` (255 or 65535), as a fraction of full scale.
    pub fn level(level: f64, full_scale: f64, file: &Path) -> Result<Dark> {
        if !(level >= 0.0 && level < full_scale) {
            return Err(Error::out_of_range(
                format!("black_level of {}", file.display()),
                level,
                format!("0 to below the file's full scale {full_scale}"),
            ));
        }
        Ok(Dark::Level((level / full_scale) as f32))
    }

    /// `image` less the dark values (see the module docs).
    pub fn subtract_from(&self, image: &mut LinearImage) {
        let dark_at = |i: usize| match self {
            Dark::Level(level) => *level,
            Dark::Frame(frame) => frame.data[i],
        };
        for (i, v) in image.data.iter_mut().enumerate() {
            if *v < 1.0 {
                *v = (*v - dark_at(i)).max(0.0);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;

    #[test]
    fn the_dark_is_removed_and_clipped_pixels_stay_clipped() {
        let mut image = Image::new(2, 2, 1, vec![0.5, 0.01, 1.0, 0.3]).unwrap();
        Dark::level(655.35, 65535.0, Path::new("c.png"))
            .unwrap()
            .subtract_from(&mut image);
        let close =
            |got: &[f32], want: [f32; 4]| got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-6);
        assert!(
            close(&image.data, [0.49, 0.0, 1.0, 0.29]),
            "{:?}",
            image.data
        );
        let frame = Image::new(2, 2, 1, vec![0.1, 0.0, 0.2, 0.3]).unwrap();
        Dark::Frame(frame).subtract_from(&mut image);
        assert!(
            close(&image.data, [0.39, 0.0, 1.0, 0.0]),
            "{:?}",
            image.data
        );
        let refused = Dark::level(300.0, 255.0, Path::new("c.png")).err();
        assert_eq!(refused.map(|e| e.kind()), Some("OutOfRange"));
    }
}
