//! Filter selection (paper section 3.2): choose `count` filters from a candidate library
//! so that the resulting sensing matrix is best for reconstruction. Two criteria:
//! - [`SelectionCriterion::Condition`], the paper's: minimise cond(C);
//! - [`SelectionCriterion::Noise`]: minimise the expected in-band RMSE of the regularised
//!   linear estimate `ŝ = (CᵀC + λDᵀD)⁻¹Cᵀp` over a prior of real reflectances under the
//!   sensor noise model: `E‖ŝ − s‖² = tr(E R Eᵀ) + tr(A Σ Aᵀ)` with `E = AC − I`, R the
//!   prior's second moment and Σ the noise covariance at the prior's mean signal.
//!
//! The search is exhaustive while the number of subsets is at most
//! [`EXHAUSTIVE_LIMIT`] (C(18, 8) = 43 758 takes seconds), otherwise greedy forward
//! selection followed by single swaps until no swap improves.

use crate::capture::CameraNoise;
use crate::demux::difference_gram;
use crate::rig::{EffectiveResponses, OutOfBand, SensingMatrix};
use crate::spectrum::{Interpolation, ResponseCurve, SpectralShape};
use crate::{Error, Result};
use faer::linalg::solvers::DenseSolveCore;
use rayon::prelude::*;
use serde::Serialize;

/// Largest number of subsets searched exhaustively.
pub const EXHAUSTIVE_LIMIT: u64 = 3_000_000;

/// What "best" means.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SelectionCriterion {
    /// Smallest cond(C) (the paper).
    Condition,
    /// Smallest expected reconstruction RMSE under noise.
    Noise,
}

crate::choice::named_choices!(SelectionCriterion, "selection criterion" {
    Condition = "condition" "Smallest cond(C), as the paper.",
    Noise = "noise" "Smallest expected reconstruction error under sensor noise.",
});

/// The noise model of the `Noise` criterion (per-measurement variance in C's units).
pub type NoiseModel = CameraNoise;

/// Search settings.
#[derive(Debug, Clone)]
pub struct SelectionOptions {
    pub count: usize,
    pub criterion: SelectionCriterion,
    pub noise: NoiseModel,
    pub lambda: f64,
    /// How many best subsets to report.
    pub keep: usize,
    /// Search exhaustively while the number of subsets is at most this
    /// (default [`EXHAUSTIVE_LIMIT`]); otherwise greedy selection plus swaps.
    pub exhaustive_limit: u64,
}

/// Scores of one subset.
#[derive(Debug, Clone, Serialize)]
pub struct SubsetScore {
    /// Indices into the candidate list, increasing.
    pub filters: Vec<usize>,
    pub condition_number: f64,
    /// Expected in-band RMSE of reflectance (the `Noise` criterion).
    pub expected_rmse: f64,
}

/// The outcome of a search.
#[derive(Debug, Clone, Serialize)]
pub struct SelectionReport {
    pub candidates: Vec<String>,
    pub exhaustive: bool,
    pub evaluated: u64,
    /// Best subsets, best first.
    pub best: Vec<SubsetScore>,
}

/// Precomputed per-candidate rows of C and the prior statistics.
struct Problem {
    n: usize,
    channels: usize,
    /// Rows of C per candidate, `channels × n` each, normalised per camera.
    rows: Vec<Vec<f64>>,
    /// Prior spectra on the knots, one per column (`n × count`).
    prior: faer::Mat<f64>,
    /// `DᵀD`, row-major `n × n`.
    difference_gram: Vec<f64>,
    /// Mean prior spectrum on the knots.
    mean: Vec<f64>,
    reported: std::ops::Range<usize>,
    lambda: f64,
    noise: NoiseModel,
}

fn binomial(n: usize, k: usize) -> u64 {
    let k = k.min(n - k);
    (0..k).fold(1u64, |acc, i| {
        acc.saturating_mul((n - i) as u64) / (i as u64 + 1)
    })
}

