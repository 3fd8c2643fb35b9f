//! Multi-baseline registration: one disparity per pixel of a reference view, tested
//! against every other view of the array at once.
//!
//! For disparity d, pixel (x, y) of the reference is compared with the learned features of
//! view v at `(x, y) + d · shift(v)` (the array geometry, [`ArrayGeometry::shift`]); a
//! fractional row position interpolates the two dot products, which is exact for the
//! bilinearly interpolated feature. The cost of view v is `(1 − cos)/2`, as for a pair.
//! Views are grouped into half-arrays (left, right, above, below the reference); the cost
//! of (x, y, d) is the smallest mean over a half-array that sees the point, so that a
//! surface occluded on one side is still matched on the other (Kang, Szeliski & Chai 2001,
//! "Handling occlusions in dense multi-view stereo"). Then SGM with penalties from the
//! reference's gradients and winner-take-all per view; the subpixel offset comes from the
//! raw multi-view costs summed over a window of the same surface (equiangular fit, see
//! [`windowed_subpixel`]: the parabola on SGM costs locks to whole pixels); finally each map is
//! checked against its row and column neighbours' maps (a pixel is kept if at least one
//! neighbour agrees within [`LEFT_RIGHT_TOLERANCE`]), failures are filled from the
//! background side and a 5×5 median smooths the result.

use super::RegistrationSettings;
use super::{
    fill_from_background, find, smooth_within_surfaces, ArrayGeometry, GridImage, Registration,
    SUBPIXEL_WINDOW_RADIUS,
};
use crate::stereo::{
    median_filter, semi_global_matching, tower_features, unit_range, windowed_subpixel,
    winner_take_all, CostVolume, FeatureMap, GreyImage, MatchSettings, MatchingCost,
    LEFT_RIGHT_TOLERANCE,
};
use crate::{Error, Result};
use rayon::prelude::*;
use std::time::Instant;

/// Half-arrays: views left of, right of, above and below the reference.
const HALVES: usize = 4;
/// Fractional row offsets below this are treated as whole rows (one dot product).
const WHOLE_ROW: f64 = 1e-6;

/// Learned features stored as bfloat16 (the upper half of each f32, rounded to nearest):
/// all views' features are held at once, 4.2 GB as f32 for eight 1920×1080 views, half that
/// as bf16. The cosine of unit 64-d features moves by about 1e-3, well below the cost
/// differences between disparities.
#[derive(Debug, Clone, PartialEq)]
pub struct CompactFeatures {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<u16>,
}

impl From<FeatureMap> for CompactFeatures {
    fn from(map: FeatureMap) -> Self {
        let data = map
            .data
            .iter()
            .map(|v| {
                let bits = v.to_bits();
                // Round to nearest even on the dropped half.
                ((bits + 0x7FFF + ((bits >> 16) & 1)) >> 16) as u16
            })
            .collect();
        CompactFeatures {
            width: map.width,
            height: map.height,
            channels: map.channels,
            data,
        }
    }
}

/// The f32 value of a bfloat16.
#[inline(always)]
fn widen(v: u16) -> f32 {
    f32::from_bits((v as u32) << 16)
}

/// Dot product of two bf16 vectors with eight independent f32 accumulators (vectorised by
/// the compiler).
#[inline(always)]
fn dot(a: &[u16], b: &[u16]) -> f32 {
    let mut lanes = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(&p, &q)| widen(p) * widen(q))
        .sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            lanes[i] += widen(x[i]) * widen(y[i]);
        }
    }
    lanes.iter().sum::<f32>() + tail
}

/// The half-arrays view `to` belongs to, seen from `from`.
fn halves_of(from: (usize, usize), to: (usize, usize)) -> [bool; HALVES] {
    [to.1 < from.1, to.1 > from.1, to.0 < from.0, to.0 > from.0]
}

/// The occlusion-robust multi-view cost volume of view `reference` (see the module docs).
pub fn multi_view_cost_volume(
    features: &[CompactFeatures],
    positions: &[(usize, usize)],
    reference: usize,
    geometry: &ArrayGeometry,
    max_disp: usize,
) -> CostVolume {
    let fr = &features[reference];
    let (w, h) = (fr.width, fr.height);
    let me = positions[reference];
    let others: Vec<(usize, (f64, f64), [bool; HALVES])> = (0..features.len())
        .filter(|&v| v != reference)
        .map(|v| {
            (
                v,
                geometry.shift(me, positions[v]),
                halves_of(me, positions[v]),
            )
        })
        .collect();
    #[cfg(target_arch = "x86_64")]
    let avx2 = is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma");
    let mut volume = CostVolume::new(w, h, max_disp);
    // Per task: running sums and counts per half-array, laid out [half][d][x] so that the
    // inner loop over x writes contiguously.
    let plane = max_disp * w;
    volume
        .data
        .par_chunks_mut(w * max_disp)
        .enumerate()
        .for_each_init(
            || (vec![0f32; HALVES * plane], vec![0u16; HALVES * plane]),
            |(sums, counts), (y, row)| {
                sums.fill(0.0);
                counts.fill(0);
                let job = RowJob {
                    features,
                    others: &others,
                    reference: fr,
                    y,
                    max_disp,
                };
                #[cfg(target_arch = "x86_64")]
                {
                    if avx2 {
                        // SAFETY: the CPU supports AVX2 and FMA (checked above).
                        unsafe { accumulate_row_avx2(&job, sums, counts) };
                    } else {
                        accumulate_row(&job, sums, counts);
                    }
                }
                #[cfg(not(target_arch = "x86_64"))]
                accumulate_row(&job, sums, counts);
                for x in 0..w {
                    for d in 0..max_disp {
                        let mut best = CostVolume::INVALID;
                        for k in 0..HALVES {
                            let j = k * plane + d * w + x;
                            if counts[j] > 0 {
                                best = best.min(sums[j] / counts[j] as f32);
                            }
                        }
                        row[x * max_disp + d] = best;
                    }
                }
            },
        );
    volume
}

