//! A spectral prior learned from the scene itself, for pixels that some cameras do not
//! see (beyond the paper). Runs after demultiplexing, before the guided filter.
//!
//! Why: near a view's border and behind occluders, fewer cameras see a pixel, so it has
//! fewer measurements than bands; the smoothness term of Eq. 6 then decides the spectrum,
//! and a smooth spectrum is a poor guess. The pixels every camera sees are well
//! determined, and the same materials usually appear among them. Their spectra are
//! clustered (k-means) into a mixture of Gaussians, each with a weight, a mean μ_m and a
//! covariance Σ_m. Each under-measured pixel, with measurements P_a through the rows C_a
//! of C that see it, takes the posterior mean under that mixture: per component the
//! linear minimum mean square error estimate
//!
//! ŝ_m = μ_m + Σ_m C_aᵀ (C_a Σ_m C_aᵀ + R)⁻¹ (P_a − C_a μ_m),
//!
//! weighted by how well the component explains P_a, clamped to ŝ ≥ 0. R is the
//! measurement noise, estimated from the residuals of the complete pixels. With one
//! component this is the plain linear estimate under the scene's mean and covariance.
//! The prior comes from the reconstruction, not from a spectral library, so the
//! simulator's reflectance sets stay out of the reconstruction (no inverse crime).
//!
//! A pixel whose measurements no component finds plausible (the innovation
//! `P_a − C_a μ_m` far out in its χ² distribution: a wrong match, or a material the
//! complete pixels lack) keeps its Eq. 6 spectrum, since the estimate would extrapolate
//! wildly there. The gate is looser for pixels that at most a quarter of the rows see:
//! Eq. 6 has little to go on there, so falling back to it costs more.
//!
//! Some materials are never seen completely (a surface along the top of a view, which
//! the lower row of cameras cannot reach). Propagation rounds ([`ScenePrior::fill_view`])
//! add them: components learned from the filled estimates of pixels at least half the
//! rows see join the mixture, and every under-measured pixel is estimated again.
//!
//! In: C (rows × knots), a view's measurements (`pixels × rows`, NaN where not seen), its
//! spectra on all knots and their residuals ([`super::measurement_residuals`]). Out: the
//! spectra of incompletely measured pixels replaced in place.

use crate::{Error, Result};
use faer::{Mat, Side};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;
use std::collections::HashMap;
use std::ops::Range;

/// Pixels per rayon task.
const PIXELS_PER_TASK: usize = 4096;
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
const K_MEANS_RUNS: u64 = 2;
/// k-means fits its centres to at most this many of the samples.
const K_MEANS_SAMPLES: usize = 4096;
/// Lloyd iterations of k-means at most.
const K_MEANS_ITERATIONS: usize = 15;
/// The least measurement noise assumed (rms, reflectance units): 0.1 % of white.
const NOISE_FLOOR: f64 = 1e-3;
/// A propagation round clusters its samples into this many times fewer clusters than the
/// complete pixels (they hold the few materials the complete pixels lack): on the clutter
/// preset 8 instead of 32 gave the same PSNR (36.95 / 36.97 dB with true disparities) at
/// two thirds of the time.
const EXTENSION_CLUSTER_DIVISOR: usize = 4;
/// A cluster's covariance is shrunk towards the scene's with the weight of this many
/// samples, so that small clusters stay positive definite.
const SHRINKAGE_SAMPLES: f64 = 100.0;
/// Innovations beyond this many χ² standard deviations above their mean are outliers...
const GATE_SIGMAS: f64 = 4.0;
/// ...or this many, for pixels that at most a quarter of the rows see.
const SPARSE_GATE_SIGMAS: f64 = 16.0;
/// At most this many components enter one pixel's estimate.
const MAX_PER_PIXEL: usize = 8;
/// Components whose posterior weight falls below this fraction of the best one's are
/// left out of the estimate.
const NEGLIGIBLE_WEIGHT: f64 = 1e-2;

/// Settings of the scene prior, as recorded in the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScenePriorSettings {
    /// Multiplies the noise level learned from the complete pixels' residuals: larger
    /// trusts the measurements less and the prior's means more.
    pub noise_scale: f64,
    /// Clusters per k-means run; 1 gives a single Gaussian (the scene's mean and
    /// covariance).
    pub clusters: usize,
    /// Rounds that extend the mixture with the materials the complete pixels lack, from
    /// the pixels at least half the rows measure (see [`ScenePrior::fill_view`]); 0 keeps
    /// the complete pixels' mixture alone.
    pub propagation_rounds: usize,
    /// Before the prior: pixels whose residual exceeds this multiple of the complete
    /// pixels' median keep only their own capture's measurements
    /// ([`super::keep_own_where_inconsistent`]); 0 leaves every measurement in.
    pub inconsistency_factor: f64,
}

