//! The scene prior's model: a mixture of Gaussians over the spectra of a view's trusted
//! pixels, learned by k-means ([`super::k_means`]) and shrunk towards the scene's
//! covariance, and its estimate of the pixels that some rows do not measure (the posterior
//! mean, [`super::estimate`]).
//!
//! In: a view's measurements, spectra and residuals. Out: the mixture; the spectra of the
//! under-measured pixels replaced by its estimate.

use super::estimate::{estimate_batch, Gains, Projected};
use super::gaussian::{gaussian_of, Component};
use super::k_means::{k_means, nearest_centre};
use super::ScenePriorReport;
use crate::rig::SensingMatrix;
use crate::{Error, Result};
use rayon::prelude::*;
use std::collections::HashMap;
use std::ops::Range;

/// Pixels per batch of the estimate.
const BATCH: usize = 256;
/// At most this many complete pixels enter the prior (an even subsample).
const MAX_SAMPLES: usize = 1 << 16;
/// Fewer trusted complete pixels than this many per knot: no prior (the view keeps the
/// demultiplexed spectra).
const SAMPLES_PER_KNOT: usize = 20;
/// A cluster with fewer members than this many per knot is dropped from the mixture.
const MEMBERS_PER_KNOT: usize = 2;
/// k-means runs from this many seeds, and the mixture holds the clusters of all of them
/// with weights divided accordingly. One run's clusters depend on its seed, and so did
/// the clutter preset's PSNR (by 0.5 dB between seeds at 32 clusters); the pooled
/// mixture of four varied by 0.02 dB. Two instead of four scored within 0.1 dB at r0c0 on
/// the presets (tabletop 37.10 / 37.10, clutter 36.72 / 36.69, periodic 33.98 / 34.08 dB
/// at 640×480) and took the refinement of 8 views from 19.7 to 11.8 s: every estimate
/// weighs every component.
pub(super) const K_MEANS_RUNS: u64 = 2;
/// The least measurement noise assumed (rms, reflectance units): 0.1 % of white.
pub(super) const NOISE_FLOOR: f64 = 1e-3;
/// A cluster's covariance is shrunk towards the scene's with the weight of this many
/// samples, so that small clusters stay positive definite.
const SHRINKAGE_SAMPLES: f64 = 100.0;

/// Which pixels a prior learns from (besides a finite spectrum and residual).
pub(super) struct Eligible {
    /// How many rows they have measured.
    pub(super) measured: Range<usize>,
    /// A pixel whose residual exceeds this stays out even in the better half.
    pub(super) max_residual: Option<f32>,
}

/// A mixture of Gaussians over the spectra of the trusted complete pixels.
#[derive(Debug, Clone)]
pub struct ScenePrior {
    knots: usize,
    components: Vec<Component>,
    pub(super) samples: usize,
    /// Trusted pixels the samples were drawn from (an even subsample of at most
    /// `MAX_SAMPLES`): what a merged mixture weighs this one's components by.
    trusted: usize,
    /// Median residual of the trusted samples, reflectance units.
    pub(super) noise: f64,
}

impl ScenePrior {
    /// Learns the prior from the pixels where every row is measured, the spectrum is
    /// finite and the residual is at most the median of such pixels (the better half:
    /// misregistered pixels stay out), in `clusters` clusters per k-means run (1: one
    /// Gaussian). None when too few pixels qualify.
    pub fn learn(
        rows: usize,
        knots: usize,
        measurements: &[f32],
        spectra: &[f32],
        residuals: &[f32],
        clusters: usize,
    ) -> Result<Option<ScenePrior>> {
        Self::learn_from(
            rows,
            knots,
            measurements,
            spectra,
            residuals,
            clusters,
            Eligible {
                measured: rows..rows + 1,
                max_residual: None,
            },
        )
    }