/// One row's work: the reference row `y` against every other view.
struct RowJob<'a> {
    features: &'a [CompactFeatures],
    others: &'a [(usize, (f64, f64), [bool; HALVES])],
    reference: &'a CompactFeatures,
    y: usize,
    max_disp: usize,
}

/// [`accumulate_row`] compiled for AVX2 + FMA (the build targets baseline x86-64; this is
/// where the multi-view cost spends its time: 1.5× faster at 320×240×64 on this CPU).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn accumulate_row_avx2(job: &RowJob<'_>, sums: &mut [f32], counts: &mut [u16]) {
    accumulate_row(job, sums, counts)
}

/// Adds the costs of reference row `job.y` against every other view to the per-half sums
/// and counts (layout `[half][d][x]`).
#[inline(always)]
fn accumulate_row(job: &RowJob<'_>, sums: &mut [f32], counts: &mut [u16]) {
    let fr = job.reference;
    let (w, h, c, y, max_disp) = (fr.width, fr.height, fr.channels, job.y, job.max_disp);
    let plane = max_disp * w;
    let row_a = &fr.data[y * w * c..][..w * c];
    for &(v, (sx, sy), halves) in job.others {
        let fv = &job.features[v];
        let members: Vec<usize> = (0..HALVES).filter(|&k| halves[k]).collect();
        for d in 0..max_disp {
            let ys = y as f64 + sy * d as f64;
            if ys < 0.0 || ys > (h - 1) as f64 {
                continue;
            }
            let y0 = ys.floor() as usize;
            let fy = (ys - y0 as f64) as f32;
            let two_rows = fy as f64 > WHOLE_ROW && y0 + 1 < h;
            let offset = (sx * d as f64).round() as isize;
            let x_lo = (-offset).max(0) as usize;
            let x_hi = (w as isize - offset.max(0)).max(0) as usize;
            if x_lo >= x_hi {
                continue;
            }
            let row_b0 = &fv.data[y0 * w * c..][..w * c];
            let row_b1 = &fv.data[(y0 + usize::from(two_rows)) * w * c..][..w * c];
            for x in x_lo..x_hi {
                let a = &row_a[x * c..][..c];
                let xs = (x as isize + offset) as usize;
                let mut similarity = dot(a, &row_b0[xs * c..][..c]);
                if two_rows {
                    let below = dot(a, &row_b1[xs * c..][..c]);
                    similarity += fy * (below - similarity);
                }
                let cost = (0.5 - 0.5 * similarity).clamp(0.0, 1.0);
                for &k in &members {
                    let j = k * plane + d * w + x;
                    sums[j] += cost;
                    counts[j] += 1;
                }
            }
        }
    }
}

/// Keeps pixels of view `i` that a row or column neighbour's map confirms; NaN elsewhere.
fn cross_check(
    disparities: &[Vec<f32>],
    positions: &[(usize, usize)],
    images: &[GridImage],
    geometry: &ArrayGeometry,
    i: usize,
    width: usize,
    height: usize,
) -> Vec<f32> {
    let (r, c) = positions[i];
    let neighbours: Vec<(usize, (f64, f64))> = [
        (r, c + 1),
        (r, c.wrapping_sub(1)),
        (r + 1, c),
        (r.wrapping_sub(1), c),
    ]
    .iter()
    .filter_map(|&(rr, cc)| find(images, rr, cc))
    .map(|j| (j, geometry.shift(positions[i], positions[j])))
    .collect();
    if neighbours.is_empty() {
        return disparities[i].clone();
    }
    disparities[i]
        .iter()
        .enumerate()
        .map(|(p, &d)| {
            if !d.is_finite() {
                return f32::NAN;
            }
            let (x, y) = ((p % width) as f64, (p / width) as f64);
            let confirmed = neighbours.iter().any(|&(j, (sx, sy))| {
                let (xs, ys) = ((x + sx * d as f64).round(), (y + sy * d as f64).round());
                xs >= 0.0
                    && ys >= 0.0
                    && xs < width as f64
                    && ys < height as f64
                    && (disparities[j][ys as usize * width + xs as usize] - d).abs()
                        <= LEFT_RIGHT_TOLERANCE
            });
            if confirmed {
                d
            } else {
                f32::NAN
            }
        })
        .collect()
}

