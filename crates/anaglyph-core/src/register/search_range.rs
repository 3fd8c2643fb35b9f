//! The disparity search range from the captures themselves (`reconstruct --disp-range
//! auto`, the default), run before registration: the array is registered on images
//! downsampled 2× or 4× over the widest range at which the outermost views still overlap
//! (signed: a third of it below zero, for arrays calibrated to a plane), and the 2nd and
//! 98th percentiles of those disparities, scaled back with a margin, become the
//! full-resolution range, from the views inside the array
//! ([`ArrayGeometry::interior_views`]) and only where another view's map confirms them.
//! Where the views themselves go coarse to fine ([`CoarseToFine::applies`]), so does this
//! registration (its own coarse level 2× coarser again): the coarse range is several times
//! what the views need. The range starts at 0 unless the coarse disparities reach below
//! −0.5 coarse pixel, so an array rectified to infinity is searched from 0 as before.
//! A user no longer needs the nearest working distance (`f·b_x / z_min`).

use super::{register_views, ArrayGeometry, CoarseToFine, RegistrationSettings, ViewImage};
use crate::disparity::DisparityMap;
use crate::stereo::DisparityRange;
use crate::{Error, Result};
use serde::Serialize;
use std::time::Instant;

/// Fraction of the coarse disparities the range must cover below its top (and above its
/// bottom: `1 − COVERED_QUANTILE`). A range wider than needed costs quality (spurious
/// matches where few views overlap: tabletop r0c0 29.6 / 29.1 / 28.7 dB at 52 / 56 / 60
/// for a largest true disparity of 45.6), so coarse outliers must not set it: 0.99 chose
/// 71 there, 0.98 chooses 59.
const COVERED_QUANTILE: f64 = 0.98;
/// Share of the coarse search range below zero.
const NEGATIVE_SHARE: usize = 3;
/// The covered low quantile must lie below minus this many coarse pixels for the range to
/// reach below 0 (an array rectified to infinity has no negative disparities; coarse noise
/// around a far background stays within about half a pixel).
const NEGATIVE_EVIDENCE_PX: f64 = 0.5;
/// The quantile of the coarse disparities that decides whether the range reaches below 0.
const NEGATIVE_QUANTILE: f64 = 0.005;
/// Multiplicative margin on the covered disparity.
const MARGIN: f64 = 1.1;
/// Largest coarse search range (disparities at the coarse scale).
const MAX_COARSE_DISPARITY: usize = 128;

/// The chosen range and how it was found.
#[derive(Debug, Clone, Serialize)]
pub struct SearchRange {
    /// Disparities searched at full resolution.
    pub range: DisparityRange,
    /// Downsampling factor of the coarse registration.
    pub factor: usize,
    /// Coarse range searched (coarse pixels).
    pub coarse_range: DisparityRange,
    /// The covered quantiles of the confirmed coarse disparities, in full-resolution
    /// pixels: low (the 2nd percentile, or the 0.5th when that reaches further below 0)
    /// and high (the 98th).
    pub covered_disparity_px: [f64; 2],
    pub seconds: f64,
}

