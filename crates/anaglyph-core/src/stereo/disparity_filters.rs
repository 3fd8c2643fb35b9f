//! The last stages of the chain `cost -> aggregate -> sgm -> refine`, on disparity maps
//! (MC-CNN section 4): filling of left–right failures (occlusions from the background
//! side, mismatches by the median of the nearest consistent pixels in 16 directions), a
//! 5×5 median filter and an intensity-gated bilateral filter. NaN marks invalid pixels.

use super::cost_volume::{matched_indices, right_column};
use super::{CostVolume, DisparityRange, GreyImage, LEFT_RIGHT_TOLERANCE};
use rayon::prelude::*;

/// The right view's winner-take-all disparities from the left volume
/// (`d_R(x) = argmin_d C(x + d, d)` over the d whose left pixel is inside the image, the
/// lowest d of equal costs). One pass over each row of the volume in its own order, each
/// cost compared with the best so far of the right pixel it matches.
pub fn right_disparity(volume: &CostVolume) -> Vec<f32> {
    let (w, h, dm, range) = (volume.width, volume.height, volume.count(), volume.range);
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each_init(
        || (vec![0usize; w], vec![0f32; w]),
        |(best, best_cost), (y, row)| {
            best.fill(0);
            best_cost.fill(f32::INFINITY);
            let costs = &volume.data[y * w * dm..][..w * dm];
            for (x, pixel) in costs.chunks_exact(dm).enumerate() {
                for k in matched_indices(x, w, range) {
                    let xr = right_column(x, k, range);
                    if pixel[k] < best_cost[xr] {
                        (best[xr], best_cost[xr]) = (k, pixel[k]);
                    }
                }
            }
            for (value, &k) in row.iter_mut().zip(best.iter()) {
                *value = range.at(k);
            }
        },
    );
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

/// Median over the `(2·radius + 1)²` window of finite values (NaN pixels stay NaN). The
/// 5×5 window of [`median_row_5x5`] where its 25 values are all finite, lanes of
/// pixels at a time through a selection network; the window sorted elsewhere.
pub fn median_filter(disparity: &[f32], width: usize, height: usize, radius: usize) -> Vec<f32> {
    let mut out = vec![0f32; width * height];
    let window = || {
        (
            Vec::with_capacity((2 * radius + 1).pow(2)),
            vec![false; width],
        )
    };
    out.par_chunks_mut(width)
        .enumerate()
        .for_each_init(window, |(window, done), (y, row)| {
            done.fill(false);
            if radius == 2 {
                median_row_5x5(disparity, (width, height), y, row, done);
            }
            for (x, value) in row.iter_mut().enumerate() {
                if done[x] {
                    continue;
                }
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
                *value = median(window);
            }
        });
    out
}

/// Values in a 5×5 window, and the wire of a selection network left holding their median.
const WINDOW_5X5: usize = 25;
const MEDIAN_WIRE: usize = WINDOW_5X5 / 2;
/// Wires of the network: the window padded with +∞ to a power of two.
const WIRES: usize = 32;
/// Pixels through the network at a time (one vector of f32 lanes per wire).
const MEDIAN_LANES: usize = 8;

/// Comparators `(i, j)`, `i < j`, each putting the lesser of wires i and j on i: Batcher's
/// odd–even merge sort of [`WIRES`] wires, without the comparators that can change
/// nothing (the greater wire still holding its +∞ padding) or nothing of
/// [`MEDIAN_WIRE`]'s value (their outputs never reach it), so that wire
/// [`MEDIAN_WIRE`] ends with the 13th smallest of the 25 values on wires 0..25.
fn median_network() -> &'static [(u8, u8)] {
    static NETWORK: std::sync::OnceLock<Vec<(u8, u8)>> = std::sync::OnceLock::new();
    NETWORK.get_or_init(|| {
        let mut sorting = Vec::new();
        let mut p = 1;
        while p < WIRES {
            let mut k = p;
            while k >= 1 {
                for j in (k % p..WIRES - k).step_by(2 * k) {
                    for i in 0..k.min(WIRES - j - k) {
                        if (i + j) / (2 * p) == (i + j + k) / (2 * p) {
                            sorting.push((i + j, i + j + k));
                        }
                    }
                }
                k /= 2;
            }
            p *= 2;
        }
        // Forward: a comparator whose greater wire still holds +∞ leaves both wires as
        // they are; one whose lesser wire does moves the padding to the greater.
        let mut padding: Vec<bool> = (0..WIRES).map(|i| i >= WINDOW_5X5).collect();
        let mut effective = Vec::new();
        for (i, j) in sorting {
            if padding[j] {
                continue;
            }
            if padding[i] {
                (padding[i], padding[j]) = (false, true);
            }
            effective.push((i, j));
        }
        // Backward: keep the comparators that feed the median's wire.
        let mut needed = [false; WIRES];
        needed[MEDIAN_WIRE] = true;
        let mut kept = Vec::new();
        for &(i, j) in effective.iter().rev() {
            if needed[i] || needed[j] {
                (needed[i], needed[j]) = (true, true);
                kept.push((i as u8, j as u8));
            }
        }
        kept.reverse();
        kept
    })
}

