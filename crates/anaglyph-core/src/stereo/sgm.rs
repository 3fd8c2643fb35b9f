//! Semi-global matching (Hirschmüller 2008) with MC-CNN's gradient-dependent penalties
//! (Zbontar & LeCun 2016): along each path direction r,
//! `L_r(p,d) = C(p,d) + min(L_r(p−r,d), L_r(p−r,d±1) + P1, min_k L_r(p−r,k) + P2) − min_k L_r(p−r,k)`,
//! and the result is the mean of the paths. P1 and P2 are divided by Q1 where one image
//! gradient along the path exceeds D, by Q2 where both do, and P1 by V on vertical paths.

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

/// Penalties (P1, P2) at left pixel (x, y) and disparity d for the step from (px, py).
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
    d: usize,
) -> (f32, f32) {
    let gl = (left.at(x, y) - left.at(px, py)).abs() >= params.gradient_threshold;
    let gr = x >= d
        && px >= d
        && (right.at(x - d, y) - right.at(px - d, py)).abs() >= params.gradient_threshold;
    let divisor = match (gl, gr) {
        (false, false) => 1.0,
        (true, true) => params.q2,
        _ => params.q1,
    };
    let p1 = params.p1 / divisor / if vertical { params.v } else { 1.0 };
    (p1, params.p2 / divisor)
}

/// One scan: updates `current` (this pixel's L) from `previous` (the pixel before).
#[allow(clippy::too_many_arguments)]
fn step(costs: &[f32], previous: &[f32], current: &mut [f32], p1: impl Fn(usize) -> (f32, f32)) {
    let dmax = costs.len();
    let min_prev = previous.iter().cloned().fold(f32::INFINITY, f32::min);
    for d in 0..dmax {
        let (p1, p2) = p1(d);
        let mut best = previous[d];
        if d > 0 {
            best = best.min(previous[d - 1] + p1);
        }
        if d + 1 < dmax {
            best = best.min(previous[d + 1] + p1);
        }
        best = best.min(min_prev + p2);
        current[d] = costs[d] + best - min_prev;
    }
}

pub(crate) fn aggregate(
    volume: &CostVolume,
    left: &GreyImage,
    right: &GreyImage,
    params: &SgmParameters,
    directions: &[(i64, i64)],
) -> CostVolume {
    let (w, h, dm) = (volume.width, volume.height, volume.max_disp);
    let mut sum = vec![0f32; w * h * dm];
    for &(dx, dy) in directions {
        let vertical = dx == 0;
        let mut lr = vec![0f32; w * h * dm];
        // Pixels are visited so that p − r is always done before p.
        let ys: Vec<usize> = if dy >= 0 {
            (0..h).collect()
        } else {
            (0..h).rev().collect()
        };
        let xs: Vec<usize> = if dx >= 0 {
            (0..w).collect()
        } else {
            (0..w).rev().collect()
        };
        if dy == 0 {
            lr.par_chunks_mut(w * dm).enumerate().for_each(|(y, row)| {
                for &x in &xs {
                    let costs = volume.pixel(x, y);
                    let px = x as i64 - dx;
                    if px < 0 || px >= w as i64 {
                        row[x * dm..(x + 1) * dm].copy_from_slice(costs);
                        continue;
                    }
                    let px = px as usize;
                    let (a, b) = if px < x {
                        row.split_at_mut(x * dm)
                    } else {
                        let (b, a) = row.split_at_mut(px * dm);
                        (a, b)
                    };
                    let (previous, current) = if px < x {
                        (&a[px * dm..(px + 1) * dm], &mut b[..dm])
                    } else {
                        (&a[..dm], &mut b[x * dm..(x + 1) * dm])
                    };
                    step(costs, previous, current, |d| {
                        penalties(left, right, params, vertical, x, y, px, y, d)
                    });
                }
            });
        } else {
            for &y in &ys {
                let py = y as i64 - dy;
                if py < 0 || py >= h as i64 {
                    for x in 0..w {
                        lr[(y * w + x) * dm..(y * w + x + 1) * dm]
                            .copy_from_slice(volume.pixel(x, y));
                    }
                    continue;
                }
                let py = py as usize;
                let (before, after) = lr.split_at_mut(y.max(py) * w * dm);
                let (previous_row, current_row) = if py < y {
                    (
                        &before[py * w * dm..(py + 1) * w * dm],
                        &mut after[..w * dm],
                    )
                } else {
                    (&after[..w * dm], &mut before[y * w * dm..(y + 1) * w * dm])
                };
                current_row
                    .par_chunks_mut(dm)
                    .enumerate()
                    .for_each(|(x, current)| {
                        let costs = volume.pixel(x, y);
                        let px = x as i64 - dx;
                        if px < 0 || px >= w as i64 {
                            current.copy_from_slice(costs);
                            return;
                        }
                        let px = px as usize;
                        step(costs, &previous_row[px * dm..(px + 1) * dm], current, |d| {
                            penalties(left, right, params, vertical, x, y, px, py, d)
                        });
                    });
            }
        }
        sum.par_iter_mut().zip(&lr).for_each(|(s, l)| *s += l);
    }
    let n = directions.len() as f32;
    sum.par_iter_mut().for_each(|s| *s /= n);
    CostVolume {
        width: w,
        height: h,
        max_disp: dm,
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
        let (w, h, dm) = (9, 7, 5);
        let mut seed = 3;
        let volume = CostVolume {
            width: w,
            height: h,
            max_disp: dm,
            data: (0..w * h * dm).map(|_| uniform(&mut seed)).collect(),
        };
        let image = GreyImage {
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
            let got = aggregate(&volume, &image, &image, &params, &[(dx, dy)]);
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
                p: &SgmParameters,
                memo: &mut Vec<f32>,
            ) -> f32 {
                let (w, h, dm) = (v.width as i64, v.height as i64, v.max_disp);
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
                        .map(|k| l(px, py, k, dir, v, img, p, memo))
                        .collect();
                    let (p1, p2) = penalties(
                        img,
                        img,
                        p,
                        dir.0 == 0,
                        x as usize,
                        y as usize,
                        px as usize,
                        py as usize,
                        d,
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
