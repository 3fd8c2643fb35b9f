//! k-means clustering of spectra (k-means++ seeding, Lloyd iterations), which splits the
//! scene prior's samples into the materials its mixture models.
//!
//! In: spectra (`n × knots`), a cluster count and a seed. Out: the cluster centres, and the
//! nearest centre of any spectrum.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// k-means fits its centres to at most this many of the samples.
const K_MEANS_SAMPLES: usize = 4096;
/// Lloyd iterations of k-means at most.
const K_MEANS_ITERATIONS: usize = 15;

/// ‖a − b‖², in four independent sums so that the loop vectorises.
fn squared_distance(a: &[f64], b: &[f64]) -> f64 {
    let mut lanes = [0.0f64; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = a4
        .remainder()
        .iter()
        .zip(b4.remainder())
        .map(|(x, y)| (x - y) * (x - y))
        .sum();
    for (x, y) in a4.zip(b4) {
        for ((lane, x), y) in lanes.iter_mut().zip(x).zip(y) {
            *lane += (x - y) * (x - y);
        }
    }
    lanes.iter().sum::<f64>() + tail
}

/// k-means of the spectra (`n × knots`) into at most `k` clusters: the centres, fitted
/// to an even subsample of at most [`K_MEANS_SAMPLES`] spectra offset by `seed`, and
/// seeded by k-means++ from `seed`.
pub(super) fn k_means(spectra: &[f64], knots: usize, k: usize, seed: u64) -> Vec<Vec<f64>> {
    let all = spectra.len() / knots;
    let stride = all.div_ceil(K_MEANS_SAMPLES);
    let subsample: Vec<f64> = (seed as usize % stride..all)
        .step_by(stride)
        .flat_map(|i| spectra[i * knots..(i + 1) * knots].iter().copied())
        .collect();
    let n = subsample.len() / knots;
    let point = |i: usize| &subsample[i * knots..(i + 1) * knots];
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut centres: Vec<Vec<f64>> = vec![point(rng.random_range(0..n)).to_vec()];
    let mut nearest: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| squared_distance(point(i), &centres[0]))
        .collect();
    while centres.len() < k {
        let total: f64 = nearest.iter().sum();
        if !(total > 0.0) {
            break;
        }
        let mut target = rng.random_range(0.0..total);
        let pick = nearest
            .iter()
            .position(|d| {
                target -= d;
                target <= 0.0
            })
            .unwrap_or(n - 1);
        let centre = point(pick).to_vec();
        nearest
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, d)| *d = d.min(squared_distance(point(i), &centre)));
        centres.push(centre);
    }
    let mut labels = vec![usize::MAX; n];
    for _ in 0..K_MEANS_ITERATIONS {
        let changed: usize = labels
            .par_iter_mut()
            .enumerate()
            .map(|(i, label)| {
                let best = nearest_centre(point(i), &centres);
                let changed = usize::from(best != *label);
                *label = best;
                changed
            })
            .sum();
        if changed == 0 {
            break;
        }
        let mut sums = vec![vec![0.0f64; knots]; centres.len()];
        let mut counts = vec![0usize; centres.len()];
        for (i, &label) in labels.iter().enumerate() {
            counts[label] += 1;
            sums[label]
                .iter_mut()
                .zip(point(i))
                .for_each(|(s, x)| *s += x);
        }
        for ((centre, sum), count) in centres.iter_mut().zip(sums).zip(counts) {
            if count > 0 {
                *centre = sum.into_iter().map(|s| s / count as f64).collect();
            }
        }
    }
    centres
}

/// The index of the centre nearest to `point`.
pub(super) fn nearest_centre(point: &[f64], centres: &[Vec<f64>]) -> usize {
    centres
        .iter()
        .map(|c| squared_distance(point, c))
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(0, |(c, _)| c)
}
