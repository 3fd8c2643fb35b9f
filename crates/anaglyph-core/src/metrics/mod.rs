//! Accuracy metrics of a reconstruction against ground truth (paper Table 1): PSNR with a
//! stated peak (1.0 for reflectance), SSIM (Wang et al. 2004), spectral angle and RMSE,
//! per channel and averaged. Cubes are band-interleaved by pixel, `H × W × N`.

mod ssim;

pub use ssim::{masked_ssim, ssim, ssim_map, SSIM_K1, SSIM_K2, SSIM_SIGMA, SSIM_WINDOW};

/// Peak signal-to-noise ratio in dB: `10 log10(peak² / MSE)`; ∞ for identical inputs.
pub fn psnr(truth: &[f64], estimate: &[f64], peak: f64) -> f64 {
    let mse = mean_squared_error(truth, estimate);
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (peak * peak / mse).log10()
    }
}

/// Mean squared error over pairs where both values are finite.
pub fn mean_squared_error(truth: &[f64], estimate: &[f64]) -> f64 {
    let (sum, count) = truth
        .iter()
        .zip(estimate)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .fold((0.0, 0usize), |(s, c), (a, b)| {
            (s + (a - b) * (a - b), c + 1)
        });
    if count == 0 {
        f64::NAN
    } else {
        sum / count as f64
    }
}

/// Root-mean-square error.
pub fn rmse(truth: &[f64], estimate: &[f64]) -> f64 {
    mean_squared_error(truth, estimate).sqrt()
}

/// Spectral angle in radians between two spectra (0 = same shape).
pub fn spectral_angle(truth: &[f64], estimate: &[f64]) -> f64 {
    let dot: f64 = truth.iter().zip(estimate).map(|(a, b)| a * b).sum();
    let na: f64 = truth.iter().map(|a| a * a).sum::<f64>().sqrt();
    let nb: f64 = estimate.iter().map(|b| b * b).sum::<f64>().sqrt();
    if na == 0.0 || nb == 0.0 {
        return if na == nb {
            0.0
        } else {
            std::f64::consts::FRAC_PI_2
        };
    }
    (dot / (na * nb)).clamp(-1.0, 1.0).acos()
}

/// Per-band PSNR of two `pixels × bands` arrays.
pub fn psnr_per_band(truth: &[f64], estimate: &[f64], bands: usize, peak: f64) -> Vec<f64> {
    (0..bands)
        .map(|b| {
            let t: Vec<f64> = truth.iter().skip(b).step_by(bands).copied().collect();
            let e: Vec<f64> = estimate.iter().skip(b).step_by(bands).copied().collect();
            psnr(&t, &e, peak)
        })
        .collect()
}

/// Mean spectral angle (radians) over pixels of two `pixels × bands` arrays.
pub fn mean_spectral_angle(truth: &[f64], estimate: &[f64], bands: usize) -> f64 {
    let angles: Vec<f64> = truth
        .chunks_exact(bands)
        .zip(estimate.chunks_exact(bands))
        .map(|(a, b)| spectral_angle(a, b))
        .filter(|v| v.is_finite())
        .collect();
    angles.iter().sum::<f64>() / angles.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_of_a_known_error() {
        // MSE 0.01 with peak 1 is 20 dB.
        assert!((psnr(&[0.0, 0.0], &[0.1, -0.1], 1.0) - 20.0).abs() < 1e-12);
        assert_eq!(psnr(&[0.3], &[0.3], 1.0), f64::INFINITY);
        let bands = psnr_per_band(&[0.0, 1.0, 0.0, 1.0], &[0.1, 1.0, 0.1, 1.0], 2, 1.0);
        assert!((bands[0] - 20.0).abs() < 1e-12 && bands[1].is_infinite());
        assert!((rmse(&[0.0, 0.0], &[0.3, 0.4]) - (0.125f64).sqrt()).abs() < 1e-15);
    }

    #[test]
    fn spectral_angle_ignores_scale() {
        assert!(spectral_angle(&[1.0, 2.0], &[2.0, 4.0]).abs() < 1e-7);
        assert!(
            (spectral_angle(&[1.0, 0.0], &[0.0, 3.0]) - std::f64::consts::FRAC_PI_2).abs() < 1e-12
        );
    }
}