impl Problem {
    fn stacked(&self, subset: &[usize]) -> Vec<f64> {
        subset
            .iter()
            .flat_map(|&f| self.rows[f].iter().copied())
            .collect()
    }

    fn condition(&self, subset: &[usize]) -> f64 {
        let c = self.stacked(subset);
        let m = subset.len() * self.channels;
        let mat = faer::MatRef::from_row_major_slice(&c, m, self.n);
        match mat.singular_values() {
            Ok(sv) => crate::rig::condition_from_singular_values(&sv),
            Err(_) => f64::INFINITY,
        }
    }

    fn expected_rmse(&self, subset: &[usize]) -> f64 {
        use faer::linalg::matmul::matmul;
        use faer::{Accum, Mat, Par};
        let n = self.n;
        let stacked = self.stacked(subset);
        let m = subset.len() * self.channels;
        let c = faer::MatRef::from_row_major_slice(&stacked, m, n);
        // H = CᵀC + λDᵀD
        let mut h = Mat::from_fn(n, n, |i, j| self.lambda * self.difference_gram[i * n + j]);
        matmul(h.as_mut(), Accum::Add, c.transpose(), c, 1.0, Par::Seq);
        let Ok(llt) = h.llt(faer::Side::Lower) else {
            return f64::INFINITY;
        };
        let h_inv = llt.inverse();
        // A = (H⁻¹Cᵀ) on the reported rows; E = A C − I on those rows.
        let reported = self.reported.clone();
        let k = reported.len();
        let mut a = Mat::<f64>::zeros(k, m);
        matmul(
            a.as_mut(),
            Accum::Replace,
            h_inv.as_ref().subrows(reported.start, k),
            c.transpose(),
            1.0,
            Par::Seq,
        );
        let mut e = Mat::<f64>::zeros(k, n);
        matmul(e.as_mut(), Accum::Replace, a.as_ref(), c, 1.0, Par::Seq);
        for (row, i) in reported.clone().enumerate() {
            e[(row, i)] -= 1.0;
        }
        // Bias: mean over prior spectra of ‖E s‖², as ‖E S‖²_F / count.
        let samples = self.prior.ncols();
        let mut es = Mat::<f64>::zeros(k, samples);
        matmul(
            es.as_mut(),
            Accum::Replace,
            e.as_ref(),
            self.prior.as_ref(),
            1.0,
            Par::Seq,
        );
        let bias = es.norm_l2().powi(2) / samples as f64;
        // Variance at the mean signal: Σ_r σ_r² ‖A[:, r]‖².
        let mut variance = 0.0;
        for r in 0..m {
            let signal: f64 = stacked[r * n..(r + 1) * n]
                .iter()
                .zip(&self.mean)
                .map(|(c, s)| c * s)
                .sum();
            let sigma = self.noise.sigma(signal);
            let column: f64 = (0..k).map(|row| a[(row, r)].powi(2)).sum();
            variance += sigma * sigma * column;
        }
        ((bias + variance) / k as f64).sqrt()
    }

    fn score(&self, subset: &[usize], criterion: SelectionCriterion) -> f64 {
        match criterion {
            SelectionCriterion::Condition => self.condition(subset),
            SelectionCriterion::Noise => self.expected_rmse(subset),
        }
    }
}

/// The camera every candidate filter would sit in front of, and the reconstruction it
/// serves.
#[derive(Debug, Clone, Copy)]
pub struct SelectionCamera<'a> {
    pub sensor: &'a ResponseCurve,
    pub illuminant: Option<&'a ResponseCurve>,
    pub sensor_interpolation: Interpolation,
    /// The reconstruction bands.
    pub reported: SpectralShape,
    pub out_of_band: OutOfBand,
}

/// The reflectance prior of the noise criterion: the 99 test samples of CIE 224:2017's
/// colour-fidelity index (built in).
pub const SELECTION_PRIOR: &str = "tcs_cfi2017_99";