    /// [`ScenePrior::learn`] from the `eligible` pixels instead of the complete ones.
    pub(super) fn learn_from(
        rows: usize,
        knots: usize,
        measurements: &[f32],
        spectra: &[f32],
        residuals: &[f32],
        clusters: usize,
        eligible: Eligible,
    ) -> Result<Option<ScenePrior>> {
        check_shapes(rows, knots, measurements, spectra)?;
        let pixels = measurements.len() / rows;
        if residuals.len() != pixels {
            return Err(Error::Shape {
                op: "scene prior: residuals against pixels".into(),
                got: vec![residuals.len()],
                expected: vec![pixels],
            });
        }
        if clusters == 0 {
            return Err(Error::out_of_range(
                "scene prior clusters",
                0.0,
                "at least 1",
            ));
        }
        let Eligible {
            measured,
            max_residual,
        } = eligible;
        let eligible: Vec<usize> = (0..pixels)
            .into_par_iter()
            .filter(|&px| {
                residuals[px].is_finite()
                    && measured.contains(
                        &measurements[px * rows..(px + 1) * rows]
                            .iter()
                            .filter(|v| v.is_finite())
                            .count(),
                    )
                    && spectra[px * knots..(px + 1) * knots]
                        .iter()
                        .all(|v| v.is_finite())
            })
            .collect();
        if eligible.is_empty() {
            return Ok(None);
        }
        let mut sorted: Vec<f32> = eligible.iter().map(|&px| residuals[px]).collect();
        let middle = sorted.len() / 2;
        let mut median = *sorted.select_nth_unstable_by(middle, f32::total_cmp).1;
        if let Some(limit) = max_residual {
            median = median.min(limit);
        }
        let trusted: Vec<usize> = eligible
            .into_iter()
            .filter(|&px| residuals[px] <= median)
            .collect();
        if trusted.len() < SAMPLES_PER_KNOT * knots {
            return Ok(None);
        }
        let stride = trusted.len().div_ceil(MAX_SAMPLES);
        let trusted_pixels = trusted.len();
        let samples: Vec<f64> = trusted
            .into_iter()
            .step_by(stride)
            .flat_map(|px| {
                spectra[px * knots..(px + 1) * knots]
                    .iter()
                    .map(|&v| v as f64)
            })
            .collect();
        let count = samples.len() / knots;
        let scene = gaussian_of(&samples, knots, 0.0);
        let components = if clusters == 1 {
            vec![scene]
        } else {
            let runs = K_MEANS_RUNS as f64;
            let mut components = Vec::new();
            for seed in 0..K_MEANS_RUNS {
                let centres = k_means(&samples, knots, clusters, seed);
                let labels: Vec<usize> = samples
                    .par_chunks_exact(knots)
                    .map(|sample| nearest_centre(sample, &centres))
                    .collect();
                let mut members: Vec<Vec<f64>> = vec![Vec::new(); clusters];
                for (sample, &label) in samples.chunks_exact(knots).zip(&labels) {
                    members[label].extend_from_slice(sample);
                }
                for members in members {
                    let n = members.len() / knots;
                    if n < MEMBERS_PER_KNOT * knots {
                        continue;
                    }
                    let mut component =
                        gaussian_of(&members, knots, (n as f64 / count as f64 / runs).ln());
                    let own = n as f64 / (n as f64 + SHRINKAGE_SAMPLES);
                    for (c, s) in component.covariance.iter_mut().zip(&scene.covariance) {
                        *c = own * *c + (1.0 - own) * s;
                    }
                    components.push(component);
                }
            }
            if components.is_empty() {
                vec![scene]
            } else {
                components
            }
        };
        Ok(Some(ScenePrior {
            knots,
            components,
            samples: count,
            trusted: trusted_pixels,
            noise: median as f64,
        }))
    }

    /// The mixture of this prior and one learned from `other`'s samples, each component's
    /// weight scaled by its prior's share of the trusted pixels. The noise level stays this one's.
    pub(super) fn merged(mut self, other: ScenePrior) -> ScenePrior {
        let total = (self.trusted + other.trusted) as f64;
        let (own, theirs) = (
            (self.trusted as f64 / total).ln(),
            (other.trusted as f64 / total).ln(),
        );
        self.components.iter_mut().for_each(|c| c.log_weight += own);
        self.components
            .extend(other.components.into_iter().map(|mut c| {
                c.log_weight += theirs;
                c
            }));
        self.samples += other.samples;
        self.trusted += other.trusted;
        self
    }

