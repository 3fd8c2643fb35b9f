//! The residual of a pixel's solve, `‖P − Cŝ‖`, the truth-free measure every later stage of
//! the solve reads: a misregistered pixel gathers measurements of different surfaces,
//! which no single spectrum reproduces, so its residual stands out from the view's noise
//! floor.
//!
//! In: C, a view's measurements (`pixels × rows`, NaN where not visible) and the solved
//! spectra on all of C's knots. Out: the rms residual per pixel in reflectance units
//! (each row divided by its response to a perfect white), and the median over the pixels
//! every row measures (the noise floor the stages compare against).

use crate::rig::SensingMatrix;
use crate::{Error, Result};
use rayon::prelude::*;

/// Pixels per rayon task.
const PIXELS_PER_TASK: usize = 4096;

/// The rms residual of each pixel's measured rows, in reflectance units; NaN where the
/// pixel has no measurement or no finite spectrum. `spectra` hold every knot of C.
pub fn measurement_residuals(
    sensing: &SensingMatrix,
    measurements: &[f32],
    spectra: &[f32],
) -> Result<Vec<f32>> {
    let (rows, cols) = (sensing.rows(), sensing.cols());
    let pixels = measurements.len() / rows;
    if measurements.len() != pixels * rows || spectra.len() != pixels * cols {
        return Err(Error::Shape {
            op: "residuals: measurements and spectra against pixels × (rows, knots) of C".into(),
            got: vec![measurements.len(), spectra.len()],
            expected: vec![pixels * rows, pixels * cols],
        });
    }
    let c = sensing.values();
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
                    *value = pixel_residual(p, s, predicted, &white);
                }
            },
        );
    Ok(residuals)
}

/// The rms of one pixel's white-normalised misfit over its measured rows.
fn pixel_residual(measured: &[f32], spectrum: &[f32], predicted: &[f64], white: &[f64]) -> f32 {
    if spectrum.iter().any(|v| !v.is_finite()) {
        return f32::NAN;
    }
    let (mut sum, mut count) = (0.0f64, 0usize);
    for ((&p, &predicted), &white) in measured.iter().zip(predicted).zip(white) {
        if p.is_finite() {
            sum += ((p as f64 - predicted) * white).powi(2);
            count += 1;
        }
    }
    if count > 0 {
        (sum / count as f64).sqrt() as f32
    } else {
        f32::NAN
    }
}

/// The median residual of the pixels whose every row is measured and whose residual is
/// finite (None when there are none): the view's noise floor.
pub fn median_of_complete(residuals: &[f32], measurements: &[f32], rows: usize) -> Option<f32> {
    let mut complete: Vec<f32> = residuals
        .iter()
        .zip(measurements.chunks_exact(rows))
        .filter(|(r, p)| r.is_finite() && p.iter().all(|m| m.is_finite()))
        .map(|(&r, _)| r)
        .collect();
    median(&mut complete)
}

/// The upper median of `values` (None when empty), reordering them.
pub(crate) fn median(values: &mut [f32]) -> Option<f32> {
    if values.is_empty() {
        return None;
    }
    let middle = values.len() / 2;
    Some(*values.select_nth_unstable_by(middle, f32::total_cmp).1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::test_support::matrix;

    #[test]
    fn residuals_are_zero_for_explained_measurements_and_flag_a_mixture() {
        // Two rows, two knots: C = [[1, 1], [2, 0]]; white responses 2 and 2.
        let c = matrix(2, vec![1.0, 1.0, 2.0, 0.0]);
        let s = [0.3f32, 0.5, 0.3, 0.5, 0.3, 0.5];
        let p = [
            0.8f32,
            0.6, // explained exactly
            0.8,
            0.6 + 0.2, // row 1 off by 0.2 (0.1 in reflectance)
            f32::NAN,
            0.6, // one row missing, the other explained
        ];
        let r = measurement_residuals(&c, &p, &s).unwrap();
        assert!(r[0].abs() < 1e-7);
        assert!(
            (r[1] - (0.1f32.powi(2) / 2.0).sqrt()).abs() < 1e-6,
            "{}",
            r[1]
        );
        assert!(r[2].abs() < 1e-7);
        assert!(matches!(
            measurement_residuals(&c, &p, &s[..4]),
            Err(Error::Shape { .. })
        ));
    }

    #[test]
    fn the_noise_floor_is_the_median_of_completely_measured_pixels() {
        let residuals = [0.3f32, 0.1, f32::NAN, 0.2, 9.0];
        let measurements = [1.0f32, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, f32::NAN];
        // Pixels 0, 1 and 3 count (2 has no residual, 4 misses a row): median 0.2.
        assert_eq!(median_of_complete(&residuals, &measurements, 2), Some(0.2));
        assert_eq!(median_of_complete(&[f32::NAN], &[1.0, 1.0], 2), None);
    }
}