impl Default for ScenePriorSettings {
    fn default() -> Self {
        // Measured on the presets at 640×480 (README, "Scene prior"): noise scales of
        // 0.3 and 0.5 gain alike in PSNR, 0.5 keeps SSIM; 3 leans so hard on the mean that
        // it loses 7 dB. 32 clusters beat 16 and 64. Inconsistency factors 3, 4 and 6 gain
        // alike (within 0.2 dB on the clutter and periodic presets).
        ScenePriorSettings {
            noise_scale: 0.5,
            clusters: 32,
            propagation_rounds: 2,
            inconsistency_factor: 4.0,
        }
    }
}

/// What the prior did to one view, for the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScenePriorReport {
    /// Complete pixels whose spectra built the prior.
    pub samples: usize,
    /// Incompletely but well measured pixels (at least half the rows) whose estimates
    /// added components in the last propagation round.
    pub propagated_samples: usize,
    /// Gaussians in the mixture.
    pub components: usize,
    /// Pixels whose spectra were replaced by the prior's estimate.
    pub filled_pixels: usize,
    /// Under-measured pixels left as they were because the prior found their
    /// measurements implausible.
    pub rejected_pixels: usize,
    /// The measurement noise assumed, in reflectance units (rms per measurement).
    pub noise: f64,
    /// Pixels whose other cameras' measurements were masked as inconsistent before the
    /// prior ([`ScenePriorSettings::inconsistency_factor`]).
    pub inconsistent_pixels: usize,
}

/// Which pixels a prior learns from (besides a finite spectrum and residual).
struct Eligible {
    /// How many rows they have measured.
    measured: Range<usize>,
    /// A pixel whose residual exceeds this stays out even in the better half.
    max_residual: Option<f32>,
}

/// One Gaussian of the mixture.
#[derive(Debug, Clone)]
struct Component {
    /// Log of its share of the mixture.
    log_weight: f64,
    mean: Vec<f64>,
    /// `knots × knots`, row-major.
    covariance: Vec<f64>,
}

