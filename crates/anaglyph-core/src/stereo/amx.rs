//! The matching network's 3×3 "same" convolutions on Intel AMX tiles (Advanced Matrix
//! Extensions, `tdpbf16ps`), the inner loop of the learned cost in the stage
//! `captures -> stereo (cost -> ...)` where the CPU has them. A tile product multiplies a
//! 16 × 32 block of bfloat16 values by a 32 × 16 one into 16 × 16 f32 sums, 8192
//! products per instruction: more than ten times the f32 FMA rate of the same core, so the
//! convolution is computed directly (nine taps × the input channels per output), with no
//! Winograd transforms.
//!
//! The layer's input rows are rounded to bfloat16 (to nearest, ties to even) into a
//! zero-padded copy in which each tap of a block of 16 output pixels is one strided tile
//! load (16 consecutive pixels × 32 channels); the kernels are rounded once, packed as the
//! tiles' right-hand side. Products of bfloat16 values are exact in f32, so the result is
//! the direct convolution of the rounded values up to the order of the f32 sums, which
//! [`convolve_rows_portable`] (the twin the tests compare with) computes in plain code.
//! Against the f32 convolution the outputs differ by the rounding of the inputs, about
//! 2⁻⁹ of their scale.

use super::network::{ConvLayer, KERNEL};
use super::tower::FeatureMap;
use std::ops::Range;

/// Pixels (rows of a left-hand tile) and channels per tile block: a tile row holds 64
/// bytes, 32 bfloat16 values or 16 f32 sums.
const BLOCK: usize = 16;
/// Input channels per tile product (pairs of channels along a tile row).
const CHANNELS: usize = 2 * BLOCK;
/// Output pixels per step of the kernel: two left-hand tiles.
const PIXELS: usize = 2 * BLOCK;
/// Output channels per step of the kernel: two right-hand tiles.
const OUTPUTS: usize = 2 * BLOCK;
/// Taps of a 3×3 kernel.
const TAPS: usize = KERNEL * KERNEL;
/// bfloat16 values in one 16-row tile of 64 bytes.
const TILE_VALUES: usize = BLOCK * CHANNELS;

/// Whether a layer's shape fits the tiles: whole blocks of 32 input and 32 output channels.
pub(crate) fn fits(layer: &ConvLayer) -> bool {
    layer.inputs > 0
        && layer.inputs.is_multiple_of(CHANNELS)
        && layer.outputs > 0
        && layer.outputs.is_multiple_of(OUTPUTS)
}

/// `value` rounded to the nearest bfloat16 (ties to even), as its bits; finite inputs.
#[inline(always)]
pub(crate) fn to_bf16(value: f32) -> u16 {
    let bits = value.to_bits();
    ((bits + 0x7fff + ((bits >> 16) & 1)) >> 16) as u16
}

/// The f32 value of bfloat16 bits.
#[cfg(test)]
fn from_bf16(bits: u16) -> f32 {
    f32::from_bits((bits as u32) << 16)
}

/// A layer's kernels rounded to bfloat16 and packed as right-hand tiles: for tap t, block
/// of 32 input channels b and block of 16 outputs j, one tile of 16 rows (channel pairs
/// 2r, 2r + 1 of the block) × 16 outputs × the pair, at
/// `packed[((t·in/32 + b)·out/16 + j)·512 ..]`.
pub(crate) fn pack_kernels(layer: &ConvLayer) -> Vec<u16> {
    let (cin, cout) = (layer.inputs, layer.outputs);
    let mut packed = vec![0u16; TAPS * cin * cout];
    let (blocks_in, blocks_out) = (cin / CHANNELS, cout / BLOCK);
    for tap in 0..TAPS {
        for b in 0..blocks_in {
            for j in 0..blocks_out {
                let tile = &mut packed[((tap * blocks_in + b) * blocks_out + j) * TILE_VALUES..]
                    [..TILE_VALUES];
                for r in 0..BLOCK {
                    for n in 0..BLOCK {
                        for pair in 0..2 {
                            let c = b * CHANNELS + 2 * r + pair;
                            let o = j * BLOCK + n;
                            tile[(r * BLOCK + n) * 2 + pair] =
                                to_bf16(layer.weight[(tap * cin + c) * cout + o]);
                        }
                    }
                }
            }
        }
    }
    packed
}

