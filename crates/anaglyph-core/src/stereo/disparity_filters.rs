//! The last stages of the chain `cost -> aggregate -> sgm -> refine`, on disparity maps
//! (MC-CNN section 4): filling of left–right failures (occlusions from the background
//! side, mismatches by the median of the nearest consistent pixels in 16 directions), a
//! 5×5 median filter and an intensity-gated bilateral filter. NaN marks invalid pixels.

use super::cost_volume::matched_indices;
use super::{CostVolume, DisparityRange, GreyImage, LEFT_RIGHT_TOLERANCE};
use rayon::prelude::*;

/// The right view's winner-take-all disparities from the left volume
/// (`d_R(x) = argmin_d C(x + d, d)` over the d whose left pixel is inside the image).
pub fn right_disparity(volume: &CostVolume) -> Vec<f32> {
    let (w, h, dm, range) = (volume.width, volume.height, volume.count(), volume.range);
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (xr, value) in row.iter_mut().enumerate() {
            // Left pixel x = xr + min + k lies inside the image for these k.
            let first = -(xr as i64) - range.min as i64;
            let clamp = |v: i64| v.clamp(0, dm as i64) as usize;
            let (mut best, mut best_cost) = (0, f32::INFINITY);
            for k in clamp(first)..clamp(first + w as i64) {
                let x = (xr as i64 + range.min as i64 + k as i64) as usize;
                let c = volume.data[(y * w + x) * dm + k];
                if c < best_cost {
                    (best, best_cost) = (k, c);
                }
            }
            *value = range.at(best);
        }
    });
    out
}

/// What the left–right check says about a left pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Consistency {
    Correct,
    /// Some other disparity would be consistent: a wrong match.
    Mismatch,
    /// No disparity is consistent: the point is hidden in the right view.
    Occlusion,
}

/// MC-CNN's classification: correct if `|d − d_R(x − d)| ≤ 1`, a mismatch if another
/// disparity `d'` satisfies `|d' − d_R(x − d')| ≤ 1`, an occlusion otherwise.
pub fn classify(
    left: &[f32],
    right: &[f32],
    width: usize,
    range: DisparityRange,
) -> Vec<Consistency> {
    left.par_iter()
        .enumerate()
        .map(|(i, &d)| {
            let (x, row) = (i % width, i - i % width);
            let consistent = |d: f32| {
                let xr = x as f32 - d.round();
                xr >= 0.0
                    && xr < width as f32
                    && (right[row + xr as usize] - d).abs() <= LEFT_RIGHT_TOLERANCE
            };
            if d.is_finite() && consistent(d) {
                Consistency::Correct
            } else if matched_indices(x, width, range).any(|k| consistent(range.at(k))) {
                Consistency::Mismatch
            } else {
                Consistency::Occlusion
            }
        })
        .collect()
}

/// The 16 directions of the mismatch search, as unit steps.
fn directions() -> [(f32, f32); 16] {
    std::array::from_fn(|k| {
        let angle = k as f32 * std::f32::consts::PI / 8.0;
        (angle.cos(), angle.sin())
    })
}

/// Replaces failed pixels: occlusions by the first correct pixel to their left (the
/// background side), mismatches by the median of the nearest correct pixel in each of 16
/// directions. Pixels with no correct pixel to draw from stay NaN.
pub fn fill_inconsistent(
    disparity: &[f32],
    classes: &[Consistency],
    width: usize,
    height: usize,
) -> Vec<f32> {
    let dirs = directions();
    let correct = |x: usize, y: usize| classes[y * width + x] == Consistency::Correct;
    let mut out = disparity.to_vec();
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let mut found = Vec::with_capacity(16);
        for x in 0..width {
            match classes[y * width + x] {
                Consistency::Correct => {}
                Consistency::Occlusion => {
                    row[x] = (0..x)
                        .rev()
                        .find(|&xx| correct(xx, y))
                        .map_or(f32::NAN, |xx| disparity[y * width + xx]);
                }
                Consistency::Mismatch => {
                    found.clear();
                    for &(dx, dy) in &dirs {
                        let mut step = 1.0f32;
                        loop {
                            let xx = (x as f32 + dx * step).round();
                            let yy = (y as f32 + dy * step).round();
                            if xx < 0.0 || yy < 0.0 || xx >= width as f32 || yy >= height as f32 {
                                break;
                            }
                            let (xx, yy) = (xx as usize, yy as usize);
                            if correct(xx, yy) {
                                found.push(disparity[yy * width + xx]);
                                break;
                            }
                            step += 1.0;
                        }
                    }
                    row[x] = median(&mut found);
                }
            }
        }
    });
    out
}

