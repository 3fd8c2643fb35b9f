//! The matching-cost volume shared by every cost and refinement stage: for each left pixel
//! (x, y) and each disparity d of a signed [`DisparityRange`], the cost of matching it with
//! right pixel (x − d, y); lower is better. Stored pixel-major (`(y·w + x)·D + k` for
//! d = min + k), so one pixel's costs are contiguous for the per-pixel scans of SGM and
//! the winner-take-all.

pub use crate::disparity::DisparityRange;
pub use crate::image::GreyImage;
use std::ops::Range;

/// Costs for `width × height` pixels over the disparities of `range`.
#[derive(Debug, Clone, PartialEq)]
pub struct CostVolume {
    pub width: usize,
    pub height: usize,
    pub range: DisparityRange,
    /// `(y·width + x)·count + k` for disparity `range.min + k`; pairs whose right pixel
    /// falls outside the image hold [`CostVolume::INVALID`].
    pub data: Vec<f32>,
}

impl CostVolume {
    /// Cost of a match whose right pixel lies outside the image (worse than any real cost
    /// of the normalised costs here, which lie in [0, 1]).
    pub const INVALID: f32 = 1.0;

    pub fn new(width: usize, height: usize, range: DisparityRange) -> Self {
        CostVolume {
            width,
            height,
            range,
            data: crate::io::filled_large(width * height * range.count(), Self::INVALID),
        }
    }

    /// Disparities per pixel.
    pub fn count(&self) -> usize {
        self.range.count()
    }

    /// The costs of pixel (x, y) over all disparities.
    pub fn pixel(&self, x: usize, y: usize) -> &[f32] {
        let n = self.count();
        let i = (y * self.width + x) * n;
        &self.data[i..i + n]
    }

    /// The indices k whose right pixel `x − (min + k)` lies inside the image.
    pub fn matched(&self, x: usize) -> Range<usize> {
        matched_indices(x, self.width, self.range)
    }

    /// Keeps, at every pixel and disparity, the lower of this volume's cost and `other`'s
    /// (a volume of the same size and range).
    pub fn keep_lower(&mut self, other: &CostVolume) {
        debug_assert_eq!(self.data.len(), other.data.len());
        keep_lower(&mut self.data, &other.data);
    }

    /// The index of a whole disparity `d` (None outside the range or not finite).
    pub fn index_of(&self, d: f32) -> Option<usize> {
        self.range
            .contains(d)
            .then(|| (d as i64 - self.range.min as i64) as usize)
    }
}

/// The lower of `costs` and `other` at each entry, into `costs` ([`CostVolume::keep_lower`]
/// of any part of two volumes).
pub(crate) fn keep_lower(costs: &mut [f32], other: &[f32]) {
    for (a, b) in costs.iter_mut().zip(other) {
        *a = a.min(*b);
    }
}

/// The indices k of `range` whose right pixel `x − (min + k)` lies in `[0, width)`.
pub fn matched_indices(x: usize, width: usize, range: DisparityRange) -> Range<usize> {
    let first = x as i64 - range.min as i64 - width as i64 + 1;
    let end = x as i64 - range.min as i64 + 1;
    let clamp = |v: i64| v.clamp(0, range.count() as i64) as usize;
    clamp(first)..clamp(end)
}

/// The right column matched by left column x at index k of `range`: `x − (min + k)`
/// (k from [`matched_indices`]).
#[inline(always)]
pub fn right_column(x: usize, k: usize, range: DisparityRange) -> usize {
    (x as i64 - range.min as i64 - k as i64) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matched_indices_keep_the_right_pixel_inside() {
        let width = 10;
        for range in [DisparityRange::new(0, 4), DisparityRange::new(-6, 3)] {
            let range = range.unwrap();
            for x in 0..width {
                let expected: Vec<usize> = (0..range.count())
                    .filter(|&k| {
                        let xr = x as i64 - range.min as i64 - k as i64;
                        (0..width as i64).contains(&xr)
                    })
                    .collect();
                let got: Vec<usize> = matched_indices(x, width, range).collect();
                assert_eq!(got, expected, "x {x} range {range}");
            }
        }
    }
}
