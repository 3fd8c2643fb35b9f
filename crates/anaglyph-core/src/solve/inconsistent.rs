//! Pixels whose warped measurements no single spectrum explains keep only their own
//! capture's (beyond the paper). Runs after demultiplexing, before the scene prior
//! ([`super::ScenePriorStage`]), which then estimates them from what is left.
//!
//! Why: a pixel that registration got wrong gathers the other cameras' measurements of
//! other surfaces. Demultiplexing fits one spectrum to all of them, and the compromise is
//! wrong in every band. The view's own capture needs no warping, so it is right whatever
//! the disparity. Where the rms residual `‖P − Cŝ‖` exceeds `factor` times the median
//! residual of the view's completely measured pixels, the other cameras' measurements are
//! masked as not seen (never invented), the pixel is solved again from its own channels,
//! and the scene prior replaces that solve with its estimate from the same channels
//! through the spectra of the view's well-measured pixels. On the periodic preset, where
//! the cameras of one row match a grating half a period off, this takes the reference
//! view from 29.8 to 34.0 dB (docs/reconstruction.md, "Inconsistent pixels"). In a view with too few
//! complete pixels to learn a prior, they keep the solve from their own channels.
//!
//! In: C, a view's measurements (`pixels × rows`, NaN where not seen), the rows of its own
//! capture, its spectra on all knots and their residuals. Out: the measurements, spectra
//! and residuals of the inconsistent pixels replaced in place; how many there were.

use super::{check_at_least, measurement_residuals, median_of_complete, SolveStage, ViewSolve};
use crate::demux::demultiplex_as;
use crate::Result;

/// The stage: pixels whose residual exceeds `factor` × the noise floor keep only their own
/// capture's measurements.
#[derive(Debug, Clone, Copy)]
pub struct InconsistentPixels {
    pub factor: f64,
}

impl SolveStage for InconsistentPixels {
    fn name(&self) -> &'static str {
        "inconsistent pixels"
    }

    fn needs_residuals(&self) -> bool {
        true
    }

    fn run(&self, solve: &mut ViewSolve<'_>) -> Result<()> {
        let changed = keep_own_where_inconsistent(solve, self.factor)?;
        solve.report.inconsistent_pixels = Some(changed);
        Ok(())
    }
}

