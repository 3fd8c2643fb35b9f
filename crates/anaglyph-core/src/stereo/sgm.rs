//! Semi-global matching (Hirschmüller 2008) with MC-CNN's gradient-dependent penalties
//! (Zbontar & LeCun 2016): along each path direction r,
//! `L_r(p,d) = C(p,d) + min(L_r(p−r,d), L_r(p−r,d±1) + P1, min_k L_r(p−r,k) + P2) − min_k L_r(p−r,k)`,
//! and the result is the mean of the paths. P1 and P2 are divided by Q1 where one image
//! gradient along the path exceeds D, by Q2 where both do, and P1 by V on vertical paths.

#[cfg(test)]
use super::DisparityRange;
use super::{CostVolume, GreyImage};
use rayon::prelude::*;
use std::ops::Range;

/// SGM settings; [`SgmParameters::MC_CNN_FAST_KITTI`] are MC-CNN fast's published values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SgmParameters {
    pub p1: f32,
    pub p2: f32,
    pub q1: f32,
    pub q2: f32,
    /// Divides P1 on vertical paths.
    pub v: f32,
    /// Gradient threshold D (image values in [0, 1]).
    pub gradient_threshold: f32,
    /// 4 (horizontal and vertical) or 8 (with diagonals) path directions.
    pub paths: usize,
}

impl SgmParameters {
    /// MC-CNN fast on KITTI 2015 (Zbontar & LeCun 2016, Table 6), its costs in [−1, 1]
    /// rescaled to ours in [0, 1] (P1, P2 halved).
    pub const MC_CNN_FAST_KITTI: SgmParameters = SgmParameters {
        p1: 2.3 / 2.0,
        p2: 42.3 / 2.0,
        q1: 3.0,
        q2: 6.0,
        v: 1.25,
        gradient_threshold: 0.08,
        paths: 4,
    };
    /// MC-CNN accurate on KITTI 2015; its costs (−sigmoid, in [−1, 0]) already span one
    /// unit like ours, so the values are unchanged.
    pub const MC_CNN_ACCURATE_KITTI: SgmParameters = SgmParameters {
        p1: 2.3,
        p2: 55.8,
        q1: 3.0,
        q2: 6.0,
        v: 1.75,
        gradient_threshold: 0.08,
        paths: 4,
    };
}

const DIRECTIONS: [(i64, i64); 8] = [
    (1, 0),
    (-1, 0),
    (0, 1),
    (0, -1),
    (1, 1),
    (-1, -1),
    (1, -1),
    (-1, 1),
];

/// Aggregates `volume` along the configured paths; `left`/`right` give the gradients.
pub fn semi_global_matching(
    volume: &CostVolume,
    left: &GreyImage,
    right: &GreyImage,
    params: &SgmParameters,
) -> CostVolume {
    let directions = &DIRECTIONS[..if params.paths >= 8 { 8 } else { 4 }];
    aggregate(volume, left, right, params, directions)
}

/// Penalties (P1, P2) at left pixel (x, y) and disparity d for the step from (px, py):
/// the plain definition, which the tests check the fast path against.
#[cfg(test)]
#[allow(clippy::too_many_arguments)]
fn penalties(
    left: &GreyImage,
    right: &GreyImage,
    params: &SgmParameters,
    vertical: bool,
    x: usize,
    y: usize,
    px: usize,
    py: usize,
    d: i64,
) -> (f32, f32) {
    let gl = (left.at(x, y) - left.at(px, py)).abs() >= params.gradient_threshold;
    let inside = |v: i64| (0..left.width as i64).contains(&v);
    let (xr, pxr) = (x as i64 - d, px as i64 - d);
    let gr = inside(xr)
        && inside(pxr)
        && (right.at(xr as usize, y) - right.at(pxr as usize, py)).abs()
            >= params.gradient_threshold;
    let divisor = match (gl, gr) {
        (false, false) => 1.0,
        (true, true) => params.q2,
        _ => params.q1,
    };
    let p1 = params.p1 / divisor / if vertical { params.v } else { 1.0 };
    (p1, params.p2 / divisor)
}