/// Median of finite values (mean of the middle two for an even count); NaN if none.
fn median(values: &mut Vec<f32>) -> f32 {
    values.retain(|v| v.is_finite());
    if values.is_empty() {
        return f32::NAN;
    }
    let n = values.len();
    let (_, upper, _) = values.select_nth_unstable_by(n / 2, f32::total_cmp);
    let upper = *upper;
    if n % 2 == 1 {
        upper
    } else {
        let lower = values[..n / 2]
            .iter()
            .cloned()
            .fold(f32::NEG_INFINITY, f32::max);
        0.5 * (lower + upper)
    }
}

/// Median over the `(2·radius + 1)²` window of finite values (NaN pixels stay NaN).
pub fn median_filter(disparity: &[f32], width: usize, height: usize, radius: usize) -> Vec<f32> {
    let mut out = vec![0f32; width * height];
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let mut window = Vec::with_capacity((2 * radius + 1).pow(2));
        for (x, value) in row.iter_mut().enumerate() {
            let centre = disparity[y * width + x];
            if !centre.is_finite() {
                *value = centre;
                continue;
            }
            window.clear();
            for yy in y.saturating_sub(radius)..(y + radius + 1).min(height) {
                window.extend_from_slice(
                    &disparity[yy * width + x.saturating_sub(radius)
                        ..yy * width + (x + radius + 1).min(width)],
                );
            }
            *value = median(&mut window);
        }
    });
    out
}

/// Bilateral filter settings (MC-CNN: σ 4.64, τ 5 on images normalised to zero mean and
/// unit deviation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bilateral {
    /// Spatial Gaussian σ, pixels.
    pub sigma: f32,
    /// Neighbours whose normalised intensity differs by `threshold` or more are ignored.
    pub threshold: f32,
    /// Window radius, pixels.
    pub radius: usize,
}