/// Estimates the search range of `images` (see the module docs) with the registration
/// `settings` (their `max_disp` is ignored).
pub fn estimate_search_range(
    images: &[ViewImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
) -> Result<SearchRange> {
    let clock = Instant::now();
    let Some(first) = images.first() else {
        return Err(Error::disparity_range(
            "search range",
            "no views",
            "at least one",
        ));
    };
    let (w, h) = (first.image.width, first.image.height);
    let span = geometry.extent()[0].max(1.0);
    let factor = match w.min(h) {
        s if s >= 400 => 4,
        s if s >= 120 => 2,
        _ => 1,
    };
    let coarse: Vec<ViewImage> = images
        .iter()
        .map(|v| v.downsampled(factor, false))
        .collect();
    let coarse_w = w / factor;
    // As many coarse disparities as the array's span allows, and no more than every
    // neighbour's shift fits in the coarse images (a two-camera array spans one baseline:
    // the first bound alone reached the images' whole width).
    let shift = geometry.longest_neighbour_shift().max(1.0);
    let fitting = ((coarse_w.min(h / factor).saturating_sub(1)) as f64 / shift) as usize;
    let coarse_max = ((coarse_w as f64 / span) as usize)
        .min(fitting)
        .clamp(4, MAX_COARSE_DISPARITY);
    let coarse_range =
        DisparityRange::new(-((coarse_max / NEGATIVE_SHARE) as i32), coarse_max as i32)?;
    if coarse_w < 16 || h / factor < 16 {
        return Err(Error::disparity_range(
            "search range",
            format!("{w}x{h} px, too small to estimate a range"),
            "a larger image, or a search range given (--disp-range MIN:MAX)",
        ));
    }
    let registration = register_views(
        &coarse,
        geometry,
        &RegistrationSettings {
            range: coarse_range,
            // Coarse to fine itself where the views are (its coarse level 2× coarser):
            // the coarse range is several times the views' (−42:128 at 4× for a 3×3
            // array's 1600×1200 views, whose disparities span 0:39).
            coarse_to_fine: if settings.coarse_to_fine.applies(w, h) {
                CoarseToFine::On
            } else {
                CoarseToFine::Off
            },
            previous: None,
            ..*settings
        },
        &|_, _| {},
    )?;
    for (stage, seconds) in &registration.timings {
        tracing::debug!("search range: {stage}: {seconds:.3} s");
    }
    // An outer view's pixels near its outer edge see other views on one side only, and
    // their coarse multi-view costs favour disparities where fewer, spectrally closer views
    // overlap: on a simulated 3×3 narrow-band array at 800×600, a quarter of every outer
    // view's coarse disparities sat at 68 coarse px (4×) while the truth spans −2.3 to 2.2,
    // and the range became −19:307 instead of −12:12; the centre view alone gave the right
    // range.
    let interior = geometry.interior_views();
    let mut values: Vec<f32> = interior
        .iter()
        .flat_map(|&v| agreeing_disparities(&coarse, &registration.disparities, geometry, v))
        .collect();
    if values.is_empty() {
        return Err(Error::unusable(
            "the coarse registration",
            "it found no disparity; give the search range (--disp-range MIN:MAX)",
        ));
    }
    values.sort_by(f32::total_cmp);
    let quantile = |q: f64| values[((values.len() - 1) as f64 * q) as usize] as f64;
    let (low, high) = (quantile(1.0 - COVERED_QUANTILE), quantile(COVERED_QUANTILE));
    // Points beyond a calibration plane may be few: the sign is decided further out.
    let low = low.min(quantile(NEGATIVE_QUANTILE));
    let f = factor as f64;
    let widest = ((w as f64 / span) as i32).max(4);
    let max = ((high.max(0.0) * f * MARGIN).ceil() as i32 + 2 * factor as i32).clamp(4, widest);
    let min = if low < -NEGATIVE_EVIDENCE_PX {
        ((low * f * MARGIN).floor() as i32 - 2 * factor as i32).max(-widest)
    } else {
        0
    };
    Ok(SearchRange {
        range: DisparityRange::new(min, max.max(min + 2))?,
        factor,
        coarse_range,
        covered_disparity_px: [low * f, high.max(0.0) * f],
        seconds: clock.elapsed().as_secs_f64(),
    })
}

/// Largest difference (coarse pixels) between a pixel's disparity and the one another view
/// gives the point it matches for the two to agree.
const AGREEMENT_PX: f32 = 1.0;

/// View `v`'s finite disparities of `maps` (one per view of `views`) at pixels that its own
/// view measures and whose match in some other view is measured there and agrees
/// (within [`AGREEMENT_PX`]). A pixel without one has only SGM's propagated guess or a
/// spurious match: on an array registered to a plane by homographies, where the warp
/// leaves the margins of shifted cameras unmeasured, such guesses widened the true −5:5
/// to −22:30 (and cost 1 dB); with the check it is −10:11.
fn agreeing_disparities(
    views: &[ViewImage],
    maps: &[DisparityMap],
    geometry: &ArrayGeometry,
    v: usize,
) -> Vec<f32> {
    // The disparity view `j` gives at (x, y), if it measures that pixel.
    let at = |j: usize, x: f64, y: f64| {
        let view = &views[j];
        let (w, h) = (view.image.width, view.image.height);
        let (xi, yi) = (x.round(), y.round());
        if !(xi >= 0.0 && yi >= 0.0 && xi < w as f64 && yi < h as f64) {
            return None;
        }
        let i = yi as usize * w + xi as usize;
        view.measured
            .as_deref()
            .is_none_or(|m| m[i])
            .then_some(maps[j].data[i])
    };
    let w = views[v].image.width;
    let shifts: Vec<(usize, (f64, f64))> = (0..views.len())
        .filter(|&j| j != v)
        .map(|j| (j, geometry.shift(v, j)))
        .collect();
    let needed = shifts.len().min(2);
    let agrees = |x: f64, y: f64, d: f32| {
        let dd = f64::from(d);
        let agreeing = shifts.iter().filter(|&&(j, (sx, sy))| {
            at(j, x + dd * sx, y + dd * sy).is_some_and(|other| (other - d).abs() <= AGREEMENT_PX)
        });
        agreeing.count() >= needed
    };
    maps[v]
        .data
        .iter()
        .enumerate()
        .filter(|&(i, &d)| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            d.is_finite() && at(v, x, y).is_some() && agrees(x, y, d)
        })
        .map(|(_, &d)| d)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::GreyImage;

    #[test]
    fn downsampling_averages_and_keeps_unmeasured_pixels_unmeasured() {
        let view = ViewImage {
            image: GreyImage {
                channels: 1,
                width: 4,
                height: 2,
                data: vec![0.0, 1.0, 2.0, 3.0, 1.0, 2.0, 3.0, 4.0],
            },
            matching: Vec::new(),
            measured: Some(vec![true, true, true, false, true, true, true, true]),
        };
        let coarse = view.downsampled(2, false);
        assert_eq!((coarse.image.width, coarse.image.height), (2, 1));
        assert_eq!(coarse.image.data, vec![1.0, 3.0]);
        assert_eq!(coarse.measured, Some(vec![true, false]));
    }
}
