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

/// Bᵀ of F(4, 3) (interpolation points 0, ±1, ±2, ∞) on six values.
#[inline(always)]
fn input_transform([d0, d1, d2, d3, d4, d5]: [f32; TILE]) -> [f32; TILE] {
    [
        4.0 * d0 - 5.0 * d2 + d4,
        -4.0 * (d1 + d2) + d3 + d4,
        4.0 * (d1 - d2) - d3 + d4,
        2.0 * (d3 - d1) - d2 + d4,
        2.0 * (d1 - d3) - d2 + d4,
        4.0 * d1 - 5.0 * d3 + d5,
    ]
}

/// Aᵀ of F(4, 3) on six values.
#[inline(always)]
fn output_transform([m0, m1, m2, m3, m4, m5]: [f32; TILE]) -> [f32; OUT] {
    let (sum12, diff12) = (m1 + m2, m1 - m2);
    let (sum34, diff34) = (m3 + m4, m3 - m4);
    [
        m0 + sum12 + sum34,
        diff12 + 2.0 * diff34,
        sum12 + 4.0 * sum34,
        diff12 + 8.0 * diff34 + m5,
    ]
}

/// `outputs[k][c] = transform(inputs[0][c], …, inputs[5][c])[k]` for every channel c:
/// one of the 1-D transforms over whole channel vectors (contiguous, so it vectorises).
#[inline(always)]
fn transform_channels<const N: usize>(
    inputs: [&[f32]; TILE],
    mut outputs: [&mut [f32]; N],
    transform: impl Fn([f32; TILE]) -> [f32; N],
) {
    let n = outputs[0].len();
    let inputs = inputs.map(|s| &s[..n]);
    for o in outputs.iter_mut() {
        assert_eq!(o.len(), n);
    }
    for c in 0..n {
        let values = transform(inputs.map(|s| s[c]));
        for (o, v) in outputs.iter_mut().zip(values) {
            o[c] = v;
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

impl TileRun {
    /// Input columns the run reads: `x0 − 1 ..< x0 + 4·tiles + 1`.
    fn columns(&self) -> usize {
        self.tiles * OUT + KERNEL - 1
    }
}

/// The input tiles of a run in the transform domain,
/// `transformed[(point·run.tiles + tile)·inputs + c]`, in two passes: Bᵀ down the six
/// input rows of every column the run reads (into `band`, row i of the result at
/// `band[(i·columns + column)·inputs + c]`; each column once, though neighbouring tiles
/// share two), then B along each tile's six columns.
#[inline(always)]
fn transform_inputs(
    input: &FeatureMap,
    run: TileRun,
    (band, zeros): (&mut [f32], &[f32]),
    transformed: &mut [f32],
) {
    let (w, h, cin) = (input.width, input.height, input.channels);
    let columns = run.columns();
    let band = &mut band[..TILE * columns * cin];
    for column in 0..columns {
        let xx = (run.x0 + column).wrapping_sub(1);
        let rows: [&[f32]; TILE] = std::array::from_fn(|i| {
            let yy = (run.y0 + i).wrapping_sub(1);
            if yy < h && xx < w {
                input.pixel(xx, yy)
            } else {
                zeros
            }
        });
        let mut band_rows = band.chunks_exact_mut(columns * cin);
        let outputs: [&mut [f32]; TILE] = std::array::from_fn(|_| {
            let row = band_rows.next().expect("six band rows");
            &mut row[column * cin..][..cin]
        });
        transform_channels(rows, outputs, input_transform);
    }
    let mut points = transformed[..POINTS * run.tiles * cin].chunks_exact_mut(run.tiles * cin);
    let mut points: [&mut [f32]; POINTS] = std::array::from_fn(|_| points.next().expect("36"));
    for (i, band_row) in band.chunks_exact(columns * cin).enumerate() {
        for tile in 0..run.tiles {
            let tile_columns: [&[f32]; TILE] =
                std::array::from_fn(|j| &band_row[(tile * OUT + j) * cin..][..cin]);
            let [p0, p1, p2, p3, p4, p5] = &mut points[i * TILE..(i + 1) * TILE] else {
                unreachable!("six points per row of the tile")
            };
            let outputs = [p0, p1, p2, p3, p4, p5].map(|p| &mut p[tile * cin..][..cin]);
            transform_channels(tile_columns, outputs, input_transform);
        }
    }
}

/// A run's output tiles from the products in the transform domain
/// (`products[(point·run.tiles + tile)·outputs + o]`), plus bias, optionally rectified,
/// into `out`: the run's row of tiles, `rows` ≤ 4 image rows of width `w`. Per tile, Aᵀ
/// down each of its six columns (into `half`, `half[(k·6 + j)·outputs + o]`), then A
/// along each of its four rows (into `pixels`, then biased into `out`).
#[inline(always)]
fn transform_outputs(
    products: &[f32],
    (layer, relu): (&ConvLayer, bool),
    (run, w, rows): (TileRun, usize, usize),
    (half, pixels): (&mut [f32], &mut [f32]),
    out: &mut [f32],
) {
    let (cout, tiles) = (layer.outputs, run.tiles);
    let (half, pixels) = (&mut half[..OUT * TILE * cout], &mut pixels[..OUT * cout]);
    for tile in 0..tiles {
        let x0 = run.x0 + tile * OUT;
        for j in 0..TILE {
            let column: [&[f32]; TILE] = std::array::from_fn(|i| {
                &products[((i * TILE + j) * tiles + tile) * cout..][..cout]
            });
            let mut half_rows = half.chunks_exact_mut(TILE * cout);
            let outputs: [&mut [f32]; OUT] = std::array::from_fn(|_| {
                let row = half_rows.next().expect("four rows");
                &mut row[j * cout..][..cout]
            });
            transform_channels(column, outputs, output_transform);
        }
        let columns = OUT.min(w - x0);
        for (k, half_row) in half.chunks_exact(TILE * cout).enumerate().take(rows) {
            let inputs: [&[f32]; TILE] = std::array::from_fn(|j| &half_row[j * cout..][..cout]);
            let mut tile_row = pixels.chunks_exact_mut(cout);
            let outputs: [&mut [f32]; OUT] =
                std::array::from_fn(|_| tile_row.next().expect("four pixels"));
            transform_channels(inputs, outputs, output_transform);
            let dst = &mut out[(k * w + x0) * cout..][..columns * cout];
            for (dst, src) in dst.chunks_exact_mut(cout).zip(pixels.chunks_exact(cout)) {
                for ((d, s), b) in dst.iter_mut().zip(src).zip(&layer.bias) {
                    let v = s + b;
                    *d = if relu { v.max(0.0) } else { v };
                }
            }
        }
    }
}

/// Tiles transformed and multiplied together: the run's transform-domain inputs and
/// products (2 × 36 × 32 × 64 floats for the network's 64 maps) stay in a core's L2 cache.
const RUN_TILES: usize = 32;

/// Per-thread scratch: a run of tiles in the transform domain, input and output side,
/// and the transforms' intermediate rows.
#[derive(Default)]
pub(crate) struct WinogradScratch {
    transformed: Vec<f32>,
    products: Vec<f32>,
    band: Vec<f32>,
    zeros: Vec<f32>,
    half: Vec<f32>,
    pixels: Vec<f32>,
}

impl WinogradScratch {
    fn fit(&mut self, cin: usize, cout: usize) {
        let columns = RUN_TILES * OUT + KERNEL - 1;
        self.transformed.resize(POINTS * RUN_TILES * cin, 0.0);
        self.products.resize(POINTS * RUN_TILES * cout, 0.0);
        self.band.resize(TILE * columns * cin, 0.0);
        self.zeros.resize(cin, 0.0);
        self.half.resize(OUT * TILE * cout, 0.0);
        self.pixels.resize(OUT * cout, 0.0);
    }
}

/// Output rows `rows` of one "same" 3×3 convolution of `input` (rows outside it read as
/// zeros) plus bias, optionally rectified, into `out` (`rows.len() × width × outputs`);
/// `kernels` from [`transform_kernels`]. The same result as the direct convolution up to
/// float rounding. Single-threaded: callers parallelise. The transforms run compiled for
/// AVX2 and FMA where the CPU has them, else portable.
pub(crate) fn winograd_convolve_rows(
    input: &FeatureMap,
    layer: (&ConvLayer, &[f32], bool),
    rows: Range<usize>,
    out: &mut [f32],
    scratch: &mut WinogradScratch,
) {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::has_avx2_fma() {
        // SAFETY: the CPU supports AVX2 and FMA (checked just above).
        unsafe { convolve_rows_avx2(input, layer, rows, out, scratch) };
        return;
    }
    convolve_rows(input, layer, rows, out, scratch);
}

/// [`convolve_rows`] compiled for AVX2 and FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn convolve_rows_avx2(
    input: &FeatureMap,
    layer: (&ConvLayer, &[f32], bool),
    rows: Range<usize>,
    out: &mut [f32],
    scratch: &mut WinogradScratch,
) {
    convolve_rows(input, layer, rows, out, scratch)
}

/// [`winograd_convolve_rows`] in portable code (its twin, which the tests check against
/// the direct convolution too): runs of tiles transformed, multiplied point by point
/// (`gemm`) and transformed back.
#[inline(always)]
pub(crate) fn convolve_rows(
    input: &FeatureMap,
    (layer, kernels, relu): (&ConvLayer, &[f32], bool),
    rows: Range<usize>,
    out: &mut [f32],
    s: &mut WinogradScratch,
) {
    let (w, cin, cout) = (input.width, layer.inputs, layer.outputs);
    let tiles_x = w.div_ceil(OUT);
    s.fit(cin, cout);
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
            transform_inputs(input, run, (&mut s.band, &s.zeros), &mut s.transformed);
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
            let buffers = (&mut s.half[..], &mut s.pixels[..]);
            transform_outputs(&s.products, (layer, relu), placement, buffers, out);
        }
    }
}
