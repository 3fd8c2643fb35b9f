//! The disparity search range from the captures themselves (`reconstruct --max-disp auto`),
//! run before registration: the array is registered on images downsampled 2× or 4× over
//! the widest range at which the outermost views still overlap, and the 98th percentile of
//! those disparities, scaled back with a margin, becomes the full-resolution range.
//! A user no longer needs the nearest working distance (`f·b_x / z_min`).

use super::{register_views, ArrayGeometry, GridImage, RegistrationSettings};
use crate::stereo::GreyImage;
use crate::{Error, Result};
use serde::Serialize;
use std::time::Instant;

/// Fraction of the coarse disparities the range must cover. A range wider than needed
/// costs quality (spurious matches where few views overlap: tabletop r0c0 29.6 / 29.1 /
/// 28.7 dB at 52 / 56 / 60 for a largest true disparity of 45.6), so coarse outliers must
/// not set it: 0.99 chose 71 there, 0.98 chooses 59.
const COVERED_QUANTILE: f64 = 0.98;
/// Multiplicative margin on the covered disparity.
const MARGIN: f64 = 1.1;
/// Largest coarse search range (disparities at the coarse scale).
const MAX_COARSE_DISPARITY: usize = 128;

/// The chosen range and how it was found.
#[derive(Debug, Clone, Serialize)]
pub struct SearchRange {
    /// Disparities searched at full resolution: `[0, max_disp)`.
    pub max_disp: usize,
    /// Downsampling factor of the coarse registration.
    pub factor: usize,
    /// Coarse range searched (coarse pixels).
    pub coarse_max_disp: usize,
    /// The covered quantile of the coarse disparities, in full-resolution pixels.
    pub covered_disparity_px: f64,
    pub seconds: f64,
}

/// Box-averages `image` by `factor` (and its measured mask: a coarse pixel is measured only
/// if all its fine pixels are).
fn downsample(view: &GridImage, factor: usize) -> GridImage {
    let (w, h) = (view.image.width / factor, view.image.height / factor);
    let fine_w = view.image.width;
    let mut data = Vec::with_capacity(w * h);
    let mut measured = view.measured.as_ref().map(|_| Vec::with_capacity(w * h));
    for y in 0..h {
        for x in 0..w {
            let (mut sum, mut all) = (0.0f32, true);
            for dy in 0..factor {
                for dx in 0..factor {
                    let i = (y * factor + dy) * fine_w + x * factor + dx;
                    sum += view.image.data[i];
                    if let Some(mask) = &view.measured {
                        all &= mask[i];
                    }
                }
            }
            data.push(sum / (factor * factor) as f32);
            if let Some(m) = measured.as_mut() {
                m.push(all);
            }
        }
    }
    GridImage {
        row: view.row,
        col: view.col,
        image: GreyImage {
            channels: 1,
            width: w,
            height: h,
            data,
        },
        matching: Vec::new(),
        measured,
    }
}

/// Estimates the search range of `images` (see the module docs) with the registration
/// `settings` (their `max_disp` is ignored).
pub fn estimate_search_range(
    images: &[GridImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
) -> Result<SearchRange> {
    let clock = Instant::now();
    let Some(first) = images.first() else {
        return Err(Error::mismatch("search range", "no views", "at least one"));
    };
    let (w, h) = (first.image.width, first.image.height);
    let span = geometry.cols.saturating_sub(1).max(1);
    let factor = match w.min(h) {
        s if s >= 400 => 4,
        s if s >= 120 => 2,
        _ => 1,
    };
    let coarse: Vec<GridImage> = images.iter().map(|v| downsample(v, factor)).collect();
    let coarse_w = w / factor;
    let coarse_max_disp = (coarse_w / span).clamp(4, MAX_COARSE_DISPARITY);
    if coarse_w < 16 || h / factor < 16 {
        return Err(Error::mismatch(
            "search range",
            format!("{w}x{h} px, too small to estimate a range"),
            "a larger image, or a search range given (--max-disp)",
        ));
    }
    let registration = register_views(
        &coarse,
        geometry,
        &RegistrationSettings {
            max_disp: coarse_max_disp,
            ..*settings
        },
        &|_, _| {},
    )?;
    let mut values: Vec<f32> = registration
        .disparities
        .iter()
        .flatten()
        .copied()
        .filter(|d| d.is_finite())
        .collect();
    if values.is_empty() {
        return Err(Error::unusable(
            "the coarse registration",
            "it found no disparity; give the search range (--max-disp)",
        ));
    }
    values.sort_by(f32::total_cmp);
    let covered = values[((values.len() - 1) as f64 * COVERED_QUANTILE) as usize] as f64;
    let covered_px = covered.max(0.0) * factor as f64;
    let max_disp = ((covered_px * MARGIN).ceil() as usize + 2 * factor).clamp(4, (w / span).max(4));
    Ok(SearchRange {
        max_disp,
        factor,
        coarse_max_disp,
        covered_disparity_px: covered_px,
        seconds: clock.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downsampling_averages_and_keeps_unmeasured_pixels_unmeasured() {
        let view = GridImage {
            row: 0,
            col: 1,
            image: GreyImage {
                channels: 1,
                width: 4,
                height: 2,
                data: vec![0.0, 1.0, 2.0, 3.0, 1.0, 2.0, 3.0, 4.0],
            },
            matching: Vec::new(),
            measured: Some(vec![true, true, true, false, true, true, true, true]),
        };
        let coarse = downsample(&view, 2);
        assert_eq!((coarse.image.width, coarse.image.height), (2, 1));
        assert_eq!(coarse.image.data, vec![1.0, 3.0]);
        assert_eq!(coarse.measured, Some(vec![true, false]));
    }
}
