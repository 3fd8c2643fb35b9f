//! The learned cross-spectral matching cost (paper section 2.2, MC-CNN): each image goes
//! through the network's convolutional tower ([`super::tower`]); the fast network
//! compares the L2-normalised features by cosine similarity, the accurate one runs its
//! fully connected layers on every (pixel, disparity) pair. The result is an ordinary
//! [`CostVolume`] in [0, 1] for the refinement chain.

use super::contrast::negated;
use super::cost_volume::{keep_lower, matched_indices, right_column};
use super::network::MatchingNetwork;
use super::tower::{tower_features, FeatureMap, StripScratch, Tower, STRIP_ROWS};
use super::{CostVolume, DisparityRange, GreyImage};
use crate::scratch::ScratchPool;
use rayon::prelude::*;

/// `dst = a · b` for row-major `a` (m × k), `b` (k × n), `dst` (m × n), single-threaded
/// (callers parallelise over blocks).
pub(crate) fn matmul(dst: &mut [f32], a: &[f32], b: &[f32], m: usize, n: usize, k: usize) {
    assert!(b.len() >= k * n);
    // bᵀ's element (i, j) is b[i·n + j]: column stride 1, row stride n.
    product(dst, a, (b, 1, n as isize), (m, n, k));
}

/// `dst = a · bᵀ` for row-major `a` (m × k), `b` (n × k), `dst` (m × n), single-threaded.
fn matmul_transposed(dst: &mut [f32], a: &[f32], b: &[f32], m: usize, n: usize, k: usize) {
    assert!(b.len() >= n * k);
    // bᵀ's element (i, j) is b[j·k + i]: column stride k, row stride 1.
    product(dst, a, (b, k as isize, 1), (m, n, k));
}

