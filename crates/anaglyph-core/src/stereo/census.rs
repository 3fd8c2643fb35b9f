//! The census cost (Zabih & Woodfill 1994): each pixel becomes a bit string saying which
//! neighbours in a window are darker than it; the cost is the Hamming distance of the two
//! strings, divided by the window size so that it lies in [0, 1]. It only compares
//! intensities within one image, so it survives gain and offset changes between cameras,
//! but not the intensity inversions of strongly different filters.

use super::cost_volume::{matched_indices, right_column};
use super::{CostVolume, DisparityRange, GreyImage};
use rayon::prelude::*;

/// Census window (7 × 9: 62 comparisons fit a u64), as in the baseline.
const HALF_WIDTH: usize = 4;
const HALF_HEIGHT: usize = 3;

fn census_transform(image: &GreyImage) -> Vec<u64> {
    let (w, h) = (image.width, image.height);
    let mut bits = vec![0u64; w * h];
    bits.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let centre = image.at(x, y);
            let mut code = 0u64;
            for dy in -(HALF_HEIGHT as i64)..=HALF_HEIGHT as i64 {
                for dx in -(HALF_WIDTH as i64)..=HALF_WIDTH as i64 {
                    if dx == 0 && dy == 0 {
                        continue;
                    }
                    // Clamp to the border (replicate edge pixels).
                    let nx = (x as i64 + dx).clamp(0, w as i64 - 1) as usize;
                    let ny = (y as i64 + dy).clamp(0, h as i64 - 1) as usize;
                    code = (code << 1) | u64::from(image.at(nx, ny) < centre);
                }
            }
            *out = code;
        }
    });
    bits
}

/// Census cost volume of a rectified pair (left is the reference).
pub fn census_cost_volume(
    left: &GreyImage,
    right: &GreyImage,
    range: DisparityRange,
) -> CostVolume {
    let (w, h) = (left.width, left.height);
    let bits_per_code = ((2 * HALF_WIDTH + 1) * (2 * HALF_HEIGHT + 1) - 1) as f32;
    let (l, r) = (census_transform(left), census_transform(right));
    let mut volume = CostVolume::new(w, h, range);
    let n = range.count();
    volume
        .data
        .par_chunks_mut(w * n)
        .enumerate()
        .for_each(|(y, row)| {
            for x in 0..w {
                for k in matched_indices(x, w, range) {
                    let xr = right_column(x, k, range);
                    row[x * n + k] =
                        (l[y * w + x] ^ r[y * w + xr]).count_ones() as f32 / bits_per_code;
                }
            }
        });
    volume
}
