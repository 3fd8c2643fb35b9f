//! Mutual information as a matching cost (Hirschmüller's HMI, PAMI 2008): from a current
//! disparity map, the joint histogram of corresponding intensities gives, per intensity
//! pair, `mi(i, k) = h_L(i) + h_R(k) − h_LR(i, k)` with Parzen-smoothed entropies; the
//! pixel-wise cost is `−mi`. It models any one-to-one relation between the two images'
//! intensities, inversions included, which is what different filters produce. The
//! matcher iterates: census disparities, then MI costs from them, SGM, and again.

use super::cost_volume::{matched_indices, right_column};
use super::{CostVolume, DisparityRange, GreyImage};
use rayon::prelude::*;

/// Intensity bins (images are scaled to [0, 1] first).
pub const BINS: usize = 64;
/// Parzen window σ, in bins.
const PARZEN_SIGMA: f64 = 1.0;

fn bin(v: f32) -> usize {
    ((v.clamp(0.0, 1.0) * (BINS - 1) as f32).round() as usize).min(BINS - 1)
}

/// Separable Gaussian smoothing of a `BINS`-wide table with `rows` rows (1 or `BINS`).
fn smooth(table: &[f64], rows: usize) -> Vec<f64> {
    let radius = (3.0 * PARZEN_SIGMA).ceil() as i64;
    let kernel: Vec<f64> = (-radius..=radius)
        .map(|k| (-(k * k) as f64 / (2.0 * PARZEN_SIGMA * PARZEN_SIGMA)).exp())
        .collect();
    let conv = |get: &dyn Fn(i64) -> f64, i: i64, n: i64| -> f64 {
        let (mut s, mut w) = (0.0, 0.0);
        for (j, k) in (-radius..=radius).zip(&kernel) {
            let t = i + j;
            if t >= 0 && t < n {
                s += k * get(t);
                w += k;
            }
        }
        s / w
    };
    let n = BINS as i64;
    let mut horizontal = vec![0.0; table.len()];
    for r in 0..rows {
        for c in 0..BINS {
            horizontal[r * BINS + c] = conv(&|t| table[r * BINS + t as usize], c as i64, n);
        }
    }
    if rows == 1 {
        return horizontal;
    }
    let mut out = vec![0.0; table.len()];
    for r in 0..rows {
        for c in 0..BINS {
            out[r * BINS + c] = conv(
                &|t| horizontal[t as usize * BINS + c],
                r as i64,
                rows as i64,
            );
        }
    }
    out
}

/// `−mi(i, k)` rescaled to [0, 1], from the correspondences of `disparity` (row-major
/// `BINS × BINS`, left intensity bin major).
pub fn mutual_information_table(
    left: &GreyImage,
    right: &GreyImage,
    disparity: &[f32],
) -> Vec<f32> {
    let w = left.width;
    let mut joint = vec![0.0f64; BINS * BINS];
    let mut n = 0.0;
    for (i, &d) in disparity.iter().enumerate() {
        if !d.is_finite() {
            continue;
        }
        let (x, y) = (i % w, i / w);
        let xr = x as f32 - d.round();
        if xr < 0.0 || xr >= w as f32 {
            continue;
        }
        joint[bin(left.data[i]) * BINS + bin(right.at(xr as usize, y))] += 1.0;
        n += 1.0;
    }
    let n = f64::max(n, 1.0);
    let (mut pl, mut pr) = (vec![0.0; BINS], vec![0.0; BINS]);
    for i in 0..BINS {
        for k in 0..BINS {
            let p = joint[i * BINS + k] / n;
            joint[i * BINS + k] = p;
            pl[i] += p;
            pr[k] += p;
        }
    }
    let entropy = |p: &[f64], rows: usize| -> Vec<f64> {
        let smoothed = smooth(p, rows);
        let logs: Vec<f64> = smoothed.iter().map(|v| -(v.max(1e-12)).ln() / n).collect();
        smooth(&logs, rows)
    };
    let (hlr, hl, hr) = (entropy(&joint, BINS), entropy(&pl, 1), entropy(&pr, 1));
    let cost: Vec<f64> = (0..BINS * BINS)
        .map(|j| -(hl[j / BINS] + hr[j % BINS] - hlr[j]))
        .collect();
    let lo = cost.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = cost.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let span = if hi > lo { hi - lo } else { 1.0 };
    cost.iter().map(|c| ((c - lo) / span) as f32).collect()
}

/// The pixel-wise MI cost volume for the correspondences of `disparity`.
pub fn mutual_information_cost_volume(
    left: &GreyImage,
    right: &GreyImage,
    range: DisparityRange,
    disparity: &[f32],
) -> CostVolume {
    let table = mutual_information_table(left, right, disparity);
    let (w, h) = (left.width, left.height);
    let left_bins: Vec<usize> = left.data.iter().map(|&v| bin(v)).collect();
    let right_bins: Vec<usize> = right.data.iter().map(|&v| bin(v)).collect();
    let mut volume = CostVolume::new(w, h, range);
    let n = range.count();
    volume
        .data
        .par_chunks_mut(w * n)
        .enumerate()
        .for_each(|(y, row)| {
            for x in 0..w {
                let t = &table[left_bins[y * w + x] * BINS..][..BINS];
                for k in matched_indices(x, w, range) {
                    row[x * n + k] = t[right_bins[y * w + right_column(x, k, range)]];
                }
            }
        });
    volume
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutual_information_prefers_the_inverted_intensity() {
        // Right = 1 − left at the true disparity 0: MI must rate (v, 1 − v) as cheap and
        // (v, v) as expensive, which no intensity-difference cost does.
        let w = 64;
        let data: Vec<f32> = (0..w * 32)
            .map(|i| ((i * 37) % 101) as f32 / 100.0)
            .collect();
        let left = GreyImage {
            channels: 1,
            width: w,
            height: 32,
            data: data.clone(),
        };
        let right = GreyImage {
            channels: 1,
            width: w,
            height: 32,
            data: data.iter().map(|v| 1.0 - v).collect(),
        };
        let table = mutual_information_table(&left, &right, &vec![0.0; w * 32]);
        let (a, b) = (bin(0.2), bin(0.8));
        assert!(table[a * BINS + b] < 0.2, "{}", table[a * BINS + b]);
        assert!(table[a * BINS + a] > 0.8, "{}", table[a * BINS + a]);
    }
}
