//! Cross-based cost aggregation (Zhang, Lu & Lafruit 2009, as MC-CNN uses it): every pixel
//! grows four arms along which the intensity stays within `intensity` of its own and the
//! distance below `distance`; the support of a left pixel p at disparity d is the
//! intersection of p's cross in the left image with (p − d)'s cross in the right image,
//! and each iteration replaces a cost by its mean over the support, horizontally then
//! vertically (alternating the order per iteration, as MC-CNN). In the chain
//! `cost -> aggregate -> sgm -> refine`, it comes before and optionally after SGM.

#[cfg(test)]
use super::cost_volume::right_column;
use super::{CostVolume, GreyImage};
use rayon::prelude::*;

/// Cross-based aggregation settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CrossAggregation {
    /// Largest intensity difference inside an arm (images in [0, 1]).
    pub intensity: f32,
    /// Longest arm, pixels.
    pub distance: usize,
    /// Number of aggregation passes.
    pub iterations: usize,
}

/// Arm lengths of every pixel: (left, right, up, down), each at most `distance`.
pub(crate) fn arms(image: &GreyImage, intensity: f32, distance: usize) -> Vec<[u16; 4]> {
    let (w, h) = (image.width, image.height);
    let mut out = vec![[0u16; 4]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, arm) in row.iter_mut().enumerate() {
            let centre = image.at(x, y);
            let reach = |dx: i64, dy: i64| {
                let mut n = 0;
                while n < distance {
                    let (xx, yy) = (
                        x as i64 + dx * (n as i64 + 1),
                        y as i64 + dy * (n as i64 + 1),
                    );
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        break;
                    }
                    if (image.at(xx as usize, yy as usize) - centre).abs() >= intensity {
                        break;
                    }
                    n += 1;
                }
                n as u16
            };
            *arm = [reach(-1, 0), reach(1, 0), reach(0, -1), reach(0, 1)];
        }
    });
    out
}

/// Aggregates `volume` in place (pixels whose right match is outside the image keep
/// their cost and are left out of their neighbours' means).
pub fn cross_based_aggregation(
    volume: &mut CostVolume,
    left: &GreyImage,
    right: &GreyImage,
    settings: &CrossAggregation,
) {
    if settings.iterations == 0 {
        return;
    }
    let left_arms = arms(left, settings.intensity, settings.distance);
    let right_arms = arms(right, settings.intensity, settings.distance);
    for iteration in 0..settings.iterations {
        let horizontal_first = iteration % 2 == 0;
        for horizontal in [horizontal_first, !horizontal_first] {
            aggregate_1d(volume, &left_arms, &right_arms, horizontal);
        }
    }
}

/// One 1-D pass: horizontal (along rows) or vertical (along columns).
fn aggregate_1d(
    volume: &mut CostVolume,
    left_arms: &[[u16; 4]],
    right_arms: &[[u16; 4]],
    horizontal: bool,
) {
    let (w, h, dm, range) = (volume.width, volume.height, volume.count(), volume.range);
    let source = volume.data.clone();
    // The right pixel of left pixel p at index d, if inside the image.
    let right_pixel = move |p: usize, d: usize| {
        let xr = (p % w) as i64 - range.min as i64 - d as i64;
        (0..w as i64).contains(&xr).then(|| p - p % w + xr as usize)
    };
    let (lines, length) = if horizontal { (h, w) } else { (w, h) };
    let index = move |line: usize, i: usize| {
        if horizontal {
            line * w + i
        } else {
            i * w + line
        }
    };
    let results: Vec<(usize, Vec<f32>)> = (0..lines)
        .into_par_iter()
        .map(|line| {
            let mut out = vec![0f32; length * dm];
            let mut prefix = vec![0f32; length + 1];
            let mut counts = vec![0u32; length + 1];
            for d in 0..dm {
                // Prefix sums of the valid costs along the line at this disparity.
                for i in 0..length {
                    let p = index(line, i);
                    let valid = right_pixel(p, d).is_some();
                    let c = source[p * dm + d];
                    prefix[i + 1] = prefix[i] + if valid { c } else { 0.0 };
                    counts[i + 1] = counts[i] + u32::from(valid);
                }
                for i in 0..length {
                    let p = index(line, i);
                    let Some(q) = right_pixel(p, d) else {
                        out[i * dm + d] = source[p * dm + d];
                        continue;
                    };
                    let (a, b) = if horizontal { (0, 1) } else { (2, 3) };
                    let before = left_arms[p][a].min(right_arms[q][a]) as usize;
                    let after = left_arms[p][b].min(right_arms[q][b]) as usize;
                    let (lo, hi) = (i - before.min(i), (i + after).min(length - 1) + 1);
                    let n = counts[hi] - counts[lo];
                    out[i * dm + d] = if n > 0 {
                        (prefix[hi] - prefix[lo]) / n as f32
                    } else {
                        source[p * dm + d]
                    };
                }
            }
            (line, out)
        })
        .collect();
    for (line, out) in results {
        for i in 0..length {
            let p = index(line, i);
            volume.data[p * dm..(p + 1) * dm].copy_from_slice(&out[i * dm..(i + 1) * dm]);
        }
    }
}

