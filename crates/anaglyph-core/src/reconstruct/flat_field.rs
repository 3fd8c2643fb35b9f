//! The white board as a flat field: its smooth shape per channel, by which each capture is
//! divided pixel by pixel, so that what the lens and the light do across the frame
//! (vignetting, an uneven source) cancels as it does in the white board.
//!
//! In: a white-board capture and the saturation level. Out: per pixel and channel, the
//! white board's value relative to its channel mean (1 where it is flat), smoothed by a
//! Gaussian of [`smoothing_sigma`] with saturated pixels left out (normalised
//! convolution), so that the board's own noise is not divided into the scene.

use crate::image::gaussian_blur_plane;
use crate::io::LinearImage;

/// Smallest relative value kept: a white board darker than this fraction of its mean
/// (a corner lost to vignetting) leaves the pixel unmeasured.
pub const MIN_FLAT_FIELD: f32 = 0.05;

/// The smoothing of the white board, pixels: a hundredth of the frame's diagonal, at
/// least 4 (σ = 8 px at 640×480 averages about 800 pixels, cutting the board's noise
/// 28-fold; vignetting varies over hundreds of pixels).
pub fn smoothing_sigma(width: usize, height: usize) -> f32 {
    ((width as f32).hypot(height as f32) / 100.0).max(4.0)
}

/// Per pixel and channel (the capture's layout), the white board's smoothed value over
/// its channel mean `means[c]`; NaN where the board is saturated all around or darker
/// than [`MIN_FLAT_FIELD`].
pub fn flat_field(white: &LinearImage, means: &[f64], saturation: f32) -> Vec<f32> {
    let (w, h, ch) = (white.width, white.height, white.channels);
    let sigma = smoothing_sigma(w, h);
    let mut field = vec![f32::NAN; w * h * ch];
    for c in 0..ch {
        let usable = |v: f32| v.is_finite() && v < saturation;
        let plane = |f: &dyn Fn(f32) -> f32| {
            let data = white
                .data
                .iter()
                .skip(c)
                .step_by(ch)
                .map(|&v| f(v))
                .collect();
            gaussian_blur_plane(w, h, data, sigma)
        };
        let values = plane(&|v| if usable(v) { v } else { 0.0 });
        let weights = plane(&|v| f32::from(u8::from(usable(v))));
        let mean = means[c] as f32;
        for (i, (v, k)) in values.iter().zip(&weights).enumerate() {
            let relative = v / k / mean;
            if *k > 1e-3 && relative >= MIN_FLAT_FIELD {
                field[i * ch + c] = relative;
            }
        }
    }
    field
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vignetted_noisy_white_board_gives_its_smooth_falloff() {
        let (w, h) = (80usize, 60usize);
        let falloff = |x: usize, y: usize| {
            let (dx, dy) = (x as f32 - 39.5, y as f32 - 29.5);
            1.0 - 0.5 * (dx * dx + dy * dy) / (39.5f32 * 39.5 + 29.5 * 29.5)
        };
        // ±2 % noise (a fixed pseudo-random pattern), and one saturated pixel.
        let noise = |i: usize| 0.02 * (((i * 7919) % 101) as f32 / 50.0 - 1.0);
        let mut data: Vec<f32> = (0..w * h)
            .map(|i| 0.6 * falloff(i % w, i / w) * (1.0 + noise(i)))
            .collect();
        data[30 * w + 40] = 1.0;
        let white = LinearImage::new(w, h, 1, data).unwrap();
        let field = flat_field(&white, &[0.6], 0.99);
        // Away from the borders (where the blur sees half a window), within 1 %.
        for y in 10..h - 10 {
            for x in 10..w - 10 {
                let f = field[y * w + x];
                assert!((f / falloff(x, y) - 1.0).abs() < 0.01, "({x}, {y}): {f}");
            }
        }
        assert!(field.iter().all(|f| f.is_finite()));
    }
}
