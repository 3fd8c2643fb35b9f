//! The first check of a run, before any stage: captures no camera could have recorded
//! of a lit scene are refused, naming the camera and what was measured, instead of being
//! solved into a reflectance of zero (a black capture) or of nothing (a saturated one).
//!
//! In: the array's captures and the saturation level. Out: an [`Error::Unusable`] for a
//! camera that is black, saturated over nearly all of its values, or constant (no
//! texture to register, no signal to measure), or nothing.

use super::ArrayCaptures;
use crate::image::Image;
use crate::{Error, Result};

/// A value below this fraction of full scale counts as black (131 of 65535 in a 16-bit
/// capture, 0 in an 8-bit one).
pub const BLACK_LEVEL: f32 = 0.002;
/// A camera is refused when at least this fraction of its values is black, or is
/// saturated.
pub const UNUSABLE_FRACTION: f64 = 0.99;
/// A channel whose unsaturated values all lie within this span of full scale is constant.
pub const CONSTANT_SPAN: f32 = 1.0 / 4096.0;

/// What one pass over a capture measures.
#[derive(Debug, Clone, Copy)]
struct SignalStatistics {
    values: usize,
    black: usize,
    saturated: usize,
    /// The smallest span of unsaturated values over the channels.
    narrowest_span: f32,
}

impl SignalStatistics {
    fn of(image: &Image<f32>, saturation: f32) -> Self {
        let channels = image.channels.max(1);
        let mut low = vec![f32::INFINITY; channels];
        let mut high = vec![f32::NEG_INFINITY; channels];
        let (mut values, mut black, mut saturated) = (0, 0, 0);
        for (i, &v) in image.data.iter().enumerate() {
            if !v.is_finite() {
                continue;
            }
            values += 1;
            if v < BLACK_LEVEL {
                black += 1;
            }
            if v >= saturation {
                saturated += 1;
                continue;
            }
            let c = i % channels;
            low[c] = low[c].min(v);
            high[c] = high[c].max(v);
        }
        let narrowest_span = low
            .iter()
            .zip(&high)
            .map(|(l, h)| if h >= l { h - l } else { 0.0 })
            .fold(f32::INFINITY, f32::min);
        SignalStatistics {
            values,
            black,
            saturated,
            narrowest_span,
        }
    }

    fn fraction(&self, count: usize) -> f64 {
        count as f64 / self.values.max(1) as f64
    }
}

/// Refuses the first camera whose capture is black, saturated or constant.
pub(super) fn check_capture_signal(captures: &ArrayCaptures, saturation: f32) -> Result<()> {
    for cam in &captures.cameras {
        check_signal(&cam.capture, saturation, &format!("camera {}", cam.name))?;
    }
    Ok(())
}

/// Refuses an image (`what`, e.g. "camera r0c1" or "the left image") that is black,
/// saturated at `saturation` (a fraction of full scale; infinite: not checked) or constant:
/// a picture no camera records of a lit, textured scene.
pub fn check_signal(image: &Image<f32>, saturation: f32, what: &str) -> Result<()> {
    let stats = SignalStatistics::of(image, saturation);
    let black = stats.fraction(stats.black);
    if black >= UNUSABLE_FRACTION {
        return Err(Error::unusable(
            what,
            format!(
                "its capture is black ({:.1} % of values below {BLACK_LEVEL} of full \
                 scale; expected a lit scene): a lens cap, no light, or the wrong file?",
                100.0 * black
            ),
        ));
    }
    let saturated = stats.fraction(stats.saturated);
    if saturated >= UNUSABLE_FRACTION {
        return Err(Error::unusable(
            what,
            format!(
                "its capture is saturated ({:.1} % of values at or above the saturation \
                 level {saturation}; expected most below it): expose it lower",
                100.0 * saturated
            ),
        ));
    }
    if stats.narrowest_span < CONSTANT_SPAN {
        return Err(Error::unusable(
            what,
            format!(
                "a channel of its capture is constant (its values span {:.2e} of full \
                 scale; expected a textured scene and sensor noise): a synthetic or \
                 stuck image?",
                stats.narrowest_span
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reconstruct::CameraCapture;

    fn array_of(images: Vec<Image<f32>>) -> ArrayCaptures {
        let cameras = images
            .into_iter()
            .enumerate()
            .map(|(col, capture)| CameraCapture {
                name: format!("r0c{col}"),
                capture,
                white: None,
                exposure: Some(1.0),
                calibration: None,
            })
            .collect();
        ArrayCaptures::from_cameras(cameras).unwrap()
    }

    /// A textured capture: values between 0.1 and 0.6.
    fn textured() -> Image<f32> {
        let data = (0..16 * 12 * 3)
            .map(|i| 0.1 + 0.5 * ((i * 7919) % 101) as f32 / 100.0)
            .collect();
        Image::new(16, 12, 3, data).unwrap()
    }

    fn filled(value: f32) -> Image<f32> {
        Image::new(16, 12, 3, vec![value; 16 * 12 * 3]).unwrap()
    }

    fn refusal(images: Vec<Image<f32>>) -> Option<String> {
        check_capture_signal(&array_of(images), 0.98)
            .err()
            .map(|e| e.to_string())
    }

    #[test]
    fn textured_captures_pass_and_a_dark_one_is_not_black() {
        let dim = Image {
            data: textured().data.iter().map(|v| v * 0.05).collect(),
            ..textured()
        };
        assert_eq!(refusal(vec![textured(), dim]), None);
    }

    #[test]
    fn a_black_saturated_or_constant_camera_is_named() {
        for (bad, words) in [
            (filled(0.0), "black (100.0 %"),
            (filled(1.0), "saturated (100.0 %"),
            (filled(0.4), "constant"),
        ] {
            let message = refusal(vec![textured(), bad]).expect("refused");
            assert!(
                message.starts_with("camera r0c1 cannot be used") && message.contains(words),
                "{message}"
            );
        }
    }

    #[test]
    fn a_few_saturated_or_missing_values_are_no_reason_to_refuse() {
        let mut capture = textured();
        for v in capture.data.iter_mut().step_by(10) {
            *v = 1.0;
        }
        capture.data[0] = f32::NAN;
        assert_eq!(refusal(vec![capture]), None);
    }
}
