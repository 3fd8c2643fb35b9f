//! Agreement between the views' disparity maps: the registration's check on itself.
//!
//! A surface point seen by view i at (x, y) with disparity d appears in view j at
//! `(x, y) + d · shift(i, j)` ([`ArrayGeometry::shift`]), and j's own map should give it
//! the same disparity there. Multi-baseline registration keeps only the pixels that a
//! neighbour ([`ArrayGeometry::neighbours`]) confirms ([`confirmed_by_neighbours`]). After registration, the
//! fraction of a view's pixels that some neighbour confirms ([`neighbour_agreement`])
//! tells a user, without any ground truth, how far to trust the maps. Occlusions keep it
//! below 1, and repetitive or textureless surfaces, where each view picks a different
//! wrong match, pull it down.

use super::ArrayGeometry;
use crate::disparity::DisparityMap;
use crate::stereo::LEFT_RIGHT_TOLERANCE;
use rayon::prelude::*;
use serde::Serialize;

/// Fraction of a view's pixels that its neighbours confirm under which `reconstruct`
/// warns. Measured on the presets at 640×480 with multi-baseline registration (search
/// ranges 52 / 91 / 120): the tabletop's eight views 0.984–0.997 and the clutter's
/// 0.918–0.991, against 0.650–0.854 on the periodic scene, whose registration fails. The
/// true disparities give 0.951–1.000 on all three (occlusions keep them below 1).
pub const LOW_AGREEMENT_WARNING: f64 = 0.9;

/// The value of `map` (a neighbour's) at the pixel nearest to where the point of pixel
/// (x, y) at disparity `d` lands (`shift` per unit disparity); None outside its frame.
fn at_match(map: &DisparityMap, (x, y): (f64, f64), d: f32, shift: (f64, f64)) -> Option<f32> {
    let (width, height) = (map.width, map.height);
    let (xs, ys) = (
        (x + shift.0 * d as f64).round(),
        (y + shift.1 * d as f64).round(),
    );
    let inside = xs >= 0.0 && ys >= 0.0 && xs < width as f64 && ys < height as f64;
    inside.then(|| map.data[ys as usize * width + xs as usize])
}

/// View `i`'s map with NaN wherever no neighbour's map agrees within
/// [`LEFT_RIGHT_TOLERANCE`] at the corresponding pixel. A view without neighbours is
/// returned as it is.
pub fn confirmed_by_neighbours(
    disparities: &[DisparityMap],
    geometry: &ArrayGeometry,
    i: usize,
) -> DisparityMap {
    let own = &disparities[i];
    let width = own.width;
    let neighbours: Vec<(usize, (f64, f64))> = geometry
        .neighbours(i)
        .into_iter()
        .map(|j| (j, geometry.shift(i, j)))
        .collect();
    if neighbours.is_empty() {
        return own.clone();
    }
    let data = own
        .data
        .par_iter()
        .enumerate()
        .map(|(p, &d)| {
            if !d.is_finite() {
                return f32::NAN;
            }
            let (x, y) = ((p % width) as f64, (p / width) as f64);
            let confirmed = neighbours.iter().any(|&(j, shift)| {
                at_match(&disparities[j], (x, y), d, shift)
                    .is_some_and(|other| (other - d).abs() <= LEFT_RIGHT_TOLERANCE)
            });
            if confirmed {
                d
            } else {
                f32::NAN
            }
        })
        .collect();
    DisparityMap { data, ..*own }
}

/// For every view, the fraction of its pixels with a disparity that a neighbour confirms (see [`confirmed_by_neighbours`]); NaN for a view with no finite
/// disparity, 1 for a view without neighbours.
pub fn neighbour_agreement(disparities: &[DisparityMap], geometry: &ArrayGeometry) -> Vec<f64> {
    (0..disparities.len())
        .map(|i| {
            let known = disparities[i].data.iter().filter(|d| d.is_finite()).count();
            if known == 0 {
                return f64::NAN;
            }
            let confirmed = confirmed_by_neighbours(disparities, geometry, i)
                .data
                .iter()
                .filter(|d| d.is_finite())
                .count();
            confirmed as f64 / known as f64
        })
        .collect()
}