/// Multi-baseline registration of every view (see the module docs).
pub fn multi_baseline_disparities(
    images: &[GridImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Registration> {
    let network = match settings.cost {
        MatchingCost::Learned(network) if !network.is_accurate() => network,
        other => {
            return Err(Error::invalid(
                "multi-baseline registration",
                format!(
                    "needs the fast learned cost (its features compare across views); got {} \
                     (use pairwise registration for it)",
                    other.name()
                ),
            ))
        }
    };
    let (w, h) = (images[0].image.width, images[0].image.height);
    let dm = settings.max_disp;
    let positions: Vec<(usize, usize)> = images.iter().map(|v| (v.row, v.col)).collect();
    let chain = MatchSettings::for_cost(&settings.cost, dm);
    let mut timings = Vec::new();
    let clock = Instant::now();
    let features: Vec<CompactFeatures> = images
        .iter()
        .map(|v| {
            let mut compact = CompactFeatures::from(tower_features(network, &v.image));
            if let Some(measured) = &v.measured {
                let c = compact.channels;
                for (feature, _) in compact
                    .data
                    .chunks_exact_mut(c)
                    .zip(measured)
                    .filter(|(_, m)| !**m)
                {
                    feature.fill(0); // cosine 0 with everything: a neutral cost of 0.5
                }
            }
            compact
        })
        .collect();
    timings.push(("features".to_string(), clock.elapsed().as_secs_f64()));
    let flat = GreyImage {
        width: w,
        height: h,
        data: vec![0.0; w * h],
    };
    let (mut cost_seconds, mut refine_seconds) = (0.0, 0.0);
    let mut raw = Vec::with_capacity(images.len());
    for i in 0..images.len() {
        let clock = Instant::now();
        let volume = multi_view_cost_volume(&features, &positions, i, geometry, dm);
        cost_seconds += clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        let disparity = match &chain.sgm {
            Some(p) => winner_take_all(&semi_global_matching(
                &volume,
                &unit_range(&images[i].image),
                &flat,
                p,
            )),
            None => winner_take_all(&volume),
        };
        raw.push(windowed_subpixel(
            &volume,
            &disparity,
            SUBPIXEL_WINDOW_RADIUS,
        ));
        refine_seconds += clock.elapsed().as_secs_f64();
        progress(i + 1, images.len());
    }
    drop(features);
    timings.push(("multi-view cost".to_string(), cost_seconds));
    timings.push(("SGM + subpixel".to_string(), refine_seconds));
    let clock = Instant::now();
    let disparities = (0..images.len())
        .into_par_iter()
        .map(|i| {
            let mut checked = cross_check(&raw, &positions, images, geometry, i, w, h);
            fill_from_background(&mut checked, w);
            smooth_within_surfaces(&median_filter(&checked, w, h, 2), w, h)
        })
        .collect();
    timings.push((
        "cross-check, fill, median".to_string(),
        clock.elapsed().as_secs_f64(),
    ));
    Ok(Registration {
        disparities,
        timings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random unit features; view v is view 0 shifted by its disparity along the geometry.
    #[test]
    fn the_true_disparity_has_the_lowest_cost() {
        let (w, h, c, d_true) = (24usize, 20usize, 8usize, 3usize);
        let geometry = ArrayGeometry {
            rows: 2,
            cols: 2,
            baseline_ratio: 1.0,
        };
        let mut state = 12345u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
        };
        let base: Vec<f32> = (0..w * h * c).map(|_| next()).collect();
        let positions = [(0, 0), (0, 1), (1, 0), (1, 1)];
        let features: Vec<CompactFeatures> = positions
            .iter()
            .map(|&(r, col)| {
                let mut data = vec![0f32; w * h * c];
                for y in 0..h {
                    for x in 0..w {
                        // View (r, col) sees reference pixel (x, y) at (x − col·d, y − r·d).
                        let (sx, sy) = (x + col * d_true, y + r * d_true);
                        let (sx, sy) = (sx.min(w - 1), sy.min(h - 1));
                        let src = &base[(sy * w + sx) * c..][..c];
                        let norm = src.iter().map(|v| v * v).sum::<f32>().sqrt();
                        for k in 0..c {
                            data[(y * w + x) * c + k] = src[k] / norm;
                        }
                    }
                }
                CompactFeatures::from(FeatureMap {
                    width: w,
                    height: h,
                    channels: c,
                    data,
                })
            })
            .collect();
        let volume = multi_view_cost_volume(&features, &positions, 0, &geometry, 6);
        let wta = winner_take_all(&volume);
        let (x, y) = (w / 2, h / 2);
        assert_eq!(wta[y * w + x], d_true as f32);
        // bf16 storage: the cosine of identical unit vectors is 1 to about 1e-3.
        assert!(volume.pixel(x, y)[d_true] < 2e-3);
    }
}