/// A mixture of Gaussians over the spectra of the trusted complete pixels.
#[derive(Debug, Clone)]
pub struct ScenePrior {
    knots: usize,
    components: Vec<Component>,
    samples: usize,
    /// Trusted pixels the samples were drawn from (an even subsample of at most
    /// `MAX_SAMPLES`): what a merged mixture weighs this one's components by.
    trusted: usize,
    /// Median residual of the trusted samples, reflectance units.
    noise: f64,
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
    fn learn_from(
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
            return Err(Error::invalid(
                "scene prior",
                "the mixture needs at least one cluster",
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
    fn merged(mut self, other: ScenePrior) -> ScenePrior {
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

    /// The whole stage for one view: learns the prior from the complete pixels and fills
    /// the under-measured ones, then propagates it `settings.propagation_rounds` times.
    ///
    /// Why propagate: a material the complete pixels lack (a surface near the top of the
    /// view, which the lower row of cameras cannot see) has no component, so its pixels
    /// take a wrong material's spectrum or fall back to Eq. 6. Where at least half the
    /// rows measure such a surface, its filled estimate is good (the clutter preset's
    /// pixels seen by the upper row alone: 38.4 dB). So each round learns further
    /// components from those pixels — incomplete, at least half the rows, residual no
    /// larger than the complete pixels' median — adds them to the complete pixels'
    /// mixture (weights by sample count), and refills every under-measured pixel.
    ///
    /// `residuals` (per pixel, [`super::measurement_residuals`]) must match `spectra` on
    /// entry and are updated to the final spectra. None when too few complete pixels
    /// qualify (the spectra are left alone).
    pub fn fill_view(
        c: &[f64],
        rows: usize,
        measurements: &[f32],
        spectra: &mut [f32],
        residuals: &mut Vec<f32>,
        settings: &ScenePriorSettings,
    ) -> Result<Option<ScenePriorReport>> {
        if rows == 0 || !c.len().is_multiple_of(rows) {
            return Err(Error::Shape {
                op: "scene prior: C against rows".into(),
                got: vec![c.len()],
                expected: vec![rows],
            });
        }
        let knots = c.len() / rows;
        let Some(prior) = Self::learn(
            rows,
            knots,
            measurements,
            spectra,
            residuals,
            settings.clusters,
        )?
        else {
            return Ok(None);
        };
        // Every round estimates all under-measured pixels again, so that a pixel the
        // extended mixture rejects keeps the previous round's estimate.
        let mut report =
            prior.fill_incomplete(c, rows, measurements, spectra, settings.noise_scale)?;
        *residuals = super::measurement_residuals(c, rows, measurements, spectra)?;
        for _ in 0..settings.propagation_rounds {
            let Some(extension) = Self::learn_from(
                rows,
                knots,
                measurements,
                spectra,
                residuals,
                settings.clusters.div_ceil(EXTENSION_CLUSTER_DIVISOR),
                Eligible {
                    measured: rows.div_ceil(2)..rows,
                    max_residual: Some(prior.noise.max(NOISE_FLOOR) as f32),
                },
            )?
            else {
                break;
            };
            let added = extension.samples;
            let extended = prior.clone().merged(extension);
            report =
                extended.fill_incomplete(c, rows, measurements, spectra, settings.noise_scale)?;
            report.samples = prior.samples;
            report.propagated_samples = added;
            *residuals = super::measurement_residuals(c, rows, measurements, spectra)?;
        }
        Ok(Some(report))
    }

    /// Replaces the spectra of pixels that have some but not all rows measured with the
    /// prior's estimate from their measurements. `noise_scale` multiplies the learned
    /// noise level (rms per measurement, reflectance units) to give R; each row's noise
    /// is that level times the row's response to a perfect white.
    pub fn fill_incomplete(
        &self,
        c: &[f64],
        rows: usize,
        measurements: &[f32],
        spectra: &mut [f32],
        noise_scale: f64,
    ) -> Result<ScenePriorReport> {
        let knots = self.knots;
        if c.len() != rows * knots {
            return Err(Error::Shape {
                op: "scene prior: C against rows × knots".into(),
                got: vec![c.len()],
                expected: vec![rows, knots],
            });
        }
        check_shapes(rows, knots, measurements, spectra)?;
        if rows > 128 {
            return Err(Error::invalid(
                "scene prior",
                format!("{rows} measurement rows; at most 128 are supported"),
            ));
        }
        if !(noise_scale > 0.0) || !noise_scale.is_finite() {
            return Err(Error::invalid(
                "scene prior",
                format!("noise scale {noise_scale} must be positive and finite"),
            ));
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
            inconsistent_pixels: 0,
        })
    }
}

/// The prior's estimates for a batch of pixels that share their measured rows: None
/// for a pixel whose measurements no component finds plausible. Runs the AVX2 + FMA build
/// where the CPU has them (about 3x over the baseline x86-64 one).
fn estimate_batch(
    gains: &Gains,
    projected: &[Projected],
    knots: usize,
    rows: usize,
    measurements: &[f32],
    pixels: &[usize],
) -> Vec<Option<Vec<f32>>> {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::has_avx2_fma() {
        // SAFETY: the CPU supports AVX2 and FMA (checked just above).
        return unsafe { estimate_batch_avx2(gains, projected, knots, rows, measurements, pixels) };
    }
    estimate_batch_body(gains, projected, knots, rows, measurements, pixels)
}

/// [`estimate_batch`] compiled for AVX2 and FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn estimate_batch_avx2(
    gains: &Gains,
    projected: &[Projected],
    knots: usize,
    rows: usize,
    measurements: &[f32],
    pixels: &[usize],
) -> Vec<Option<Vec<f32>>> {
    estimate_batch_body(gains, projected, knots, rows, measurements, pixels)
}

/// The body of [`estimate_batch`], inlined into each build.
#[inline(always)]
fn estimate_batch_body(
    gains: &Gains,
    projected: &[Projected],
    knots: usize,
    rows: usize,
    measurements: &[f32],
    pixels: &[usize],
) -> Vec<Option<Vec<f32>>> {
    let (n, a) = (pixels.len(), gains.rows.len());
    let components = gains.per_component.len();
    // Measurements, row by row across the batch.
    let mut measured = vec![0.0f64; a * n];
    for (row, &r) in measured.chunks_exact_mut(n).zip(&gains.rows) {
        for (v, &px) in row.iter_mut().zip(pixels) {
            *v = measurements[px * rows + r] as f64;
        }
    }
    let mut log_posterior = vec![0.0f64; components * n];
    let mut closest = vec![f64::INFINITY; n];
    let mut innovations = vec![0.0f64; a * n];
    let mut distances = vec![0.0f64; n];
    // Pixel by pixel: the log posterior weight of every component.
    for (m, gain) in gains.per_component.iter().enumerate() {
        for ((y, m), o) in innovations
            .chunks_exact_mut(n)
            .zip(measured.chunks_exact(n))
            .zip(&gain.offset)
        {
            y.iter_mut().zip(m).for_each(|(y, m)| *y = m - o);
        }
        gain.whiten_batch(&mut innovations, &mut distances);
        for (k, (c, d)) in closest.iter_mut().zip(&distances).enumerate() {
            *c = c.min(*d);
            log_posterior[k * components + m] = gain.log_weight - 0.5 * (gain.log_det + d);
        }
    }
    let mut y = vec![0.0f64; a];
    let mut pixel = vec![0.0f64; a];
    let mut best: Vec<(f64, usize)> = Vec::with_capacity(MAX_PER_PIXEL);
    let mut estimate = vec![0.0f64; knots];
    (0..n)
        .map(|k| {
            // Measurements no component finds plausible (a wrong match, a material the
            // complete pixels lack): the estimate would extrapolate wildly, so the pixel
            // keeps its Eq. 6 spectrum.
            if closest[k] > gains.gate {
                return None;
            }
            let log_posterior = log_posterior[k * components..(k + 1) * components]
                .iter()
                .copied();
            for (v, row) in pixel.iter_mut().zip(measured.chunks_exact(n)) {
                *v = row[k];
            }
            // The components that matter: the MAX_PER_PIXEL most probable, of those with
            // a posterior at least NEGLIGIBLE_WEIGHT of the best one's; their weights
            // renormalised. The cap bounds the cost where many components explain a pixel
            // alike (unstructured spectra).
            best.clear();
            for (m, l) in log_posterior.enumerate() {
                if best.len() < MAX_PER_PIXEL {
                    best.push((l, m));
                } else if l > best[MAX_PER_PIXEL - 1].0 {
                    best[MAX_PER_PIXEL - 1] = (l, m);
                } else {
                    continue;
                }
                best.sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
            }
            let top = best[0].0;
            let floor = top + NEGLIGIBLE_WEIGHT.ln();
            best.retain(|&(l, _)| l >= floor);
            let kept: f64 = best.iter().map(|&(l, _)| (l - top).exp()).sum();
            estimate.iter_mut().for_each(|e| *e = 0.0);
            for &(l, m) in &best {
                let (gain, component) = (&gains.per_component[m], &projected[m]);
                let weight = (l - top).exp() / kept;
                for ((y, m), o) in y.iter_mut().zip(&pixel).zip(&gain.offset) {
                    *y = m - o;
                }
                gain.whiten(&mut y);
                gain.unwhiten(&mut y);
                // μ + Σ C_aᵀ y, with Σ C_aᵀ the rows `rows` of C Σ, transposed.
                for (e, m) in estimate.iter_mut().zip(component.mean) {
                    *e += weight * m;
                }
                for (&r, &y) in gains.rows.iter().zip(&y) {
                    let row = &component.c_sigma[r * knots..(r + 1) * knots];
                    for (e, v) in estimate.iter_mut().zip(row) {
                        *e += weight * y * v;
                    }
                }
            }
            Some(estimate.iter().map(|e| e.max(0.0) as f32).collect())
        })
        .collect()
}

/// A component seen through C: its mean, `C Σ` and `C Σ Cᵀ`.
struct Projected<'a> {
    log_weight: f64,
    mean: &'a [f64],
    /// `C μ`, rows.
    c_mean: Vec<f64>,
    /// `C Σ`, rows × knots, row-major.
    c_sigma: Vec<f64>,
    /// `C Σ Cᵀ`, rows × rows, row-major.
    c_sigma_ct: Vec<f64>,
}

impl<'a> Projected<'a> {
    fn new(component: &'a Component, c: &[f64], rows: usize, knots: usize) -> Self {
        let c_mean = c
            .chunks_exact(knots)
            .map(|row| row.iter().zip(&component.mean).map(|(a, b)| a * b).sum())
            .collect();
        let mut c_sigma = vec![0.0; rows * knots];
        for (out, row) in c_sigma.chunks_exact_mut(knots).zip(c.chunks_exact(knots)) {
            for (k, &ck) in row.iter().enumerate() {
                let sigma_row = &component.covariance[k * knots..(k + 1) * knots];
                out.iter_mut()
                    .zip(sigma_row)
                    .for_each(|(o, s)| *o += ck * s);
            }
        }
        let c_sigma_ct = (0..rows * rows)
            .map(|k| {
                let (i, j) = (k / rows, k % rows);
                c_sigma[i * knots..(i + 1) * knots]
                    .iter()
                    .zip(&c[j * knots..(j + 1) * knots])
                    .map(|(a, b)| a * b)
                    .sum()
            })
            .collect();
        Projected {
            log_weight: component.log_weight,
            mean: &component.mean,
            c_mean,
            c_sigma,
            c_sigma_ct,
        }
    }
}

/// What the estimate needs for one set of measured rows: per component, the innovation's
/// offset and the Cholesky factor of its covariance.
struct Gains {
    rows: Vec<usize>,
    per_component: Vec<Gain>,
    /// Largest squared Mahalanobis distance of an innovation the estimate accepts.
    gate: f64,
}

impl Gains {
    fn new(
        projected: &[Projected],
        all_rows: usize,
        white: &[f64],
        noise: f64,
        key: u128,
    ) -> Result<Gains> {
        let rows: Vec<usize> = (0..all_rows).filter(|&r| key & (1 << r) != 0).collect();
        let a = rows.len();
        let per_component = projected
            .iter()
            .map(|component| {
                let system = Mat::from_fn(a, a, |i, j| {
                    let value = component.c_sigma_ct[rows[i] * all_rows + rows[j]];
                    if i == j {
                        value + (noise * white[rows[i]]).powi(2)
                    } else {
                        value
                    }
                });
                let llt = system.llt(Side::Lower).map_err(|_| {
                    Error::invalid(
                        "scene prior",
                        "the prior's measurement covariance is not positive definite",
                    )
                })?;
                let factor = llt.L();
                let mut lower = Vec::with_capacity(a * (a + 1) / 2);
                for j in 0..a {
                    lower.extend((j..a).map(|i| factor[(i, j)]));
                }
                let log_det = 2.0 * (0..a).map(|i| factor[(i, i)].ln()).sum::<f64>();
                Ok(Gain {
                    log_weight: component.log_weight,
                    offset: rows.iter().map(|&r| component.c_mean[r]).collect(),
                    lower,
                    log_det,
                })
            })
            .collect::<Result<_>>()?;
        // Squared Mahalanobis distances of consistent measurements follow χ² with `a`
        // degrees of freedom: mean a, standard deviation √(2a).
        let sigmas = if 4 * a <= all_rows {
            SPARSE_GATE_SIGMAS
        } else {
            GATE_SIGMAS
        };
        let gate = a as f64 + sigmas * (2.0 * a as f64).sqrt();
        Ok(Gains {
            rows,
            per_component,
            gate,
        })
    }
}

/// One component's share of [`Gains`].
struct Gain {
    log_weight: f64,
    /// `C_a μ`, the measurements the component's mean spectrum would give.
    offset: Vec<f64>,
    /// The Cholesky factor L of `C_a Σ C_aᵀ + R`, lower triangle packed by columns
    /// (each from its diagonal down).
    lower: Vec<f64>,
    /// `ln det (C_a Σ C_aᵀ + R)`.
    log_det: f64,
}

impl Gain {
    /// Replaces x by `L⁻¹ x` and returns its squared norm, the squared Mahalanobis
    /// distance `xᵀ (C_a Σ C_aᵀ + R)⁻¹ x`. Column by column, so the inner loop is an
    /// axpy that vectorises.
    #[inline(always)]
    fn whiten(&self, x: &mut [f64]) -> f64 {
        let mut column = self.lower.as_slice();
        let mut distance = 0.0;
        for j in 0..x.len() {
            let (below, rest) = x[j..].split_at_mut(1);
            let value = below[0] / column[0];
            below[0] = value;
            distance += value * value;
            for (v, l) in rest.iter_mut().zip(&column[1..]) {
                *v -= l * value;
            }
            column = &column[x.len() - j..];
        }
        distance
    }