/// Masks the other cameras' measurements of every pixel whose residual exceeds `factor`
/// times the median residual of the completely measured pixels, and solves those pixels
/// again from the view's own rows alone; their residuals are recomputed. Returns how many
/// pixels changed; none when no pixel is completely measured. The solve must hold every
/// knot of C and its residuals.
pub fn keep_own_where_inconsistent(solve: &mut ViewSolve<'_>, factor: f64) -> Result<usize> {
    check_at_least("inconsistency factor", factor, f64::MIN_POSITIVE)?;
    solve.check_full("inconsistent pixels")?;
    let context = solve.context;
    let rows = context.sensing.rows();
    let knots = solve.knots.len();
    let own = context.camera_rows[solve.camera].clone();
    let residuals = solve.residuals.as_deref().unwrap_or_default();
    let median = solve
        .statistics
        .inconsistent_median
        .or_else(|| median_of_complete(residuals, &solve.measurements, rows));
    solve.statistics.inconsistent_median = median;
    let Some(median) = median else {
        return Ok(0);
    };
    let limit = factor as f32 * median;
    let inconsistent: Vec<usize> = solve
        .measurements
        .chunks_exact(rows)
        .zip(residuals)
        .enumerate()
        .filter(|(_, (measured, &residual))| {
            residual > limit
                && measured
                    .iter()
                    .enumerate()
                    .any(|(r, m)| m.is_finite() && !own.contains(&r))
        })
        .map(|(px, _)| px)
        .collect();
    if inconsistent.is_empty() {
        return Ok(0);
    }
    let mut own_only = Vec::with_capacity(inconsistent.len() * rows);
    for &px in &inconsistent {
        for (r, m) in solve.measurements[px * rows..(px + 1) * rows]
            .iter_mut()
            .enumerate()
        {
            if !own.contains(&r) {
                *m = f32::NAN;
            }
            own_only.push(*m);
        }
    }
    let (solved_again, _) = demultiplex_as::<f32, f32>(
        context.sensing.values(),
        rows,
        &own_only,
        None,
        solve.knots.clone(),
        &context.options,
    )?;
    for (i, &px) in inconsistent.iter().enumerate() {
        solve.spectra[px * knots..(px + 1) * knots]
            .copy_from_slice(&solved_again[i * knots..(i + 1) * knots]);
    }
    let again = measurement_residuals(context.sensing, &own_only, &solved_again)?;
    let residuals = solve.residuals_mut("inconsistent pixels")?;
    for (&px, value) in inconsistent.iter().zip(again) {
        residuals[px] = value;
    }
    Ok(inconsistent.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::test_support::{context, demultiplexed, matrix};
    use crate::Error;

    /// Six rows over eight knots (two cameras of three channels), smooth spectra, small
    /// noise; pixel 5's second camera reads another surface.
    fn scene() -> (Vec<f64>, Vec<f32>) {
        let (rows, knots, pixels) = (6, 8, 40);
        let c: Vec<f64> = (0..rows * knots)
            .map(|k| {
                let (r, j) = ((k / knots) as f64, (k % knots) as f64);
                (-(j - 1.4 * r).powi(2) / 6.0).exp() + 0.05
            })
            .collect();
        let mut measurements = Vec::with_capacity(pixels * rows);
        for px in 0..pixels {
            let s: Vec<f64> = (0..knots)
                .map(|j| 0.3 + 0.2 * ((j as f64 * 0.4) + px as f64).sin())
                .collect();
            for r in 0..rows {
                let noise = 1e-3 * ((px * 7 + r * 3) as f64).sin();
                let mut p: f64 = c[r * knots..(r + 1) * knots]
                    .iter()
                    .zip(&s)
                    .map(|(a, b)| a * b)
                    .sum();
                if px == 5 && r >= 3 {
                    p = 0.2 * p + 0.9; // a brighter surface of another colour
                }
                measurements.push((p + noise) as f32);
            }
        }
        (c, measurements)
    }

    #[test]
    fn a_pixel_that_gathered_another_surface_keeps_its_own_measurements() {
        let (c, measurements) = scene();
        let (rows, knots) = (6, 8);
        let sensing = matrix(rows, c.clone());
        let context = context(&sensing, vec![0..3, 3..6]);
        let before = measurements.clone();
        let mut solve = demultiplexed(&context, measurements, vec![false; 80]);
        let residuals = solve.residuals.clone().unwrap();
        let worst = residuals
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .unwrap()
            .0;
        assert_eq!(worst, 5, "the corrupted pixel stands out: {residuals:?}");
        let changed = keep_own_where_inconsistent(&mut solve, 4.0).unwrap();
        assert_eq!(changed, 1);
        for px in 0..before.len() / rows {
            for r in 0..rows {
                let (now, was) = (solve.measurements[px * rows + r], before[px * rows + r]);
                if px == 5 && r >= 3 {
                    assert!(now.is_nan(), "pixel 5 row {r} is masked");
                } else {
                    assert_eq!(now.to_bits(), was.to_bits(), "pixel {px} row {r} is kept");
                }
            }
        }
        // Solved from its own three channels alone, the pixel fits them again.
        let residual = solve.residuals.as_ref().unwrap()[5];
        assert!(residual < 1e-3, "residual after the mask: {residual}");
        let own_fit: f32 = (0..3)
            .map(|r| {
                let p: f32 = c[r * knots..(r + 1) * knots]
                    .iter()
                    .zip(&solve.spectra[5 * knots..6 * knots])
                    .map(|(a, b)| *a as f32 * b)
                    .sum();
                (p - solve.measurements[5 * rows + r]).abs()
            })
            .fold(0.0, f32::max);
        assert!(own_fit < 2e-3, "own channels reproduced within {own_fit}");
    }

    #[test]
    fn bad_settings_and_shapes_are_refused() {
        let (c, measurements) = scene();
        let sensing = matrix(6, c);
        let context = context(&sensing, vec![0..3, 3..6]);
        let mut solve = demultiplexed(&context, measurements, vec![false; 80]);
        for factor in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                keep_own_where_inconsistent(&mut solve, factor),
                Err(Error::OutOfRange { .. })
            ));
        }
        solve.measurements.truncate(6 * 10);
        assert!(matches!(
            keep_own_where_inconsistent(&mut solve, 4.0),
            Err(Error::Shape { .. })
        ));
        solve.residuals = None;
        assert!(matches!(
            keep_own_where_inconsistent(&mut solve, 4.0),
            Err(Error::StageDependency { .. })
        ));
    }
}
