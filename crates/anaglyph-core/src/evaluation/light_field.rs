//! Scores of a reconstructed light field against the simulator's truth, the paper's
//! Table 1 layout: per view, PSNR and SSIM of every band (reflectance, peak 1) and their
//! averages, the mean spectral angle, over all pixels and over the pixels every camera
//! sees (where registration cannot be blamed for a missing measurement).
//!
//! A pixel without a reconstruction (NaN) counts as reflectance 0, so that coverage gaps
//! lower the score instead of hiding; the coverage is reported beside it.

use crate::disparity::DisparityMap;
use crate::metrics::{masked_ssim, psnr, spectral_angle};
use crate::register::ArrayGeometry;
use crate::{Error, Result};
use serde::Serialize;

/// Largest difference (px per column step) between two views' true disparities for a
/// surface point to count as the same point, i.e. seen by both.
pub const SAME_POINT_PX: f32 = 0.5;

/// The share of pixels whose estimated disparity is more than `threshold_px` off the
/// truth or missing (NaN), over the pixels with a finite truth where `mask` holds (None:
/// all): bad-1 or bad-2 by `threshold_px`. NaN when no pixel counts.
pub fn bad_pixel_share(
    estimate: &[f32],
    truth: &[f32],
    mask: Option<&[bool]>,
    threshold_px: f32,
) -> f64 {
    let (bad, total) = estimate
        .iter()
        .zip(truth)
        .enumerate()
        .filter(|&(i, (_, t))| t.is_finite() && mask.is_none_or(|m| m[i]))
        .fold((0usize, 0usize), |(b, n), (_, (e, t))| {
            let right = (e - t).abs() <= threshold_px;
            (b + usize::from(!right), n + 1)
        });
    bad as f64 / total as f64
}

/// Scores of one view.
#[derive(Debug, Clone, Serialize)]
pub struct BandScores {
    pub band_psnr: Vec<f64>,
    pub band_ssim: Vec<f64>,
    /// Mean of `band_psnr` (the paper's "average").
    pub psnr: f64,
    pub ssim: f64,
    pub spectral_angle_deg: f64,
    /// Pixels scored.
    pub pixels: usize,
}

/// Scores `estimate` against `truth` (both `height × width × bands`) over the pixels
/// where `mask` is true (all pixels without one).
pub fn score_cube(
    truth: &[f32],
    estimate: &[f32],
    width: usize,
    height: usize,
    bands: usize,
    mask: Option<&[bool]>,
) -> Result<BandScores> {
    let n = width * height;
    if truth.len() != n * bands || estimate.len() != n * bands || mask.is_some_and(|m| m.len() != n)
    {
        return Err(Error::Shape {
            op: "scoring a reconstruction".into(),
            got: vec![estimate.len(), mask.map_or(n, <[bool]>::len)],
            expected: vec![truth.len(), n],
        });
    }
    let all = vec![true; n];
    let mask = mask.unwrap_or(&all);
    let value = |v: f32| if v.is_finite() { v as f64 } else { 0.0 };
    let mut band_psnr = Vec::with_capacity(bands);
    let mut band_ssim = Vec::with_capacity(bands);
    for b in 0..bands {
        let plane = |cube: &[f32]| -> Vec<f64> {
            cube.iter()
                .skip(b)
                .step_by(bands)
                .map(|&v| value(v))
                .collect()
        };
        let (t, e) = (plane(truth), plane(estimate));
        let pick = |p: &[f64]| -> Vec<f64> {
            p.iter()
                .zip(mask)
                .filter(|(_, &m)| m)
                .map(|(&v, _)| v)
                .collect()
        };
        band_psnr.push(psnr(&pick(&t), &pick(&e), 1.0));
        band_ssim.push(masked_ssim(&t, &e, width, height, 1.0, mask));
    }
    let (mut angle, mut counted) = (0.0, 0usize);
    for i in (0..n).filter(|&i| mask[i]) {
        let t: Vec<f64> = truth[i * bands..][..bands]
            .iter()
            .map(|&v| value(v))
            .collect();
        let e: Vec<f64> = estimate[i * bands..][..bands]
            .iter()
            .map(|&v| value(v))
            .collect();
        angle += spectral_angle(&t, &e);
        counted += 1;
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    Ok(BandScores {
        psnr: mean(&band_psnr),
        ssim: mean(&band_ssim),
        band_psnr,
        band_ssim,
        spectral_angle_deg: (angle / counted.max(1) as f64).to_degrees(),
        pixels: counted,
    })
}

/// The pixels of view `reference` that every other view sees, from the views' true
/// disparity maps (`disparities[v]` is view v's of `geometry`, per column step).
pub fn seen_by_all_views(
    disparities: &[DisparityMap],
    geometry: &ArrayGeometry,
    reference: usize,
) -> Vec<bool> {
    let own = &disparities[reference];
    let (width, height) = (own.width, own.height);
    (0..width * height)
        .map(|i| {
            let d = own.data[i];
            if !d.is_finite() {
                return false;
            }
            let (x, y) = ((i % width) as f64, (i / width) as f64);
            (0..geometry.len()).all(|v| {
                if v == reference {
                    return true;
                }
                let (sx, sy) = geometry.shift(reference, v);
                let (px, py) = ((x + sx * d as f64).round(), (y + sy * d as f64).round());
                let other = &disparities[v];
                px >= 0.0
                    && py >= 0.0
                    && px < other.width as f64
                    && py < other.height as f64
                    && (other.data[py as usize * other.width + px as usize] - d).abs()
                        <= SAME_POINT_PX
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perfect_and_offset_reconstructions_score_as_expected() {
        let (w, h, nb) = (16, 12, 3);
        let truth: Vec<f32> = (0..w * h * nb)
            .map(|i| 0.1 + (i % 17) as f32 / 20.0)
            .collect();
        let perfect = score_cube(&truth, &truth, w, h, nb, None).unwrap();
        assert!(perfect.psnr.is_infinite() && (perfect.ssim - 1.0).abs() < 1e-12);
        assert!(perfect.spectral_angle_deg < 1e-3);
        // A uniform error of 0.01: PSNR = 40 dB in every band.
        let off: Vec<f32> = truth.iter().map(|v| v + 0.01).collect();
        let scores = score_cube(&truth, &off, w, h, nb, None).unwrap();
        assert!(scores.band_psnr.iter().all(|p| (p - 40.0).abs() < 1e-3));
        // A NaN pixel counts as zero.
        let mut holed = truth.clone();
        holed[..nb].fill(f32::NAN);
        let mut mask = vec![true; w * h];
        mask[0] = false;
        let masked = score_cube(&truth, &holed, w, h, nb, Some(&mask)).unwrap();
        assert!(masked.psnr.is_infinite() && masked.pixels == w * h - 1);
        assert!(score_cube(&truth, &holed, w, h, nb, None)
            .unwrap()
            .psnr
            .is_finite());
    }

    #[test]
    fn a_fronto_parallel_plane_is_seen_except_at_the_borders() {
        let (w, h) = (20, 10);
        let geometry = ArrayGeometry::grid(1, 2, 1.0);
        let plane = DisparityMap::new(
            w,
            h,
            crate::disparity::DisparityConvention::ColumnStep,
            vec![3.0f32; w * h],
        )
        .unwrap();
        let seen = seen_by_all_views(&[plane.clone(), plane], &geometry, 0);
        for (i, s) in seen.iter().enumerate() {
            assert_eq!(*s, i % w >= 3, "pixel {i}");
        }
    }
}
