//! Registration (paper section 3.3), the stage `stereo -> register (warp) -> demux`: one
//! disparity map per view of a rectified array, then every capture warped to every view.
//!
//! **Convention.** Disparities are in pixels per disparity baseline (a grid's horizontal
//! baseline, so pixels per column step; a free layout's shortest camera distance), the
//! simulator's truth convention: a surface point at (x, y) of a view at position p (in
//! disparity baselines, [`ArrayGeometry`]) with disparity d appears at `(x, y) + d·(p − q)`
//! in the view at q. One map per view therefore registers it to every other camera of the
//! array, diagonal and hexagonal neighbours included: the paper's intermediary images (a
//! diagonal pair reached through the camera sharing a row with one and a column with the
//! other) become a single resampling along each pair's own baseline.
//!
//! **Modes** ([`RegistrationMode`]):
//! - *pairwise*: each view is matched with its nearest row and column neighbours by
//!   the heterogeneous matcher (vertical pairs by transposition, views on the right or
//!   bottom edge by mirroring), the two maps are fused where they agree, and what neither
//!   pair can see is filled from the background side;
//! - *multi-baseline*: the learned features of a view are compared with those of every
//!   other view at the disparity the array geometry predicts, costs are summed over the
//!   best half-array (occlusion-robust, Kang et al. 2001), refined by SGM, and checked
//!   against the neighbouring views' maps. By default the features come from the array's
//!   common signals ([`common_signals`]: what every camera's channels can estimate alike,
//!   so that filters do not invert contrast between views), merged by a shared projection.

mod agreement;
mod ambiguous_planes;
mod common_signal;
mod compact_features;
mod feature_projection;
mod geometry;
mod multi_baseline;
mod pairwise;
mod search_range;
mod warp;

pub use agreement::{
    confirmed_by_neighbours, neighbour_agreement, pair_agreements, PairAgreement,
    LOW_AGREEMENT_WARNING,
};
pub use ambiguous_planes::{
    apply_region_planes, region_planes, resolve_ambiguous_planes, vote_with_neighbours, Ambiguity,
    RegionPlane,
};
pub use common_signal::{
    common_signal_images, common_signals, CommonSignal, MatchingImage, COMMON_SIGNALS,
};
pub use geometry::ArrayGeometry;
pub use multi_baseline::{multi_baseline_disparities, COARSE_TO_FINE_PIXELS};
pub use pairwise::pairwise_disparities;
pub use search_range::{estimate_search_range, SearchRange};
pub use warp::{
    gather_measurements, Admission, Gathered, NormalisedView, Visibility, WarpKernel,
    CONSISTENCY_PX,
};

use crate::disparity::DisparityMap;
use crate::stereo::{DisparityRange, GreyImage, MatchingCost};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// How disparities are estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RegistrationMode {
    /// Row and column neighbours matched pairwise, fused.
    Pairwise,
    /// All views at once along the array geometry (learned cost only).
    #[default]
    MultiBaseline,
}

crate::choice::named_choices!(RegistrationMode, "registration" {
    MultiBaseline = "multi-baseline" "Each view against all others at once along the array geometry (learned cost).",
    Pairwise = "pairwise" "Row and column neighbours matched pairwise, fused.",
});

/// Whether multi-baseline registration goes coarse to fine: the whole range at half the
/// resolution, then a band around those disparities at full resolution
/// ([`multi_baseline_disparities`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CoarseToFine {
    /// From [`COARSE_TO_FINE_PIXELS`] per view, at every level.
    #[default]
    Auto,
    /// At full resolution whatever the size (the coarse level as `Auto`).
    On,
    /// The whole range at full resolution.
    Off,
}

impl CoarseToFine {
    /// Whether views of `width × height` go coarse to fine.
    pub fn applies(self, width: usize, height: usize) -> bool {
        match self {
            CoarseToFine::Auto => width * height >= COARSE_TO_FINE_PIXELS,
            CoarseToFine::On => true,
            CoarseToFine::Off => false,
        }
    }
}