/// `dst = a · B` for row-major `a` (m × k) and `dst` (m × n), where B's element (i, j) is
/// `b[i·row_stride + j·col_stride]` (the caller checks that `b` holds them all).
fn product(
    dst: &mut [f32],
    a: &[f32],
    (b, col_stride, row_stride): (&[f32], isize, isize),
    (m, n, k): (usize, usize, usize),
) {
    assert!(dst.len() >= m * n && a.len() >= m * k);
    if m == 0 || n == 0 {
        return;
    }
    // SAFETY: the assertions here and in the callers keep every access of the strides in
    // bounds, and `dst` does not alias `a` or `b` (distinct borrows).
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            n as isize,
            false,
            a.as_ptr(),
            1,
            k as isize,
            b.as_ptr(),
            col_stride,
            row_stride,
            0.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

/// The learned cost volume of a rectified pair (left is the reference), in [0, 1]:
/// `(1 − cos)/2` for fast networks, `1 − sigmoid(output)` for accurate ones.
pub fn learned_cost_volume(
    network: &MatchingNetwork,
    left: &GreyImage,
    right: &GreyImage,
    range: DisparityRange,
) -> CostVolume {
    if !network.is_accurate() {
        return streamed_cosine_costs(network, left, &[right], range);
    }
    let (fl, fr) = rayon::join(
        || tower_features(network, left),
        || tower_features(network, right),
    );
    accurate_costs(network, &fl, &fr, range)
}

/// [`learned_cost_volume`] for either sign of the right image at every pixel and
/// disparity ([`super::Contrast::Either`]): the lower of the costs against `right` and
/// against it negated, the left image's features computed once.
pub fn learned_cost_volume_either_sign(
    network: &MatchingNetwork,
    left: &GreyImage,
    right: &GreyImage,
    range: DisparityRange,
) -> CostVolume {
    let negated_right = negated(right);
    if !network.is_accurate() {
        return streamed_cosine_costs(network, left, &[right, &negated_right], range);
    }
    let (fl, (fr, fr_negated)) = rayon::join(
        || tower_features(network, left),
        || {
            rayon::join(
                || tower_features(network, right),
                || tower_features(network, &negated_right),
            )
        },
    );
    let mut volume = accurate_costs(network, &fl, &fr, range);
    volume.keep_lower(&accurate_costs(network, &fl, &fr_negated, range));
    volume
}

/// The fast network's cosine costs of `left` against each of `rights`, the lowest kept
/// ([`CostVolume::keep_lower`]), strip by strip: a strip's rows of every image go through
/// the tower and straight into that strip's costs, so no whole image's features are held
/// (two 95 MB maps for a 741×500 pair) and they are used while in cache. Equal to
/// [`cosine_costs`] of [`tower_features`].
fn streamed_cosine_costs(
    network: &MatchingNetwork,
    left: &GreyImage,
    rights: &[&GreyImage],
    range: DisparityRange,
) -> CostVolume {
    let (w, h, n) = (left.width, left.height, range.count());
    let tower = Tower::new(network);
    let (left_input, right_inputs) = rayon::join(
        || Tower::input(left),
        || rights.iter().map(|r| Tower::input(r)).collect::<Vec<_>>(),
    );
    let c = tower.features();
    let mut volume = CostVolume::new(w, h, range);
    let pool = ScratchPool::<(StripScratch, [Vec<f32>; 4])>::new();
    volume
        .data
        .par_chunks_mut(STRIP_ROWS * w * n)
        .enumerate()
        .for_each_init(
            || pool.take(),
            |lent, (strip, costs)| {
                let (scratch, [fl, fr, products, other]) = &mut **lent;
                let first = strip * STRIP_ROWS;
                let rows = first..first + costs.len() / (w * n);
                tower.strip(&left_input, rows.clone(), fl, scratch);
                for (i, right) in right_inputs.iter().enumerate() {
                    tower.strip(right, rows.clone(), fr, scratch);
                    let pairs = fl.chunks_exact(w * c).zip(fr.chunks_exact(w * c));
                    for (row, (lr, rr)) in costs.chunks_exact_mut(w * n).zip(pairs) {
                        if i == 0 {
                            cosine_row(lr, rr, c, range, row, products);
                        } else {
                            other.resize(w * n, CostVolume::INVALID);
                            cosine_row(lr, rr, c, range, other, products);
                            keep_lower(row, other);
                        }
                    }
                }
            },
        );
    volume
}

/// Left pixels per product block of [`cosine_row`]: the block's right pixels are these
/// plus the range's width, so wider blocks waste fewer products outside the band.
const COSINE_BLOCK: usize = 48;

/// `(1 − fl·fr)/2` over L2-normalised features, row by row ([`cosine_row`]).
pub fn cosine_costs(fl: &FeatureMap, fr: &FeatureMap, range: DisparityRange) -> CostVolume {
    let (w, h, c, n) = (fl.width, fl.height, fl.channels, range.count());
    let mut volume = CostVolume::new(w, h, range);
    volume
        .data
        .par_chunks_mut(w * n)
        .enumerate()
        .for_each_init(Vec::new, |products, (y, row)| {
            let rows = (
                &fl.data[y * w * c..][..w * c],
                &fr.data[y * w * c..][..w * c],
            );
            cosine_row(rows.0, rows.1, c, range, row, products);
        });
    volume
}

/// One row's cosine costs (`costs`: width × the range's count, its unmatched entries
/// left as they are) from its left and right features (width × `c`). Each block of left
/// pixels is multiplied with all the right pixels its disparities reach in one matrix
/// product (`gemm`), of which the band of matched pairs is kept.
fn cosine_row(
    left_row: &[f32],
    right_row: &[f32],
    c: usize,
    range: DisparityRange,
    costs: &mut [f32],
    products: &mut Vec<f32>,
) {
    let (w, n) = (left_row.len() / c.max(1), range.count());
    for x0 in (0..w).step_by(COSINE_BLOCK) {
        let xs = x0..(x0 + COSINE_BLOCK).min(w);
        // Right columns x − d for x in the block and d in the range, in the image.
        let first = (x0 as i64 - range.max as i64).max(0);
        let last = (xs.end as i64 - 1 - range.min as i64).min(w as i64 - 1);
        if first > last {
            continue;
        }
        let (first, columns) = (first as usize, (last - first + 1) as usize);
        products.resize(xs.len() * columns, 0.0);
        matmul_transposed(
            products,
            &left_row[x0 * c..xs.end * c],
            &right_row[first * c..][..columns * c],
            xs.len(),
            columns,
            c,
        );
        for (x, dots) in xs.zip(products.chunks_exact(columns)) {
            let pixel = &mut costs[x * n..][..n];
            for k in matched_indices(x, w, range) {
                let dot = dots[right_column(x, k, range) - first];
                pixel[k] = (0.5 - 0.5 * dot).clamp(0.0, 1.0);
            }
        }
    }
}

/// The accurate network's fully connected head over every (pixel, disparity) pair. The
/// first layer splits into a left and a right product computed once per pixel; the other
/// layers are batched per row and disparity.
fn accurate_costs(
    network: &MatchingNetwork,
    fl: &FeatureMap,
    fr: &FeatureMap,
    range: DisparityRange,
) -> CostVolume {
    let (w, h, c, n) = (fl.width, fl.height, fl.channels, range.count());
    let first = &network.dense[0];
    let units = first.outputs;
    let widest = network.dense.iter().map(|l| l.outputs).max().unwrap_or(1);
    let mut volume = CostVolume::new(w, h, range);
    volume.data.par_chunks_mut(w * n).enumerate().for_each_init(
        || {
            (
                vec![0f32; w * units],
                vec![0f32; w * units],
                vec![0f32; w * widest],
                vec![0f32; w * widest],
            )
        },
        |(al, ar, hidden, next), (y, row)| {
            matmul(
                al,
                &fl.data[y * w * c..][..w * c],
                &first.weight[..c * units],
                w,
                units,
                c,
            );
            matmul(
                ar,
                &fr.data[y * w * c..][..w * c],
                &first.weight[c * units..],
                w,
                units,
                c,
            );
            for k in 0..n {
                // Left columns whose right column x − d lies inside the image.
                let d = range.min as i64 + k as i64;
                let columns =
                    (d.max(0) as usize).min(w)..((w as i64 + d).clamp(0, w as i64) as usize);
                let m = columns.len();
                if m == 0 {
                    continue;
                }
                for (j, x) in columns.clone().enumerate() {
                    let out = &mut hidden[j * units..][..units];
                    for (((o, a), b), bias) in out
                        .iter_mut()
                        .zip(&al[x * units..][..units])
                        .zip(&ar[right_column(x, k, range) * units..][..units])
                        .zip(&first.bias)
                    {
                        *o = (a + b + bias).max(0.0);
                    }
                }
                let mut width = units;
                for (j, layer) in network.dense.iter().enumerate().skip(1) {
                    matmul(next, hidden, &layer.weight, m, layer.outputs, width);
                    let last = j + 1 == network.dense.len();
                    for pixel in next[..m * layer.outputs].chunks_exact_mut(layer.outputs) {
                        for (v, b) in pixel.iter_mut().zip(&layer.bias) {
                            *v += b;
                            if !last {
                                *v = v.max(0.0);
                            }
                        }
                    }
                    std::mem::swap(hidden, next);
                    width = layer.outputs;
                }
                for (j, x) in columns.enumerate() {
                    let logit = hidden[j * width];
                    row[x * n + k] = 1.0 / (1.0 + logit.exp());
                }
            }
        },
    );
    volume
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plain dot product the blocked products are checked against.
    fn dot(a: &[f32], b: &[f32]) -> f32 {
        a.iter().zip(b).map(|(p, q)| p * q).sum()
    }

    /// Unit feature vectors of deterministic noise.
    fn unit_features(w: usize, h: usize, c: usize, seed: u64) -> FeatureMap {
        let mut state = seed;
        let mut data: Vec<f32> = (0..w * h * c)
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect();
        for v in data.chunks_exact_mut(c) {
            let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.iter_mut().for_each(|x| *x /= norm);
        }
        FeatureMap {
            width: w,
            height: h,
            channels: c,
            data,
        }
    }

    #[test]
    fn blocked_cosine_costs_equal_the_pairwise_dot_products() {
        for (w, c, min, max) in [
            (101, 64, 0, 63),
            (37, 16, -20, 5),
            (5, 8, 3, 40),
            (130, 24, -70, -60),
        ] {
            let (fl, fr) = (unit_features(w, 3, c, 1), unit_features(w, 3, c, 2));
            let range = DisparityRange::new(min, max).expect("range");
            let volume = cosine_costs(&fl, &fr, range);
            let n = range.count();
            for y in 0..3 {
                for x in 0..w {
                    for k in 0..n {
                        let got = volume.data[(y * w + x) * n + k];
                        let want = if matched_indices(x, w, range).contains(&k) {
                            let xr = right_column(x, k, range);
                            let d = dot(fl.pixel(x, y), fr.pixel(xr, y));
                            (0.5 - 0.5 * d).clamp(0.0, 1.0)
                        } else {
                            CostVolume::INVALID
                        };
                        assert!(
                            (got - want).abs() <= 1e-6,
                            "{w} wide, {c} channels, range {min}:{max}: ({x}, {y}, {k}) {got} against {want}"
                        );
                    }
                }
            }
        }
    }

    /// A `w × h` grey image of deterministic noise with some structure.
    fn grey(w: usize, h: usize, seed: u64) -> GreyImage {
        let noise = unit_features(w, h, 1, seed);
        GreyImage {
            channels: 1,
            width: w,
            height: h,
            data: (noise.data.iter().enumerate())
                .map(|(i, v)| 0.5 + 0.3 * v + 0.1 * ((i % w) as f32 * 0.3).sin())
                .collect(),
        }
    }

    #[test]
    fn streamed_costs_equal_the_costs_of_whole_feature_maps() {
        let network = MatchingNetwork::default_fast().expect("embedded network");
        // 75 rows: two whole strips and a ragged one; a signed range.
        let (w, h) = (57, 75);
        let (left, right) = (grey(w, h, 3), grey(w, h, 4));
        let range = DisparityRange::new(-5, 12).expect("range");
        let (fl, fr) = (
            tower_features(&network, &left),
            tower_features(&network, &right),
        );
        let want = cosine_costs(&fl, &fr, range);
        let got = learned_cost_volume(&network, &left, &right, range);
        assert_eq!(got.data, want.data);
        let mut want = want;
        let fr_negated = tower_features(&network, &negated(&right));
        want.keep_lower(&cosine_costs(&fl, &fr_negated, range));
        let got = learned_cost_volume_either_sign(&network, &left, &right, range);
        assert_eq!(got.data, want.data);
    }
}
