//! Zero-mean normalised cross-correlation over a square window: invariant to gain and
//! offset between the two images, the classic radiometrically robust window cost. Cost =
//! (1 − ZNCC)/2 in [0, 1]; textureless windows (zero variance) cost 0.5.

use super::cost_volume::matched_indices;
use super::{CostVolume, DisparityRange, GreyImage};
use rayon::prelude::*;

/// Window radius: 9 × 9 windows.
const RADIUS: usize = 4;

/// Box mean over the (clamped) window around every pixel, via per-row prefix sums.
fn box_mean(values: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut rows = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let (a, b) = (x.saturating_sub(RADIUS), (x + RADIUS).min(w - 1));
            rows[y * w + x] =
                values[y * w + a..=y * w + b].iter().sum::<f64>() / (b - a + 1) as f64;
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(RADIUS), (y + RADIUS).min(h - 1));
        for x in 0..w {
            out[y * w + x] = (a..=b).map(|yy| rows[yy * w + x]).sum::<f64>() / (b - a + 1) as f64;
        }
    }
    out
}

/// ZNCC cost volume of a rectified pair (left is the reference).
pub fn zncc_cost_volume(left: &GreyImage, right: &GreyImage, range: DisparityRange) -> CostVolume {
    let (w, h) = (left.width, left.height);
    let l: Vec<f64> = left.data.iter().map(|&v| v as f64).collect();
    let r: Vec<f64> = right.data.iter().map(|&v| v as f64).collect();
    let sq = |v: &[f64]| v.iter().map(|x| x * x).collect::<Vec<f64>>();
    let (ml, mr) = (box_mean(&l, w, h), box_mean(&r, w, h));
    let (ml2, mr2) = (box_mean(&sq(&l), w, h), box_mean(&sq(&r), w, h));
    let (mut volume, n) = (CostVolume::new(w, h, range), range.count());
    let costs: Vec<Vec<f32>> = (0..n)
        .into_par_iter()
        .map(|k| {
            // The right pixel x − d of pixel i, its column clamped (edge replicated).
            let d = range.min as i64 + k as i64;
            let shifted = |i: usize| {
                let x = (i % w) as i64;
                i - (i % w) + (x - d).clamp(0, w as i64 - 1) as usize
            };
            // E[L(x) R(x − d)] over the window, with R shifted by d.
            let product: Vec<f64> = (0..w * h).map(|i| l[i] * r[shifted(i)]).collect();
            let mlr = box_mean(&product, w, h);
            (0..w * h)
                .map(|i| {
                    let j = shifted(i);
                    let cov = mlr[i] - ml[i] * mr[j];
                    let var = (ml2[i] - ml[i] * ml[i]).max(0.0) * (mr2[j] - mr[j] * mr[j]).max(0.0);
                    let zncc = if var > 1e-12 {
                        (cov / var.sqrt()).clamp(-1.0, 1.0)
                    } else {
                        0.0
                    };
                    (0.5 * (1.0 - zncc)) as f32
                })
                .collect()
        })
        .collect();
    for y in 0..h {
        for x in 0..w {
            for k in matched_indices(x, w, range) {
                volume.data[(y * w + x) * n + k] = costs[k][y * w + x];
            }
        }
    }
    volume
}