/// Whether the step into each pixel along direction (dx, dy) crosses an edge
/// (`|I(p) − I(p − r)| ≥ D`); false where p − r is outside the image.
fn edge_flags(image: &GreyImage, dx: i64, dy: i64, threshold: f32) -> Vec<bool> {
    let (w, h) = (image.width as i64, image.height as i64);
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (px, py) = (x - dx, y - dy);
            px >= 0
                && py >= 0
                && px < w
                && py < h
                && (image.data[i as usize] - image.data[(py * w + px) as usize]).abs() >= threshold
        })
        .collect()
}

/// Penalty divisors `[none, one, both]` gradients.
fn divisors(params: &SgmParameters) -> [f32; 3] {
    [1.0, params.q1, params.q2]
}

/// The penalties of every step into one row along one direction, per disparity, laid out
/// so that one pixel's are contiguous: for pixel x, disparity index d reads entry
/// `w − 1 − x + d`, whose right pixel is `x − min − d`. One table per left edge flag.
struct RowPenalties {
    p1: [Vec<f32>; 2],
    p2: [Vec<f32>; 2],
    width: usize,
    count: usize,
}

impl RowPenalties {
    fn new(width: usize, count: usize) -> Self {
        let len = width + count - 1;
        RowPenalties {
            p1: [vec![0.0; len], vec![0.0; len]],
            p2: [vec![0.0; len], vec![0.0; len]],
            width,
            count,
        }
    }

    /// The tables for one row, from its right edge flags. The right gradient exists only
    /// where the right pixel is inside the image (the flags are false where its
    /// predecessor along the path is not).
    fn fill(&mut self, right_edges: &[bool], min_disp: i64, base: (f32, f32), d: &[f32; 3]) {
        self.fill_columns(right_edges, min_disp, base, d, 0..self.width);
    }

    /// [`Self::fill`] for the steps into the left pixels `columns` only (the entries
    /// [`Self::at`] reads for them).
    fn fill_columns(
        &mut self,
        right_edges: &[bool],
        min_disp: i64,
        (p1, p2): (f32, f32),
        d: &[f32; 3],
        columns: Range<usize>,
    ) {
        if columns.is_empty() {
            return;
        }
        let w = self.width as i64;
        let first = self.width - columns.end;
        for j in first..self.width - columns.start + self.count - 1 {
            let xr = w - 1 - min_disp - j as i64;
            let right = usize::from((0..w).contains(&xr) && right_edges[xr as usize]);
            for left in 0..2 {
                self.p1[left][j] = p1 / d[left + right];
                self.p2[left][j] = p2 / d[left + right];
            }
        }
    }

    /// (P1, P2) per disparity of the step into pixel x.
    #[inline(always)]
    fn at(&self, x: usize, left_edge: bool) -> (&[f32], &[f32]) {
        let (first, table) = (self.width - 1 - x, usize::from(left_edge));
        (
            &self.p1[table][first..][..self.count],
            &self.p2[table][first..][..self.count],
        )
    }
}

/// One pixel's path costs, `count + 2` values with +∞ at both ends (so that the
/// neighbouring disparities of the first and last need no test), and their minimum.
#[derive(Clone)]
struct PathCosts {
    values: Vec<f32>,
    min: f32,
}

impl PathCosts {
    fn new(count: usize) -> Self {
        let mut values = vec![f32::INFINITY; count + 2];
        values[1..=count].fill(0.0);
        PathCosts { values, min: 0.0 }
    }

    /// A path's first pixel: its own costs, added to `sum`.
    #[inline(always)]
    fn start(&mut self, costs: &[f32], sum: &mut [f32]) {
        let n = costs.len();
        self.values[1..=n].copy_from_slice(costs);
        for (s, c) in sum.iter_mut().zip(costs) {
            *s += c;
        }
        self.min = minimum(costs);
    }