/// How well one view's map agrees with one neighbour's.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairAgreement {
    /// The neighbour's name.
    pub neighbour: String,
    /// Of the view's pixels with a disparity whose point lies inside the neighbour's frame
    /// and has a disparity there, the fraction that agree within
    /// [`LEFT_RIGHT_TOLERANCE`] (NaN: none to compare).
    pub agreeing: f64,
    /// How many pixels were compared.
    pub compared: usize,
}

/// View `i`'s agreement with each of its neighbours, one by one.
pub fn pair_agreements(
    disparities: &[DisparityMap],
    geometry: &ArrayGeometry,
    i: usize,
) -> Vec<PairAgreement> {
    let width = disparities[i].width;
    geometry
        .neighbours(i)
        .into_iter()
        .map(|j| {
            let shift = geometry.shift(i, j);
            let (mut agreeing, mut compared) = (0usize, 0usize);
            for (p, &d) in disparities[i].data.iter().enumerate() {
                let xy = ((p % width) as f64, (p / width) as f64);
                if !d.is_finite() {
                    continue;
                }
                let other = at_match(&disparities[j], xy, d, shift);
                if let Some(other) = other.filter(|o| o.is_finite()) {
                    compared += 1;
                    agreeing += usize::from((other - d).abs() <= LEFT_RIGHT_TOLERANCE);
                }
            }
            PairAgreement {
                neighbour: geometry.names[j].clone(),
                agreeing: agreeing as f64 / compared as f64,
                compared,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::disparity::DisparityConvention;

    /// A fronto-parallel plane at disparity 3 seen by a 2×2 array: every map agrees
    /// wherever the neighbour sees the point. Corrupting a block of one view's map
    /// removes exactly that block's agreement.
    #[test]
    fn agreement_counts_the_pixels_a_neighbour_confirms() {
        let (w, h) = (20usize, 16usize);
        let geometry = ArrayGeometry::grid(2, 2, 1.0);
        let plane =
            DisparityMap::new(w, h, DisparityConvention::ColumnStep, vec![3.0f32; w * h]).unwrap();
        let mut maps = vec![plane.clone(); 4];
        let agreement = neighbour_agreement(&maps, &geometry);
        // View (0, 0) finds its right neighbour at x − 3 (in frame for x ≥ 3) and the one
        // below at y − 3 (y ≥ 3): only the 3×3 corner x, y < 3 has neither.
        let expected = 1.0 - 9.0 / (w * h) as f64;
        for a in &agreement {
            assert!((a - expected).abs() < 1e-12, "{agreement:?}");
        }
        // View (0, 0) claims disparity 8 in a 5×4 block: no neighbour agrees there.
        for y in 6..10 {
            for x in 8..13 {
                maps[0].data[y * w + x] = 8.0;
            }
        }
        let confirmed = confirmed_by_neighbours(&maps, &geometry, 0);
        assert!(confirmed.data[7 * w + 10].is_nan());
        assert_eq!(confirmed.data[12 * w + 15], 3.0);
        let agreement = neighbour_agreement(&maps, &geometry);
        let expected0 = 1.0 - (9.0 + 20.0) / (w * h) as f64;
        assert!((agreement[0] - expected0).abs() < 1e-12, "{}", agreement[0]);
        // Pair by pair: the right neighbour compares x ≥ 3 and disagrees on the block.
        let pairs = pair_agreements(&maps, &geometry, 0);
        assert_eq!(pairs.len(), 2);
        let right = pairs.iter().find(|p| p.neighbour == "r0c1").unwrap();
        assert_eq!(right.compared, (w - 3) * h);
        assert!((right.agreeing - (1.0 - 20.0 / ((w - 3) * h) as f64)).abs() < 1e-12);
        // Unknown pixels count neither way; a map with none is NaN.
        maps[3].data = vec![f32::NAN; w * h];
        assert!(neighbour_agreement(&maps, &geometry)[3].is_nan());
    }
}
