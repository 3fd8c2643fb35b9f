//! A reconstructed view as a JSON-friendly record (everything but the images), as the
//! manifest lists it.

use super::ReconstructedView;
use crate::demux::DemuxReport;
use crate::register::{PairAgreement, Visibility};
use crate::solve::{DisputedReport, ScenePriorReport};
use serde::Serialize;

/// The result of [`super::reconstruct`] for one view, without its images.
#[derive(Debug, Clone, Serialize)]
pub struct ViewSummary {
    /// The camera's name (see [`crate::rig::Camera::name`]).
    pub name: String,
    pub visibility: Visibility,
    pub demux: DemuxReport,
    /// Smallest and largest finite disparity.
    pub disparity_range: [f32; 2],
    pub neighbour_agreement: Option<f64>,
    /// Agreement with each neighbour's map.
    pub pair_agreements: Vec<PairAgreement>,
    pub unmeasured_pixels: usize,
    pub median_residual: Option<f64>,
    pub disputed: Option<DisputedReport>,
    pub inconsistent_pixels: Option<usize>,
    pub scene_prior: Option<ScenePriorReport>,
    pub moved_to_planes: Option<usize>,
}

impl ReconstructedView {
    pub fn summary(&self) -> ViewSummary {
        ViewSummary {
            name: self.name.clone(),
            visibility: self.visibility.clone(),
            demux: self.solve.demux.clone(),
            disparity_range: self.disparity.range(),
            neighbour_agreement: self.neighbour_agreement,
            pair_agreements: self.pair_agreements.clone(),
            unmeasured_pixels: self.solve.demux.unmeasured_pixels,
            median_residual: self.solve.median_residual,
            disputed: self.solve.disputed,
            inconsistent_pixels: self.solve.inconsistent_pixels,
            scene_prior: self.solve.scene_prior,
            moved_to_planes: self.moved_to_planes,
        }
    }
}