/// The built-in modelled gel library, the default candidates.
pub fn builtin_candidates() -> Result<Vec<ResponseCurve>> {
    crate::builtin::filter_names()
        .into_iter()
        .map(crate::builtin::filter)
        .collect()
}

/// [`select_filters`] for `sensor` (under `illuminant`) with the paper's reconstruction
/// bands, the sensor resampled by cubic spline and the [`SELECTION_PRIOR`].
pub fn select_for_sensor(
    candidates: &[ResponseCurve],
    sensor: &ResponseCurve,
    illuminant: Option<&ResponseCurve>,
    options: &SelectionOptions,
    out_of_band: OutOfBand,
) -> Result<SelectionReport> {
    if !(options.lambda.is_finite() && options.lambda >= 0.0) {
        return Err(Error::out_of_range(
            "lambda",
            options.lambda,
            "finite and >= 0",
        ));
    }
    let noise = &options.noise;
    if !(noise.full_well_electrons > 0.0 && noise.full_well_electrons.is_finite()) {
        let value = noise.full_well_electrons;
        return Err(Error::out_of_range(
            "full well (e-)",
            value,
            "positive and finite",
        ));
    }
    if !(noise.read_noise_electrons >= 0.0 && noise.read_noise_electrons.is_finite()) {
        let value = noise.read_noise_electrons;
        return Err(Error::out_of_range(
            "read noise (e-)",
            value,
            "finite and >= 0",
        ));
    }
    let prior = crate::builtin::reflectances(SELECTION_PRIOR)?;
    let camera = SelectionCamera {
        sensor,
        illuminant,
        sensor_interpolation: Interpolation::CubicSpline,
        reported: SpectralShape::PAPER_BANDS,
        out_of_band,
    };
    select_filters(candidates, &camera, &prior, options)
}

/// Chooses `options.count` of `candidates` for `camera`. `prior` is a set of reflectances
/// (one column each) for the noise criterion.
pub fn select_filters(
    candidates: &[ResponseCurve],
    camera: &SelectionCamera<'_>,
    prior: &ResponseCurve,
    options: &SelectionOptions,
) -> Result<SelectionReport> {
    let SelectionCamera {
        sensor,
        illuminant,
        sensor_interpolation,
        reported,
        out_of_band,
    } = *camera;
    let k = options.count;
    if k == 0 || k > candidates.len() {
        return Err(Error::setting(
            "filter selection",
            format!("count {k} with {} candidates", candidates.len()),
            format!("a count of 1 to {}", candidates.len()),
        ));
    }
    let cameras: Vec<(&ResponseCurve, &ResponseCurve, String)> = candidates
        .iter()
        .map(|f| (sensor, f, f.name().to_string()))
        .collect();
    let responses = EffectiveResponses::of_cameras(&cameras, illuminant, sensor_interpolation)?;
    let c = SensingMatrix::from_responses(&responses, reported, out_of_band)?;
    let n = c.cols();
    let channels = sensor.channel_count();
    let rows = (0..candidates.len())
        .map(|f| c.values()[f * channels * n..(f + 1) * channels * n].to_vec())
        .collect();
    // Prior on the knots (clamped at the ends of the data's range).
    let (lo, hi) = prior.domain();
    let knots: Vec<f64> = c
        .unknowns
        .wavelengths()
        .iter()
        .map(|w| w.clamp(lo, hi))
        .collect();
    let spectra: Vec<Vec<f64>> = (0..prior.channel_count())
        .map(|j| prior.sample(j, &knots, Interpolation::Linear))
        .collect::<Result<_>>()?;
    let count = spectra.len().max(1) as f64;
    let mut mean = vec![0.0; n];
    for spectrum in &spectra {
        for (m, v) in mean.iter_mut().zip(spectrum) {
            *m += v / count;
        }
    }
    let prior_matrix = faer::Mat::from_fn(n, spectra.len(), |i, j| spectra[j][i]);
    let problem = Problem {
        n,
        channels,
        rows,
        prior: prior_matrix,
        difference_gram: difference_gram(n),
        mean,
        reported: c.reported_offset..c.reported_offset + reported.count,
        lambda: options.lambda,
        noise: options.noise,
    };
    let total = binomial(candidates.len(), k);
    let exhaustive = total <= options.exhaustive_limit;
    let mut scored: Vec<(f64, Vec<usize>)> = if exhaustive {
        combinations(candidates.len(), k)
            .into_par_iter()
            .map(|s| (problem.score(&s, options.criterion), s))
            .collect()
    } else {
        greedy_with_swaps(&problem, candidates.len(), k, options.criterion)
    };
    let evaluated = if exhaustive {
        total
    } else {
        scored.len() as u64
    };
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    scored.dedup_by(|a, b| a.1 == b.1);
    let best = scored
        .into_iter()
        .take(options.keep.max(1))
        .map(|(_, filters)| SubsetScore {
            condition_number: problem.condition(&filters),
            expected_rmse: problem.expected_rmse(&filters),
            filters,
        })
        .collect();
    Ok(SelectionReport {
        candidates: candidates.iter().map(|c| c.name().to_string()).collect(),
        exhaustive,
        evaluated,
        best,
    })
}

