//! Planes through ambiguous regions (beyond the paper): the last step of multi-baseline
//! registration, after the median. Where a view's matching costs have several equally
//! good minima (a repetitive texture), its disparities are replaced by the plane that most
//! of the region's disparities lie on, wherever that plane's cost is a plausible one.
//!
//! Why: a grating of vertical stripes looks the same at every whole period of disparity to
//! every camera of the array beside the reference, and the learned cost prefers no period
//! over another (on the periodic preset's grating the true disparity is not even the least
//! of a column's summed costs). SGM then follows a different period in each column, and
//! 70 % of the grating's pixels of r0c0 land one or more periods off. Each wrong period
//! differs from column to column, while the right one is shared by every column that found
//! it, so a robust plane fit (RANSAC) over the region picks the true surface out of its
//! aliases.
//!
//! Steps per view: a pixel is ambiguous if its raw multi-view costs have a local minimum
//! at least [`SEPARATION`] steps from the best one and within [`AMBIGUITY_MARGIN`] of it
//! ([`Ambiguity::of_volume`]); a region is a connected set of pixels most of whose
//! neighbourhood is ambiguous; a region large enough gets a RANSAC plane
//! `d = a·x + b·y + c` (inliers within [`INLIER_PX`]), refitted by least squares on its
//! inliers, and kept if at least [`MIN_INLIER_FRACTION`] of the region lies on it
//! ([`region_planes`]); the plane is put to the vote of the view's row and column
//! neighbours, whose maps carried into the view give their own planes for the region
//! ([`vote_with_neighbours`]); then every pixel of the region more than
//! [`REPLACE_BEYOND_PX`] off the plane takes the plane's disparity if its cost there is
//! below the median of its costs (a surface of another depth that strays into the region
//! has a clear minimum elsewhere and keeps it; [`apply_region_planes`]).
//!
//! In: a view's disparity map after the median, its [`Ambiguity`], a cost function at
//! fractional disparities and its neighbours' maps. Out: the map, changed in place; the
//! count of replaced pixels.

use crate::stereo::{CostVolume, DisparityRange};
use rayon::prelude::*;

/// Cost margin over the best cost within which another local minimum makes a pixel
/// ambiguous (the multi-view costs lie in [0, 1]; on the periodic preset's grating the
/// minima of one pixel lie within 0.01 of each other).
pub const AMBIGUITY_MARGIN: f32 = 0.01;
/// Least distance, in disparity steps, of a competing minimum from the best one: nearer
/// minima are the same match (noise on a broad minimum).
pub const SEPARATION: usize = 3;
/// Half-width of the window whose ambiguous fraction decides a region's pixels.
pub const REGION_RADIUS: usize = 7;
/// Ambiguous fraction of the window above which a pixel belongs to a region.
pub const REGION_FRACTION: f64 = 0.6;
/// Least region size as a fraction of the image (3072 pixels at 640×480): a plane needs
/// a surface, not a patch.
pub const MIN_REGION_FRACTION: f64 = 0.01;
/// Distance from the plane, in pixels of disparity, within which a pixel is an inlier.
pub const INLIER_PX: f32 = 0.5;
/// Least fraction of a region on its plane for the plane to be used (the grating's true
/// plane holds 28 % of its region).
pub const MIN_INLIER_FRACTION: f64 = 0.2;
/// Pixels nearer the plane than this keep their own (subpixel) disparity.
pub const REPLACE_BEYOND_PX: f32 = 1.0;
/// RANSAC draws per region.
const ITERATIONS: usize = 300;
/// Pixels of a region that score each RANSAC draw.
const SCORING_SAMPLE: usize = 3000;

/// Per pixel of a view: whether its costs are ambiguous, and the median of its costs.
#[derive(Debug, Clone, PartialEq)]
pub struct Ambiguity {
    pub width: usize,
    pub height: usize,
    pub ambiguous: Vec<bool>,
    pub median_cost: Vec<f32>,
}