crate::choice::named_choices!(CoarseToFine, "coarse-to-fine" {
    Auto = "auto" "From one megapixel per view: the whole range at half the resolution, then a band around it at full resolution.",
    On = "on" "Coarse to fine whatever the size.",
    Off = "off" "The whole range at full resolution (time and memory grow with pixels × range).",
});

/// The mode `anaglyph reconstruct` and the demo use unless told otherwise (measured in
/// `examples/light_field_quality.rs`; see docs/reconstruction.md).
pub const DEFAULT_REGISTRATION: RegistrationMode = RegistrationMode::MultiBaseline;

/// What registration needs besides the images.
#[derive(Debug, Clone, Copy)]
pub struct RegistrationSettings<'a> {
    pub mode: RegistrationMode,
    pub cost: MatchingCost<'a>,
    /// Disparities searched, per disparity baseline (signed: an array calibrated to a plane sees
    /// points beyond it at negative disparities).
    pub range: DisparityRange,
    /// Whether multi-baseline registration goes coarse to fine (pairwise registration
    /// does not read it).
    pub coarse_to_fine: CoarseToFine,
    /// A frame of a sequence: the previous frame's maps, which multi-baseline
    /// registration searches around instead of over the whole range (pairwise
    /// registration does not read it).
    pub previous: Option<PreviousMaps<'a>>,
}

/// The previous frame's maps, which the next frame of a sequence searches around (temporal
/// reuse): each tile of a view over the disparities its previous map held near it, widened
/// by `margin` for motion in depth (the whole range where the previous map was unsure
/// there, or where the winners pile up at an end of the band); in views large enough to
/// go coarse to fine, the costs pulled towards the previous disparity where the view's
/// camera saw nothing move.
#[derive(Debug, Clone, Copy)]
pub struct PreviousMaps<'a> {
    /// Per view, the previous frame's map (the views' size and column-step convention).
    pub maps: &'a [DisparityMap],
    /// Per view, the pixels of its camera's capture that moved since the previous
    /// disparities were found there (None: unknown; no pixel is pulled).
    pub moved: Option<&'a [Vec<bool>]>,
    /// Disparities a tile's band reaches beyond the previous ones near it, px.
    pub margin: f32,
}

/// How the tiles of a banded search went (coarse to fine, or around a previous frame's
/// maps), summed over views.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct BandedSearch {
    /// Tiles searched (all views).
    pub tiles: usize,
    /// Of them, those searched over the whole range: the guide was unsure there, or the
    /// winners piled up at an end of the band.
    pub whole_range: usize,
    /// Disparities searched per tile, on average.
    pub mean_band: f64,
}

/// Half-size of the window of the subpixel refinement of both registration modes (11×11,
/// [`crate::stereo::windowed_subpixel`]): on the tabletop at 640×480 (multi-baseline),
/// radius 1 / 2 / 3 / 5 gave r0c0 28.99 / 29.07 / 29.17 / 29.28 dB, 8 no more.
pub const SUBPIXEL_WINDOW_RADIUS: usize = 5;

/// A view's grey image for matching (its place in the array is the [`ArrayGeometry`]'s
/// entry of the same index).
#[derive(Debug, Clone)]
pub struct ViewImage {
    pub image: GreyImage,
    /// The images whose learned features multi-baseline registration compares (the common
    /// signals, merged by [`feature_projection`]); empty: `image` itself. `image` stays the
    /// guide of SGM's penalties and the input of pairwise matching and of the search range.
    pub matching: Vec<GreyImage>,
    /// Which pixels hold a measurement (None: all). A rectified camera has none outside
    /// its source frame; multi-baseline matching gives such pixels no features, so they
    /// neither match nor attract matches (their disparity comes from SGM's neighbours).
    pub measured: Option<Vec<bool>>,
}