    /// [`Gain::whiten`] for a batch: `x` holds the innovations row by row across the
    /// batch (`a × n`), `distances` receives the n squared distances.
    #[inline(always)]
    fn whiten_batch(&self, x: &mut [f64], distances: &mut [f64]) {
        let n = distances.len();
        let a = x.len() / n;
        distances.iter_mut().for_each(|d| *d = 0.0);
        let mut column = self.lower.as_slice();
        for j in 0..a {
            let (head, rest) = x[j * n..].split_at_mut(n);
            let inverse = 1.0 / column[0];
            for (v, d) in head.iter_mut().zip(distances.iter_mut()) {
                *v *= inverse;
                *d += *v * *v;
            }
            for (row, l) in rest.chunks_exact_mut(n).zip(&column[1..]) {
                row.iter_mut().zip(&*head).for_each(|(v, h)| *v -= l * h);
            }
            column = &column[a - j..];
        }
    }

    /// Replaces z by `L⁻ᵀ z`: after [`Gain::whiten`], x becomes `(L Lᵀ)⁻¹ x`.
    #[inline(always)]
    fn unwhiten(&self, z: &mut [f64]) {
        let a = z.len();
        let mut end = self.lower.len();
        for j in (0..a).rev() {
            // Column j of L, from the diagonal down, is row j of Lᵀ from the diagonal on.
            let column = &self.lower[end - (a - j)..end];
            let partial: f64 = column[1..]
                .iter()
                .zip(&z[j + 1..])
                .map(|(l, v)| l * v)
                .sum();
            z[j] = (z[j] - partial) / column[0];
            end -= a - j;
        }
    }
}

/// Mean and covariance of the given spectra (`n × knots`, row-major): per chunk of
/// pixels the column sums and the product Xᵀ X (one `matmul`), summed over chunks.
fn gaussian_of(spectra: &[f64], knots: usize, log_weight: f64) -> Component {
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
fn k_means(spectra: &[f64], knots: usize, k: usize, seed: u64) -> Vec<Vec<f64>> {
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
fn nearest_centre(point: &[f64], centres: &[Vec<f64>]) -> usize {
    centres
        .iter()
        .map(|c| squared_distance(point, c))
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(0, |(c, _)| c)
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

#[cfg(test)]
mod tests {
    use super::*;
    use faer::linalg::solvers::Solve;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Spectra on 6 knots from a rank-2 model `μ + B z`, seen through 6 positive rows;
    /// pixels whose index is a multiple of 3 lose rows 2..6.
    fn low_rank_scene(pixels: usize) -> (Vec<f64>, Vec<f32>, Vec<f32>, Vec<f32>) {
        let (rows, knots) = (6, 6);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let c: Vec<f64> = (0..rows * knots)
            .map(|_| rng.random_range(0.1..1.0))
            .collect();
        let mean = [0.4, 0.45, 0.5, 0.5, 0.45, 0.4];
        let basis = [
            [0.1, 0.1, 0.1, 0.1, 0.1, 0.1],
            [0.1, 0.06, 0.02, -0.02, -0.06, -0.1],
        ];
        let mut truth = Vec::with_capacity(pixels * knots);
        let mut measurements = Vec::with_capacity(pixels * rows);
        for px in 0..pixels {
            let z: [f64; 2] = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
            let s: Vec<f64> = (0..knots)
                .map(|k| mean[k] + z[0] * basis[0][k] + z[1] * basis[1][k])
                .collect();
            for row in c.chunks_exact(knots) {
                let value: f64 = row.iter().zip(&s).map(|(a, b)| a * b).sum();
                let seen = px % 3 != 0 || measurements.len() % rows < 2;
                measurements.push(if seen { value as f32 } else { f32::NAN });
            }
            truth.extend(s.iter().map(|&v| v as f32));
        }
        // What Eq. 6 would leave for the under-measured pixels: a flat guess.
        let spectra: Vec<f32> = truth
            .chunks_exact(knots)
            .enumerate()
            .flat_map(|(px, s)| {
                let flat = s.iter().sum::<f32>() / knots as f32;
                s.iter()
                    .map(move |&v| if px % 3 == 0 { flat } else { v })
                    .collect::<Vec<_>>()
            })
            .collect();
        (c, measurements, spectra, truth)
    }

    #[test]
    fn a_low_rank_scene_is_recovered_from_two_measurements() {
        let pixels = 3000;
        let (c, measurements, mut spectra, truth) = low_rank_scene(pixels);
        let residuals: Vec<f32> = (0..pixels)
            .map(|px| if px % 3 == 0 { 0.0 } else { 1e-4 })
            .collect();
        let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, 1)
            .unwrap()
            .unwrap();
        assert_eq!(prior.samples, 2000);
        let complete_before: Vec<f32> = spectra
            .chunks_exact(6)
            .enumerate()
            .filter(|(px, _)| px % 3 != 0)
            .flat_map(|(_, s)| s.to_vec())
            .collect();
        let report = prior
            .fill_incomplete(&c, 6, &measurements, &mut spectra, 1.0)
            .unwrap();
        assert_eq!((report.filled_pixels, report.rejected_pixels), (1000, 0));
        assert_eq!(report.noise, 1e-3);
        let mut worst = 0.0f32;
        for (px, (s, t)) in spectra
            .chunks_exact(6)
            .zip(truth.chunks_exact(6))
            .enumerate()
        {
            if px % 3 == 0 {
                for (a, b) in s.iter().zip(t) {
                    worst = worst.max((a - b).abs());
                }
            }
        }
        // Two measurements pin a rank-2 model: errors of the noise floor's order (1e-3
        // of white) instead of the flat guess's 0.2.
        assert!(worst < 0.01, "worst error {worst}");
        let complete_after: Vec<f32> = spectra
            .chunks_exact(6)
            .enumerate()
            .filter(|(px, _)| px % 3 != 0)
            .flat_map(|(_, s)| s.to_vec())
            .collect();
        assert_eq!(complete_before, complete_after);
    }

    #[test]
    fn measurements_the_prior_finds_implausible_keep_their_spectrum() {
        let pixels = 3000;
        let (c, mut measurements, mut spectra, _) = low_rank_scene(pixels);
        let residuals = vec![1e-4f32; pixels];
        let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, 1)
            .unwrap()
            .unwrap();
        // Pixel 0 sees rows 0 and 1; make them disagree (as a wrong match would).
        measurements[0] *= 3.0;
        let before = spectra[..6].to_vec();
        let report = prior
            .fill_incomplete(&c, 6, &measurements, &mut spectra, 1.0)
            .unwrap();
        assert_eq!((report.filled_pixels, report.rejected_pixels), (999, 1));
        assert_eq!(&spectra[..6], &before[..]);
    }

    #[test]
    fn more_assumed_noise_leans_on_the_mean() {
        let pixels = 3000;
        let (c, measurements, spectra, truth) = low_rank_scene(pixels);
        let residuals = vec![1e-4f32; pixels];
        let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, 1)
            .unwrap()
            .unwrap();
        let error_with = |scale: f64| {
            let mut filled = spectra.clone();
            prior
                .fill_incomplete(&c, 6, &measurements, &mut filled, scale)
                .unwrap();
            let mut sum = 0.0f64;
            for (px, (s, t)) in filled
                .chunks_exact(6)
                .zip(truth.chunks_exact(6))
                .enumerate()
            {
                if px % 3 == 0 {
                    sum += s
                        .iter()
                        .zip(t)
                        .map(|(a, b)| ((a - b) as f64).powi(2))
                        .sum::<f64>();
                }
            }
            (sum / 6000.0).sqrt()
        };
        let (sharp, vague) = (error_with(1.0), error_with(1e4));
        // A noise of 1 (white) swamps the measurements: the estimate is the scene's mean,
        // whose error is the spread of the spectra (about 0.08 rms).
        assert!(sharp < 0.005 && vague > 0.05, "{sharp} {vague}");
    }

    #[test]
    fn too_few_complete_pixels_give_no_prior_and_bad_input_is_refused() {
        let (c, measurements, mut spectra, _) = low_rank_scene(150);
        let residuals = vec![0.0f32; 150];
        // 100 complete pixels: under 20 per knot.
        assert!(
            ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, 1)
                .unwrap()
                .is_none()
        );
        assert!(ScenePrior::learn(6, 6, &measurements, &spectra[1..], &residuals, 1).is_err());
        assert!(ScenePrior::learn(6, 6, &measurements, &spectra, &residuals[1..], 1).is_err());
        let (_, m, s, _) = low_rank_scene(3000);
        let prior = ScenePrior::learn(6, 6, &m, &s, &vec![0.0; 3000], 1)
            .unwrap()
            .unwrap();
        assert!(prior
            .fill_incomplete(&c, 6, &measurements, &mut spectra, 0.0)
            .is_err());
        assert!(prior
            .fill_incomplete(&c, 6, &measurements, &mut spectra, f64::NAN)
            .is_err());
        assert!(prior
            .fill_incomplete(&c[1..], 6, &measurements, &mut spectra, 1.0)
            .is_err());
        assert!(ScenePrior::learn(6, 6, &m, &s, &vec![0.0; 3000], 0).is_err());
    }