impl Ambiguity {
    /// Scans every pixel's costs in `volume` (see the module docs); costs at or above
    /// [`CostVolume::INVALID`] (no view sees the match) take part in neither test.
    pub fn of_volume(volume: &CostVolume) -> Self {
        let dm = volume.count();
        let (ambiguous, median_cost): (Vec<bool>, Vec<f32>) = volume
            .data
            .par_chunks(dm.max(1))
            .map_init(Vec::new, |valid, costs| {
                if dm == 0 {
                    return (false, f32::NAN);
                }
                let usable = |c: f32| c < CostVolume::INVALID;
                let best = (0..dm)
                    .filter(|&d| usable(costs[d]))
                    .min_by(|&a, &b| costs[a].total_cmp(&costs[b]));
                let Some(best) = best else {
                    return (false, f32::NAN);
                };
                let bar = costs[best] + AMBIGUITY_MARGIN;
                let ambiguous = (1..dm.saturating_sub(1)).any(|d: usize| {
                    d.abs_diff(best) >= SEPARATION
                        && usable(costs[d])
                        && costs[d] <= bar
                        && costs[d] <= costs[d - 1]
                        && costs[d] <= costs[d + 1]
                });
                valid.clear();
                valid.extend(costs.iter().copied().filter(|&c| usable(c)));
                let middle = valid.len() / 2;
                let (_, median, _) = valid.select_nth_unstable_by(middle, f32::total_cmp);
                (ambiguous, *median)
            })
            .unzip();
        Ambiguity {
            width: volume.width,
            height: volume.height,
            ambiguous,
            median_cost,
        }
    }

    /// Pixels whose window of half-width [`REGION_RADIUS`] is more than
    /// [`REGION_FRACTION`] ambiguous (windows clipped at the image border).
    fn region_mask(&self) -> Vec<bool> {
        let (w, h) = (self.width, self.height);
        // Integral image with a zero row and column in front.
        let mut integral = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += u32::from(self.ambiguous[y * w + x]);
                integral[(y + 1) * (w + 1) + x + 1] = integral[y * (w + 1) + x + 1] + row;
            }
        }
        let r = REGION_RADIUS;
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
                let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
                let count = integral[y1 * (w + 1) + x1] + integral[y0 * (w + 1) + x0]
                    - integral[y0 * (w + 1) + x1]
                    - integral[y1 * (w + 1) + x0];
                let area = ((x1 - x0) * (y1 - y0)) as f64;
                count as f64 > REGION_FRACTION * area
            })
            .collect()
    }
}

