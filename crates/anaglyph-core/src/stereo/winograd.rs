//! Winograd's minimal filtering F(4×4, 3×3) (Lavin & Gray 2016) for the matching network's
//! 3×3 "same" convolutions, the inner loop of the learned cost in the stage
//! `captures -> stereo (cost -> ...)`. Each 6×6 input tile and each kernel go to the
//! transform domain, where the 36 element-wise products over channels become 36 small
//! matrix products (`gemm`), and each tile comes back as 4×4 outputs: 36 multiplications
//! per output channel and tile instead of 144, so about a quarter of the direct
//! convolution's arithmetic. Single-threaded over the rows asked for, with the caller's
//! scratch buffers: the tower ([`super::tower`]) runs one strip of rows per rayon task.

use super::learned::matmul;
use super::network::{ConvLayer, KERNEL};
use super::tower::FeatureMap;
use std::ops::Range;

/// Side of an output tile.
const OUT: usize = 4;
/// Side of an input tile (`OUT + KERNEL − 1`).
const TILE: usize = OUT + KERNEL - 1;
/// Points of the transform domain.
const POINTS: usize = TILE * TILE;

/// Kernel transform G of F(4, 3).
const G: [[f64; KERNEL]; TILE] = [
    [1.0 / 4.0, 0.0, 0.0],
    [-1.0 / 6.0, -1.0 / 6.0, -1.0 / 6.0],
    [-1.0 / 6.0, 1.0 / 6.0, -1.0 / 6.0],
    [1.0 / 24.0, 1.0 / 12.0, 1.0 / 6.0],
    [1.0 / 24.0, -1.0 / 12.0, 1.0 / 6.0],
    [0.0, 0.0, 1.0],
];

/// The layer's kernels in the transform domain, `u[(point·inputs + c)·outputs + o]`
/// = (G g Gᵀ)[point] of the kernel from input `c` to output `o` (computed in f64).
pub(crate) fn transform_kernels(layer: &ConvLayer) -> Vec<f32> {
    let (cin, cout) = (layer.inputs, layer.outputs);
    let mut u = vec![0f32; POINTS * cin * cout];
    for c in 0..cin {
        for o in 0..cout {
            let g = |ky: usize, kx: usize| layer.weight[((ky * KERNEL + kx) * cin + c) * cout + o];
            let mut gg = [[0f64; KERNEL]; TILE];
            for (row, g_row) in gg.iter_mut().zip(&G) {
                for (kx, value) in row.iter_mut().enumerate() {
                    *value = (0..KERNEL).map(|k| g_row[k] * g(k, kx) as f64).sum();
                }
            }
            for (i, row) in gg.iter().enumerate() {
                for (j, g_col) in G.iter().enumerate() {
                    let value: f64 = (0..KERNEL).map(|k| row[k] * g_col[k]).sum();
                    u[((i * TILE + j) * cin + c) * cout + o] = value as f32;
                }
            }
        }
    }
    u
}

/// Channels transformed together (one AVX register of f32).
const LANES: usize = 8;

/// A group of channels' values at one position of a tile.
type Lanes = [f32; LANES];

/// Bᵀ of F(4, 3) (interpolation points 0, ±1, ±2, ∞) applied lane-wise to the six lane
/// vectors `d[at(0)], …, d[at(5)]`.
#[inline(always)]
fn input_transform(d: &[Lanes], at: impl Fn(usize) -> usize) -> [Lanes; TILE] {
    let mut r = [[0f32; LANES]; TILE];
    let (v0, v1, v2, v3, v4, v5) = (
        &d[at(0)],
        &d[at(1)],
        &d[at(2)],
        &d[at(3)],
        &d[at(4)],
        &d[at(5)],
    );
    for l in 0..LANES {
        let [d0, d1, d2, d3, d4, d5] = [v0[l], v1[l], v2[l], v3[l], v4[l], v5[l]];
        r[0][l] = 4.0 * d0 - 5.0 * d2 + d4;
        r[1][l] = -4.0 * (d1 + d2) + d3 + d4;
        r[2][l] = 4.0 * (d1 - d2) - d3 + d4;
        r[3][l] = 2.0 * (d3 - d1) - d2 + d4;
        r[4][l] = 2.0 * (d1 - d3) - d2 + d4;
        r[5][l] = 4.0 * d1 - 5.0 * d3 + d5;
    }
    r
}