/// The padded input's width in pixels for an image `w` wide: the output pixels rounded up
/// to whole steps of 32, plus one zero column either side.
fn padded_width(w: usize) -> usize {
    w.div_ceil(PIXELS) * PIXELS + 2
}

/// A layer's input in bfloat16, zero-padded so that each tap of a block of 16 output
/// pixels is one strided tile load: for output rows `first ..< first + rows` of an image
/// `height` rows high, data row j holds image row `first + j − 1` (zeros outside the
/// image), pixel x at column x + 1 of [`padded_width`] columns (zeros in the others),
/// `data[(j·padded_width + 1 + x)·channels + c]`.
#[derive(Default)]
#[cfg_attr(test, derive(PartialEq, Debug))]
pub(crate) struct Padded {
    width: usize,
    height: usize,
    channels: usize,
    first: usize,
    rows: usize,
    data: Vec<u16>,
}

impl Padded {
    /// Lays the buffer out for output rows `rows` of a `width × height` image of
    /// `channels` values per pixel: the padding columns and the rows outside the image
    /// zeroed, the image's rows left to be written ([`Self::fill_from`] or a previous
    /// layer's [`Destination::Padded`]).
    pub(crate) fn prepare(
        &mut self,
        (width, height, channels): (usize, usize, usize),
        rows: &Range<usize>,
    ) {
        let pw = padded_width(width);
        let row_values = pw * channels;
        (self.width, self.height, self.channels) = (width, height, channels);
        (self.first, self.rows) = (rows.start, rows.len());
        self.data.resize((rows.len() + 2) * row_values, 0);
        for (j, row) in self.data.chunks_exact_mut(row_values).enumerate() {
            if image_row(rows.start, height, j).is_some() {
                row[..channels].fill(0);
                row[(width + 1) * channels..].fill(0);
            } else {
                row.fill(0);
            }
        }
    }

    /// The image row that data row `j` holds, if inside the image.
    fn image_row(&self, j: usize) -> Option<usize> {
        image_row(self.first, self.height, j)
    }

    /// The values of image row `y`'s pixels (width × channels), which the layout holds.
    fn pixels_mut(&mut self, y: usize) -> &mut [u16] {
        let j = y + 1 - self.first;
        let row_values = padded_width(self.width) * self.channels;
        &mut self.data[j * row_values + self.channels..][..self.width * self.channels]
    }

    /// The whole layout, padding included.
    #[cfg(test)]
    pub(crate) fn values(&self) -> &[u16] {
        &self.data
    }

    /// Rounds the image's rows from `input`, whose row 0 is image row `input_first` and
    /// which holds every image row of the layout.
    pub(crate) fn fill_from(&mut self, input: &FeatureMap, input_first: usize) {
        let (w, c) = (self.width, self.channels);
        assert!(input.width == w && input.channels == c);
        for j in 0..self.rows + 2 {
            let Some(y) = self.image_row(j) else { continue };
            let local = y - input_first;
            let src = &input.data[local * w * c..][..w * c];
            for (d, &s) in self.pixels_mut(y).iter_mut().zip(src) {
                *d = to_bf16(s);
            }
        }
    }
}

/// The image row that data row `j` of a [`Padded`] layout for output rows from `first`
/// holds, if inside an image `height` rows high.
fn image_row(first: usize, height: usize, j: usize) -> Option<usize> {
    (first + j).checked_sub(1).filter(|&y| y < height)
}

