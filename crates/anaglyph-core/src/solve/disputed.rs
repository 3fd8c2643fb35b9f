//! Disputed measurements are kept only where they agree with the rest (beyond the paper).
//! Runs right after demultiplexing, before [`super::InconsistentPixels`].
//!
//! Why: on a repetitive surface each view's registration picks one of several disparities
//! a whole period apart, and different views pick different ones. The warp's visibility
//! test compares the reference's disparity with the source camera's own map, so it would
//! mask most of the array there, although the reference's disparity, a period off, reads
//! the same values. With [`crate::register::Admission::DepthOrder`] such measurements are
//! admitted as disputed when the reference's own depth order finds no nearer surface in
//! the way. Sometimes it is the reference's map that is wrong (a period off for one row of
//! cameras but not the other), and then the disputed measurements read other surfaces.
//! So each pixel with a disputed measurement is solved twice: with them and without. The
//! pixel keeps them only if its rms residual `‖P − Cŝ‖` with them stays within
//! `tolerance` times the larger of its residual without them and the median residual of
//! the view's completely measured pixels (the noise floor). On the periodic preset's
//! reference view this takes PSNR from 34.1 to about 35 dB, with the other presets within
//! 0.1 dB (docs/reconstruction.md, "Disputed measurements").
//!
//! In: C, a view's measurements (`pixels × rows`, NaN where not seen), which camera's
//! measurements are disputed (`pixels × cameras`), each camera's rows, the spectra on all
//! knots and their residuals. Out: measurements, spectra and residuals of the pixels whose
//! disputed measurements disagree, replaced in place by the solve without them.

use super::{check_at_least, measurement_residuals, median_of_complete, SolveStage, ViewSolve};
use crate::demux::demultiplex_as;
use crate::{Error, Result};
use serde::Serialize;

/// The stage: disputed measurements kept where the residual with them stays within
/// `tolerance` × the larger of the residual without them and the view's noise floor.
#[derive(Debug, Clone, Copy)]
pub struct DisputedMeasurements {
    pub tolerance: f64,
}

impl SolveStage for DisputedMeasurements {
    fn name(&self) -> &'static str {
        "disputed measurements"
    }

    fn needs_residuals(&self) -> bool {
        true
    }

    fn run(&self, solve: &mut ViewSolve<'_>) -> Result<()> {
        let report = revert_disputed(solve, self.tolerance)?;
        solve.report.disputed = Some(report);
        Ok(())
    }
}

/// What [`revert_disputed`] did to a view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct DisputedReport {
    /// Pixels with at least one disputed measurement.
    pub pixels: usize,
    /// Of those, the pixels whose disputed measurements were dropped.
    pub dropped: usize,
}