    /// Two materials on 6 knots, each varying along its own direction, seen through 6
    /// rows; pixels whose index is a multiple of 3 keep rows 0 and 1 only.
    fn two_material_scene(pixels: usize) -> (Vec<f64>, Vec<f32>, Vec<f32>, Vec<f32>) {
        let (rows, knots) = (6, 6);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let c: Vec<f64> = (0..rows * knots)
            .map(|_| rng.random_range(0.1..1.0))
            .collect();
        let means = [
            [0.2, 0.25, 0.3, 0.5, 0.7, 0.8],
            [0.7, 0.6, 0.4, 0.3, 0.25, 0.2],
        ];
        let directions = [
            [0.1, -0.1, 0.1, -0.1, 0.1, -0.1],
            [0.0, 0.1, 0.1, -0.1, -0.1, 0.0],
        ];
        let mut truth = Vec::with_capacity(pixels * knots);
        let mut measurements = Vec::with_capacity(pixels * rows);
        for px in 0..pixels {
            let material = usize::from(rng.random_bool(0.5));
            let z: f64 = rng.random_range(-1.0..1.0);
            let s: Vec<f64> = (0..knots)
                .map(|k| means[material][k] + z * directions[material][k])
                .collect();
            for (r, row) in c.chunks_exact(knots).enumerate() {
                let value: f64 = row.iter().zip(&s).map(|(a, b)| a * b).sum();
                let seen = px % 3 != 0 || r < 2;
                measurements.push(if seen { value as f32 } else { f32::NAN });
            }
            truth.extend(s.iter().map(|&v| v as f32));
        }
        let spectra: Vec<f32> = truth
            .chunks_exact(knots)
            .enumerate()
            .flat_map(|(px, s)| {
                let flat = s.iter().sum::<f32>() / knots as f32;
                s.iter()
                    .map(move |&v| if px % 3 == 0 { flat } else { v })
                    .collect::<Vec<_>>()
            })
            .collect();
        (c, measurements, spectra, truth)
    }

