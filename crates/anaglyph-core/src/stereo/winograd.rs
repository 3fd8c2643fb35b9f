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
/// one of the 1-D transforms over whole channel vectors, one channel at a time (LLVM
/// leaves this loop of six inputs and up to six outputs scalar; [`Avx2`] is its
/// vectorised twin).
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

/// The two 1-D transforms over whole channel vectors ([`transform_channels`] of
/// [`input_transform`] and of [`output_transform`]): [`Portable`], or [`Avx2`] with the
/// same arithmetic in the same order, so bit for bit the same values.
trait Transforms: Copy {
    fn inputs(self, inputs: [&[f32]; TILE], outputs: [&mut [f32]; TILE]);
    fn outputs(self, inputs: [&[f32]; TILE], outputs: [&mut [f32]; OUT]);
}

/// The transforms in portable code, one channel at a time.
#[derive(Clone, Copy)]
struct Portable;

impl Transforms for Portable {
    #[inline(always)]
    fn inputs(self, inputs: [&[f32]; TILE], outputs: [&mut [f32]; TILE]) {
        transform_channels(inputs, outputs, input_transform);
    }
    #[inline(always)]
    fn outputs(self, inputs: [&[f32]; TILE], outputs: [&mut [f32]; OUT]) {
        transform_channels(inputs, outputs, output_transform);
    }
}

/// The transforms eight channels at a time in AVX registers (the rest as [`Portable`]).
/// Only made where the CPU has AVX2 and FMA ([`Avx2::new`]).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct Avx2 {
    _checked: (),
}

#[cfg(target_arch = "x86_64")]
impl Avx2 {
    fn new() -> Option<Self> {
        crate::cpu::has_avx2_fma().then_some(Avx2 { _checked: () })
    }
}

#[cfg(target_arch = "x86_64")]
impl Transforms for Avx2 {
    #[inline(always)]
    fn inputs(self, inputs: [&[f32]; TILE], outputs: [&mut [f32]; TILE]) {
        // SAFETY: an `Avx2` exists only where the CPU has AVX2 and FMA.
        unsafe { avx2::inputs(inputs, outputs) }
    }
    #[inline(always)]
    fn outputs(self, inputs: [&[f32]; TILE], outputs: [&mut [f32]; OUT]) {
        // SAFETY: as above.
        unsafe { avx2::outputs(inputs, outputs) }
    }
}

