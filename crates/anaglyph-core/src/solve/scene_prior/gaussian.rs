//! One Gaussian of the scene prior's mixture: the mean and covariance of a set of
//! spectra.
//!
//! In: spectra (`n × knots`, row-major). Out: their mean and covariance, as a component
//! with the given log weight.

use rayon::prelude::*;

/// Pixels per rayon task.
const PIXELS_PER_TASK: usize = 4096;

/// One Gaussian of the mixture.
#[derive(Debug, Clone)]
pub(super) struct Component {
    /// Log of its share of the mixture.
    pub(super) log_weight: f64,
    pub(super) mean: Vec<f64>,
    /// `knots × knots`, row-major.
    pub(super) covariance: Vec<f64>,
}

/// Mean and covariance of the given spectra (`n × knots`, row-major): per chunk of
/// pixels the column sums and the product Xᵀ X (one `matmul`), summed over chunks.
pub(super) fn gaussian_of(spectra: &[f64], knots: usize, log_weight: f64) -> Component {
    let n = (spectra.len() / knots) as f64;
    let (sum, outer) = spectra
        .par_chunks(PIXELS_PER_TASK * knots)
        .map(|chunk| {
            let rows = chunk.len() / knots;
            let mut sum = vec![0.0f64; knots];
            for s in chunk.chunks_exact(knots) {
                sum.iter_mut().zip(s).for_each(|(a, &v)| *a += v);
            }
            let mut outer = vec![0.0f64; knots * knots];
            let x = faer::MatRef::from_row_major_slice(chunk, rows, knots);
            faer::linalg::matmul::matmul(
                faer::MatMut::from_row_major_slice_mut(&mut outer, knots, knots),
                faer::Accum::Replace,
                x.transpose(),
                x,
                1.0,
                faer::Par::Seq,
            );
            (sum, outer)
        })
        .reduce(
            || (vec![0.0; knots], vec![0.0; knots * knots]),
            |(mut a, mut b), (c, d)| {
                a.iter_mut().zip(c).for_each(|(a, c)| *a += c);
                b.iter_mut().zip(d).for_each(|(b, d)| *b += d);
                (a, b)
            },
        );
    let mean: Vec<f64> = sum.iter().map(|s| s / n).collect();
    // Symmetric by construction: the product's rounding may differ across the diagonal.
    let covariance: Vec<f64> = (0..knots * knots)
        .map(|k| {
            let (i, j) = (k / knots, k % knots);
            let (i, j) = (i.min(j), i.max(j));
            outer[i * knots + j] / n - mean[i] * mean[j]
        })
        .collect();
    Component {
        log_weight,
        mean,
        covariance,
    }
}