/// The tower's first layer (one input channel) straight into the next layer's padded
/// input: each pixel the sum of its nine taps times the kernel's columns, plus bias,
/// optionally rectified, rounded to bfloat16, for every image row of `out`'s layout.
/// `input` is the whole image (rows and columns outside it read as zeros). Vectorised
/// for AVX-512 where the CPU has it, the same code otherwise.
pub(crate) fn first_layer_into(
    input: &FeatureMap,
    placement: (&ConvLayer, bool),
    out: &mut Padded,
) {
    #[cfg(target_arch = "x86_64")]
    if is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has the features the function is compiled for.
        return unsafe { first_layer_avx512(input, placement, out) };
    }
    first_layer_body(input, placement, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
unsafe fn first_layer_avx512(input: &FeatureMap, placement: (&ConvLayer, bool), out: &mut Padded) {
    first_layer_body(input, placement, out)
}

#[inline(always)]
fn first_layer_body(input: &FeatureMap, (layer, relu): (&ConvLayer, bool), out: &mut Padded) {
    let (w, h, cout) = (input.width, input.height, layer.outputs);
    assert!(layer.inputs == 1 && input.channels == 1 && layer.weight.len() == TAPS * cout);
    assert!(out.width == w && out.height == h && out.channels == cout);
    let mut sums = vec![0f32; cout];
    for j in 0..out.rows + 2 {
        let Some(y) = out.image_row(j) else { continue };
        let pixels = out.pixels_mut(y);
        for (x, dst) in pixels.chunks_exact_mut(cout).enumerate() {
            sums.fill(0.0);
            for tap in 0..TAPS {
                let (yy, xx) = (
                    (y + tap / KERNEL).wrapping_sub(1),
                    (x + tap % KERNEL).wrapping_sub(1),
                );
                if yy >= h || xx >= w {
                    continue;
                }
                let v = input.data[yy * w + xx];
                let weights = &layer.weight[tap * cout..][..cout];
                for (s, &k) in sums.iter_mut().zip(weights) {
                    *s = v.mul_add(k, *s);
                }
            }
            for ((d, &s), &b) in dst.iter_mut().zip(&sums).zip(&layer.bias) {
                let v = s + b;
                *d = to_bf16(if relu { v.max(0.0) } else { v });
            }
        }
    }
}

/// Where a tile convolution's output rows go.
pub(crate) enum Destination<'a> {
    /// f32 values, `rows × width × outputs`.
    Values(&'a mut [f32]),
    /// The next layer's input, rounded to bfloat16: prepared for output rows whose input
    /// rows inside the image are these rows.
    Padded(&'a mut Padded),
}

/// Checks that `layer` fits the tiles and reads `input`, has `kernels` packed from it,
/// and that `out` takes its output.
fn check(input: &Padded, layer: &ConvLayer, kernels: &[u16], out: &Destination<'_>) {
    assert!(
        fits(layer)
            && input.channels == layer.inputs
            && kernels.len() == TAPS * layer.inputs * layer.outputs
            && input.data.len() == (input.rows + 2) * padded_width(input.width) * input.channels
    );
    match out {
        Destination::Values(values) => {
            assert!(values.len() >= input.rows * input.width * layer.outputs)
        }
        Destination::Padded(next) => {
            let (first, rows) = (input.first, input.rows);
            assert!(next.width == input.width && next.channels == layer.outputs);
            assert!((0..next.rows + 2).all(|j| next
                .image_row(j)
                .is_none_or(|y| (first..first + rows).contains(&y))));
        }
    }
}

/// Output pixel `x` of output row `r` (of the input's rows), values
/// `outputs[first ..< first + sums.len()]`: the sums plus bias, optionally rectified,
/// into `out`.
#[inline(always)]
fn finish(
    sums: &[f32],
    (bias, relu): (&[f32], bool),
    (input, r, x, first): (&Padded, usize, usize, usize),
    out: &mut Destination<'_>,
) {
    let cout = bias.len();
    let bias = &bias[first..][..sums.len()];
    let value = |s: f32, b: f32| if relu { (s + b).max(0.0) } else { s + b };
    match out {
        Destination::Values(values) => {
            let dst = &mut values[(r * input.width + x) * cout + first..][..sums.len()];
            for ((d, &s), &b) in dst.iter_mut().zip(sums).zip(bias) {
                *d = value(s, b);
            }
        }
        Destination::Padded(next) => {
            let dst = &mut next.pixels_mut(input.first + r)[x * cout + first..][..sums.len()];
            for ((d, &s), &b) in dst.iter_mut().zip(sums).zip(bias) {
                *d = to_bf16(value(s, b));
            }
        }
    }
}

/// The "same" 3×3 convolution of `input`'s rows plus bias, optionally rectified, into
/// `out`, on AMX tiles; `kernels` from [`pack_kernels`]. Single-threaded: callers
/// parallelise. Each step of 32 pixels × 32 outputs sums its nine taps × the input
/// channels in four tiles, stored to a 4 KB block and finished from there (L1).
///
/// # Safety
/// The CPU must have AMX-TILE and AMX-BF16, permitted for this process
/// ([`crate::cpu::has_amx_bf16`]), and the layer must [`fits`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw")]
pub(crate) unsafe fn convolve(
    input: &Padded,
    (layer, kernels, relu): (&ConvLayer, &[u16], bool),
    mut out: Destination<'_>,
) {
    use std::arch::asm;
    check(input, layer, kernels, &out);
    let (w, cin, cout) = (input.width, layer.inputs, layer.outputs);
    let pw = padded_width(w);
    let (blocks_in, blocks_out) = (cin / CHANNELS, cout / BLOCK);
    // Palette 1, all eight tiles 16 rows of 64 bytes.
    let mut config = [0u8; 64];
    config[0] = 1;
    for t in 0..8 {
        config[16 + 2 * t..18 + 2 * t].copy_from_slice(&64u16.to_le_bytes());
        config[48 + t] = BLOCK as u8;
    }
    let (a_stride, b_stride, c_stride) = (cin * 2, 64usize, OUTPUTS * 4);
    // Two blocks of sums in turn: a step's tiles go to one while the other, stored by
    // the step before, is finished, so that the vector work overlaps the tile products.
    let mut blocks = [[0f32; PIXELS * OUTPUTS]; 2];
    // The (row, first pixel, first output) of the block stored last, not yet finished.
    let mut pending: Option<(usize, usize, usize)> = None;
    let padded = input.data.as_ptr();
    let finish_block =
        |block: &[f32; PIXELS * OUTPUTS], (r, x0, first), out: &mut Destination<'_>| {
            for (p, sums) in block.chunks_exact(OUTPUTS).enumerate() {
                let x = x0 + p;
                if x < w {
                    finish(sums, (&layer.bias, relu), (input, r, x, first), out);
                }
            }
        };
    // SAFETY: the caller guarantees AMX; every tile load reads 16 rows of 64 bytes inside
    // the input (x + tap column ≤ padded width − 1, rows within its rows + 2, as `check`
    // asserted) or inside `kernels` (whole packed tiles), and every store writes 16 rows
    // of 64 bytes inside one of `blocks` (32 pixels × 32 outputs); the tiles are released
    // before returning.
    let mut turn = 0;
    unsafe {
        asm!("ldtilecfg [{}]", in(reg) config.as_ptr(), options(nostack, readonly));
        for r in 0..input.rows {
            for x0 in (0..pw - 2).step_by(PIXELS) {
                for step in 0..cout / OUTPUTS {
                    asm!(
                        "tilezero tmm0",
                        "tilezero tmm1",
                        "tilezero tmm2",
                        "tilezero tmm3",
                        options(nostack, nomem)
                    );
                    for tap in 0..TAPS {
                        let (ky, kx) = (tap / KERNEL, tap % KERNEL);
                        for b in 0..blocks_in {
                            let a0 = padded.add(((r + ky) * pw + x0 + kx) * cin + b * CHANNELS);
                            let a1 = a0.add(BLOCK * cin);
                            let b0 = kernels
                                .as_ptr()
                                .add(((tap * blocks_in + b) * blocks_out + 2 * step) * TILE_VALUES);
                            let b1 = b0.add(TILE_VALUES);
                            asm!(
                                "tileloadd tmm4, [{a0} + {sa}*1]",
                                "tileloadd tmm5, [{a1} + {sa}*1]",
                                "tileloadd tmm6, [{b0} + {sb}*1]",
                                "tileloadd tmm7, [{b1} + {sb}*1]",
                                "tdpbf16ps tmm0, tmm4, tmm6",
                                "tdpbf16ps tmm1, tmm4, tmm7",
                                "tdpbf16ps tmm2, tmm5, tmm6",
                                "tdpbf16ps tmm3, tmm5, tmm7",
                                a0 = in(reg) a0,
                                a1 = in(reg) a1,
                                b0 = in(reg) b0,
                                b1 = in(reg) b1,
                                sa = in(reg) a_stride,
                                sb = in(reg) b_stride,
                                options(nostack, readonly)
                            );
                        }
                    }
                    if let Some(at) = pending {
                        finish_block(&blocks[1 - turn], at, &mut out);
                    }
                    let c00 = blocks[turn].as_mut_ptr();
                    let c01 = c00.add(BLOCK);
                    let c10 = c00.add(BLOCK * OUTPUTS);
                    let c11 = c10.add(BLOCK);
                    asm!(
                        "tilestored [{c00} + {sc}*1], tmm0",
                        "tilestored [{c01} + {sc}*1], tmm1",
                        "tilestored [{c10} + {sc}*1], tmm2",
                        "tilestored [{c11} + {sc}*1], tmm3",
                        c00 = in(reg) c00,
                        c01 = in(reg) c01,
                        c10 = in(reg) c10,
                        c11 = in(reg) c11,
                        sc = in(reg) c_stride,
                        options(nostack)
                    );
                    pending = Some((r, x0, step * OUTPUTS));
                    turn = 1 - turn;
                }
            }
        }
        asm!("tilerelease", options(nostack, nomem));
    }
    if let Some(at) = pending {
        finish_block(&blocks[1 - turn], at, &mut out);
    }
}

/// [`convolve`] in portable code, its twin for the tests: the same padded bfloat16 input
/// and packed kernels, each output the f32 sum of the exact products.
#[cfg(test)]
pub(crate) fn convolve_portable(
    input: &Padded,
    (layer, kernels, relu): (&ConvLayer, &[u16], bool),
    mut out: Destination<'_>,
) {
    check(input, layer, kernels, &out);
    let (w, cin, cout) = (input.width, layer.inputs, layer.outputs);
    let pw = padded_width(w);
    let (blocks_in, blocks_out) = (cin / CHANNELS, cout / BLOCK);
    let mut sums = vec![0f32; cout];
    for r in 0..input.rows {
        for x in 0..w {
            sums.fill(0.0);
            for tap in 0..TAPS {
                let (ky, kx) = (tap / KERNEL, tap % KERNEL);
                let a = &input.data[((r + ky) * pw + x + kx) * cin..][..cin];
                for (c, &value) in a.iter().enumerate() {
                    let (b, pair_row, pair) = (c / CHANNELS, (c % CHANNELS) / 2, c % 2);
                    let value = from_bf16(value);
                    for (o, sum) in sums.iter_mut().enumerate() {
                        let (j, n) = (o / BLOCK, o % BLOCK);
                        let tile = ((tap * blocks_in + b) * blocks_out + j) * TILE_VALUES;
                        let weight = kernels[tile + (pair_row * BLOCK + n) * 2 + pair];
                        *sum += value * from_bf16(weight);
                    }
                }
            }
            finish(&sums, (&layer.bias, relu), (input, r, x, 0), &mut out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_to_bfloat16_is_to_nearest_even() {
        assert_eq!(from_bf16(to_bf16(1.0)), 1.0);
        assert_eq!(from_bf16(to_bf16(-2.5)), -2.5);
        // 1 + 2⁻⁸ lies halfway between 1 and 1 + 2⁻⁷: ties go to the even 1.
        assert_eq!(from_bf16(to_bf16(1.0 + 1.0 / 256.0)), 1.0);
        // 1 + 3·2⁻⁸ lies halfway between 1 + 2⁻⁷ and 1 + 2⁻⁶: to the even 1 + 2⁻⁶.
        assert_eq!(from_bf16(to_bf16(1.0 + 3.0 / 256.0)), 1.0 + 1.0 / 64.0);
        // Just above the halfway point rounds up.
        assert_eq!(
            from_bf16(to_bf16(f32::from_bits((1.0f32).to_bits() + 0x8001))),
            1.0 + 1.0 / 128.0
        );
        for v in [0.3f32, -7.77, 1e-3, 123.456] {
            assert!((from_bf16(to_bf16(v)) - v).abs() <= v.abs() / 256.0);
        }
    }
}
