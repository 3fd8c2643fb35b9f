//! The spectra cut to the rig's reported bands: the solve estimates C's out-of-band knots
//! too (the light a camera integrates outside the reported range), but the cube holds the
//! bands the rig asked for.
//!
//! In: spectra on `knots` (a range of C's columns that contains the reported bands). Out:
//! spectra on the reported bands; the residuals, which describe the full solve, are
//! dropped.

use super::{SolveStage, ViewSolve};
use crate::{Error, Result};

/// The stage: keep the reported bands of every pixel's spectrum.
#[derive(Debug, Clone, Copy)]
pub struct ReportedBands;

impl SolveStage for ReportedBands {
    fn name(&self) -> &'static str {
        "reported bands"
    }

    fn needs_residuals(&self) -> bool {
        false
    }

    fn run(&self, solve: &mut ViewSolve<'_>) -> Result<()> {
        let reported = solve.context.reported_knots();
        if solve.knots == reported {
            return Ok(());
        }
        let knots = solve.knots.clone();
        if reported.start < knots.start || reported.end > knots.end {
            return Err(Error::Shape {
                op: "reported bands within the solved knots".into(),
                got: vec![knots.start, knots.end],
                expected: vec![reported.start, reported.end],
            });
        }
        let within = reported.start - knots.start..reported.end - knots.start;
        solve.spectra = solve
            .spectra
            .chunks_exact(knots.len())
            .flat_map(|s| s[within.clone()].iter().copied())
            .collect();
        solve.knots = reported;
        solve.residuals = None;
        Ok(())
    }
}