/// The connected regions (4-neighbourhood) of `mask` with at least `min_size` pixels, each
/// as its pixel indices.
fn regions(mask: &[bool], width: usize, height: usize, min_size: usize) -> Vec<Vec<usize>> {
    let mut seen = vec![false; mask.len()];
    let mut found = Vec::new();
    let mut stack = Vec::new();
    for start in 0..mask.len() {
        if !mask[start] || seen[start] {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut region = Vec::new();
        while let Some(i) = stack.pop() {
            region.push(i);
            let (x, y) = (i % width, i / width);
            let mut visit = |j: usize| {
                if mask[j] && !seen[j] {
                    seen[j] = true;
                    stack.push(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < width {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - width);
            }
            if y + 1 < height {
                visit(i + width);
            }
        }
        if region.len() >= min_size {
            found.push(region);
        }
    }
    found
}

/// A disparity plane `d = a·x + b·y + c`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Plane {
    a: f64,
    b: f64,
    c: f64,
}

impl Plane {
    fn at(&self, x: usize, y: usize) -> f64 {
        self.a * x as f64 + self.b * y as f64 + self.c
    }

    /// The plane through three points (x, y, d); None if they are (nearly) collinear.
    fn through(points: [(f64, f64, f64); 3]) -> Option<Plane> {
        let [(x0, y0, d0), (x1, y1, d1), (x2, y2, d2)] = points;
        let (ux, uy, ud) = (x1 - x0, y1 - y0, d1 - d0);
        let (vx, vy, vd) = (x2 - x0, y2 - y0, d2 - d0);
        let det = ux * vy - uy * vx;
        if det.abs() < 1.0 {
            return None; // under a pixel² of spanned area
        }
        let a = (ud * vy - uy * vd) / det;
        let b = (ux * vd - ud * vx) / det;
        Some(Plane {
            a,
            b,
            c: d0 - a * x0 - b * y0,
        })
    }

    /// The least-squares plane through `points` (coordinates centred for conditioning);
    /// None if they do not span a plane.
    fn fit(points: &[(f64, f64, f64)]) -> Option<Plane> {
        let n = points.len() as f64;
        if points.len() < 3 {
            return None;
        }
        let (mx, my, md) = points.iter().fold((0.0, 0.0, 0.0), |s, p| {
            (s.0 + p.0 / n, s.1 + p.1 / n, s.2 + p.2 / n)
        });
        let (mut sxx, mut sxy, mut syy, mut sxd, mut syd) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(x, y, d) in points {
            let (x, y, d) = (x - mx, y - my, d - md);
            sxx += x * x;
            sxy += x * y;
            syy += y * y;
            sxd += x * d;
            syd += y * d;
        }
        let det = sxx * syy - sxy * sxy;
        if !(det > 1e-9 * (sxx * syy).max(1e-300)) {
            return None;
        }
        let a = (sxd * syy - syd * sxy) / det;
        let b = (syd * sxx - sxd * sxy) / det;
        Some(Plane {
            a,
            b,
            c: md - a * mx - b * my,
        })
    }
}

/// A small deterministic generator (SplitMix64) for the RANSAC draws, so that a run is
/// reproducible.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// The plane most of `points` lie on (RANSAC, then least squares on its inliers), with
/// the fraction of `points` within [`INLIER_PX`] of it.
fn dominant_plane(points: &[(f64, f64, f64)], seed: u64) -> Option<(Plane, f64)> {
    if points.len() < 3 {
        return None;
    }
    let mut rng = SplitMix(seed);
    let sample: Vec<(f64, f64, f64)> = if points.len() <= SCORING_SAMPLE {
        points.to_vec()
    } else {
        (0..SCORING_SAMPLE)
            .map(|_| points[rng.below(points.len())])
            .collect()
    };
    let tolerance = f64::from(INLIER_PX);
    let inliers = |plane: &Plane, of: &[(f64, f64, f64)]| {
        of.iter()
            .filter(|p| (plane.a * p.0 + plane.b * p.1 + plane.c - p.2).abs() < tolerance)
            .count()
    };
    let mut best: Option<(Plane, usize)> = None;
    for _ in 0..ITERATIONS {
        let draw = [
            sample[rng.below(sample.len())],
            sample[rng.below(sample.len())],
            sample[rng.below(sample.len())],
        ];
        let Some(plane) = Plane::through(draw) else {
            continue;
        };
        let count = inliers(&plane, &sample);
        if best.is_none_or(|(_, most)| count > most) {
            best = Some((plane, count));
        }
    }
    let (plane, _) = best?;
    let on_plane: Vec<(f64, f64, f64)> = points
        .iter()
        .copied()
        .filter(|p| (plane.a * p.0 + plane.b * p.1 + plane.c - p.2).abs() < tolerance)
        .collect();
    let refitted = Plane::fit(&on_plane).unwrap_or(plane);
    let fraction = inliers(&refitted, points) as f64 / points.len() as f64;
    Some((refitted, fraction))
}

/// An ambiguous region of a view: its pixels, the plane most of its disparities lie on,
/// and whether that plane is used: it holds [`MIN_INLIER_FRACTION`] of the region, or a
/// neighbouring view finds it too ([`vote_with_neighbours`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RegionPlane {
    pub pixels: Vec<usize>,
    plane: Option<Plane>,
    pub accepted: bool,
}

/// The ambiguous regions of a view's map (`ambiguity`'s size) and each one's dominant
/// plane (see the module docs).
pub fn region_planes(disparity: &[f32], ambiguity: &Ambiguity) -> Vec<RegionPlane> {
    let (w, h) = (ambiguity.width, ambiguity.height);
    if disparity.len() != w * h {
        return Vec::new();
    }
    let min_size = ((MIN_REGION_FRACTION * (w * h) as f64).ceil() as usize).max(3);
    regions(&ambiguity.region_mask(), w, h, min_size)
        .into_iter()
        .enumerate()
        .map(|(k, pixels)| {
            let points: Vec<(f64, f64, f64)> = pixels
                .iter()
                .filter(|&&i| disparity[i].is_finite())
                .map(|&i| ((i % w) as f64, (i / w) as f64, f64::from(disparity[i])))
                .collect();
            let found = dominant_plane(&points, 0x5EED + k as u64);
            if let Some((plane, held)) = found {
                tracing::debug!(
                    "ambiguous region of {} px: plane {:.4}·x + {:.4}·y + {:.2} holds {held:.3}",
                    pixels.len(),
                    plane.a,
                    plane.b,
                    plane.c,
                );
            }
            RegionPlane {
                pixels,
                plane: found.map(|(plane, _)| plane),
                accepted: found.is_some_and(|(_, held)| held >= MIN_INLIER_FRACTION),
            }
        })
        .collect()
}

/// The least and largest x and y of `pixels` (row-major, `width` wide).
fn bounding_box(pixels: &[usize], width: usize) -> [(usize, usize); 4] {
    let (mut x0, mut x1, mut y0, mut y1) = (usize::MAX, 0, usize::MAX, 0);
    for &i in pixels {
        let (x, y) = (i % width, i / width);
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
}

/// Whether two planes lie within [`REPLACE_BEYOND_PX`] of each other at every corner of
/// the region's bounding box.
fn same_plane(a: &Plane, b: &Plane, corners: &[(usize, usize); 4]) -> bool {
    corners
        .iter()
        .all(|&(x, y)| (a.at(x, y) - b.at(x, y)).abs() <= f64::from(REPLACE_BEYOND_PX))
}

/// Checks each region's plane against the row and column neighbours of the view: each
/// neighbour's map (after its own plane step) is carried into the view along the array
/// geometry (`shifts[k]`: the shift per unit disparity from neighbour k to the view), and
/// the plane its disparities in the region lie on is that neighbour's opinion. The region
/// takes the plane that most opinions, its own included, agree with (a tie keeps its own),
/// and uses it if it is its own accepted plane or at least two opinions share it.
/// A view whose corner position sees the repetitive texture through fewer baselines can
/// take a period's alias for its plane where its neighbours found the surface (the
/// demo's periodic scene at 320×240: r0c0 chose an alias, r0c1 and r1c0 the truth).
/// Returns how many regions changed plane or came to be used.
pub fn vote_with_neighbours(
    regions: &mut [RegionPlane],
    disparity: &[f32],
    width: usize,
    height: usize,
    neighbours: &[(&[f32], (f64, f64))],
) -> usize {
    if regions.is_empty() || neighbours.is_empty() {
        return 0;
    }
    let mut label = vec![u32::MAX; width * height];
    for (k, region) in regions.iter().enumerate() {
        for &i in &region.pixels {
            label[i] = k as u32;
        }
    }
    // Per neighbour and region, its disparities carried into the region.
    let opinions: Vec<Vec<Option<Plane>>> = neighbours
        .iter()
        .enumerate()
        .map(|(n, &(map, (sx, sy)))| {
            let mut carried = vec![Vec::new(); regions.len()];
            for (q, &d) in map.iter().enumerate() {
                if !d.is_finite() {
                    continue;
                }
                let x = ((q % width) as f64 + sx * f64::from(d)).round();
                let y = ((q / width) as f64 + sy * f64::from(d)).round();
                if x < 0.0 || y < 0.0 || x >= width as f64 || y >= height as f64 {
                    continue;
                }
                let p = y as usize * width + x as usize;
                if let Some(points) = carried.get_mut(label[p] as usize) {
                    points.push((x, y, f64::from(d)));
                }
            }
            carried
                .iter()
                .zip(regions.iter())
                .enumerate()
                .map(|(k, (points, region))| {
                    if points.len() * 10 < region.pixels.len() {
                        return None; // the neighbour sees too little of the region
                    }
                    let seed = 0xB0A7 + (n * regions.len() + k) as u64;
                    dominant_plane(points, seed)
                        .and_then(|(plane, held)| (held >= MIN_INLIER_FRACTION).then_some(plane))
                })
                .collect()
        })
        .collect();
    let mut changed = 0;
    for (k, region) in regions.iter_mut().enumerate() {
        let corners = bounding_box(&region.pixels, width);
        let candidates: Vec<Plane> = region
            .plane
            .into_iter()
            .chain(opinions.iter().filter_map(|o| o[k]))
            .collect();
        let Some(&first) = candidates.first() else {
            continue;
        };
        let support = |c: &Plane| {
            candidates
                .iter()
                .filter(|o| same_plane(c, o, &corners))
                .count()
        };
        let mut best = (first, support(&first));
        for c in &candidates[1..] {
            let s = support(c);
            if s > best.1 {
                best = (*c, s);
            }
        }
        if region
            .plane
            .is_some_and(|own| same_plane(&best.0, &own, &corners))
        {
            // Kept: used if it held enough of the region or a neighbour shares it.
            if !region.accepted && best.1 >= 2 {
                region.accepted = true;
                changed += 1;
            }
            continue;
        }
        if best.1 < 2 {
            region.accepted = false;
            continue;
        }
        // Refit on the view's own disparities on the chosen plane where enough lie on it.
        let on_plane: Vec<(f64, f64, f64)> = region
            .pixels
            .iter()
            .filter(|&&i| {
                let d = disparity[i];
                d.is_finite()
                    && (best.0.at(i % width, i / width) - f64::from(d)).abs() < f64::from(INLIER_PX)
            })
            .map(|&i| {
                (
                    (i % width) as f64,
                    (i / width) as f64,
                    f64::from(disparity[i]),
                )
            })
            .collect();
        let refitted = (on_plane.len() * 20 >= region.pixels.len())
            .then(|| Plane::fit(&on_plane))
            .flatten()
            .filter(|p| same_plane(p, &best.0, &corners));
        region.plane = Some(refitted.unwrap_or(best.0));
        region.accepted = true;
        changed += 1;
    }
    changed
}

/// Moves the pixels of each region more than [`REPLACE_BEYOND_PX`] off its plane onto it,
/// where the plane's cost is below the median of the pixel's costs (see the module docs);
/// `cost(x, y, d)` is the view's multi-view cost at a fractional disparity, searched over
/// `range`. Returns how many pixels changed.
pub fn apply_region_planes(
    disparity: &mut [f32],
    ambiguity: &Ambiguity,
    range: DisparityRange,
    regions: &[RegionPlane],
    cost: &(dyn Fn(usize, usize, f32) -> f32 + Sync),
) -> usize {
    let w = ambiguity.width;
    if disparity.len() != w * ambiguity.height || range.count() < 2 {
        return 0;
    }
    let mut replaced = 0;
    for region in regions {
        let Some(plane) = region.plane.filter(|_| region.accepted) else {
            continue;
        };
        let updates: Vec<(usize, f32)> = region
            .pixels
            .par_iter()
            .filter_map(|&i| {
                let (x, y) = (i % w, i / w);
                let on_plane = plane.at(x, y) as f32;
                let own = disparity[i];
                let off = !(own.is_finite() && (own - on_plane).abs() <= REPLACE_BEYOND_PX);
                let inside = range.contains(on_plane);
                (off && inside && cost(x, y, on_plane) < ambiguity.median_cost[i])
                    .then_some((i, on_plane))
            })
            .collect();
        replaced += updates.len();
        for (i, d) in updates {
            disparity[i] = d;
        }
    }
    replaced
}

/// [`region_planes`] then [`apply_region_planes`] on one view, without neighbours.
pub fn resolve_ambiguous_planes(
    disparity: &mut [f32],
    ambiguity: &Ambiguity,
    range: DisparityRange,
    cost: &(dyn Fn(usize, usize, f32) -> f32 + Sync),
) -> usize {
    let regions = region_planes(disparity, ambiguity);
    apply_region_planes(disparity, ambiguity, range, &regions, cost)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane of disparities under a cost with a minimum at every whole period: the costs
    /// cannot tell the periods apart (noise picks), columns start a random number of
    /// periods off, and the plane brings every pixel back.
    #[test]
    fn a_periodic_plane_is_recovered_from_column_aliases() {
        // A plane behind the calibration plane and across it: signed disparities.
        let (w, h, period) = (120usize, 90usize, 7.0f32);
        let range = DisparityRange::new(-40, 24).unwrap();
        let dm = range.count();
        let truth = |x: usize, y: usize| -10.0 + 0.05 * x as f32 + 0.02 * y as f32;
        let mut rng = SplitMix(42);
        let mut noise = || (rng.next() % 1000) as f32 / 1000.0 * 0.004;
        let mut volume = CostVolume::new(w, h, range);
        for y in 0..h {
            for x in 0..w {
                for d in 0..dm {
                    let phase = 2.0 * std::f32::consts::PI * (range.at(d) - truth(x, y)) / period;
                    volume.data[(y * w + x) * dm + d] = 0.3 - 0.1 * phase.cos() + noise();
                }
            }
        }
        let cost = |x: usize, y: usize, d: f32| {
            let phase = 2.0 * std::f32::consts::PI * (d - truth(x, y)) / period;
            0.3 - 0.1 * phase.cos()
        };
        // Columns a whole number of periods off: 0 in 2 columns of 5, ±1, +2 elsewhere.
        let offsets = [0.0, 1.0, 0.0, -1.0, 2.0];
        let mut disparity: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                truth(x, y) + period * offsets[(x / 6) % offsets.len()]
            })
            .collect();
        let ambiguity = Ambiguity::of_volume(&volume);
        assert!(ambiguity.ambiguous.iter().filter(|&&a| a).count() > w * h * 9 / 10);
        let changed = resolve_ambiguous_planes(&mut disparity, &ambiguity, range, &cost);
        assert!(changed > w * h / 2, "changed {changed}");
        let worst = (0..w * h)
            .map(|i| (disparity[i] - truth(i % w, i / w)).abs())
            .fold(0f32, f32::max);
        assert!(worst < 0.05, "worst error {worst} px");
    }

    /// Costs with one clear minimum are not ambiguous, and the map stays as it is.
    #[test]
    fn a_clear_minimum_leaves_the_map_alone() {
        let (w, h, dm) = (80usize, 60usize, 32usize);
        let mut volume = CostVolume::new(w, h, DisparityRange::up_to(dm).unwrap());
        let truth = |x: usize| 5.0 + 0.2 * x as f32;
        for y in 0..h {
            for x in 0..w {
                for d in 0..dm {
                    volume.data[(y * w + x) * dm + d] =
                        (0.1 * (d as f32 - truth(x)).abs()).min(0.8);
                }
            }
        }
        let ambiguity = Ambiguity::of_volume(&volume);
        assert!(ambiguity.ambiguous.iter().all(|&a| !a));
        let mut disparity: Vec<f32> = (0..w * h).map(|i| truth(i % w) + 0.3).collect();
        let before = disparity.clone();
        let cost = |_: usize, _: usize, _: f32| 0.0;
        assert_eq!(
            resolve_ambiguous_planes(
                &mut disparity,
                &ambiguity,
                DisparityRange::up_to(dm).unwrap(),
                &cost
            ),
            0
        );
        assert_eq!(disparity, before);
    }

    /// A surface of another depth inside the region keeps its disparity where its costs
    /// have their minimum there, not on the plane.
    #[test]
    fn a_surface_with_its_own_minimum_keeps_it() {
        let (w, h, dm, period) = (100usize, 80usize, 64usize, 7.0f32);
        let plane = |x: usize| 30.0 + 0.03 * x as f32;
        // A 12×12 patch at disparity 12 with a sharp minimum.
        let patch = |x: usize, y: usize| (40..52).contains(&x) && (30..42).contains(&y);
        let cost = |x: usize, y: usize, d: f32| {
            if patch(x, y) {
                0.1 + 0.02 * (d - 12.0).abs()
            } else {
                let phase = 2.0 * std::f32::consts::PI * (d - plane(x)) / period;
                0.3 - 0.1 * phase.cos()
            }
        };
        let mut rng = SplitMix(7);
        let mut volume = CostVolume::new(w, h, DisparityRange::up_to(dm).unwrap());
        for y in 0..h {
            for x in 0..w {
                for d in 0..dm {
                    let jitter = (rng.next() % 1000) as f32 / 1000.0 * 0.004;
                    volume.data[(y * w + x) * dm + d] = cost(x, y, d as f32) + jitter;
                }
            }
        }
        let mut disparity: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if patch(x, y) {
                    12.0
                } else {
                    plane(x) + if (x / 10) % 3 == 1 { period } else { 0.0 }
                }
            })
            .collect();
        let ambiguity = Ambiguity::of_volume(&volume);
        resolve_ambiguous_planes(
            &mut disparity,
            &ambiguity,
            DisparityRange::up_to(dm).unwrap(),
            &cost,
        );
        for y in 0..h {
            for x in 0..w {
                let d = disparity[y * w + x];
                let expected = if patch(x, y) { 12.0 } else { plane(x) };
                assert!(
                    (d - expected).abs() < 0.05,
                    "({x}, {y}): {d} against {expected}"
                );
            }
        }
    }

    /// A view whose region plane is an alias a period off takes the plane its two
    /// neighbours' maps agree on; with one dissenting neighbour it keeps its own.
    #[test]
    fn two_neighbours_outvote_an_alias_plane() {
        let (w, h, dm, period) = (120usize, 90usize, 64usize, 7.0f32);
        let truth = |x: usize| 20.0 + 0.04 * x as f32;
        let cost = |x: usize, _: usize, d: f32| {
            let phase = 2.0 * std::f32::consts::PI * (d - truth(x)) / period;
            0.3 - 0.1 * phase.cos()
        };
        let mut rng = SplitMix(3);
        let mut volume = CostVolume::new(w, h, DisparityRange::up_to(dm).unwrap());
        for (i, slot) in volume.data.iter_mut().enumerate() {
            let (p, d) = (i / dm, i % dm);
            *slot = cost(p % w, p / w, d as f32) + (rng.next() % 1000) as f32 / 1000.0 * 0.004;
        }
        let ambiguity = Ambiguity::of_volume(&volume);
        // The view: 60 % of its columns a period off, the rest right.
        let view: Vec<f32> = (0..w * h)
            .map(|i| truth(i % w) + if (i % w) % 5 < 3 { period } else { 0.0 })
            .collect();
        let mut regions = region_planes(&view, &ambiguity);
        assert_eq!(regions.len(), 1);
        let alias = regions[0].plane.unwrap();
        assert!((alias.at(60, 45) as f32 - truth(60) - period).abs() < 0.1);
        // Neighbours one column step to the right and one row down (shift from them to
        // the view: +d along x, and +d·ratio along y), on the true surface.
        // The right neighbour's pixel x sees the view's x + d: d = truth(x + d).
        let right: Vec<f32> = (0..w * h)
            .map(|i| (20.0 + 0.04 * (i % w) as f32) / 0.96)
            .collect();
        let below: Vec<f32> = (0..w * h).map(|i| truth(i % w)).collect();
        let wrong: Vec<f32> = below.iter().map(|d| d + 2.0 * period).collect();
        let mut dissent = regions.clone();
        let changed = vote_with_neighbours(
            &mut regions,
            &view,
            w,
            h,
            &[(&right, (1.0, 0.0)), (&below, (0.0, 0.0))],
        );
        assert_eq!(changed, 1);
        let mut planar = view.clone();
        apply_region_planes(
            &mut planar,
            &ambiguity,
            DisparityRange::up_to(dm).unwrap(),
            &regions,
            &cost,
        );
        for (i, d) in planar.iter().enumerate() {
            assert!((d - truth(i % w)).abs() < 0.6, "pixel {i}: {d}");
        }
        let kept = vote_with_neighbours(
            &mut dissent,
            &view,
            w,
            h,
            &[(&right, (1.0, 0.0)), (&wrong, (0.0, 0.0))],
        );
        assert_eq!(kept, 0);
        assert_eq!(dissent[0].plane, Some(alias));
    }
}