    /// One path step into a pixel with costs `costs` from `previous`:
    /// `L(d) = C(d) + min(L'(d), L'(d ± 1) + P1(d), min L' + P2(d)) − min L'`, added to
    /// `sum`. (`min(a, b) + P1` is `min(a + P1, b + P1)` exactly: rounding is monotone.)
    #[inline(always)]
    fn step(
        &mut self,
        previous: &PathCosts,
        costs: &[f32],
        (p1, p2): (&[f32], &[f32]),
        sum: &mut [f32],
    ) {
        let n = costs.len();
        let (prev, min_prev) = (&previous.values[..n + 2], previous.min);
        let current = &mut self.values[1..=n];
        let (p1, p2, sum) = (&p1[..n], &p2[..n], &mut sum[..n]);
        for d in 0..n {
            let neighbour = prev[d].min(prev[d + 2]) + p1[d];
            let best = prev[d + 1].min(neighbour).min(min_prev + p2[d]);
            let value = costs[d] + best - min_prev;
            current[d] = value;
            sum[d] += value;
        }
        self.min = minimum(current);
    }
}

/// The least of a slice (+∞ when empty; NaN never least), over eight independent lanes
/// so that it vectorises.
#[inline(always)]
pub(super) fn minimum(values: &[f32]) -> f32 {
    let mut lanes = [f32::INFINITY; 8];
    let chunks = values.chunks_exact(8);
    let tail = chunks
        .remainder()
        .iter()
        .fold(f32::INFINITY, |m, &v| m.min(v));
    for chunk in chunks {
        for (lane, &v) in lanes.iter_mut().zip(chunk) {
            *lane = lane.min(v);
        }
    }
    lanes.iter().fold(tail, |m, &v| m.min(v))
}

/// (P1, P2) of one path direction before the gradient divisors: P1 divided by V on
/// vertical paths.
fn direction_penalties(params: &SgmParameters, dx: i64) -> (f32, f32) {
    let vertical = dx == 0;
    (params.p1 / if vertical { params.v } else { 1.0 }, params.p2)
}

/// Sums the path costs of `directions` (mean over paths). Memory: the output plus a row
/// of path costs per direction; nothing is allocated per pixel. The horizontal paths run
/// together, row by row; the others row after row along the path, each row's pixels in
/// parallel.
pub(crate) fn aggregate(
    volume: &CostVolume,
    left: &GreyImage,
    right: &GreyImage,
    params: &SgmParameters,
    directions: &[(i64, i64)],
) -> CostVolume {
    let (w, h, dm) = (volume.width, volume.height, volume.count());
    let mut sum = crate::io::zeroed_large(w * h * dm);
    let horizontal: Vec<i64> = directions
        .iter()
        .filter(|d| d.1 == 0)
        .map(|d| d.0)
        .collect();
    let vertical: Vec<i64> = directions
        .iter()
        .filter(|d| d.0 == 0 && d.1 != 0)
        .map(|d| d.1)
        .collect();
    let diagonal: Vec<(i64, i64)> = directions
        .iter()
        .copied()
        .filter(|d| d.0 != 0 && d.1 != 0)
        .collect();
    // The pass that runs last divides the sums by the number of paths as it leaves each
    // part of them, instead of a pass of its own over the whole volume.
    let n = directions.len() as f32;
    let last = |is_last: bool| is_last.then_some(n);
    if !horizontal.is_empty() {
        let finish = last(vertical.is_empty() && diagonal.is_empty());
        aggregate_along_rows(volume, left, right, params, &horizontal, &mut sum, finish);
    }
    if !vertical.is_empty() {
        let finish = last(diagonal.is_empty());
        aggregate_along_columns(volume, left, right, params, &vertical, &mut sum, finish);
    }
    for (i, &direction) in diagonal.iter().enumerate() {
        let finish = last(i + 1 == diagonal.len());
        aggregate_across_rows(volume, left, right, params, direction, &mut sum, finish);
    }
    CostVolume {
        width: w,
        height: h,
        range: volume.range,
        data: sum,
    }
}

