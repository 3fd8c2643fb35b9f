//! The matching-cost volume shared by every cost and refinement stage: for each left pixel
//! (x, y) and disparity d, the cost of matching it with right pixel (x − d, y); lower is
//! better. Stored pixel-major (`(y·w + x)·D + d`), so one pixel's costs are contiguous for
//! the per-pixel scans of SGM and the winner-take-all.

pub use crate::image::GreyImage;

/// Costs for `width × height` pixels and `max_disp` disparities.
#[derive(Debug, Clone, PartialEq)]
pub struct CostVolume {
    pub width: usize,
    pub height: usize,
    pub max_disp: usize,
    /// `(y·width + x)·max_disp + d`; pairs whose right pixel falls outside the image hold
    /// [`CostVolume::INVALID`].
    pub data: Vec<f32>,
}

impl CostVolume {
    /// Cost of a match whose right pixel lies outside the image (worse than any real cost
    /// of the normalised costs here, which lie in [0, 1]).
    pub const INVALID: f32 = 1.0;

    pub fn new(width: usize, height: usize, max_disp: usize) -> Self {
        CostVolume {
            width,
            height,
            max_disp,
            data: vec![Self::INVALID; width * height * max_disp],
        }
    }

    /// The costs of pixel (x, y) over all disparities.
    pub fn pixel(&self, x: usize, y: usize) -> &[f32] {
        let i = (y * self.width + x) * self.max_disp;
        &self.data[i..i + self.max_disp]
    }
}