/// The plain definition, for tests: the mean over the support, looping over pixels.
#[cfg(test)]
pub(crate) fn reference_pass(
    volume: &CostVolume,
    left_arms: &[[u16; 4]],
    right_arms: &[[u16; 4]],
    horizontal: bool,
) -> CostVolume {
    let (w, h, dm) = (volume.width, volume.height, volume.count());
    let mut out = volume.clone();
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            for d in volume.matched(x) {
                let q = y * w + right_column(x, d, volume.range);
                let (a, b) = if horizontal { (0, 1) } else { (2, 3) };
                let before = left_arms[p][a].min(right_arms[q][a]) as i64;
                let after = left_arms[p][b].min(right_arms[q][b]) as i64;
                let (mut sum, mut n) = (0.0f64, 0);
                for k in -before..=after {
                    let (xx, yy) = if horizontal {
                        (x as i64 + k, y as i64)
                    } else {
                        (x as i64, y as i64 + k)
                    };
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        continue;
                    }
                    if !volume.matched(xx as usize).contains(&d) {
                        continue;
                    }
                    sum += volume.data[(yy as usize * w + xx as usize) * dm + d] as f64;
                    n += 1;
                }
                out.data[p * dm + d] = (sum / n as f64) as f32;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::DisparityRange;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn aggregation_equals_the_plain_support_mean() {
        for range in [DisparityRange::new(0, 6), DisparityRange::new(-4, 2)] {
            aggregation_equals_the_plain_support_mean_over(range.unwrap());
        }
    }

    fn aggregation_equals_the_plain_support_mean_over(range: DisparityRange) {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (w, h, dm) = (23, 17, range.count());
        let image = |rng: &mut ChaCha8Rng| GreyImage {
            channels: 1,
            width: w,
            height: h,
            // Blocky values so that arms have varied lengths.
            data: (0..w * h)
                .map(|i| ((i % w) / 4 + (i / w) / 3) as f32 * 0.05 + rng.random::<f32>() * 0.02)
                .collect(),
        };
        let (left, right) = (image(&mut rng), image(&mut rng));
        let mut volume = CostVolume::new(w, h, range);
        for y in 0..h {
            for x in 0..w {
                for d in volume.matched(x) {
                    volume.data[(y * w + x) * dm + d] = rng.random();
                }
            }
        }
        let (la, ra) = (arms(&left, 0.08, 5), arms(&right, 0.08, 5));
        assert!(
            la.iter().any(|a| a[0] > 0 && a[0] < 5),
            "arms have varied lengths"
        );
        for horizontal in [true, false] {
            let mut fast = volume.clone();
            aggregate_1d(&mut fast, &la, &ra, horizontal);
            let slow = reference_pass(&volume, &la, &ra, horizontal);
            for (a, b) in fast.data.iter().zip(&slow.data) {
                assert!((a - b).abs() < 1e-5, "{a} vs {b}");
            }
        }
    }
}
