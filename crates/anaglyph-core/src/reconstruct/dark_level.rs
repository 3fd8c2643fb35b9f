//! Dark subtraction, the first correction of a real sensor's values: what a camera
//! records with no light (its black level, or a dark frame that also holds fixed-pattern
//! offsets) is removed from its capture and its white board before they are calibrated.
//!
//! In: a picture read as values in [0, 1] and the camera's [`Dark`]. Out: the picture less
//! the dark values, clamped at 0; values at full scale stay at full scale, so that clipped
//! pixels remain saturated (the saturation level applies to the dark-subtracted values).

use super::capture_checks::{BLACK_LEVEL, UNUSABLE_FRACTION};
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

    /// `image` less the dark values (see the module docs). A picture with signal that is
    /// black once the dark is removed is refused naming the dark (`dark`, e.g. "dark frame
    /// darks/r0c0.png"), not the picture (`picture` of `camera`, e.g. "capture
    /// (captures/r0c0.png)" of "camera r0c0"): such a dark was recorded at another exposure
    /// or gain, or the two were swapped.
    pub fn subtract_from(
        &self,
        image: &mut LinearImage,
        camera: &str,
        picture: &str,
        dark: &str,
    ) -> Result<()> {
        let dark_at = |i: usize| match self {
            Dark::Level(level) => *level,
            Dark::Frame(frame) => frame.data[i],
        };
        let (mut values, mut black_before, mut black_after) = (0usize, 0usize, 0usize);
        let (mut picture_sum, mut dark_sum) = (0.0f64, 0.0f64);
        for (i, v) in image.data.iter_mut().enumerate() {
            if !v.is_finite() {
                continue;
            }
            values += 1;
            black_before += usize::from(*v < BLACK_LEVEL);
            picture_sum += f64::from(*v);
            dark_sum += f64::from(dark_at(i));
            if *v < 1.0 {
                *v = (*v - dark_at(i)).max(0.0);
            }
            black_after += usize::from(*v < BLACK_LEVEL);
        }
        let fraction = |count: usize| count as f64 / values.max(1) as f64;
        // "capture (captures/r0c0.png)" is named whole once, then by its first word.
        let noun = picture.split(" (").next().unwrap_or(picture);
        if fraction(black_before) < UNUSABLE_FRACTION && fraction(black_after) >= UNUSABLE_FRACTION
        {
            let values = values.max(1) as f64;
            return Err(Error::unusable(
                camera,
                format!(
                    "its {dark} is at or above its {picture} on {:.1} % of values (mean {:.4} \
                     of full scale against {:.4}); expected a dark below the {noun}, recorded \
                     with the lens capped at the same exposure and gain: a dark of another \
                     exposure, or the two swapped?",
                    100.0 * fraction(black_after),
                    dark_sum / values,
                    picture_sum / values,
                ),
            ));
        }
        Ok(())
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
            .subtract_from(&mut image, "camera c", "capture", "black level")
            .unwrap();
        let close =
            |got: &[f32], want: [f32; 4]| got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-6);
        assert!(
            close(&image.data, [0.49, 0.0, 1.0, 0.29]),
            "{:?}",
            image.data
        );
        let frame = Image::new(2, 2, 1, vec![0.1, 0.0, 0.2, 0.3]).unwrap();
        Dark::Frame(frame)
            .subtract_from(&mut image, "camera c", "capture", "dark frame")
            .unwrap();
        assert!(
            close(&image.data, [0.39, 0.0, 1.0, 0.0]),
            "{:?}",
            image.data
        );
        let refused = Dark::level(300.0, 255.0, Path::new("c.png")).err();
        assert_eq!(refused.map(|e| e.kind()), Some("OutOfRange"));
    }

    /// A dark brighter than the picture is blamed, not the picture it blackens; a
    /// picture black before the dark is left to the capture checks.
    #[test]
    fn a_dark_above_the_picture_is_refused_naming_the_dark() {
        let picture = Image::new(2, 2, 1, vec![0.2, 0.25, 0.3, 0.2]).unwrap();
        let bright = Dark::Frame(Image::new(2, 2, 1, vec![0.4; 4]).unwrap());
        let error = bright
            .subtract_from(
                &mut picture.clone(),
                "camera c",
                "capture",
                "dark frame d.png",
            )
            .unwrap_err();
        let text = error.to_string();
        assert_eq!(error.kind(), "Unusable");
        assert!(
            text.contains("camera c cannot be used: its dark frame d.png is at or above its capture on 100.0 %")
                && text.contains("mean 0.4000 of full scale against 0.2375); expected a dark below the capture,"),
            "{text}"
        );
        let mut black = Image::new(2, 2, 1, vec![0.0; 4]).unwrap();
        bright
            .subtract_from(&mut black, "camera c", "capture", "dark frame d.png")
            .unwrap();
        let mut lit = picture;
        Dark::Level(0.1)
            .subtract_from(&mut lit, "camera c", "capture", "black level")
            .unwrap();
    }
}
