//! The scene prior's estimate of the pixels that share one set of measured rows: per
//! component the linear minimum mean square error estimate, weighted by how well the
//! component explains the measurements, gated against implausible innovations.
//!
//! In: the mixture's components seen through C ([`Projected`]), the gains of one set of
//! rows ([`Gains`]), a batch of pixels' measurements. Out: each pixel's estimate, or None
//! where no component finds its measurements plausible.

use super::gaussian::Component;
use super::whitening::Gain;
use crate::{Error, Result};
use faer::{Mat, Side};

/// Innovations beyond this many χ² standard deviations above their mean are outliers...
const GATE_SIGMAS: f64 = 4.0;
/// ...or this many, for pixels that at most a quarter of the rows see.
const SPARSE_GATE_SIGMAS: f64 = 16.0;
/// At most this many components enter one pixel's estimate.
const MAX_PER_PIXEL: usize = 8;
/// Components whose posterior weight falls below this fraction of the best one's are
/// left out of the estimate.
const NEGLIGIBLE_WEIGHT: f64 = 1e-2;

/// The prior's estimates for a batch of pixels that share their measured rows: None
/// for a pixel whose measurements no component finds plausible. Runs the AVX2 + FMA build
/// where the CPU has them (about 3x over the baseline x86-64 one).
pub(super) fn estimate_batch(
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
pub(super) struct Projected<'a> {
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
    pub(super) fn new(component: &'a Component, c: &[f64], rows: usize, knots: usize) -> Self {
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
pub(super) struct Gains {
    rows: Vec<usize>,
    per_component: Vec<Gain>,
    /// Largest squared Mahalanobis distance of an innovation the estimate accepts.
    gate: f64,
}

impl Gains {
    pub(super) fn new(
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
                let llt = system.llt(Side::Lower).map_err(|_| Error::LinearAlgebra {
                    op: "scene prior".into(),
                    message: "the prior's measurement covariance is not positive definite".into(),
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