impl ViewImage {
    /// The view box-averaged by `factor` (its matching images too where `with_matching`,
    /// else none), and its measured mask: a coarse pixel is measured only if all its fine
    /// pixels are. A remainder of fewer than `factor` rows or columns is dropped.
    pub fn downsampled(&self, factor: usize, with_matching: bool) -> ViewImage {
        let (w, h) = (self.image.width / factor, self.image.height / factor);
        let fine_w = self.image.width;
        let block = |x: usize, y: usize| {
            (0..factor).flat_map(move |dy| {
                (0..factor).map(move |dx| (y * factor + dy) * fine_w + x * factor + dx)
            })
        };
        let average = |image: &GreyImage| GreyImage {
            channels: 1,
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| {
                    let sum: f32 = block(i % w, i / w).map(|j| image.data[j]).sum();
                    sum / (factor * factor) as f32
                })
                .collect(),
        };
        ViewImage {
            image: average(&self.image),
            matching: if with_matching {
                self.matching.iter().map(average).collect()
            } else {
                Vec::new()
            },
            measured: self.measured.as_ref().map(|mask| {
                (0..w * h)
                    .map(|i| block(i % w, i / w).all(|j| mask[j]))
                    .collect()
            }),
        }
    }
}

/// Replaces the NaNs of `row` by the nearest finite value (0 if there is none).
pub fn fill_from_nearest(row: &mut [f32]) {
    if row.iter().all(|v| v.is_finite()) {
        return;
    }
    let known: Vec<usize> = (0..row.len()).filter(|&i| row[i].is_finite()).collect();
    if known.is_empty() {
        row.fill(0.0);
        return;
    }
    let mut k = 0; // first known index at or after i
    for i in 0..row.len() {
        while k < known.len() && known[k] < i {
            k += 1;
        }
        if row[i].is_finite() {
            continue;
        }
        let before = k.checked_sub(1).map(|j| known[j]);
        let after = known.get(k).copied();
        let source = match (before, after) {
            (Some(b), Some(a)) if i - b <= a - i => b,
            (_, Some(a)) => a,
            (Some(b), None) => b,
            (None, None) => continue,
        };
        row[i] = row[source];
    }
}

/// A disparity map per view (in `images` order, per column step of the array, NaN where
/// nothing could be estimated), the seconds each stage took and what the plane step
/// changed.
#[derive(Debug, Clone)]
pub struct Registration {
    pub disparities: Vec<DisparityMap>,
    pub timings: Vec<(String, f64)>,
    /// Per view, the pixels that [`resolve_ambiguous_planes`] moved to the plane of their
    /// ambiguous region (None: the mode has no such step).
    pub moved_to_planes: Option<Vec<usize>>,
    /// How a banded search's tiles went (None: every view searched over the whole range
    /// at once).
    pub banded: Option<BandedSearch>,
}