/// The median of each lane's 25 finite values on wires 0..25 (their order is lost).
#[inline(always)]
fn network_median(wires: &mut [[f32; MEDIAN_LANES]; WIRES]) -> [f32; MEDIAN_LANES] {
    for &(i, j) in median_network() {
        let (a, b) = (wires[i as usize], wires[j as usize]);
        for lane in 0..MEDIAN_LANES {
            // Finite values: `<` is the order, and compiles to one min and one max.
            let (lo, hi) = if b[lane] < a[lane] {
                (b[lane], a[lane])
            } else {
                (a[lane], b[lane])
            };
            wires[i as usize][lane] = lo;
            wires[j as usize][lane] = hi;
        }
    }
    wires[MEDIAN_WIRE]
}

/// Row `y` of the 5×5 median where whole windows are inside the map and finite, lanes
/// of [`MEDIAN_LANES`] pixels at a time, marking in `done` the pixels it wrote.
fn median_row_5x5(
    disparity: &[f32],
    (width, height): (usize, usize),
    y: usize,
    row: &mut [f32],
    done: &mut [bool],
) {
    if y < 2 || y + 2 >= height || width < 4 + MEDIAN_LANES {
        return;
    }
    let mut wires = [[f32::INFINITY; MEDIAN_LANES]; WIRES];
    for x0 in (2..width - 2 - MEDIAN_LANES + 1).step_by(MEDIAN_LANES) {
        let mut finite = true;
        for dy in 0..5 {
            let source = &disparity[(y + dy - 2) * width + x0 - 2..][..MEDIAN_LANES + 4];
            finite &= source.iter().all(|v| v.is_finite());
            for dx in 0..5 {
                wires[dy * 5 + dx].copy_from_slice(&source[dx..dx + MEDIAN_LANES]);
            }
        }
        if !finite {
            continue;
        }
        wires[WINDOW_5X5..].fill([f32::INFINITY; MEDIAN_LANES]);
        let medians = network_median(&mut wires);
        row[x0..x0 + MEDIAN_LANES].copy_from_slice(&medians);
        done[x0..x0 + MEDIAN_LANES].fill(true);
    }
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

    /// [`right_disparity`] by its definition: for each right pixel, the left pixels it
    /// matches in order of disparity.
    fn right_disparity_by_definition(volume: &CostVolume) -> Vec<f32> {
        let (w, h, dm, range) = (volume.width, volume.height, volume.count(), volume.range);
        let mut out = vec![0f32; w * h];
        for y in 0..h {
            for xr in 0..w {
                let (mut best, mut best_cost) = (0, f32::INFINITY);
                for k in 0..dm {
                    let x = xr as i64 + range.min as i64 + k as i64;
                    if (0..w as i64).contains(&x) {
                        let c = volume.data[(y * w + x as usize) * dm + k];
                        if c < best_cost {
                            (best, best_cost) = (k, c);
                        }
                    }
                }
                out[y * w + xr] = range.at(best);
            }
        }
        out
    }

    #[test]
    fn the_right_disparities_are_those_of_the_definition() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for (w, h, min, max) in [
            (23, 4, 0, 9),
            (17, 3, -6, 5),
            (5, 2, -3, 12),
            (30, 2, 4, 10),
        ] {
            let range = DisparityRange::new(min, max).unwrap();
            let mut volume = CostVolume::new(w, h, range);
            for v in volume.data.iter_mut() {
                // Few levels, so that ties are common; some NaN.
                *v = match rng.random_range(0..10) {
                    0 => f32::NAN,
                    _ => rng.random_range(0..4) as f32,
                };
            }
            let got = right_disparity(&volume);
            let want = right_disparity_by_definition(&volume);
            assert_eq!(got, want, "{w}x{h} over {min}:{max}");
        }
    }

    #[test]
    fn the_selection_network_gives_the_median_of_25() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let network = median_network();
        assert!(network.len() < 191, "{} comparators", network.len());
        for trial in 0..2000 {
            let mut wires = [[f32::INFINITY; MEDIAN_LANES]; WIRES];
            let mut want = [0f32; MEDIAN_LANES];
            for (lane, median) in want.iter_mut().enumerate() {
                // Few distinct values in some trials: ties.
                let levels: f32 = if trial % 2 == 0 { 4.0 } else { 1e6 };
                let mut values: Vec<f32> = (0..WINDOW_5X5)
                    .map(|_| rng.random_range(0.0..levels).floor())
                    .collect();
                for (wire, &v) in wires.iter_mut().zip(&values) {
                    wire[lane] = v;
                }
                values.sort_by(f32::total_cmp);
                *median = values[MEDIAN_WIRE];
            }
            assert_eq!(network_median(&mut wires), want, "trial {trial}");
        }
    }

    #[test]
    fn median_filter_equals_a_sorted_window() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (w, h) = (37, 13);
        // With invalid pixels (sorted windows mostly) and without (the network inside).
        let mut finite = random_map(&mut rng, w * h);
        finite
            .iter_mut()
            .for_each(|v| *v = if v.is_nan() { 3.5 } else { *v });
        for map in [random_map(&mut rng, w * h), finite] {
            median_filter_matches_sorted_windows(&map, w, h);
        }
    }

    fn median_filter_matches_sorted_windows(map: &[f32], w: usize, h: usize) {
        let fast = median_filter(map, w, h, 2);
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
