//! Semi-global matching (Hirschmüller 2008) with MC-CNN's gradient-dependent penalties
//! (Zbontar & LeCun 2016): along each path direction r,
//! `L_r(p,d) = C(p,d) + min(L_r(p−r,d), L_r(p−r,d±1) + P1, min_k L_r(p−r,k) + P2) − min_k L_r(p−r,k)`,
//! and the result is the mean of the paths. P1 and P2 are divided by Q1 where one image
//! gradient along the path exceeds D, by Q2 where both do, and P1 by V on vertical paths.

#[cfg(test)]
use super::DisparityRange;
use super::{CostVolume, GreyImage};
use rayon::prelude::*;

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

/// One path step at pixel p: `current[d] = C(p,d) + min(...) − min_k previous[k]`, with the
/// penalties chosen per disparity from the left edge flag and the right one at p − d
/// (`d = min_disp + index`).
#[allow(clippy::too_many_arguments)]
#[inline]
fn step(
    costs: &[f32],
    previous: &[f32],
    current: &mut [f32],
    left_edge: bool,
    right_edges: &[bool],
    (x, px): (usize, usize),
    min_disp: i64,
    p1: f32,
    p2: f32,
    divisor: &[f32; 3],
) {
    let dmax = costs.len();
    let w = right_edges.len() as i64;
    let min_prev = previous.iter().cloned().fold(f32::INFINITY, f32::min);
    for d in 0..dmax {
        // The right gradient exists only where both right pixels are inside the image.
        let (xr, pxr) = (
            x as i64 - min_disp - d as i64,
            px as i64 - min_disp - d as i64,
        );
        let right_edge = xr >= 0 && xr < w && pxr >= 0 && pxr < w && right_edges[xr as usize];
        let k = usize::from(left_edge) + usize::from(right_edge);
        let (p1, p2) = (p1 / divisor[k], p2 / divisor[k]);
        let mut best = previous[d].min(min_prev + p2);
        if d > 0 {
            best = best.min(previous[d - 1] + p1);
        }
        if d + 1 < dmax {
            best = best.min(previous[d + 1] + p1);
        }
        current[d] = costs[d] + best - min_prev;
    }
}

/// Sums the path costs of `directions` (mean over paths). Memory: the output plus two
/// rows of path costs per direction; nothing is allocated per pixel.
pub(crate) fn aggregate(
    volume: &CostVolume,
    left: &GreyImage,
    right: &GreyImage,
    params: &SgmParameters,
    directions: &[(i64, i64)],
) -> CostVolume {
    let (w, h, dm) = (volume.width, volume.height, volume.count());
    let min_disp = volume.range.min as i64;
    let mut sum = crate::io::zeroed_large(w * h * dm);
    let divisor = divisors(params);
    for &(dx, dy) in directions {
        let vertical = dx == 0;
        let p1 = params.p1 / if vertical { params.v } else { 1.0 };
        let p2 = params.p2;
        let left_edges = edge_flags(left, dx, dy, params.gradient_threshold);
        let right_edges = edge_flags(right, dx, dy, params.gradient_threshold);
        if dy == 0 {
            // Rows are independent: one pass per row, in parallel.
            sum.par_chunks_mut(w * dm).enumerate().for_each_init(
                || (vec![0f32; dm], vec![0f32; dm]),
                |(previous, current), (y, row)| {
                    let xs: Box<dyn Iterator<Item = usize>> = if dx > 0 {
                        Box::new(0..w)
                    } else {
                        Box::new((0..w).rev())
                    };
                    let right_row = &right_edges[y * w..(y + 1) * w];
                    for (i, x) in xs.enumerate() {
                        let costs = volume.pixel(x, y);
                        if i == 0 {
                            current.copy_from_slice(costs);
                        } else {
                            let px = (x as i64 - dx) as usize;
                            step(
                                costs,
                                previous,
                                current,
                                left_edges[y * w + x],
                                right_row,
                                (x, px),
                                min_disp,
                                p1,
                                p2,
                                &divisor,
                            );
                        }
                        for (s, c) in row[x * dm..(x + 1) * dm].iter_mut().zip(current.iter()) {
                            *s += c;
                        }
                        std::mem::swap(previous, current);
                    }
                },
            );
        } else {
            // Each row depends on the previous one along the path: rows in order, the
            // pixels of a row in parallel.
            let mut previous_row = vec![0f32; w * dm];
            let mut current_row = vec![0f32; w * dm];
            let ys: Vec<usize> = if dy > 0 {
                (0..h).collect()
            } else {
                (0..h).rev().collect()
            };
            for (i, &y) in ys.iter().enumerate() {
                let right_row = &right_edges[y * w..(y + 1) * w];
                current_row
                    .par_chunks_mut(dm * 32)
                    .zip(sum[y * w * dm..(y + 1) * w * dm].par_chunks_mut(dm * 32))
                    .enumerate()
                    .for_each(|(block, (current_block, sum_block))| {
                        for (j, (current, s)) in current_block
                            .chunks_exact_mut(dm)
                            .zip(sum_block.chunks_exact_mut(dm))
                            .enumerate()
                        {
                            let x = block * 32 + j;
                            let costs = volume.pixel(x, y);
                            let px = x as i64 - dx;
                            if i == 0 || px < 0 || px >= w as i64 {
                                current.copy_from_slice(costs);
                            } else {
                                let px = px as usize;
                                step(
                                    costs,
                                    &previous_row[px * dm..(px + 1) * dm],
                                    current,
                                    left_edges[y * w + x],
                                    right_row,
                                    (x, px),
                                    min_disp,
                                    p1,
                                    p2,
                                    &divisor,
                                );
                            }
                            for (a, c) in s.iter_mut().zip(current.iter()) {
                                *a += c;
                            }
                        }
                    });
                std::mem::swap(&mut previous_row, &mut current_row);
            }
        }
    }
    let n = directions.len() as f32;
    sum.par_iter_mut().for_each(|s| *s /= n);
    CostVolume {
        width: w,
        height: h,
        range: volume.range,
        data: sum,
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

    fn each_path_matches_a_plain_dynamic_programme_over(range: DisparityRange) {
        let (w, h, dm) = (9, 7, range.count());
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
