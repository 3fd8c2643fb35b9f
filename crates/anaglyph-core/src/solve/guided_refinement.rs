//! The last stage of a view's solve: the cube filtered with the view's own capture as the
//! guide ([`crate::refine`]), each pixel weighted by its confidence when that stage ran.
//!
//! In: the view's reflectance on the reported bands, its calibrated capture, the weights.
//! Out: the refined reflectance.

use super::{SolveStage, ViewSolve};
use crate::refine::{refine_view, refine_view_near, GuidedRefinement};
use crate::Result;

/// The stage: [`refine_view`] with the given settings.
#[derive(Debug, Clone, Copy)]
pub struct GuidedRefinementStage {
    pub refinement: GuidedRefinement,
}

impl SolveStage for GuidedRefinementStage {
    fn name(&self) -> &'static str {
        "guided refinement"
    }

    fn needs_residuals(&self) -> bool {
        false
    }

    fn spatial(&self) -> bool {
        true
    }

    fn run(&self, solve: &mut ViewSolve<'_>) -> Result<()> {
        let context = solve.context;
        let rows = context.camera_rows[solve.camera].clone();
        let white_response: Vec<f64> = rows.map(|r| context.sensing.row(r).iter().sum()).collect();
        let view = &context.views[solve.camera];
        match &solve.kept {
            // A sequence's frame that kept most pixels: filter again only near the others.
            Some(kept) if kept.refined.len() == solve.spectra.len() => refine_view_near(
                &mut solve.spectra,
                solve.knots.len(),
                view,
                &white_response,
                solve.weights.as_deref(),
                self.refinement,
                &kept.changed,
                &kept.refined,
            ),
            _ => refine_view(
                &mut solve.spectra,
                solve.knots.len(),
                view,
                &white_response,
                solve.weights.as_deref(),
                self.refinement,
            ),
        }
    }
}