/// Aᵀ of F(4, 3) applied lane-wise to the six lane vectors `m[at(0)], …, m[at(5)]`.
#[inline(always)]
fn output_transform(m: &[Lanes], at: impl Fn(usize) -> usize) -> [Lanes; OUT] {
    let mut r = [[0f32; LANES]; OUT];
    let (v0, v1, v2, v3, v4, v5) = (
        &m[at(0)],
        &m[at(1)],
        &m[at(2)],
        &m[at(3)],
        &m[at(4)],
        &m[at(5)],
    );
    for l in 0..LANES {
        let (sum12, diff12) = (v1[l] + v2[l], v1[l] - v2[l]);
        let (sum34, diff34) = (v3[l] + v4[l], v3[l] - v4[l]);
        r[0][l] = v0[l] + sum12 + sum34;
        r[1][l] = diff12 + 2.0 * diff34;
        r[2][l] = sum12 + 4.0 * sum34;
        r[3][l] = diff12 + 8.0 * diff34 + v5[l];
    }
    r
}

/// The first `LANES` values of `src` (fewer at a ragged end: the other lanes keep stale
/// values, which only ever reach lanes that are not stored).
#[inline(always)]
fn load(dst: &mut Lanes, src: &[f32]) {
    match src.get(..LANES) {
        Some(full) => *dst = full.try_into().expect("LANES values"),
        None => dst[..src.len()].copy_from_slice(src),
    }
}

/// `dst` from the first `dst.len()` (at most `LANES`) values of `src`.
#[inline(always)]
fn store(dst: &mut [f32], src: &Lanes) {
    match <&mut Lanes>::try_from(&mut *dst) {
        Ok(full) => *full = *src,
        Err(_) => {
            let n = dst.len();
            dst.copy_from_slice(&src[..n]);
        }
    }
}

/// A run of tiles: the top-left output pixel `(x0, y0)` of the first and how many follow
/// along the row.
#[derive(Clone, Copy)]
struct TileRun {
    x0: usize,
    y0: usize,
    tiles: usize,
}

/// The input tiles of a run in the transform domain:
/// `transformed[(point·run.tiles + tile)·inputs + c]`.
#[inline(always)]
fn transform_inputs(input: &FeatureMap, run: TileRun, transformed: &mut [f32]) {
    let (w, h, cin) = (input.width, input.height, input.channels);
    let (y0, tiles) = (run.y0, run.tiles);
    let mut d = [[0f32; LANES]; POINTS];
    let mut half = [[0f32; LANES]; POINTS];
    for tx in 0..tiles {
        let x0 = run.x0 + tx * OUT;
        for c0 in (0..cin).step_by(LANES) {
            let n = LANES.min(cin - c0);
            for i in 0..TILE {
                let yy = (y0 + i).wrapping_sub(1);
                for j in 0..TILE {
                    let xx = (x0 + j).wrapping_sub(1);
                    let slot = &mut d[i * TILE + j];
                    if yy < h && xx < w {
                        load(slot, &input.pixel(xx, yy)[c0..c0 + n]);
                    } else {
                        *slot = [0.0; LANES];
                    }
                }
            }
            // Bᵀ d over the tile's columns, then (Bᵀ d) B over its rows.
            for j in 0..TILE {
                let column = input_transform(&d, |i| i * TILE + j);
                for (i, value) in column.into_iter().enumerate() {
                    half[i * TILE + j] = value;
                }
            }
            for i in 0..TILE {
                let row = input_transform(&half, |j| i * TILE + j);
                for (j, value) in row.iter().enumerate() {
                    let point = i * TILE + j;
                    store(
                        &mut transformed[(point * tiles + tx) * cin + c0..][..n],
                        value,
                    );
                }
            }
        }
    }
}