/// Estimates every view's disparity map. `progress(done, total)` is called as views finish.
pub fn register_views(
    images: &[ViewImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Registration> {
    validate(images, geometry, settings.range)?;
    match settings.mode {
        RegistrationMode::Pairwise => pairwise_disparities(images, geometry, settings, progress),
        RegistrationMode::MultiBaseline => {
            multi_baseline_disparities(images, geometry, settings, progress)
        }
    }
}

fn validate(images: &[ViewImage], geometry: &ArrayGeometry, range: DisparityRange) -> Result<()> {
    let Some(first) = images.first() else {
        return Err(Error::raster("registration", "no views", "at least one"));
    };
    if images.len() != geometry.len() {
        return Err(Error::Shape {
            op: "registration: one image per view of the array".into(),
            got: vec![images.len()],
            expected: vec![geometry.len()],
        });
    }
    let (w, h) = (first.image.width, first.image.height);
    for (view, name) in images.iter().zip(&geometry.names) {
        if view.image.width != w || view.image.height != h || view.image.data.len() != w * h {
            return Err(Error::Shape {
                op: format!("registration: view {name}"),
                got: vec![view.image.width, view.image.height],
                expected: vec![w, h],
            });
        }
    }
    if let Some(p) = geometry
        .positions
        .iter()
        .find(|p| !(p[0].is_finite() && p[1].is_finite()))
    {
        return Err(Error::rig_layout(
            "registration",
            format!("a view at [{}, {}]", p[0], p[1]),
            "finite positions",
        ));
    }
    check_search_range(range, geometry, w, h)
}

/// Checks that `range` has at least two disparities and that its largest shift between
/// neighbours, along the longer baseline, stays inside views of `w × h`.
pub fn check_search_range(
    range: DisparityRange,
    geometry: &ArrayGeometry,
    w: usize,
    h: usize,
) -> Result<()> {
    let longest = (range.magnitude() as f64 * geometry.longest_neighbour_shift()).ceil() as usize;
    if range.count() < 2 || longest >= w.min(h) {
        return Err(Error::disparity_range(
            "search range",
            format!(
                "{range}: {} disparities, up to {longest} px along the longer baseline",
                range.count()
            ),
            format!("at least 2 disparities, each shift fitting the {w}x{h} images"),
        ));
    }
    Ok(())
}

/// Fills NaN pixels from the background side: the smaller of the nearest valid
/// disparities to the left and to the right on the same row (an occluded surface lies
/// behind its occluder). Rows without any valid pixel stay NaN.
pub fn fill_from_background(disparity: &mut [f32], width: usize) {
    for row in disparity.chunks_exact_mut(width) {
        let mut left = vec![f32::NAN; width];
        let mut last = f32::NAN;
        for (x, v) in row.iter().enumerate() {
            if v.is_finite() {
                last = *v;
            }
            left[x] = last;
        }
        let mut right = f32::NAN;
        for x in (0..width).rev() {
            if row[x].is_finite() {
                right = row[x];
                continue;
            }
            row[x] = match (left[x].is_finite(), right.is_finite()) {
                (true, true) => left[x].min(right),
                (true, false) => left[x],
                (false, true) => right,
                (false, false) => f32::NAN,
            };
        }
    }
}

/// Fills NaN pixels with the candidate their matching cost prefers: the nearest valid
/// disparities to the left, right, above and below. `cost(x, y, d)` is the pixel's cost at
/// disparity d (NaN where nothing sees it). Where no candidate has a finite cost the
/// pixel falls back to [`fill_from_background`]'s rule along its row, then its column.
///
/// A row scan alone cannot tell the background at the image edge, where one side is
/// missing, nor across a thin band bounded above and below: in the periodic scene a strip
/// of the background between a sphere and a box, seen by one row of cameras only, took the
/// disparity of the grating on its left, half a period of the background's checker off,
/// and every warped measurement there read the other colour.
pub fn fill_by_cost(
    disparity: &mut [f32],
    width: usize,
    height: usize,
    cost: &(dyn Fn(usize, usize, f32) -> f32 + Sync),
) {
    use rayon::prelude::*;
    let nearest = |len: usize, value: &dyn Fn(usize) -> f32| -> (Vec<f32>, Vec<f32>) {
        let (mut before, mut after) = (vec![f32::NAN; len], vec![f32::NAN; len]);
        let mut last = f32::NAN;
        for (i, slot) in before.iter_mut().enumerate() {
            *slot = last;
            if value(i).is_finite() {
                last = value(i);
            }
        }
        last = f32::NAN;
        for i in (0..len).rev() {
            after[i] = last;
            if value(i).is_finite() {
                last = value(i);
            }
        }
        (before, after)
    };
    let source: &[f32] = disparity;
    // Column neighbours, laid out [x][y] by the scans and read back per pixel.
    let columns: Vec<(Vec<f32>, Vec<f32>)> = (0..width)
        .into_par_iter()
        .map(|x| nearest(height, &|y| source[y * width + x]))
        .collect();
    let filled: Vec<(usize, f32)> = (0..height)
        .into_par_iter()
        .flat_map_iter(|y| {
            let row = &source[y * width..][..width];
            let (left, right) = nearest(width, &|x| row[x]);
            let columns = &columns;
            (0..width).filter(|&x| !row[x].is_finite()).map(move |x| {
                let (up, down) = (columns[x].0[y], columns[x].1[y]);
                let mut best = (f32::INFINITY, f32::NAN);
                for candidate in [left[x], right[x], up, down] {
                    if candidate.is_finite() {
                        let c = cost(x, y, candidate);
                        // Equal costs go to the background (the smaller disparity).
                        if c < best.0 || (c == best.0 && candidate < best.1) {
                            best = (c, candidate);
                        }
                    }
                }
                let fallback = |a: f32, b: f32| match (a.is_finite(), b.is_finite()) {
                    (true, true) => a.min(b),
                    (true, false) => a,
                    (false, true) => b,
                    (false, false) => f32::NAN,
                };
                let value = if best.1.is_finite() {
                    best.1
                } else {
                    let along_row = fallback(left[x], right[x]);
                    if along_row.is_finite() {
                        along_row
                    } else {
                        fallback(up, down)
                    }
                };
                (y * width + x, value)
            })
        })
        .collect();
    for (i, value) in filled {
        disparity[i] = value;
    }
}

/// Window radius of [`smooth_within_surfaces`], pixels.
pub const SURFACE_SMOOTHING_RADIUS: usize = 4;
/// Spatial Gaussian σ of [`smooth_within_surfaces`], pixels.
pub const SURFACE_SMOOTHING_SIGMA: f32 = 2.5;
/// Neighbours whose disparity differs by more than this (px) belong to another surface.
pub const SURFACE_TOLERANCE_PX: f32 = 1.0;

/// Averages each disparity with the neighbours on the same surface (within
/// [`SURFACE_TOLERANCE_PX`] of it), Gaussian-weighted: a bilateral filter whose range term
/// is the disparity itself. Warping needs disparities accurate to a fraction of a pixel
/// (an error of σ = 0.25 px costs about 3.6 dB of reflectance PSNR on the tabletop); the
/// winner-take-all and parabola leave independent per-pixel errors that this averages out,
/// while depth edges, where the disparity jumps, are kept. NaN stays NaN.
pub fn smooth_within_surfaces(disparity: &[f32], width: usize, height: usize) -> Vec<f32> {
    use rayon::prelude::*;
    let r = SURFACE_SMOOTHING_RADIUS as i64;
    let side = (2 * r + 1) as usize;
    let weights: Vec<f32> = (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
        .map(|(dx, dy)| {
            (-((dx * dx + dy * dy) as f32) / (2.0 * SURFACE_SMOOTHING_SIGMA.powi(2))).exp()
        })
        .collect();
    let mut out = vec![0f32; width * height];
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for (x, value) in row.iter_mut().enumerate() {
            let centre = disparity[y * width + x];
            if !centre.is_finite() {
                *value = centre;
                continue;
            }
            let (mut sum, mut norm) = (0f32, 0f32);
            let (y0, y1) = ((y as i64 - r).max(0), (y as i64 + r).min(height as i64 - 1));
            let (x0, x1) = ((x as i64 - r).max(0), (x as i64 + r).min(width as i64 - 1));
            for yy in y0..=y1 {
                let weight_row = &weights[((yy - y as i64 + r) as usize) * side..][..side];
                for xx in x0..=x1 {
                    let d = disparity[yy as usize * width + xx as usize];
                    if (d - centre).abs() <= SURFACE_TOLERANCE_PX {
                        let k = weight_row[(xx - x as i64 + r) as usize];
                        sum += k * d;
                        norm += k;
                    }
                }
            }
            *value = sum / norm;
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surface_smoothing_removes_noise_and_keeps_depth_edges() {
        let (w, h) = (40, 20);
        // A slanted plane (left) and a near square (right), with ±0.3 px alternating noise.
        let clean: Vec<f32> = (0..w * h)
            .map(|i| {
                if i % w < 20 {
                    10.0 + 0.05 * (i % w) as f32
                } else {
                    30.0
                }
            })
            .collect();
        let noisy: Vec<f32> = clean
            .iter()
            .enumerate()
            .map(|(i, d)| d + if (i + i / w) % 2 == 0 { 0.3 } else { -0.3 })
            .collect();
        let smooth = smooth_within_surfaces(&noisy, w, h);
        for y in 5..15 {
            for x in 5..35 {
                let i = y * w + x;
                assert!(
                    (smooth[i] - clean[i]).abs() < 0.08,
                    "({x}, {y}): {}",
                    smooth[i]
                );
            }
        }
        // The edge between 19 and 20 stays sharp.
        assert!(smooth[10 * w + 19] < 11.5 && smooth[10 * w + 20] > 29.0);
    }

    /// A band at the right edge, bounded by 20 on its left, 10 above and 30 below: the row
    /// rule can only take 20; the cost picks the candidate the pixels match best.
    #[test]
    fn cost_fill_takes_the_cheapest_neighbour() {
        let nan = f32::NAN;
        let (w, h) = (6, 5);
        let mut d = vec![10.0; w * h];
        for y in 1..4 {
            d[y * w] = 20.0;
            d[y * w + 1] = 20.0;
            for x in 2..w {
                d[y * w + x] = nan;
            }
        }
        for x in 0..w {
            d[4 * w + x] = 30.0;
        }
        let mut by_row = d.clone();
        fill_from_background(&mut by_row, w);
        assert_eq!(by_row[2 * w + 4], 20.0);

        // Rows 1–2 belong to the surface above (10), row 3 to the one below (30).
        let truth = |y: usize| if y < 3 { 10.0 } else { 30.0 };
        let cost = |_x: usize, y: usize, d: f32| (d - truth(y)).abs();
        let mut by_cost = d.clone();
        fill_by_cost(&mut by_cost, w, h, &cost);
        for y in 1..4 {
            for x in 2..w {
                assert_eq!(by_cost[y * w + x], truth(y), "({x}, {y})");
            }
        }
        // Valid pixels are untouched.
        assert_eq!(by_cost[w], 20.0);

        // Equal costs go to the smaller disparity; no finite cost falls back to the row rule.
        let mut tied = d.clone();
        fill_by_cost(&mut tied, w, h, &|_, _, _| 0.5);
        assert!(tied[w + 2..2 * w].iter().all(|&v| v == 10.0));
        let mut unseen = d.clone();
        fill_by_cost(&mut unseen, w, h, &|_, _, _| nan);
        assert_eq!(unseen, by_row);
        // A column without valid pixels above or below, in a row without any: stays NaN.
        let mut empty = vec![nan; 4];
        fill_by_cost(&mut empty, 2, 2, &|_, _, _| 0.0);
        assert!(empty.iter().all(|v| v.is_nan()));
    }

    #[test]
    fn background_fill_takes_the_farther_neighbour() {
        let nan = f32::NAN;
        let mut d = vec![5.0, nan, nan, 9.0, nan, nan, nan, 2.0];
        fill_from_background(&mut d, 4);
        assert_eq!(d[..4], [5.0, 5.0, 5.0, 9.0]);
        assert_eq!(d[4..], [2.0, 2.0, 2.0, 2.0]);
        let mut empty = vec![nan; 3];
        fill_from_background(&mut empty, 3);
        assert!(empty.iter().all(|v| v.is_nan()));
    }
}
