//! A spectral prior learned from the scene itself, for pixels that some cameras do not
//! see (beyond the paper). Runs after demultiplexing, before the guided filter.
//!
//! Why: near a view's border and behind occluders, fewer cameras see a pixel, so it has
//! fewer measurements than bands; the smoothness term of Eq. 6 then decides the spectrum,
//! and a smooth spectrum is a poor guess. The pixels every camera sees are well
//! determined, and the same materials usually appear among them. Their spectra give a
//! mean μ and covariance Σ, and each under-measured pixel takes the linear minimum mean
//! square error estimate from its own measurements P_a:
//!
//! ŝ = μ + Σ C_aᵀ (C_a Σ C_aᵀ + R)⁻¹ (P_a − C_a μ),  clamped to ŝ ≥ 0,
//!
//! R the measurement noise, estimated from the residuals of the complete pixels. The
//! prior comes from the reconstruction, not from a spectral library, so the simulator's
//! reflectance sets stay out of the reconstruction (no inverse crime). A pixel whose
//! measurements the prior finds implausible (the innovation `P_a − C_a μ` far out in its
//! χ² distribution: a wrong match, or a material the complete pixels lack) keeps its
//! Eq. 6 spectrum, since the linear estimate would extrapolate wildly there.
//!
//! In: C (rows × knots), a view's measurements (`pixels × rows`, NaN where not seen), its
//! spectra on all knots and their residuals ([`super::measurement_residuals`]). Out: the
//! spectra of incompletely measured pixels replaced in place.

use crate::{Error, Result};
use faer::linalg::solvers::Solve;
use faer::{Mat, Side};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::HashMap;

/// Pixels per rayon task.
const PIXELS_PER_TASK: usize = 4096;
/// At most this many complete pixels enter the mean and covariance (an even subsample).
const MAX_SAMPLES: usize = 1 << 16;
/// Fewer trusted complete pixels than this many per knot: no prior (the view keeps the
/// demultiplexed spectra).
const SAMPLES_PER_KNOT: usize = 20;
/// Innovations beyond this many χ² standard deviations above their mean are outliers.
const GATE_SIGMAS: f64 = 4.0;

/// Settings of the scene prior, as recorded in the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScenePriorSettings {
    /// Multiplies the noise level learned from the complete pixels' residuals: larger
    /// trusts the measurements less and the prior's mean more.
    pub noise_scale: f64,
}

impl Default for ScenePriorSettings {
    fn default() -> Self {
        // Measured on the presets at 640×480 (README, "Scene prior"): 0.3 and 0.5 gain
        // alike in PSNR, 0.5 keeps SSIM; 3 leans so hard on the mean that it loses 7 dB.
        ScenePriorSettings { noise_scale: 0.5 }
    }
}

/// What the prior did to one view, for the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScenePriorReport {
    /// Complete pixels whose spectra built the prior.
    pub samples: usize,
    /// Pixels whose spectra were replaced by the prior's estimate.
    pub filled_pixels: usize,
    /// Under-measured pixels left as they were because the prior found their
    /// measurements implausible.
    pub rejected_pixels: usize,
    /// The measurement noise assumed, in reflectance units (rms per measurement).
    pub noise: f64,
}

/// Mean and covariance of the trusted complete pixels' spectra.
#[derive(Debug, Clone)]
pub struct ScenePrior {
    knots: usize,
    mean: Vec<f64>,
    /// `knots × knots`, row-major.
    covariance: Vec<f64>,
    samples: usize,
    /// Median residual of the trusted samples, reflectance units.
    noise: f64,
}