/// `D'(p) = Σ_q g(‖p − q‖)·1{|I(p) − I(q)| < τ}·D(q) / Σ_q g(‖p − q‖)·1{…}` over finite
/// neighbours; `image` is the reference image normalised to zero mean and unit deviation.
pub fn bilateral_filter(disparity: &[f32], image: &GreyImage, settings: &Bilateral) -> Vec<f32> {
    let (w, h, r) = (image.width, image.height, settings.radius as i64);
    let weights: Vec<f32> = (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
        .map(|(dx, dy)| (-((dx * dx + dy * dy) as f32) / (2.0 * settings.sigma.powi(2))).exp())
        .collect();
    let side = (2 * r + 1) as usize;
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, value) in row.iter_mut().enumerate() {
            let centre = disparity[y * w + x];
            if !centre.is_finite() {
                *value = centre;
                continue;
            }
            let intensity = image.at(x, y);
            let (mut sum, mut norm) = (0f32, 0f32);
            let (y0, y1) = ((y as i64 - r).max(0), (y as i64 + r).min(h as i64 - 1));
            let (x0, x1) = ((x as i64 - r).max(0), (x as i64 + r).min(w as i64 - 1));
            for yy in y0..=y1 {
                let weight_row = &weights[((yy - y as i64 + r) as usize) * side..][..side];
                for xx in x0..=x1 {
                    let d = disparity[yy as usize * w + xx as usize];
                    if !d.is_finite()
                        || (image.at(xx as usize, yy as usize) - intensity).abs()
                            >= settings.threshold
                    {
                        continue;
                    }
                    let g = weight_row[(xx - x as i64 + r) as usize];
                    sum += g * d;
                    norm += g;
                }
            }
            *value = if norm > 0.0 { sum / norm } else { centre };
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_map(rng: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
        (0..n)
            .map(|_| {
                if rng.random::<f32>() < 0.1 {
                    f32::NAN
                } else {
                    rng.random_range(0.0..20.0)
                }
            })
            .collect()
    }

    #[test]
    fn median_filter_equals_a_sorted_window() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (w, h) = (19, 13);
        let map = random_map(&mut rng, w * h);
        let fast = median_filter(&map, w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let centre = map[y * w + x];
                if !centre.is_finite() {
                    assert!(fast[y * w + x].is_nan());
                    continue;
                }
                let mut window: Vec<f32> = (y.saturating_sub(2)..(y + 3).min(h))
                    .flat_map(|yy| (x.saturating_sub(2)..(x + 3).min(w)).map(move |xx| (xx, yy)))
                    .map(|(xx, yy)| map[yy * w + xx])
                    .filter(|v| v.is_finite())
                    .collect();
                window.sort_by(f32::total_cmp);
                let n = window.len();
                let want = if n % 2 == 1 {
                    window[n / 2]
                } else {
                    0.5 * (window[n / 2 - 1] + window[n / 2])
                };
                assert_eq!(fast[y * w + x], want, "({x}, {y})");
            }
        }
    }

    #[test]
    fn bilateral_filter_equals_the_weighted_mean() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let (w, h) = (17, 11);
        let map = random_map(&mut rng, w * h);
        let image = GreyImage {
            channels: 1,
            width: w,
            height: h,
            data: (0..w * h).map(|_| rng.random_range(-1.0..1.0)).collect(),
        };
        let settings = Bilateral {
            sigma: 2.0,
            threshold: 0.7,
            radius: 3,
        };
        let fast = bilateral_filter(&map, &image, &settings);
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let p = (y * w as i64 + x) as usize;
                if !map[p].is_finite() {
                    continue;
                }
                let (mut sum, mut norm) = (0.0f64, 0.0f64);
                for yy in 0..h as i64 {
                    for xx in 0..w as i64 {
                        let q = (yy * w as i64 + xx) as usize;
                        if (xx - x).abs() > 3 || (yy - y).abs() > 3 || !map[q].is_finite() {
                            continue;
                        }
                        if (image.data[q] - image.data[p]).abs() >= 0.7 {
                            continue;
                        }
                        let g = (-(((xx - x).pow(2) + (yy - y).pow(2)) as f64) / 8.0).exp();
                        sum += g * map[q] as f64;
                        norm += g;
                    }
                }
                assert!((fast[p] as f64 - sum / norm).abs() < 1e-4);
            }
        }
    }

    #[test]
    fn occlusions_fill_from_the_left_and_mismatches_from_the_16_direction_median() {
        // A 9×9 map of 4s with a 5 on the left, a failed occlusion at (2, 4) and a failed
        // mismatch at (6, 4) surrounded by 4s except one 9.
        let (w, h) = (9, 9);
        let mut map = vec![4.0f32; w * h];
        let mut classes = vec![Consistency::Correct; w * h];
        map[4 * w + 1] = 5.0;
        classes[4 * w + 2] = Consistency::Occlusion;
        map[4 * w + 2] = 30.0;
        classes[4 * w + 6] = Consistency::Mismatch;
        map[4 * w + 6] = 30.0;
        map[3 * w + 6] = 9.0;
        let filled = fill_inconsistent(&map, &classes, w, h);
        assert_eq!(filled[4 * w + 2], 5.0, "occlusion takes the left neighbour");
        assert_eq!(filled[4 * w + 6], 4.0, "mismatch takes the median");
    }

    #[test]
    fn classification_separates_mismatch_from_occlusion() {
        // One row of 6: right disparities all 0. Left pixel 3 claims d = 2 (right pixel 1
        // says 0): inconsistent, but d' = 0 would be consistent, so a mismatch. With right
        // disparities all 5, no left pixel below x = 5 can be consistent: occlusion.
        let right = vec![0.0; 6];
        let range = DisparityRange::up_to(4).unwrap();
        let classes = classify(&[0.0, 0.0, 0.0, 2.0, 0.0, 0.0], &right, 6, range);
        assert_eq!(classes[3], Consistency::Mismatch);
        assert_eq!(classes[0], Consistency::Correct);
        let classes = classify(&[1.0; 6], &[5.0; 6], 6, range);
        assert_eq!(classes[2], Consistency::Occlusion);
        // Negative disparities: right disparities all −2 confirm left pixels 0..4 at −2;
        // pixel 5 at −2 would look at right pixel 7, outside, and no other disparity
        // is consistent there: an occlusion.
        let range = DisparityRange::new(-3, 1).unwrap();
        let classes = classify(&[-2.0; 6], &[-2.0; 6], 6, range);
        assert_eq!(classes[3], Consistency::Correct);
        assert_eq!(classes[5], Consistency::Occlusion);
    }
}