    /// Root mean square error over the under-measured pixels of `two_material_scene`.
    fn under_measured_error(spectra: &[f32], truth: &[f32]) -> f64 {
        let (mut sum, mut count) = (0.0f64, 0);
        for (px, (s, t)) in spectra
            .chunks_exact(6)
            .zip(truth.chunks_exact(6))
            .enumerate()
        {
            if px % 3 == 0 {
                sum += s
                    .iter()
                    .zip(t)
                    .map(|(a, b)| ((a - b) as f64).powi(2))
                    .sum::<f64>();
                count += 6;
            }
        }
        (sum / count as f64).sqrt()
    }

    #[test]
    fn a_mixture_recovers_what_one_gaussian_blurs() {
        let pixels = 3000;
        let (c, measurements, spectra, truth) = two_material_scene(pixels);
        let residuals = vec![1e-4f32; pixels];
        let error_with = |clusters: usize| {
            let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, clusters)
                .unwrap()
                .unwrap();
            let mut filled = spectra.clone();
            let report = prior
                .fill_incomplete(&c, 6, &measurements, &mut filled, 1.0)
                .unwrap();
            assert_eq!(report.filled_pixels + report.rejected_pixels, 1000);
            (under_measured_error(&filled, &truth), report)
        };
        let (single, single_report) = error_with(1);
        let (mixture, mixture_report) = error_with(2);
        assert_eq!(single_report.components, 1);
        // Two clusters from each of the k-means runs.
        assert_eq!(mixture_report.components, 2 * K_MEANS_RUNS as usize);
        assert_eq!(mixture_report.rejected_pixels, 0);
        // Two measurements cannot pin the three directions the scene's covariance spans
        // (the two materials' own variations and the step between them); they pin one
        // material's single direction once the mixture has told the materials apart.
        assert!(mixture < 0.005, "mixture {mixture}");
        assert!(single > 5.0 * mixture, "single {single}, mixture {mixture}");
        // The flat guess it started from.
        assert!(under_measured_error(&spectra, &truth) > 0.1);
    }

    #[test]
    fn propagation_adds_a_material_the_complete_pixels_lack() {
        // Material 0 is seen completely where px % 3 != 0; material 1 never is: rows 0..4
        // there (at least half, and their spectra as good as Eq. 6 from four rows would
        // give), rows 0 and 1 alone where px % 3 == 0 (as for material 0).
        let (rows, knots, pixels) = (6, 6, 6000);
        let (c, mut measurements, mut spectra, truth) = two_material_scene(pixels);
        let material_of = |s: &[f32]| usize::from(s[0] > s[5]);
        for px in 0..pixels {
            let t = &truth[px * knots..(px + 1) * knots];
            if material_of(t) == 1 && px % 3 != 0 {
                measurements[px * rows + 4..(px + 1) * rows].fill(f32::NAN);
                spectra[px * knots..(px + 1) * knots].copy_from_slice(t);
            }
        }
        let error_with = |rounds: usize| {
            let mut filled = spectra.clone();
            let mut residuals =
                crate::refine::measurement_residuals(&c, rows, &measurements, &filled).unwrap();
            let settings = ScenePriorSettings {
                noise_scale: 1.0,
                clusters: 2,
                propagation_rounds: rounds,
                inconsistency_factor: 0.0,
            };
            let report = ScenePrior::fill_view(
                &c,
                rows,
                &measurements,
                &mut filled,
                &mut residuals,
                &settings,
            )
            .unwrap()
            .unwrap();
            // The residuals follow the final spectra.
            let expected =
                crate::refine::measurement_residuals(&c, rows, &measurements, &filled).unwrap();
            assert_eq!(residuals, expected);
            let (mut sum, mut count) = (0.0f64, 0);
            for px in (0..pixels).step_by(3) {
                let t = &truth[px * knots..(px + 1) * knots];
                if material_of(t) == 1 {
                    let s = &filled[px * knots..(px + 1) * knots];
                    sum += s
                        .iter()
                        .zip(t)
                        .map(|(a, b)| ((a - b) as f64).powi(2))
                        .sum::<f64>();
                    count += knots;
                }
            }
            ((sum / count as f64).sqrt(), report)
        };
        let (alone, alone_report) = error_with(0);
        let (propagated, report) = error_with(2);
        assert_eq!(alone_report.propagated_samples, 0);
        assert!(report.propagated_samples > 500, "{report:?}");
        assert!(report.components > alone_report.components, "{report:?}");
        // Without the material, its two-row pixels are rejected (keeping the flat guess)
        // or pulled towards the other material.
        // (Measured: 0.19 without, 0.0045 with.)
        assert!(alone > 0.1, "without propagation {alone}");
        assert!(propagated < 0.01, "with propagation {propagated}");
    }

    #[test]
    fn whitening_solves_against_the_cholesky_factor() {
        let a = 5;
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let m = Mat::from_fn(a, a, |_, _| rng.random_range(-1.0..1.0));
        let system = &m * m.transpose() + Mat::<f64>::identity(a, a);
        let llt = system.llt(Side::Lower).unwrap();
        let mut lower = Vec::new();
        for j in 0..a {
            lower.extend((j..a).map(|i| llt.L()[(i, j)]));
        }
        let gain = Gain {
            log_weight: 0.0,
            offset: vec![0.0; a],
            lower,
            log_det: 0.0,
        };
        let n = 3;
        let batch: Vec<Vec<f64>> = (0..n)
            .map(|_| (0..a).map(|_| rng.random_range(-1.0..1.0)).collect())
            .collect();
        let mut rows_across = vec![0.0; a * n];
        for (k, x) in batch.iter().enumerate() {
            for (i, v) in x.iter().enumerate() {
                rows_across[i * n + k] = *v;
            }
        }
        let mut distances = vec![0.0; n];
        gain.whiten_batch(&mut rows_across, &mut distances);
        for (k, x) in batch.iter().enumerate() {
            let expected = llt.solve(Mat::from_fn(a, 1, |i, _| x[i]));
            let quadratic: f64 = (0..a).map(|i| x[i] * expected[(i, 0)]).sum();
            let mut y = x.clone();
            let distance = gain.whiten(&mut y);
            for (i, v) in y.iter().enumerate() {
                assert!((v - rows_across[i * n + k]).abs() < 1e-12);
            }
            gain.unwhiten(&mut y);
            assert!(
                (distance - quadratic).abs() < 1e-10,
                "{distance} {quadratic}"
            );
            assert!((distances[k] - quadratic).abs() < 1e-10);
            for (i, v) in y.iter().enumerate() {
                assert!(
                    (v - expected[(i, 0)]).abs() < 1e-10,
                    "{v} {}",
                    expected[(i, 0)]
                );
            }
        }
    }
}