/// The horizontal paths (`dxs`, each ±1), added to `sum`: rows are independent, so one
/// task per row runs every direction over it while the row is in cache.
fn aggregate_along_rows(
    volume: &CostVolume,
    left: &GreyImage,
    right: &GreyImage,
    params: &SgmParameters,
    dxs: &[i64],
    sum: &mut [f32],
    finish: Option<f32>,
) {
    let (w, dm) = (volume.width, volume.count());
    let min_disp = volume.range.min as i64;
    let divisor = divisors(params);
    let threshold = params.gradient_threshold;
    let edges: Vec<(i64, Vec<bool>, Vec<bool>)> = dxs
        .iter()
        .map(|&dx| {
            let flags = |image| edge_flags(image, dx, 0, threshold);
            (dx, flags(left), flags(right))
        })
        .collect();
    sum.par_chunks_mut(w * dm).enumerate().for_each_init(
        || {
            let path = PathCosts::new(dm);
            (RowPenalties::new(w, dm), path.clone(), path)
        },
        |(penalties, previous, current), (y, row)| {
            for (dx, left_edges, right_edges) in &edges {
                let row_edges = &right_edges[y * w..(y + 1) * w];
                let base = direction_penalties(params, *dx);
                penalties.fill(row_edges, min_disp, base, &divisor);
                for i in 0..w {
                    let x = if *dx > 0 { i } else { w - 1 - i };
                    let (costs, out) = (volume.pixel(x, y), &mut row[x * dm..(x + 1) * dm]);
                    if i == 0 {
                        current.start(costs, out);
                    } else {
                        let step = penalties.at(x, left_edges[y * w + x]);
                        current.step(previous, costs, step, out);
                    }
                    std::mem::swap(previous, current);
                }
            }
            if let Some(n) = finish {
                row.iter_mut().for_each(|s| *s /= n);
            }
        },
    );
}

/// Columns per task of [`aggregate_along_columns`].
const COLUMNS_PER_TASK: usize = 32;

/// The vertical paths (`dys`, each ±1), added to `sum`: columns are independent, so one
/// task per block of [`COLUMNS_PER_TASK`] columns runs every direction down or up it,
/// with no synchronisation between rows.
fn aggregate_along_columns(
    volume: &CostVolume,
    left: &GreyImage,
    right: &GreyImage,
    params: &SgmParameters,
    dys: &[i64],
    sum: &mut [f32],
    finish: Option<f32>,
) {
    let (w, h, dm) = (volume.width, volume.height, volume.count());
    let min_disp = volume.range.min as i64;
    let (divisor, base) = (divisors(params), direction_penalties(params, 0));
    let edges: Vec<(i64, Vec<bool>, Vec<bool>)> = dys
        .iter()
        .map(|&dy| {
            let flags = |image| edge_flags(image, 0, dy, params.gradient_threshold);
            (dy, flags(left), flags(right))
        })
        .collect();
    // Each block's slice of every row: disjoint borrows, one list per block.
    let blocks = w.div_ceil(COLUMNS_PER_TASK);
    let mut columns: Vec<Vec<&mut [f32]>> = (0..blocks).map(|_| Vec::with_capacity(h)).collect();
    for row in sum.chunks_exact_mut(w * dm) {
        for (block, part) in columns
            .iter_mut()
            .zip(row.chunks_mut(COLUMNS_PER_TASK * dm))
        {
            block.push(part);
        }
    }
    columns
        .into_par_iter()
        .enumerate()
        .for_each(|(block, mut rows)| {
            let x0 = block * COLUMNS_PER_TASK;
            let xs = x0..(x0 + COLUMNS_PER_TASK).min(w);
            let mut penalties = RowPenalties::new(w, dm);
            let mut previous = vec![PathCosts::new(dm); xs.len()];
            let mut current = previous.clone();
            for (direction, (dy, left_edges, right_edges)) in edges.iter().enumerate() {
                let finish = finish.filter(|_| direction + 1 == edges.len());
                for i in 0..h {
                    let y = if *dy > 0 { i } else { h - 1 - i };
                    let row_edges = &right_edges[y * w..(y + 1) * w];
                    penalties.fill_columns(row_edges, min_disp, base, &divisor, xs.clone());
                    let out_row = &mut rows[y];
                    for (j, (path, out)) in current
                        .iter_mut()
                        .zip(out_row.chunks_exact_mut(dm))
                        .enumerate()
                    {
                        let x = x0 + j;
                        let costs = volume.pixel(x, y);
                        if i == 0 {
                            path.start(costs, out);
                        } else {
                            let step = penalties.at(x, left_edges[y * w + x]);
                            path.step(&previous[j], costs, step, out);
                        }
                    }
                    if let Some(n) = finish {
                        out_row.iter_mut().for_each(|s| *s /= n);
                    }
                    std::mem::swap(&mut previous, &mut current);
                }
            }
        });
}

