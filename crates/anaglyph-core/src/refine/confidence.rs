//! How much the guided refinement trusts each pixel: how well one spectrum explains the
//! measurements warped to it. A misregistered pixel (an occlusion border, a wrong match)
//! gathers measurements of different surfaces, which no single spectrum reproduces, so its
//! residual `‖P − Cŝ‖` stands out from the noise floor of the view.
//!
//! In: C, a view's measurements (`pixels × rows`, NaN where not visible) and the solved
//! spectra on all of C's knots. Out: the rms residual per pixel in reflectance units
//! (each row divided by its response to a perfect white), and weights
//! `1 / (1 + (ρ / σ)²)` with σ a multiple of the view's median residual.

use crate::{Error, Result};
use rayon::prelude::*;

/// Pixels per rayon task.
const PIXELS_PER_TASK: usize = 4096;

/// The rms residual of each pixel's measured rows, in reflectance units; NaN where the
/// pixel has no measurement or no finite spectrum.
pub fn measurement_residuals(
    c: &[f64],
    rows: usize,
    measurements: &[f32],
    spectra: &[f32],
) -> Result<Vec<f32>> {
    if rows == 0 || !c.len().is_multiple_of(rows) || !measurements.len().is_multiple_of(rows) {
        return Err(Error::Shape {
            op: "residuals: C and measurements against the rows of C".into(),
            got: vec![c.len(), measurements.len()],
            expected: vec![rows],
        });
    }
    let cols = c.len() / rows;
    let pixels = measurements.len() / rows;
    if spectra.len() != pixels * cols {
        return Err(Error::Shape {
            op: "residuals: spectra against pixels × knots of C".into(),
            got: vec![spectra.len()],
            expected: vec![pixels, cols],
        });
    }
    let white: Vec<f64> = c
        .chunks_exact(cols)
        .map(|row| {
            let sum: f64 = row.iter().sum();
            if sum > 0.0 {
                1.0 / sum
            } else {
                0.0
            }
        })
        .collect();
    // Cᵀ, so that a chunk's predictions are one product: (pixels × knots) · (knots × rows).
    let c_t: Vec<f64> = (0..cols * rows)
        .map(|k| c[(k % rows) * cols + k / rows])
        .collect();
    let mut residuals = vec![f32::NAN; pixels];
    residuals
        .par_chunks_mut(PIXELS_PER_TASK)
        .zip(measurements.par_chunks(PIXELS_PER_TASK * rows))
        .zip(spectra.par_chunks(PIXELS_PER_TASK * cols))
        .for_each_init(
            || (Vec::new(), Vec::new()),
            |(spectra64, predicted): &mut (Vec<f64>, Vec<f64>), ((out, p), s)| {
                let n = out.len();
                spectra64.clear();
                spectra64.extend(s.iter().map(|&v| v as f64));
                predicted.resize(n * rows, 0.0);
                faer::linalg::matmul::matmul(
                    faer::MatMut::from_row_major_slice_mut(predicted, n, rows),
                    faer::Accum::Replace,
                    faer::MatRef::from_row_major_slice(spectra64, n, cols),
                    faer::MatRef::from_row_major_slice(&c_t, cols, rows),
                    1.0,
                    faer::Par::Seq,
                );
                for (((value, p), s), predicted) in out
                    .iter_mut()
                    .zip(p.chunks_exact(rows))
                    .zip(s.chunks_exact(cols))
                    .zip(predicted.chunks_exact(rows))
                {
                    if s.iter().any(|v| !v.is_finite()) {
                        continue;
                    }
                    let (mut sum, mut count) = (0.0f64, 0usize);
                    for ((&p, &predicted), &white) in p.iter().zip(predicted).zip(&white) {
                        if p.is_finite() {
                            sum += ((p as f64 - predicted) * white).powi(2);
                            count += 1;
                        }
                    }
                    if count > 0 {
                        *value = (sum / count as f64).sqrt() as f32;
                    }
                }
            },
        );
    Ok(residuals)
}

/// Confidence weights `1 / (1 + (ρ / σ)²)` with `σ = scale × median ρ` (0 where ρ is not
/// finite), and that median.
pub fn confidence_weights(residuals: &[f32], scale: f64) -> Result<(Vec<f32>, f64)> {
    if !(scale > 0.0) || !scale.is_finite() {
        return Err(Error::invalid(
            "refinement confidence",
            format!("scale {scale} (expected a finite value > 0)"),
        ));
    }
    let mut finite: Vec<f32> = residuals
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    if finite.is_empty() {
        return Ok((vec![0.0; residuals.len()], f64::NAN));
    }
    let middle = finite.len() / 2;
    let median = *finite.select_nth_unstable_by(middle, f32::total_cmp).1 as f64;
    // A noise-free view can fit exactly: keep σ above rounding.
    let sigma = (scale * median).max(1e-7);
    let weights = residuals
        .iter()
        .map(|&r| {
            if r.is_finite() {
                (1.0 / (1.0 + (r as f64 / sigma).powi(2))) as f32
            } else {
                0.0
            }
        })
        .collect();
    Ok((weights, median))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residuals_are_zero_for_explained_measurements_and_flag_a_mixture() {
        // Two rows, two knots: C = [[1, 1], [2, 0]]; white responses 2 and 2.
        let c = [1.0, 1.0, 2.0, 0.0];
        let s = [0.3f32, 0.5, 0.3, 0.5, 0.3, 0.5];
        let p = [
            0.8f32,
            0.6, // explained exactly
            0.8,
            0.6 + 0.2, // row 1 off by 0.2 (0.1 in reflectance)
            f32::NAN,
            0.6, // one row missing, the other explained
        ];
        let r = measurement_residuals(&c, 2, &p, &s).unwrap();
        assert!(r[0].abs() < 1e-7);
        assert!(
            (r[1] - (0.1f32.powi(2) / 2.0).sqrt()).abs() < 1e-6,
            "{}",
            r[1]
        );
        assert!(r[2].abs() < 1e-7);
        assert!(measurement_residuals(&c, 2, &p, &s[..4]).is_err());
    }

    #[test]
    fn weights_fall_with_the_residual_relative_to_the_median() {
        let residuals = [0.01f32, 0.01, 0.01, 0.02, f32::NAN, 0.1];
        let (w, median) = confidence_weights(&residuals, 1.0).unwrap();
        assert!((median - 0.01).abs() < 1e-9);
        assert!((w[0] - 0.5).abs() < 1e-6);
        assert!((w[3] - 0.2).abs() < 1e-6);
        assert_eq!(w[4], 0.0);
        assert!(w[5] < 0.01);
        assert!(confidence_weights(&residuals, 0.0).is_err());
    }
}
