//! The first stage of a view's solve: masked Eq. 6 for every pixel ([`crate::demux`]).
//!
//! In: the view's measurements (`pixels × rows`, NaN where not seen). Out: its spectra on
//! every knot of C when a later stage reads residuals (and those residuals), otherwise on
//! the reported bands alone; the solver's report.

use super::{measurement_residuals, SolveStage, ViewSolve};
use crate::demux::demultiplex_as;
use crate::Result;

/// The stage: Eq. 6 on the knots the plan needs.
#[derive(Debug, Clone, Copy)]
pub struct Demultiplex {
    /// Solve every knot of C and compute the residuals (a later stage reads them).
    pub all_knots: bool,
}

impl SolveStage for Demultiplex {
    fn name(&self) -> &'static str {
        "demultiplexing"
    }

    fn needs_residuals(&self) -> bool {
        false
    }

    fn run(&self, solve: &mut ViewSolve<'_>) -> Result<()> {
        let context = solve.context;
        let sensing = context.sensing;
        let knots = if self.all_knots {
            0..sensing.cols()
        } else {
            context.reported_knots()
        };
        let (spectra, report) = demultiplex_as::<f32, f32>(
            sensing.values(),
            sensing.rows(),
            &solve.measurements,
            None,
            knots.clone(),
            &context.options,
        )?;
        solve.residuals = if self.all_knots {
            Some(measurement_residuals(
                sensing,
                &solve.measurements,
                &spectra,
            )?)
        } else {
            None
        };
        solve.knots = knots;
        solve.spectra = spectra;
        solve.report.demux = report;
        Ok(())
    }
}