    /// Replaces the spectra of pixels that have some but not all rows measured with the
    /// prior's estimate from their measurements. `noise_scale` multiplies the learned
    /// noise level (rms per measurement, reflectance units) to give R; each row's noise
    /// is that level times the row's response to a perfect white.
    pub fn fill_incomplete(
        &self,
        sensing: &SensingMatrix,
        measurements: &[f32],
        spectra: &mut [f32],
        noise_scale: f64,
    ) -> Result<ScenePriorReport> {
        let (c, rows, knots) = (sensing.values(), sensing.rows(), self.knots);
        if sensing.cols() != knots {
            return Err(Error::Shape {
                op: "scene prior: C's knots against the prior's".into(),
                got: vec![sensing.cols()],
                expected: vec![knots],
            });
        }
        check_shapes(rows, knots, measurements, spectra)?;
        if rows > 128 {
            return Err(Error::out_of_range(
                "scene prior measurement rows",
                rows as f64,
                "at most 128",
            ));
        }
        if !(noise_scale > 0.0) || !noise_scale.is_finite() {
            return Err(Error::OutOfRange {
                setting: "scene prior noise scale".into(),
                value: noise_scale,
                expected: "a finite value > 0".into(),
            });
        }
        let all = if rows == 128 {
            u128::MAX
        } else {
            (1u128 << rows) - 1
        };
        let pixels = measurements.len() / rows;
        let keys: Vec<u128> = (0..pixels)
            .into_par_iter()
            .map(|px| {
                let s = &spectra[px * knots..(px + 1) * knots];
                if s.iter().any(|v| !v.is_finite()) {
                    return 0;
                }
                let p = &measurements[px * rows..(px + 1) * rows];
                let key = p
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| v.is_finite())
                    .fold(0u128, |key, (r, _)| key | 1 << r);
                if key == all {
                    0
                } else {
                    key
                }
            })
            .collect();
        let mut distinct = keys.clone();
        distinct.par_sort_unstable();
        distinct.dedup();
        // Floor the noise so that R stays positive definite.
        let noise = (self.noise * noise_scale).max(NOISE_FLOOR);
        let white: Vec<f64> = c.chunks_exact(knots).map(|row| row.iter().sum()).collect();
        let projected: Vec<Projected> = self
            .components
            .par_iter()
            .map(|component| Projected::new(component, c, rows, knots))
            .collect();
        let gains: HashMap<u128, Gains> = distinct
            .par_iter()
            .filter(|&&k| k != 0)
            .map(|&k| Gains::new(&projected, rows, &white, noise, k).map(|g| (k, g)))
            .collect::<Result<_>>()?;
        let components = self.components.len();
        // Pixels sorted by their set of rows and cut into batches that share it, so that
        // a batch's arithmetic runs across pixels (vectorised, cache-friendly).
        let mut order: Vec<usize> = (0..pixels).filter(|&px| keys[px] != 0).collect();
        order.par_sort_unstable_by_key(|&px| (keys[px], px));
        let mut batches = Vec::new();
        let mut start = 0;
        while start < order.len() {
            let key = keys[order[start]];
            let end = order[start..]
                .iter()
                .take(BATCH)
                .position(|&px| keys[px] != key)
                .map_or((start + BATCH).min(order.len()), |n| start + n);
            batches.push(start..end);
            start = end;
        }
        let estimates: Vec<Vec<Option<Vec<f32>>>> = batches
            .par_iter()
            .map(|range| {
                let pixels = &order[range.clone()];
                let gains = &gains[&keys[pixels[0]]];
                estimate_batch(gains, &projected, knots, rows, measurements, pixels)
            })
            .collect();
        let (mut filled, mut rejected) = (0, 0);
        for (range, estimates) in batches.iter().zip(estimates) {
            for (&px, estimate) in order[range.clone()].iter().zip(estimates) {
                match estimate {
                    Some(estimate) => {
                        spectra[px * knots..(px + 1) * knots].copy_from_slice(&estimate);
                        filled += 1;
                    }
                    None => rejected += 1,
                }
            }
        }
        Ok(ScenePriorReport {
            samples: self.samples,
            propagated_samples: 0,
            components,
            filled_pixels: filled,
            rejected_pixels: rejected,
            noise,
            carried: false,
        })
    }
}

fn check_shapes(rows: usize, knots: usize, measurements: &[f32], spectra: &[f32]) -> Result<()> {
    if rows == 0 || knots == 0 || !measurements.len().is_multiple_of(rows) {
        return Err(Error::Shape {
            op: "scene prior: measurements against rows".into(),
            got: vec![measurements.len()],
            expected: vec![rows],
        });
    }
    let pixels = measurements.len() / rows;
    if spectra.len() != pixels * knots {
        return Err(Error::Shape {
            op: "scene prior: spectra against pixels × knots".into(),
            got: vec![spectra.len()],
            expected: vec![pixels, knots],
        });
    }
    Ok(())
}
