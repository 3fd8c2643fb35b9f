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

/// Per-thread buffers: the padded bfloat16 input rows and one output row's sums.
#[derive(Default)]
pub(crate) struct AmxScratch {
    padded: Vec<u16>,
    sums: Vec<f32>,
}

/// The padded input's width in pixels for an image `w` wide: the output pixels rounded up
/// to whole steps of 32, plus one zero column either side.
fn padded_width(w: usize) -> usize {
    w.div_ceil(PIXELS) * PIXELS + 2
}

/// Checks that `layer` fits the tiles, reads `input` and has `kernels` packed from it, then
/// rounds rows `rows.start − 1 ..< rows.end + 1` of `input` (zeros outside it) to
/// bfloat16 into `padded`, `padded[(row·padded_width + 1 + x)·channels + c]`, the columns
/// left of x = 0 and from x = w on zero.
#[inline(always)]
fn pad_rows(
    input: &FeatureMap,
    (layer, kernels): (&ConvLayer, &[u16]),
    rows: &Range<usize>,
    padded: &mut Vec<u16>,
) {
    let (w, h, cin) = (input.width, input.height, input.channels);
    assert!(
        fits(layer) && cin == layer.inputs && kernels.len() == TAPS * layer.inputs * layer.outputs
    );
    let pw = padded_width(w);
    let row_values = pw * cin;
    padded.clear();
    padded.resize((rows.len() + 2) * row_values, 0);
    for (i, row) in padded.chunks_exact_mut(row_values).enumerate() {
        let y = (rows.start + i).wrapping_sub(1);
        if y >= h {
            continue;
        }
        let src = &input.data[y * w * cin..(y + 1) * w * cin];
        for (d, &s) in row[cin..][..w * cin].iter_mut().zip(src) {
            *d = to_bf16(s);
        }
    }
}

/// One output row's sums (`sums[x·out + o]`, x up to the padded width) plus bias,
/// optionally rectified, into `out` (`w × out`).
#[inline(always)]
fn finish_row(sums: &[f32], bias: &[f32], relu: bool, out: &mut [f32]) {
    let cout = bias.len();
    for (dst, src) in out.chunks_exact_mut(cout).zip(sums.chunks_exact(cout)) {
        for ((d, s), b) in dst.iter_mut().zip(src).zip(bias) {
            let v = s + b;
            *d = if relu { v.max(0.0) } else { v };
        }
    }
}

/// Output rows `rows` of the "same" 3×3 convolution of `input` (rows outside it read as
/// zeros) plus bias, optionally rectified, into `out` (`rows.len() × width × outputs`),
/// on AMX tiles; `kernels` from [`pack_kernels`]. Single-threaded: callers parallelise.
///
/// # Safety
/// The CPU must have AMX-TILE and AMX-BF16, permitted for this process
/// ([`crate::cpu::has_amx_bf16`]), and the layer must [`fits`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw")]
pub(crate) unsafe fn convolve_rows(
    input: &FeatureMap,
    (layer, kernels, relu): (&ConvLayer, &[u16], bool),
    rows: Range<usize>,
    out: &mut [f32],
    scratch: &mut AmxScratch,
) {
    use std::arch::asm;
    let (w, cin, cout) = (input.width, layer.inputs, layer.outputs);
    pad_rows(input, (layer, kernels), &rows, &mut scratch.padded);
    let pw = padded_width(w);
    scratch.sums.resize(pw * cout, 0.0);
    let (blocks_in, blocks_out) = (cin / CHANNELS, cout / BLOCK);
    // Palette 1, all eight tiles 16 rows of 64 bytes.
    let mut config = [0u8; 64];
    config[0] = 1;
    for t in 0..8 {
        config[16 + 2 * t..18 + 2 * t].copy_from_slice(&64u16.to_le_bytes());
        config[48 + t] = BLOCK as u8;
    }
    let (a_stride, b_stride, c_stride) = (cin * 2, 64usize, cout * 4);
    let padded = scratch.padded.as_ptr();
    let sums = scratch.sums.as_mut_ptr();
    // SAFETY: the caller guarantees AMX; every tile load reads 16 rows of 64 bytes inside
    // `padded` (x + tap column ≤ padded width − 1, rows within the rows + 2 padded ones)
    // or inside `kernels` (whole packed tiles), and every store writes 16 rows of 64 bytes
    // inside `sums` (pixels below the padded width − 2); the tiles are released before
    // returning.
    unsafe {
        asm!("ldtilecfg [{}]", in(reg) config.as_ptr(), options(nostack, readonly));
        for (r, out_row) in out[..rows.len() * w * cout]
            .chunks_exact_mut(w * cout)
            .enumerate()
        {
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
                    let c00 = sums.add(x0 * cout + step * OUTPUTS);
                    let c01 = c00.add(BLOCK);
                    let c10 = c00.add(BLOCK * cout);
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
                }
            }
            finish_row(&scratch.sums[..w * cout], &layer.bias, relu, out_row);
        }
        asm!("tilerelease", options(nostack, nomem));
    }
}

/// [`convolve_rows`] in portable code, its twin for the tests: the same padded bfloat16
/// rows and packed kernels, each output the f32 sum of the exact products.
#[cfg(test)]
pub(crate) fn convolve_rows_portable(
    input: &FeatureMap,
    (layer, kernels, relu): (&ConvLayer, &[u16], bool),
    rows: Range<usize>,
    out: &mut [f32],
    scratch: &mut AmxScratch,
) {
    let (w, cin, cout) = (input.width, layer.inputs, layer.outputs);
    pad_rows(input, (layer, kernels), &rows, &mut scratch.padded);
    let pw = padded_width(w);
    let (blocks_in, blocks_out) = (cin / CHANNELS, cout / BLOCK);
    let mut sums = vec![0f32; w * cout];
    for (r, out_row) in out[..rows.len() * w * cout]
        .chunks_exact_mut(w * cout)
        .enumerate()
    {
        sums.fill(0.0);
        for (x, pixel) in sums.chunks_exact_mut(cout).enumerate() {
            for tap in 0..TAPS {
                let (ky, kx) = (tap / KERNEL, tap % KERNEL);
                let a = &scratch.padded[((r + ky) * pw + x + kx) * cin..][..cin];
                for (c, &value) in a.iter().enumerate() {
                    let (b, pair_row, pair) = (c / CHANNELS, (c % CHANNELS) / 2, c % 2);
                    let value = from_bf16(value);
                    for (o, sum) in pixel.iter_mut().enumerate() {
                        let (j, n) = (o / BLOCK, o % BLOCK);
                        let tile = ((tap * blocks_in + b) * blocks_out + j) * TILE_VALUES;
                        let weight = kernels[tile + (pair_row * BLOCK + n) * 2 + pair];
                        *sum += value * from_bf16(weight);
                    }
                }
            }
        }
        finish_row(&sums, &layer.bias, relu, out_row);
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