/// Solves every pixel with a disputed measurement again without its disputed cameras'
/// rows, and keeps that solve where the residual with them exceeds `tolerance` × the
/// larger of the residual without them and the median residual of the completely measured
/// pixels. The solve must hold every knot of C and its residuals.
pub fn revert_disputed(solve: &mut ViewSolve<'_>, tolerance: f64) -> Result<DisputedReport> {
    check_at_least("disputed tolerance", tolerance, 1.0)?;
    solve.check_full("disputed measurements")?;
    let context = solve.context;
    let (rows, knots) = (context.sensing.rows(), solve.knots.len());
    let cameras = context.camera_rows.len();
    let pixels = solve.measurements.len() / rows;
    if solve.disputed.len() != pixels * cameras {
        return Err(Error::Shape {
            op: "disputed measurements: flags against pixels × cameras".into(),
            got: vec![solve.disputed.len()],
            expected: vec![pixels, cameras],
        });
    }
    let residuals = solve.residuals.as_deref().unwrap_or_default();
    let floor = match solve.statistics.disputed_floor {
        Some(floor) => floor,
        None => median_of_complete(residuals, &solve.measurements, rows).unwrap_or(0.0),
    };
    solve.statistics.disputed_floor = Some(floor);
    let flags = |px: usize| &solve.disputed[px * cameras..(px + 1) * cameras];
    let candidates: Vec<usize> = (0..pixels)
        .filter(|&px| flags(px).iter().any(|&f| f))
        .collect();
    if candidates.is_empty() {
        return Ok(DisputedReport {
            pixels: 0,
            dropped: 0,
        });
    }
    let mut undisputed = Vec::with_capacity(candidates.len() * rows);
    for &px in &candidates {
        let start = undisputed.len();
        undisputed.extend_from_slice(&solve.measurements[px * rows..(px + 1) * rows]);
        for (camera, _) in flags(px).iter().enumerate().filter(|(_, &f)| f) {
            let range = context.camera_rows[camera].clone();
            undisputed[start + range.start..start + range.end].fill(f32::NAN);
        }
    }
    let (solved_without, _) = demultiplex_as::<f32, f32>(
        context.sensing.values(),
        rows,
        &undisputed,
        None,
        solve.knots.clone(),
        &context.options,
    )?;
    let without = measurement_residuals(context.sensing, &undisputed, &solved_without)?;
    let limit = tolerance as f32;
    let mut dropped = 0;
    let residuals = solve.residuals_mut("disputed measurements")?;
    let mut replaced = Vec::new();
    for (i, &px) in candidates.iter().enumerate() {
        // A NaN residual (nothing solved) keeps the measurements: nothing to compare.
        if residuals[px] > limit * without[i].max(floor) {
            residuals[px] = without[i];
            replaced.push((i, px));
            dropped += 1;
        }
    }
    for (i, px) in replaced {
        solve.measurements[px * rows..(px + 1) * rows]
            .copy_from_slice(&undisputed[i * rows..(i + 1) * rows]);
        solve.spectra[px * knots..(px + 1) * knots]
            .copy_from_slice(&solved_without[i * knots..(i + 1) * knots]);
    }
    Ok(DisputedReport {
        pixels: candidates.len(),
        dropped,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::test_support::{context, demultiplexed, matrix};

    /// Three cameras of three channels over five knots; spectra smooth, small noise. Camera
    /// 2's measurements are disputed at every pixel: of the same surface at three pixels in
    /// four, of another surface at the fourth.
    #[test]
    fn disputed_measurements_stay_where_they_agree_and_go_where_they_do_not() {
        let (rows, knots, pixels) = (9usize, 5usize, 40usize);
        let c: Vec<f64> = (0..rows * knots)
            .map(|k| {
                let (r, j) = ((k / knots) as f64, (k % knots) as f64);
                (-(j - 0.5 * r).powi(2) / 1.5).exp() + 0.05
            })
            .collect();
        let wrong = |px: usize| px % 4 == 1;
        let spectrum = |px: usize, other: bool| -> Vec<f64> {
            let phase = px as f64 * 0.1 + if other { 2.5 } else { 0.0 };
            (0..knots)
                .map(|j| 0.5 + 0.3 * (0.4 * j as f64 + phase).sin())
                .collect()
        };
        let measure = |s: &[f64], r: usize, px: usize| -> f32 {
            let noise = 5e-4 * ((px * 7 + r * 3) as f64).sin();
            ((0..knots).map(|j| c[r * knots + j] * s[j]).sum::<f64>() + noise) as f32
        };
        let mut measurements = Vec::with_capacity(pixels * rows);
        for px in 0..pixels {
            let own = spectrum(px, false);
            let seen = spectrum(px, wrong(px));
            for r in 0..rows {
                measurements.push(measure(if r >= 6 { &seen } else { &own }, r, px));
            }
        }
        let disputed: Vec<bool> = (0..pixels * 3).map(|k| k % 3 == 2).collect();
        let sensing = matrix(rows, c);
        let context = context(&sensing, vec![0..3, 3..6, 6..9]);
        let before = measurements.clone();
        let mut solve = demultiplexed(&context, measurements, disputed);
        let report = revert_disputed(&mut solve, 2.0).unwrap();
        assert_eq!(report.pixels, pixels);
        assert_eq!(report.dropped, pixels / 4);
        for px in 0..pixels {
            let row = &solve.measurements[px * rows..(px + 1) * rows];
            if !wrong(px) {
                assert_eq!(row, &before[px * rows..(px + 1) * rows], "pixel {px}");
            } else {
                assert!(row[6..].iter().all(|m| m.is_nan()), "pixel {px}");
                assert!(row[..6].iter().all(|m| m.is_finite()), "pixel {px}");
                // The solve without camera 2 recovers the pixel's own spectrum.
                let truth = spectrum(px, false);
                let got = &solve.spectra[px * knots..(px + 1) * knots];
                let rms = (got
                    .iter()
                    .zip(&truth)
                    .map(|(a, b)| (*a as f64 - b).powi(2))
                    .sum::<f64>()
                    / knots as f64)
                    .sqrt();
                assert!(rms < 0.05, "pixel {px}: rms {rms}");
            }
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let sensing = matrix(3, vec![1.0; 3]);
        let context = context(&sensing, vec![0..2, 2..3]);
        let solve = |flags: usize| demultiplexed(&context, vec![0.5f32; 6], vec![true; flags]);
        assert!(matches!(
            revert_disputed(&mut solve(3), 2.0),
            Err(Error::Shape { .. })
        ));
        for tolerance in [0.5, f64::NAN] {
            assert!(matches!(
                revert_disputed(&mut solve(4), tolerance),
                Err(Error::OutOfRange { .. })
            ));
        }
    }
}