/// [`input_transform`] and [`output_transform`] on eight channels at once: the same
/// multiplications, additions and subtractions in the same order (no fused
/// multiply-adds), so the same values bit for bit.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{input_transform, output_transform, transform_channels, OUT, TILE};
    use std::arch::x86_64::*;

    const LANES: usize = 8;

    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn inputs(inputs: [&[f32]; TILE], outputs: [&mut [f32]; TILE]) {
        let n = outputs[0].len();
        for o in &outputs {
            assert_eq!(o.len(), n);
        }
        let [i0, i1, i2, i3, i4, i5] = inputs;
        let (i0, i1, i2, i3, i4, i5) = (&i0[..n], &i1[..n], &i2[..n], &i3[..n], &i4[..n], &i5[..n]);
        let [o0, o1, o2, o3, o4, o5] = outputs;
        let blocks = n / LANES * LANES;
        let (two, four, five, minus_four) = (
            _mm256_set1_ps(2.0),
            _mm256_set1_ps(4.0),
            _mm256_set1_ps(5.0),
            _mm256_set1_ps(-4.0),
        );
        for c in (0..blocks).step_by(LANES) {
            // SAFETY: c + 8 ≤ n, the length of every input and output.
            unsafe {
                let load = |s: &[f32]| _mm256_loadu_ps(s.as_ptr().add(c));
                let (d0, d1, d2, d3, d4, d5) =
                    (load(i0), load(i1), load(i2), load(i3), load(i4), load(i5));
                let v0 = _mm256_add_ps(
                    _mm256_sub_ps(_mm256_mul_ps(four, d0), _mm256_mul_ps(five, d2)),
                    d4,
                );
                let v1 = _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(minus_four, _mm256_add_ps(d1, d2)), d3),
                    d4,
                );
                let v2 = _mm256_add_ps(
                    _mm256_sub_ps(_mm256_mul_ps(four, _mm256_sub_ps(d1, d2)), d3),
                    d4,
                );
                let v3 = _mm256_add_ps(
                    _mm256_sub_ps(_mm256_mul_ps(two, _mm256_sub_ps(d3, d1)), d2),
                    d4,
                );
                let v4 = _mm256_add_ps(
                    _mm256_sub_ps(_mm256_mul_ps(two, _mm256_sub_ps(d1, d3)), d2),
                    d4,
                );
                let v5 = _mm256_add_ps(
                    _mm256_sub_ps(_mm256_mul_ps(four, d1), _mm256_mul_ps(five, d3)),
                    d5,
                );
                _mm256_storeu_ps(o0.as_mut_ptr().add(c), v0);
                _mm256_storeu_ps(o1.as_mut_ptr().add(c), v1);
                _mm256_storeu_ps(o2.as_mut_ptr().add(c), v2);
                _mm256_storeu_ps(o3.as_mut_ptr().add(c), v3);
                _mm256_storeu_ps(o4.as_mut_ptr().add(c), v4);
                _mm256_storeu_ps(o5.as_mut_ptr().add(c), v5);
            }
        }
        if blocks < n {
            let tail = [i0, i1, i2, i3, i4, i5].map(|s| &s[blocks..]);
            let outputs = [o0, o1, o2, o3, o4, o5].map(|o| &mut o[blocks..]);
            transform_channels(tail, outputs, input_transform);
        }
    }

    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn outputs(inputs: [&[f32]; TILE], outputs: [&mut [f32]; OUT]) {
        let n = outputs[0].len();
        for o in &outputs {
            assert_eq!(o.len(), n);
        }
        let [m0, m1, m2, m3, m4, m5] = inputs;
        let (m0, m1, m2, m3, m4, m5) = (&m0[..n], &m1[..n], &m2[..n], &m3[..n], &m4[..n], &m5[..n]);
        let [o0, o1, o2, o3] = outputs;
        let blocks = n / LANES * LANES;
        let (two, four, eight) = (
            _mm256_set1_ps(2.0),
            _mm256_set1_ps(4.0),
            _mm256_set1_ps(8.0),
        );
        for c in (0..blocks).step_by(LANES) {
            // SAFETY: c + 8 ≤ n, the length of every input and output.
            unsafe {
                let load = |s: &[f32]| _mm256_loadu_ps(s.as_ptr().add(c));
                let (v0, v1, v2, v3, v4, v5) =
                    (load(m0), load(m1), load(m2), load(m3), load(m4), load(m5));
                let (sum12, diff12) = (_mm256_add_ps(v1, v2), _mm256_sub_ps(v1, v2));
                let (sum34, diff34) = (_mm256_add_ps(v3, v4), _mm256_sub_ps(v3, v4));
                let r0 = _mm256_add_ps(_mm256_add_ps(v0, sum12), sum34);
                let r1 = _mm256_add_ps(diff12, _mm256_mul_ps(two, diff34));
                let r2 = _mm256_add_ps(sum12, _mm256_mul_ps(four, sum34));
                let r3 = _mm256_add_ps(_mm256_add_ps(diff12, _mm256_mul_ps(eight, diff34)), v5);
                _mm256_storeu_ps(o0.as_mut_ptr().add(c), r0);
                _mm256_storeu_ps(o1.as_mut_ptr().add(c), r1);
                _mm256_storeu_ps(o2.as_mut_ptr().add(c), r2);
                _mm256_storeu_ps(o3.as_mut_ptr().add(c), r3);
            }
        }
        if blocks < n {
            let tail = [m0, m1, m2, m3, m4, m5].map(|s| &s[blocks..]);
            let outputs = [o0, o1, o2, o3].map(|o| &mut o[blocks..]);
            transform_channels(tail, outputs, output_transform);
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

/// The six slices `data[offset + i·stride ..][..n]`, i = 0 … 5.
#[inline(always)]
fn six(data: &[f32], offset: usize, stride: usize, n: usize) -> [&[f32]; TILE] {
    [
        &data[offset..][..n],
        &data[offset + stride..][..n],
        &data[offset + 2 * stride..][..n],
        &data[offset + 3 * stride..][..n],
        &data[offset + 4 * stride..][..n],
        &data[offset + 5 * stride..][..n],
    ]
}

/// `data` cut into rows of `stride` (the last may be shorter), `n` values of each from
/// `offset`: the first four.
#[inline(always)]
fn four_mut(data: &mut [f32], offset: usize, stride: usize, n: usize) -> [&mut [f32]; OUT] {
    let mut rows = data.chunks_mut(stride);
    let mut next = || &mut rows.next().expect("four rows")[offset..][..n];
    [next(), next(), next(), next()]
}

/// [`four_mut`]'s first six.
#[inline(always)]
fn six_mut(data: &mut [f32], offset: usize, stride: usize, n: usize) -> [&mut [f32]; TILE] {
    let mut rows = data.chunks_mut(stride);
    let mut next = || &mut rows.next().expect("six rows")[offset..][..n];
    [next(), next(), next(), next(), next(), next()]
}

/// The input tiles of a run in the transform domain,
/// `transformed[(point·run.tiles + tile)·inputs + c]`, in two passes: Bᵀ down the six
/// input rows, over all the columns the run reads at once (into `band`, row i of the
/// result at `band[(i·columns + column)·inputs + c]`; columns outside the image are
/// zeros), then B along each tile's six columns.
#[inline(always)]
fn transform_inputs(
    transforms: impl Transforms,
    input: &FeatureMap,
    run: TileRun,
    (band, zeros): (&mut [f32], &[f32]),
    transformed: &mut [f32],
) {
    let (w, h, cin) = (input.width, input.height, input.channels);
    let (columns, tiles) = (run.columns(), run.tiles);
    let span = columns * cin;
    let band = &mut band[..TILE * span];
    // Column 0 of the run is image column x0 − 1, outside the image where x0 = 0.
    let lead = usize::from(run.x0 == 0);
    let first = run.x0 + lead - 1;
    let inside = (columns - lead).min(w - first);
    let rows: [&[f32]; TILE] = std::array::from_fn(|i| {
        let yy = (run.y0 + i).wrapping_sub(1);
        if yy < h {
            &input.data[(yy * w + first) * cin..][..inside * cin]
        } else {
            &zeros[..inside * cin]
        }
    });
    for row in band.chunks_exact_mut(span) {
        row[..lead * cin].fill(0.0);
        row[(lead + inside) * cin..].fill(0.0);
    }
    let outputs = six_mut(band, lead * cin, span, inside * cin);
    transforms.inputs(rows, outputs);
    let points = &mut transformed[..POINTS * tiles * cin];
    for (i, band_row) in band.chunks_exact(span).enumerate() {
        let mut points = six_mut(
            &mut points[i * TILE * tiles * cin..],
            0,
            tiles * cin,
            tiles * cin,
        );
        for tile in 0..tiles {
            let [p0, p1, p2, p3, p4, p5] = &mut points;
            let at = tile * cin..(tile + 1) * cin;
            let outputs = [
                &mut p0[at.clone()],
                &mut p1[at.clone()],
                &mut p2[at.clone()],
                &mut p3[at.clone()],
                &mut p4[at.clone()],
                &mut p5[at],
            ];
            let tile_columns = six(band_row, tile * OUT * cin, cin, cin);
            transforms.inputs(tile_columns, outputs);
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
    transforms: impl Transforms,
    products: &[f32],
    (layer, relu): (&ConvLayer, bool),
    (run, w, rows): (TileRun, usize, usize),
    (half, pixels): (&mut [f32], &mut [f32]),
    out: &mut [f32],
) {
    let (cout, tiles) = (layer.outputs, run.tiles);
    let (half, pixels) = (&mut half[..OUT * TILE * cout], &mut pixels[..OUT * cout]);
    let bias = &layer.bias[..cout];
    for tile in 0..tiles {
        let x0 = run.x0 + tile * OUT;
        {
            let [h0, h1, h2, h3] = four_mut(half, 0, TILE * cout, TILE * cout);
            for j in 0..TILE {
                let at = j * cout..(j + 1) * cout;
                let column = six(
                    products,
                    (j * tiles + tile) * cout,
                    TILE * tiles * cout,
                    cout,
                );
                let outputs = [
                    &mut h0[at.clone()],
                    &mut h1[at.clone()],
                    &mut h2[at.clone()],
                    &mut h3[at],
                ];
                transforms.outputs(column, outputs);
            }
        }
        let columns = OUT.min(w - x0);
        for (k, half_row) in half.chunks_exact(TILE * cout).enumerate().take(rows) {
            let inputs = six(half_row, 0, cout, cout);
            let outputs = four_mut(pixels, 0, cout, cout);
            transforms.outputs(inputs, outputs);
            let dst = &mut out[(k * w + x0) * cout..][..columns * cout];
            for (dst, src) in dst.chunks_exact_mut(cout).zip(pixels.chunks_exact(cout)) {
                for ((d, s), b) in dst.iter_mut().zip(src).zip(bias) {
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
        self.zeros.resize(columns * cin, 0.0);
        self.half.resize(OUT * TILE * cout, 0.0);
        self.pixels.resize(OUT * cout, 0.0);
    }
}

/// Output rows `rows` of one "same" 3×3 convolution of `input` (rows outside it read as
/// zeros) plus bias, optionally rectified, into `out` (`rows.len() × width × outputs`);
/// `kernels` from [`transform_kernels`]. The same result as the direct convolution up to
/// float rounding. Single-threaded: callers parallelise. The transforms run in AVX
/// registers where the CPU has AVX2 and FMA ([`Avx2`]), else portable; the values are the
/// same bit for bit.
pub(crate) fn winograd_convolve_rows(
    input: &FeatureMap,
    layer: (&ConvLayer, &[f32], bool),
    rows: Range<usize>,
    out: &mut [f32],
    scratch: &mut WinogradScratch,
) {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = Avx2::new() {
        // SAFETY: `Avx2::new` checked that the CPU supports AVX2 and FMA.
        unsafe { convolve_rows_avx2(avx2, input, layer, rows, out, scratch) };
        return;
    }
    convolve_rows(input, layer, rows, out, scratch);
}

/// [`convolve_rows`] compiled for AVX2 and FMA, with the [`Avx2`] transforms.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn convolve_rows_avx2(
    avx2: Avx2,
    input: &FeatureMap,
    layer: (&ConvLayer, &[f32], bool),
    rows: Range<usize>,
    out: &mut [f32],
    scratch: &mut WinogradScratch,
) {
    convolve_rows_with(avx2, input, layer, rows, out, scratch)
}

/// [`winograd_convolve_rows`] in portable code (its twin, which the tests check against
/// the direct convolution, and bit for bit against the AVX2 one).
pub(crate) fn convolve_rows(
    input: &FeatureMap,
    layer: (&ConvLayer, &[f32], bool),
    rows: Range<usize>,
    out: &mut [f32],
    scratch: &mut WinogradScratch,
) {
    convolve_rows_with(Portable, input, layer, rows, out, scratch)
}

/// Runs of tiles transformed (by `transforms`), multiplied point by point (`gemm`) and
/// transformed back.
#[inline(always)]
fn convolve_rows_with(
    transforms: impl Transforms,
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
            let scratch = (&mut s.band[..], &s.zeros[..]);
            transform_inputs(transforms, input, run, scratch, &mut s.transformed);
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
            let layer = (layer, relu);
            transform_outputs(transforms, &s.products, layer, placement, buffers, out);
        }
    }
}
