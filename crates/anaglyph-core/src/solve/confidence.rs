//! How much the guided refinement trusts each pixel: how well one spectrum explains the
//! measurements warped to it ([`super::measurement_residuals`]).
//!
//! In: a view's residuals. Out: weights `1 / (1 + (ρ / σ)²)` with σ a multiple of the
//! view's median residual, and that median (reported per view in the manifest).

use super::residuals::median;
use super::{SolveStage, ViewSolve};
use crate::{Error, Result};

/// The stage: the view's confidence weights for the guided filter.
#[derive(Debug, Clone, Copy)]
pub struct Confidence {
    /// σ is this multiple of the view's median residual.
    pub scale: f64,
}

impl SolveStage for Confidence {
    fn name(&self) -> &'static str {
        "confidence"
    }

    fn needs_residuals(&self) -> bool {
        true
    }

    fn run(&self, solve: &mut ViewSolve<'_>) -> Result<()> {
        let given = solve.statistics.confidence_median;
        let residuals = solve.residuals_mut(self.name())?;
        let (weights, median) = weights_against(residuals, self.scale, given)?;
        solve.statistics.confidence_median = Some(median);
        solve.weights = Some(weights);
        solve.report.median_residual = Some(median);
        Ok(())
    }
}

/// Confidence weights `1 / (1 + (ρ / σ)²)` with `σ = scale × median ρ` (0 where ρ is not
/// finite), and that median.
pub fn confidence_weights(residuals: &[f32], scale: f64) -> Result<(Vec<f32>, f64)> {
    weights_against(residuals, scale, None)
}

/// [`confidence_weights`] against a `given` median residual (None: the residuals' own).
fn weights_against(residuals: &[f32], scale: f64, given: Option<f64>) -> Result<(Vec<f32>, f64)> {
    if !(scale > 0.0) || !scale.is_finite() {
        return Err(Error::OutOfRange {
            setting: "refinement confidence".into(),
            value: scale,
            expected: "a finite value > 0".into(),
        });
    }
    let median = given.or_else(|| {
        let mut finite: Vec<f32> = residuals
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .collect();
        median(&mut finite).map(f64::from)
    });
    let Some(median) = median.filter(|m| m.is_finite()) else {
        return Ok((vec![0.0; residuals.len()], f64::NAN));
    };
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
    fn weights_fall_with_the_residual_relative_to_the_median() {
        let residuals = [0.01f32, 0.01, 0.01, 0.02, f32::NAN, 0.1];
        let (w, median) = confidence_weights(&residuals, 1.0).unwrap();
        assert!((median - 0.01).abs() < 1e-9);
        assert!((w[0] - 0.5).abs() < 1e-6);
        assert!((w[3] - 0.2).abs() < 1e-6);
        assert_eq!(w[4], 0.0);
        assert!(w[5] < 0.01);
        assert!(matches!(
            confidence_weights(&residuals, 0.0),
            Err(Error::OutOfRange { .. })
        ));
    }
}