/// One diagonal path direction, added to `sum`: each row depends on the previous one
/// along the path, so rows go in order and the pixels of a row in parallel.
fn aggregate_across_rows(
    volume: &CostVolume,
    left: &GreyImage,
    right: &GreyImage,
    params: &SgmParameters,
    (dx, dy): (i64, i64),
    sum: &mut [f32],
    finish: Option<f32>,
) {
    const PIXELS_PER_TASK: usize = 32;
    let (w, h, dm) = (volume.width, volume.height, volume.count());
    let min_disp = volume.range.min as i64;
    let divisor = divisors(params);
    let left_edges = edge_flags(left, dx, dy, params.gradient_threshold);
    let right_edges = edge_flags(right, dx, dy, params.gradient_threshold);
    let mut penalties = RowPenalties::new(w, dm);
    let mut previous_row = vec![PathCosts::new(dm); w];
    let mut current_row = previous_row.clone();
    for i in 0..h {
        let y = if dy > 0 { i } else { h - 1 - i };
        let row_edges = &right_edges[y * w..(y + 1) * w];
        let base = direction_penalties(params, dx);
        penalties.fill(row_edges, min_disp, base, &divisor);
        current_row
            .par_chunks_mut(PIXELS_PER_TASK)
            .zip(sum[y * w * dm..(y + 1) * w * dm].par_chunks_mut(dm * PIXELS_PER_TASK))
            .enumerate()
            .for_each(|(block, (current_block, sum_block))| {
                for (j, (current, out)) in current_block
                    .iter_mut()
                    .zip(sum_block.chunks_exact_mut(dm))
                    .enumerate()
                {
                    let x = block * PIXELS_PER_TASK + j;
                    let costs = volume.pixel(x, y);
                    let px = x as i64 - dx;
                    if i == 0 || px < 0 || px >= w as i64 {
                        current.start(costs, out);
                    } else {
                        let step = penalties.at(x, left_edges[y * w + x]);
                        current.step(&previous_row[px as usize], costs, step, out);
                    }
                }
                if let Some(n) = finish {
                    sum_block.iter_mut().for_each(|s| *s /= n);
                }
            });
        std::mem::swap(&mut previous_row, &mut current_row);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn uniform(seed: &mut u64) -> f32 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 40) as f32) / (1u64 << 24) as f32
    }

    #[test]
    fn each_path_matches_a_plain_dynamic_programme() {
        for range in [DisparityRange::new(0, 5), DisparityRange::new(-3, 2)] {
            each_path_matches_a_plain_dynamic_programme_over(range.unwrap());
        }
    }

    #[test]
    fn several_paths_give_the_mean_of_each_path() {
        // The horizontal paths run together over each row; the result must still be
        // the mean of the paths run one by one.
        let (w, h) = (11, 6);
        let range = DisparityRange::new(-2, 5).unwrap();
        let mut seed = 7;
        let mut random = |n: usize| -> Vec<f32> { (0..n).map(|_| uniform(&mut seed)).collect() };
        let volume = CostVolume {
            width: w,
            height: h,
            range,
            data: random(w * h * range.count()),
        };
        let image = |data| GreyImage {
            channels: 1,
            width: w,
            height: h,
            data,
        };
        let (left, right) = (image(random(w * h)), image(random(w * h)));
        let params = SgmParameters {
            gradient_threshold: 0.3,
            ..SgmParameters::MC_CNN_FAST_KITTI
        };
        for directions in [&DIRECTIONS[..4], &DIRECTIONS[..]] {
            let together = aggregate(&volume, &left, &right, &params, directions);
            let mut mean = vec![0f32; together.data.len()];
            for &direction in directions {
                let single = aggregate(&volume, &left, &right, &params, &[direction]);
                for (m, v) in mean.iter_mut().zip(&single.data) {
                    *m += v / directions.len() as f32;
                }
            }
            for (i, (a, b)) in together.data.iter().zip(&mean).enumerate() {
                assert!(
                    (a - b).abs() < 1e-4,
                    "{} paths, entry {i}: {a} vs {b}",
                    directions.len()
                );
            }
        }
    }

    fn each_path_matches_a_plain_dynamic_programme_over(range: DisparityRange) {
        // More columns than one task of the vertical paths takes, the last block ragged.
        let (w, h, dm) = (71, 7, range.count());
        let mut seed = 3;
        let volume = CostVolume {
            width: w,
            height: h,
            range,
            data: (0..w * h * dm).map(|_| uniform(&mut seed)).collect(),
        };
        let image = GreyImage {
            channels: 1,
            width: w,
            height: h,
            data: (0..w * h).map(|_| uniform(&mut seed)).collect(),
        };
        let right = GreyImage {
            channels: 1,
            width: w,
            height: h,
            data: (0..w * h).map(|_| uniform(&mut seed)).collect(),
        };
        let params = SgmParameters {
            p1: 0.1,
            p2: 0.4,
            q1: 2.0,
            q2: 4.0,
            v: 1.5,
            gradient_threshold: 0.3,
            paths: 8,
        };
        for &(dx, dy) in &DIRECTIONS {
            let got = aggregate(&volume, &image, &right, &params, &[(dx, dy)]);
            // Plain recursion over the path, memoised by visiting order.
            let mut want = vec![f32::NAN; w * h * dm];
            #[allow(clippy::too_many_arguments)]
            fn l(
                x: i64,
                y: i64,
                d: usize,
                dir: (i64, i64),
                v: &CostVolume,
                img: &GreyImage,
                right: &GreyImage,
                p: &SgmParameters,
                memo: &mut Vec<f32>,
            ) -> f32 {
                let (w, h, dm) = (v.width as i64, v.height as i64, v.count());
                let i = ((y * w + x) as usize) * dm + d;
                if !memo[i].is_nan() {
                    return memo[i];
                }
                let c = v.pixel(x as usize, y as usize)[d];
                let (px, py) = (x - dir.0, y - dir.1);
                let value = if px < 0 || py < 0 || px >= w || py >= h {
                    c
                } else {
                    let prev: Vec<f32> = (0..dm)
                        .map(|k| l(px, py, k, dir, v, img, right, p, memo))
                        .collect();
                    let (p1, p2) = penalties(
                        img,
                        right,
                        p,
                        dir.0 == 0,
                        x as usize,
                        y as usize,
                        px as usize,
                        py as usize,
                        v.range.min as i64 + d as i64,
                    );
                    let m = prev.iter().cloned().fold(f32::INFINITY, f32::min);
                    let mut best = prev[d].min(m + p2);
                    if d > 0 {
                        best = best.min(prev[d - 1] + p1);
                    }
                    if d + 1 < dm {
                        best = best.min(prev[d + 1] + p1);
                    }
                    c + best - m
                };
                memo[i] = value;
                value
            }
            for y in 0..h {
                for x in 0..w {
                    for d in 0..dm {
                        let expected = l(
                            x as i64,
                            y as i64,
                            d,
                            (dx, dy),
                            &volume,
                            &image,
                            &right,
                            &params,
                            &mut want,
                        );
                        let actual = got.pixel(x, y)[d];
                        assert!(
                            (actual - expected).abs() < 1e-5,
                            "dir ({dx},{dy}) at ({x},{y},{d}): {actual} vs {expected}"
                        );
                    }
                }
            }
        }
    }
}