impl ScenePrior {
    /// Learns the prior from the pixels where every row is measured, the spectrum is
    /// finite and the residual is at most the median of such pixels (the better half:
    /// misregistered pixels stay out). None when too few pixels qualify.
    pub fn learn(
        rows: usize,
        knots: usize,
        measurements: &[f32],
        spectra: &[f32],
        residuals: &[f32],
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
        let complete: Vec<usize> = (0..pixels)
            .into_par_iter()
            .filter(|&px| {
                residuals[px].is_finite()
                    && measurements[px * rows..(px + 1) * rows]
                        .iter()
                        .all(|v| v.is_finite())
                    && spectra[px * knots..(px + 1) * knots]
                        .iter()
                        .all(|v| v.is_finite())
            })
            .collect();
        if complete.is_empty() {
            return Ok(None);
        }
        let mut sorted: Vec<f32> = complete.iter().map(|&px| residuals[px]).collect();
        let middle = sorted.len() / 2;
        let median = *sorted.select_nth_unstable_by(middle, f32::total_cmp).1;
        let trusted: Vec<usize> = complete
            .into_iter()
            .filter(|&px| residuals[px] <= median)
            .collect();
        if trusted.len() < SAMPLES_PER_KNOT * knots {
            return Ok(None);
        }
        let stride = trusted.len().div_ceil(MAX_SAMPLES);
        let samples: Vec<usize> = trusted.into_iter().step_by(stride).collect();
        let (sum, outer) = samples
            .par_chunks(PIXELS_PER_TASK)
            .map(|chunk| {
                let mut sum = vec![0.0f64; knots];
                let mut outer = vec![0.0f64; knots * knots];
                let mut s = vec![0.0f64; knots];
                for &px in chunk {
                    for (v, &x) in s.iter_mut().zip(&spectra[px * knots..(px + 1) * knots]) {
                        *v = x as f64;
                    }
                    for i in 0..knots {
                        sum[i] += s[i];
                        let row = &mut outer[i * knots..(i + 1) * knots];
                        for (o, &sj) in row.iter_mut().zip(&s) {
                            *o += s[i] * sj;
                        }
                    }
                }
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
        let n = samples.len() as f64;
        let mean: Vec<f64> = sum.iter().map(|s| s / n).collect();
        let covariance: Vec<f64> = (0..knots * knots)
            .map(|k| outer[k] / n - mean[k / knots] * mean[k % knots])
            .collect();
        Ok(Some(ScenePrior {
            knots,
            mean,
            covariance,
            samples: samples.len(),
            noise: median as f64,
        }))
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
        // Floor the noise at 0.1 % of white so that R stays positive definite.
        let noise = (self.noise * noise_scale).max(1e-3);
        let white: Vec<f64> = c.chunks_exact(knots).map(|row| row.iter().sum()).collect();
        let gains: HashMap<u128, Gain> = distinct
            .par_iter()
            .filter(|&&k| k != 0)
            .map(|&k| self.gain(c, &white, noise, k).map(|g| (k, g)))
            .collect::<Result<_>>()?;
        let (filled, rejected) = spectra
            .par_chunks_mut(PIXELS_PER_TASK * knots)
            .zip(measurements.par_chunks(PIXELS_PER_TASK * rows))
            .zip(keys.par_chunks(PIXELS_PER_TASK))
            .map(|((s, p), keys)| {
                let (mut filled, mut rejected) = (0, 0);
                for ((s, p), key) in s
                    .chunks_exact_mut(knots)
                    .zip(p.chunks_exact(rows))
                    .zip(keys)
                {
                    let Some(gain) = gains.get(key) else {
                        continue;
                    };
                    let a = gain.rows.len();
                    let mut innovation = [0.0f64; 128];
                    for ((v, &r), o) in innovation
                        .iter_mut()
                        .zip(&gain.rows)
                        .zip(&gain.innovation_offset)
                    {
                        *v = p[r] as f64 - o;
                    }
                    let innovation = &innovation[..a];
                    // Measurements the prior finds implausible (a wrong match, a material
                    // the complete pixels lack): the linear estimate would extrapolate
                    // wildly, so the pixel keeps its Eq. 6 spectrum.
                    let distance: f64 = gain
                        .innovation_precision
                        .chunks_exact(a)
                        .zip(innovation)
                        .map(|(row, x)| {
                            x * row.iter().zip(innovation).map(|(q, y)| q * y).sum::<f64>()
                        })
                        .sum();
                    if distance > gain.gate {
                        rejected += 1;
                        continue;
                    }
                    for (k, out) in s.iter_mut().enumerate() {
                        let g = &gain.matrix[k * a..(k + 1) * a];
                        let update: f64 = g.iter().zip(innovation).map(|(g, x)| g * x).sum();
                        *out = (self.mean[k] + update).max(0.0) as f32;
                    }
                    filled += 1;
                }
                (filled, rejected)
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        Ok(ScenePriorReport {
            samples: self.samples,
            filled_pixels: filled,
            rejected_pixels: rejected,
            noise,
        })
    }

    /// The gain `Σ C_aᵀ (C_a Σ C_aᵀ + R)⁻¹` for the rows in `key`.
    fn gain(&self, c: &[f64], white: &[f64], noise: f64, key: u128) -> Result<Gain> {
        let knots = self.knots;
        let rows: Vec<usize> = (0..128).filter(|&r| key & (1 << r) != 0).collect();
        let a = rows.len();
        // C_a Σ, a × knots.
        let c_sigma = Mat::from_fn(a, knots, |i, j| {
            let row = &c[rows[i] * knots..(rows[i] + 1) * knots];
            (0..knots)
                .map(|k| row[k] * self.covariance[k * knots + j])
                .sum::<f64>()
        });
        let system = Mat::from_fn(a, a, |i, j| {
            let row = &c[rows[j] * knots..(rows[j] + 1) * knots];
            let value: f64 = (0..knots).map(|k| c_sigma[(i, k)] * row[k]).sum();
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
        // (C_a Σ C_aᵀ + R)⁻¹ C_a Σ, a × knots; its transpose is the gain.
        let solved = llt.solve(&c_sigma);
        let precision = llt.solve(Mat::<f64>::identity(a, a));
        let innovation_precision: Vec<f64> =
            (0..a * a).map(|k| precision[(k / a, k % a)]).collect();
        let mut matrix = vec![0.0; knots * a];
        for k in 0..knots {
            for i in 0..a {
                matrix[k * a + i] = solved[(i, k)];
            }
        }
        let innovation_offset: Vec<f64> = rows
            .iter()
            .map(|&r| {
                let row = &c[r * knots..(r + 1) * knots];
                row.iter().zip(&self.mean).map(|(a, b)| a * b).sum()
            })
            .collect();
        // Squared Mahalanobis distances of consistent measurements follow χ² with `a`
        // degrees of freedom: mean a, standard deviation √(2a).
        let gate = a as f64 + GATE_SIGMAS * (2.0 * a as f64).sqrt();
        Ok(Gain {
            rows,
            matrix,
            innovation_offset,
            innovation_precision,
            gate,
        })
    }
}

/// The estimate's linear map for one set of measured rows.
struct Gain {
    rows: Vec<usize>,
    /// `knots × rows.len()`, row-major.
    matrix: Vec<f64>,
    /// `C_a μ`, the measurements the mean spectrum would give.
    innovation_offset: Vec<f64>,
    /// `(C_a Σ C_aᵀ + R)⁻¹`, `rows.len()²`: the inverse covariance of the innovation.
    innovation_precision: Vec<f64>,
    /// Largest squared Mahalanobis distance of an innovation the estimate accepts.
    gate: f64,
}

fn check_shapes(rows: usize, knots: usize, measurements: &[f32], spectra: &[f32]) -> Result<()> {
    if rows == 0 || knots == 0 || measurements.len() % rows != 0 {
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
        let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals)
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
        let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals)
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
        let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals)
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
        assert!(ScenePrior::learn(6, 6, &measurements, &spectra, &residuals)
            .unwrap()
            .is_none());
        assert!(ScenePrior::learn(6, 6, &measurements, &spectra[1..], &residuals).is_err());
        assert!(ScenePrior::learn(6, 6, &measurements, &spectra, &residuals[1..]).is_err());
        let (_, m, s, _) = low_rank_scene(3000);
        let prior = ScenePrior::learn(6, 6, &m, &s, &vec![0.0; 3000])
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
    }
}