/// All k-subsets of 0..n in lexicographic order.
fn combinations(n: usize, k: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    let mut idx: Vec<usize> = (0..k).collect();
    loop {
        out.push(idx.clone());
        let Some(i) = (0..k).rev().find(|&i| idx[i] != i + n - k) else {
            return out;
        };
        idx[i] += 1;
        for j in i + 1..k {
            idx[j] = idx[j - 1] + 1;
        }
    }
}

/// Greedy forward selection, then best-improvement single swaps; returns every subset scored.
fn greedy_with_swaps(
    problem: &Problem,
    n: usize,
    k: usize,
    criterion: SelectionCriterion,
) -> Vec<(f64, Vec<usize>)> {
    let mut seen = Vec::new();
    let mut chosen: Vec<usize> = Vec::new();
    while chosen.len() < k {
        let trials: Vec<(f64, Vec<usize>)> = (0..n)
            .into_par_iter()
            .filter(|f| !chosen.contains(f))
            .map(|f| {
                let mut s = chosen.clone();
                s.push(f);
                s.sort_unstable();
                // Underdetermined prefixes: rank by the noise score, which stays finite.
                (
                    problem.score(
                        &s,
                        if s.len() < k {
                            SelectionCriterion::Noise
                        } else {
                            criterion
                        },
                    ),
                    s,
                )
            })
            .collect();
        let best = trials
            .iter()
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .cloned()
            .unwrap_or_default();
        chosen = best.1;
        seen.extend(trials);
    }
    let mut current = (problem.score(&chosen, criterion), chosen);
    loop {
        let swaps: Vec<(f64, Vec<usize>)> = (0..k)
            .flat_map(|pos| (0..n).map(move |f| (pos, f)))
            .collect::<Vec<_>>()
            .into_par_iter()
            .filter(|(_, f)| !current.1.contains(f))
            .map(|(pos, f)| {
                let mut s = current.1.clone();
                s[pos] = f;
                s.sort_unstable();
                (problem.score(&s, criterion), s)
            })
            .collect();
        let best = swaps.iter().min_by(|a, b| a.0.total_cmp(&b.0)).cloned();
        seen.extend(swaps);
        match best {
            Some(b) if b.0 < current.0 => current = b,
            _ => break,
        }
    }
    seen.push(current);
    seen.into_iter().filter(|(_, s)| s.len() == k).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn combinations_are_complete_and_unique() {
        let all = combinations(6, 3);
        assert_eq!(all.len() as u64, binomial(6, 3));
        assert_eq!(all.first().unwrap(), &vec![0, 1, 2]);
        assert_eq!(all.last().unwrap(), &vec![3, 4, 5]);
        assert_eq!(binomial(18, 8), 43_758);
        assert_eq!(binomial(20, 8), 125_970);
    }
}