/// A run's output tiles from the products in the transform domain
/// (`products[(point·run.tiles + tile)·outputs + o]`), plus bias, optionally rectified,
/// into `out`: the run's row of tiles, `rows` ≤ 4 image rows of width `w`.
#[inline(always)]
fn transform_outputs(
    products: &[f32],
    layer: &ConvLayer,
    relu: bool,
    (run, w, rows): (TileRun, usize, usize),
    out: &mut [f32],
) {
    let (cout, tiles) = (layer.outputs, run.tiles);
    let mut m = [[0f32; LANES]; POINTS];
    let mut half = [[0f32; LANES]; OUT * TILE];
    for tx in 0..tiles {
        let x0 = run.x0 + tx * OUT;
        for c0 in (0..cout).step_by(LANES) {
            let n = LANES.min(cout - c0);
            for (point, value) in m.iter_mut().enumerate() {
                load(value, &products[(point * tiles + tx) * cout + c0..][..n]);
            }
            // Aᵀ m over the columns, then (Aᵀ m) A over the rows.
            for j in 0..TILE {
                let column = output_transform(&m, |k| k * TILE + j);
                for (i, value) in column.into_iter().enumerate() {
                    half[i * TILE + j] = value;
                }
            }
            let mut bias = [0f32; LANES];
            load(&mut bias, &layer.bias[c0..c0 + n]);
            for i in 0..rows.min(OUT) {
                let row = output_transform(&half, |k| i * TILE + k);
                for (j, value) in row.iter().enumerate().take(w - x0) {
                    let mut pixel = [0f32; LANES];
                    for l in 0..LANES {
                        let v = value[l] + bias[l];
                        pixel[l] = if relu { v.max(0.0) } else { v };
                    }
                    store(&mut out[(i * w + x0 + j) * cout + c0..][..n], &pixel);
                }
            }
        }
    }
}

/// [`transform_inputs`] compiled for AVX2 and FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn transform_inputs_avx2(input: &FeatureMap, run: TileRun, transformed: &mut [f32]) {
    transform_inputs(input, run, transformed)
}

/// [`transform_outputs`] compiled for AVX2 and FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn transform_outputs_avx2(
    products: &[f32],
    layer: &ConvLayer,
    relu: bool,
    placement: (TileRun, usize, usize),
    out: &mut [f32],
) {
    transform_outputs(products, layer, relu, placement, out)
}

/// Tiles transformed and multiplied together: the run's transform-domain inputs and
/// products (2 × 36 × 32 × 64 floats for the network's 64 maps) stay in a core's L2 cache.
const RUN_TILES: usize = 32;

/// Per-thread scratch: a run of tiles in the transform domain, input and output side.
#[derive(Default)]
pub(crate) struct WinogradScratch {
    transformed: Vec<f32>,
    products: Vec<f32>,
}

/// Output rows `rows` of one "same" 3×3 convolution of `input` (rows outside it read as
/// zeros) plus bias, optionally rectified, into `out` (`rows.len() × width × outputs`);
/// `kernels` from [`transform_kernels`]. The same result as the direct convolution up to
/// float rounding. Single-threaded: callers parallelise.
pub(crate) fn winograd_convolve_rows(
    input: &FeatureMap,
    (layer, kernels, relu): (&ConvLayer, &[f32], bool),
    rows: Range<usize>,
    out: &mut [f32],
    s: &mut WinogradScratch,
) {
    let (w, cin, cout) = (input.width, layer.inputs, layer.outputs);
    let tiles_x = w.div_ceil(OUT);
    #[cfg(target_arch = "x86_64")]
    let avx2 = crate::cpu::has_avx2_fma();
    s.transformed.resize(POINTS * RUN_TILES * cin, 0.0);
    s.products.resize(POINTS * RUN_TILES * cout, 0.0);
    let out = &mut out[..rows.len() * w * cout];
    for (tile_row, out) in out.chunks_mut(OUT * w * cout).enumerate() {
        let tile_rows = out.len() / (w * cout);
        for first in (0..tiles_x).step_by(RUN_TILES) {
            let run = TileRun {
                x0: first * OUT,
                y0: rows.start + tile_row * OUT,
                tiles: RUN_TILES.min(tiles_x - first),
            };
            let t = run.tiles;
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: the CPU supports AVX2 and FMA (checked above).
                unsafe { transform_inputs_avx2(input, run, &mut s.transformed) };
            } else {
                transform_inputs(input, run, &mut s.transformed);
            }
            #[cfg(not(target_arch = "x86_64"))]
            transform_inputs(input, run, &mut s.transformed);
            for point in 0..POINTS {
                matmul(
                    &mut s.products[point * t * cout..][..t * cout],
                    &s.transformed[point * t * cin..][..t * cin],
                    &kernels[point * cin * cout..][..cin * cout],
                    t,
                    cout,
                    cin,
                );
            }
            let placement = (run, w, tile_rows);
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: the CPU supports AVX2 and FMA (checked above).
                unsafe { transform_outputs_avx2(&s.products, layer, relu, placement, out) };
            } else {
                transform_outputs(&s.products, layer, relu, placement, out);
            }
            #[cfg(not(target_arch = "x86_64"))]
            transform_outputs(&s.products, layer, relu, placement, out);
        }
    }
}
