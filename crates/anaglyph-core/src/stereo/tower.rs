//! The matching network's convolutional tower over one image, the first half of the
//! learned cost in the stage `captures -> stereo (cost -> ...)`. In: a grey image and the
//! network's 3×3 "same" convolutions; out: a [`FeatureMap`] of per-pixel feature vectors
//! (L2-normalised for fast networks).
//!
//! The image goes through the tower in strips of rows, one rayon task per strip: each
//! layer computes the strip's rows plus as many rows either side as the layers after it
//! still need (the receptive field), so a strip's features equal the whole image's, and
//! the layers in between live in two small per-thread buffers instead of whole-image
//! maps. Layers with many inputs run on AMX tiles in bfloat16 where the CPU has them
//! ([`super::amx`]), else through Winograd's transform in f32 ([`super::winograd`]); the
//! first (one input channel) uses im2col and `gemm`.

use super::learned::matmul;
use super::network::{ConvLayer, MatchingNetwork, KERNEL};
use super::winograd::{transform_kernels, winograd_convolve_rows, WinogradScratch};
use super::GreyImage;
use crate::scratch::ScratchPool;
use rayon::prelude::*;
use std::ops::Range;

/// Per-pixel feature vectors, `data[(y·width + x)·channels + k]`.
pub type FeatureMap = crate::image::Image<f32>;

/// The image shifted to zero mean and scaled to unit standard deviation (MC-CNN's input
/// normalisation); a constant image becomes all zeros.
pub fn normalise_image(image: &GreyImage) -> GreyImage {
    let n = image.data.len().max(1) as f64;
    let mean = image.data.iter().map(|&v| v as f64).sum::<f64>() / n;
    let var = image
        .data
        .iter()
        .map(|&v| (v as f64 - mean).powi(2))
        .sum::<f64>()
        / n;
    let scale = if var > 0.0 { 1.0 / var.sqrt() } else { 0.0 };
    GreyImage {
        channels: 1,
        width: image.width,
        height: image.height,
        data: image
            .data
            .iter()
            .map(|&v| ((v as f64 - mean) * scale) as f32)
            .collect(),
    }
}

/// Output rows per strip: the rows recomputed either side cost about 2/`STRIP_ROWS` of
/// the tower (4 layers), and the strip's buffers stay a few MB.
pub(crate) const STRIP_ROWS: usize = 32;

/// Output pixels per `gemm` block of the im2col convolution (a few hundred KB of columns).
const BLOCK_PIXELS: usize = 1024;

/// Input channels from which a layer goes through Winograd's transform instead of im2col
/// (below it, the transforms cost more than they save: the first layer sees one channel).
const WINOGRAD_MIN_INPUTS: usize = 8;

/// How a layer's convolution runs.
enum Kernels {
    /// im2col and `gemm` on the layer's own weights.
    Direct,
    /// Winograd's transform, with the kernels in its domain.
    Winograd(Vec<f32>),
    /// AMX tiles, with the kernels rounded to bfloat16 and packed.
    #[cfg(target_arch = "x86_64")]
    Amx(Vec<u16>),
}

/// One convolution of the tower, ready to run: its kernels as its method wants them, and
/// whether a ReLU follows.
pub(crate) struct PreparedLayer<'a> {
    layer: &'a ConvLayer,
    kernels: Kernels,
    relu: bool,
}

impl<'a> PreparedLayer<'a> {
    /// The layer on AMX tiles where the CPU has them and its channels fit, else through
    /// Winograd's transform from [`WINOGRAD_MIN_INPUTS`] inputs, else direct.
    pub(crate) fn new(layer: &'a ConvLayer, relu: bool) -> Self {
        #[cfg(target_arch = "x86_64")]
        if super::amx::fits(layer) && crate::cpu::has_amx_bf16() {
            return PreparedLayer {
                layer,
                kernels: Kernels::Amx(super::amx::pack_kernels(layer)),
                relu,
            };
        }
        Self::without_tiles(layer, relu)
    }

    /// The layer on tiles whatever the CPU: the tests run the tiles' portable twin where
    /// it has none.
    #[cfg(all(test, target_arch = "x86_64"))]
    fn on_tiles(layer: &'a ConvLayer, relu: bool) -> Self {
        PreparedLayer {
            layer,
            kernels: Kernels::Amx(super::amx::pack_kernels(layer)),
            relu,
        }
    }

    /// The layer through Winograd's transform or direct, in f32 on any CPU.
    pub(crate) fn without_tiles(layer: &'a ConvLayer, relu: bool) -> Self {
        let kernels = if layer.inputs >= WINOGRAD_MIN_INPUTS {
            Kernels::Winograd(transform_kernels(layer))
        } else {
            Kernels::Direct
        };
        PreparedLayer {
            layer,
            kernels,
            relu,
        }
    }

    /// Output rows `rows` (in `input`'s rows; rows outside `input` read as zeros) of the
    /// "same" 3×3 convolution plus bias, optionally rectified, into `out`
    /// (`rows.len() × width × outputs`). Single-threaded: callers parallelise.
    pub(crate) fn convolve_rows(
        &self,
        input: &FeatureMap,
        rows: Range<usize>,
        out: &mut [f32],
        scratch: &mut ConvScratch,
    ) {
        match &self.kernels {
            #[cfg(target_arch = "x86_64")]
            Kernels::Amx(kernels) => {
                let shape = (input.width, input.height, input.channels);
                scratch.padded.prepare(shape, &rows);
                scratch.padded.fill_from(input, 0);
                let out = super::amx::Destination::Values(out);
                convolve_on_tiles(&scratch.padded, (self.layer, kernels, self.relu), out)
            }
            Kernels::Winograd(kernels) => winograd_convolve_rows(
                input,
                (self.layer, kernels, self.relu),
                rows,
                out,
                &mut scratch.winograd,
            ),
            Kernels::Direct => convolve_direct_rows(
                input,
                self.layer,
                self.relu,
                rows,
                out,
                &mut scratch.columns,
            ),
        }
    }
}

/// A layer's convolution on tiles ([`Kernels::Amx`]).
#[cfg(target_arch = "x86_64")]
fn convolve_on_tiles(
    input: &super::amx::Padded,
    placement: (&ConvLayer, &[u16], bool),
    out: super::amx::Destination<'_>,
) {
    #[cfg(test)]
    if !crate::cpu::has_amx_bf16() {
        return super::amx::convolve_portable(input, placement, out);
    }
    // SAFETY: `Kernels::Amx` is chosen only where the CPU has AMX and the layer fits
    // (`PreparedLayer::new`); the tests' `on_tiles` gets the twin above without AMX.
    unsafe { super::amx::convolve(input, placement, out) }
}

/// Per-thread buffers of the convolutions.
#[derive(Default)]
pub(crate) struct ConvScratch {
    columns: Vec<f32>,
    winograd: WinogradScratch,
    #[cfg(target_arch = "x86_64")]
    padded: super::amx::Padded,
}

/// [`PreparedLayer::convolve_rows`] as im2col and one `gemm` per block of pixels.
pub(crate) fn convolve_direct_rows(
    input: &FeatureMap,
    layer: &ConvLayer,
    relu: bool,
    rows: Range<usize>,
    out: &mut [f32],
    columns: &mut Vec<f32>,
) {
    let (w, h, cin, cout) = (input.width, input.height, layer.inputs, layer.outputs);
    let k = KERNEL * KERNEL * cin;
    let rows_per_block = (BLOCK_PIXELS / w.max(1)).max(1);
    for (block, out) in out[..rows.len() * w * cout]
        .chunks_mut(rows_per_block * w * cout)
        .enumerate()
    {
        let y0 = rows.start + block * rows_per_block;
        let pixels = out.len() / cout;
        columns.resize(pixels * k, 0.0);
        for (p, column) in columns.chunks_exact_mut(k).enumerate() {
            let (x, y) = (p % w, y0 + p / w);
            for ky in 0..KERNEL {
                for kx in 0..KERNEL {
                    let slot = &mut column[(ky * KERNEL + kx) * cin..][..cin];
                    let (yy, xx) = ((y + ky).wrapping_sub(1), (x + kx).wrapping_sub(1));
                    if yy < h && xx < w {
                        slot.copy_from_slice(input.pixel(xx, yy));
                    } else {
                        slot.fill(0.0);
                    }
                }
            }
        }
        matmul(out, columns, &layer.weight, pixels, cout, k);
        for pixel in out.chunks_exact_mut(cout) {
            for (v, b) in pixel.iter_mut().zip(&layer.bias) {
                *v += b;
                if relu {
                    *v = v.max(0.0);
                }
            }
        }
    }
}

/// The tower's features of an image (normalised here first). Fast networks: ReLU between
/// layers, none after the last, then L2 normalisation; accurate networks: ReLU after
/// every layer, no normalisation (the fully connected layers follow).
pub fn tower_features(network: &MatchingNetwork, image: &GreyImage) -> FeatureMap {
    tower_features_in_strips(network, image, STRIP_ROWS)
}

/// Per-thread buffers of a strip: the hidden layers' outputs in turn, and the
/// convolutions'.
#[derive(Default)]
pub(crate) struct StripScratch {
    maps: [FeatureMap; 2],
    conv: ConvScratch,
    /// Hidden layers' outputs in bfloat16 between two layers on tiles, in turn.
    #[cfg(target_arch = "x86_64")]
    padded: [super::amx::Padded; 2],
}

/// A network's tower with its layers prepared once, to run over the strips of one or
/// several images.
pub(crate) struct Tower<'a> {
    layers: Vec<PreparedLayer<'a>>,
    /// The last layer's outputs (1 without layers).
    features: usize,
    /// Fast networks' features are L2-normalised.
    normalise: bool,
}

impl<'a> Tower<'a> {
    pub(crate) fn new(network: &'a MatchingNetwork) -> Self {
        let depth = network.conv.len();
        let layers: Vec<PreparedLayer> = (network.conv.iter().enumerate())
            .map(|(i, layer)| PreparedLayer::new(layer, i + 1 < depth || network.is_accurate()))
            .collect();
        let features = layers.last().map_or(1, |l| l.layer.outputs);
        Tower {
            layers,
            features,
            normalise: !network.is_accurate(),
        }
    }

    /// Values per pixel of [`Self::strip`]'s output.
    pub(crate) fn features(&self) -> usize {
        self.features
    }

    /// The tower's input for an image: normalised ([`normalise_image`]), one channel.
    pub(crate) fn input(image: &GreyImage) -> FeatureMap {
        FeatureMap {
            width: image.width,
            height: image.height,
            channels: 1,
            data: normalise_image(image).data,
        }
    }

    /// The features of `input`'s rows `rows` into `out` (resized to rows × width ×
    /// [`Self::features`]), equal to those rows of the whole image's features.
    pub(crate) fn strip(
        &self,
        input: &FeatureMap,
        rows: Range<usize>,
        out: &mut Vec<f32>,
        scratch: &mut StripScratch,
    ) {
        out.resize(rows.len() * input.width * self.features, 0.0);
        strip_features(input, &self.layers, rows, out, scratch);
        if self.normalise {
            out.chunks_exact_mut(self.features).for_each(normalise_l2);
        }
    }
}

/// [`tower_features`] with strips of `strip_rows` output rows.
fn tower_features_in_strips(
    network: &MatchingNetwork,
    image: &GreyImage,
    strip_rows: usize,
) -> FeatureMap {
    let channels = network.feature_maps();
    strips_mapped(network, image, strip_rows, channels, |features, out| {
        out.copy_from_slice(features)
    })
}

/// [`tower_features`] turned strip by strip into an image of `channels` values per pixel:
/// `map(features, out)` gets a strip's features (pixels × the network's feature maps, as
/// [`tower_features`] gives them) and writes its pixels' values into `out`. No map of the
/// whole image's features is held (490 MB of 64 f32 features for a 1600×1200 view).
pub fn tower_features_mapped<T: Copy + Default + Send>(
    network: &MatchingNetwork,
    image: &GreyImage,
    channels: usize,
    map: impl Fn(&[f32], &mut [T]) + Sync,
) -> crate::image::Image<T> {
    strips_mapped(network, image, STRIP_ROWS, channels, map)
}

/// [`tower_features_mapped`] with strips of `strip_rows` output rows.
fn strips_mapped<T: Copy + Default + Send>(
    network: &MatchingNetwork,
    image: &GreyImage,
    strip_rows: usize,
    channels: usize,
    map: impl Fn(&[f32], &mut [T]) + Sync,
) -> crate::image::Image<T> {
    let (w, h) = (image.width, image.height);
    let (tower, input) = (Tower::new(network), Tower::input(image));
    let mut data = vec![T::default(); w * h * channels];
    let strip_len = strip_rows.max(1) * w * channels;
    let pool = ScratchPool::<(StripScratch, Vec<f32>)>::new();
    data.par_chunks_mut(strip_len.max(1))
        .enumerate()
        .for_each_init(
            || pool.take(),
            |lent, (strip, out)| {
                let (scratch, features) = &mut **lent;
                let first = strip * strip_rows;
                let rows = first..first + out.len() / (w * channels).max(1);
                tower.strip(&input, rows, features, scratch);
                map(features, out);
            },
        );
    crate::image::Image {
        width: w,
        height: h,
        channels,
        data,
    }
}

/// The last layer's output on image rows `rows` into `out`: each layer computes the rows
/// the next ones need (`rows` widened by one row per layer after it, within the image),
/// from the previous layer's rows, which always include one more row either side or
/// the image's border (zero padding).
fn strip_features(
    image: &FeatureMap,
    layers: &[PreparedLayer],
    rows: Range<usize>,
    out: &mut [f32],
    scratch: &mut StripScratch,
) {
    let (w, h) = (image.width, image.height);
    if layers.is_empty() {
        out.copy_from_slice(&image.data[rows.start * w..rows.end * w]);
        return;
    }
    let needed = |after: usize| rows.start.saturating_sub(after)..(rows.end + after).min(h);
    // The image row of the current f32 input's first row.
    let mut input_first = 0;
    // Which of the padded buffers holds the current input, when the layer before wrote
    // it in bfloat16 for the tiles.
    let mut padded_input: Option<usize> = None;
    for (i, layer) in layers.iter().enumerate() {
        let wanted = needed(layers.len() - 1 - i);
        let last = i + 1 == layers.len();
        #[cfg(target_arch = "x86_64")]
        if i == 0 && layer.layer.inputs == 1 && !last {
            if let Kernels::Amx(_) = layers[1].kernels {
                let next = &mut scratch.padded[0];
                next.prepare((w, h, layer.layer.outputs), &needed(layers.len() - 2));
                super::amx::first_layer_into(image, (layer.layer, layer.relu), next);
                padded_input = Some(0);
                continue;
            }
        }
        // A layer on tiles reads the bfloat16 input the layer before wrote, or writes the
        // next one's; between f32 layers it runs as any other (`convolve_rows`).
        #[cfg(target_arch = "x86_64")]
        let chained = !last && matches!(layers[i + 1].kernels, Kernels::Amx(_));
        #[cfg(target_arch = "x86_64")]
        if let (Kernels::Amx(kernels), true) = (&layer.kernels, padded_input.is_some() || chained) {
            let [first, second] = &mut scratch.padded;
            let buffers = [first, second];
            let k = match padded_input {
                Some(k) => k,
                None => {
                    let input = if i == 0 {
                        image
                    } else {
                        &scratch.maps[(i + 1) % 2]
                    };
                    buffers[0].prepare((w, h, layer.layer.inputs), &wanted);
                    buffers[0].fill_from(input, input_first);
                    0
                }
            };
            let [a, b] = buffers;
            let (input, next) = if k == 0 { (a, b) } else { (b, a) };
            let placement = (layer.layer, kernels.as_slice(), layer.relu);
            if chained {
                next.prepare((w, h, layer.layer.outputs), &needed(layers.len() - 2 - i));
                convolve_on_tiles(input, placement, super::amx::Destination::Padded(next));
                padded_input = Some(1 - k);
                continue;
            }
            let values = match last {
                true => &mut out[..],
                false => output_map(
                    &mut scratch.maps[i % 2],
                    w,
                    wanted.len(),
                    layer.layer.outputs,
                ),
            };
            convolve_on_tiles(input, placement, super::amx::Destination::Values(values));
            (input_first, padded_input) = (wanted.start, None);
            continue;
        }
        let local = wanted.start - input_first..wanted.end - input_first;
        let [even, odd] = &mut scratch.maps;
        let (previous, next) = if i % 2 == 0 {
            (&*odd, even)
        } else {
            (&*even, odd)
        };
        let input = if i == 0 { image } else { previous };
        if last {
            layer.convolve_rows(input, local, out, &mut scratch.conv);
        } else {
            let values = output_map(next, w, wanted.len(), layer.layer.outputs);
            layer.convolve_rows(input, local, values, &mut scratch.conv);
            input_first = wanted.start;
        }
    }
}

/// `map` laid out for `rows` rows of a `width`-pixel strip with `channels` values per
/// pixel, its values for a layer to write.
fn output_map(map: &mut FeatureMap, width: usize, rows: usize, channels: usize) -> &mut [f32] {
    map.data.resize(rows * width * channels, 0.0);
    (map.width, map.height, map.channels) = (width, rows, channels);
    &mut map.data
}

/// Scales a feature vector to unit length (a zero vector stays zero).
fn normalise_l2(features: &mut [f32]) {
    let norm = features.iter().map(|v| v * v).sum::<f32>().sqrt();
    if norm > 0.0 {
        features.iter_mut().for_each(|v| *v /= norm);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::winograd::{convolve_rows as portable_convolve_rows, transform_kernels};

    /// Deterministic values in [-1, 1).
    fn noise(n: usize, seed: u64) -> Vec<f32> {
        let mut state = seed;
        (0..n)
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    /// A `w × h` grey image of noise seeded `seed`.
    fn noise_image(w: usize, h: usize, seed: u64) -> GreyImage {
        GreyImage {
            channels: 1,
            width: w,
            height: h,
            data: noise(w * h, seed),
        }
    }

    /// A `w × h` map of `cin` channels and a 3×3 layer from `cin` to `cout` channels, of
    /// noise seeded `seed` (the map), `seed + 1` (the weights, scaled by 0.3) and `seed + 2`
    /// (the bias).
    fn random_convolution(
        (w, h, cin, cout): (usize, usize, usize, usize),
        seed: u64,
    ) -> (FeatureMap, ConvLayer) {
        let input = FeatureMap {
            width: w,
            height: h,
            channels: cin,
            data: noise(w * h * cin, seed),
        };
        let layer = ConvLayer {
            inputs: cin,
            outputs: cout,
            weight: (noise(KERNEL * KERNEL * cin * cout, seed + 1).iter())
                .map(|v| v * 0.3)
                .collect(),
            bias: noise(cout, seed + 2),
        };
        (input, layer)
    }

    /// The largest difference between two equally long slices, and the largest magnitude
    /// of the first.
    fn worst_difference(want: &[f32], got: &[f32]) -> (f32, f32) {
        assert_eq!(want.len(), got.len());
        let scale = want.iter().fold(0f32, |m, v| m.max(v.abs()));
        let worst = (want.iter().zip(got)).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        (worst, scale)
    }

    #[test]
    fn winograd_rows_match_the_direct_convolution_on_ragged_sizes() {
        for (w, h, cin, cout) in [
            (37, 23, 16, 24),
            (150, 9, 16, 8),
            (4, 4, 8, 8),
            (5, 1, 9, 3),
            (1, 6, 12, 5),
        ] {
            let (input, layer) = random_convolution((w, h, cin, cout), 1);
            let kernels = transform_kernels(&layer);
            // Every row, and rows inside the map whose neighbours above and below exist.
            for rows in [0..h, 1.min(h)..h.saturating_sub(2).max(1.min(h))] {
                for relu in [false, true] {
                    let len = rows.len() * w * cout;
                    let (mut direct, mut fast) = (vec![0f32; len], vec![0f32; len]);
                    let mut columns = Vec::new();
                    convolve_direct_rows(
                        &input,
                        &layer,
                        relu,
                        rows.clone(),
                        &mut direct,
                        &mut columns,
                    );
                    // The dispatching entry (AVX2 where the CPU has it) and the portable
                    // twin both agree with the direct convolution.
                    let placement = (&layer, kernels.as_slice(), relu);
                    type Convolution = fn(
                        &FeatureMap,
                        (&ConvLayer, &[f32], bool),
                        Range<usize>,
                        &mut [f32],
                        &mut WinogradScratch,
                    );
                    let fast_and_portable: [Convolution; 2] =
                        [winograd_convolve_rows, portable_convolve_rows];
                    for convolve in fast_and_portable {
                        let mut scratch = WinogradScratch::default();
                        convolve(&input, placement, rows.clone(), &mut fast, &mut scratch);
                        let (worst, scale) = worst_difference(&direct, &fast);
                        assert!(
                            worst <= 1e-5 * scale.max(1.0),
                            "{w}x{h} rows {rows:?}, {cin}->{cout}, relu {relu}: worst {worst} (scale {scale})"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn the_dispatched_winograd_rows_are_the_portable_ones_bit_for_bit() {
        // Channel counts that fill the AVX2 transforms' lanes, leave a remainder, or are
        // all remainder; widths with a ragged last run and last tile.
        for (w, h, cin, cout) in [
            (37, 9, 16, 24),
            (133, 6, 9, 12),
            (5, 5, 3, 7),
            (2, 3, 32, 32),
        ] {
            let (input, layer) = random_convolution((w, h, cin, cout), 7);
            let kernels = transform_kernels(&layer);
            for relu in [false, true] {
                let len = h * w * cout;
                let (mut fast, mut portable) = (vec![0f32; len], vec![0f32; len]);
                let placement = (&layer, kernels.as_slice(), relu);
                let mut scratch = WinogradScratch::default();
                winograd_convolve_rows(&input, placement, 0..h, &mut fast, &mut scratch);
                portable_convolve_rows(&input, placement, 0..h, &mut portable, &mut scratch);
                let differ = fast
                    .iter()
                    .zip(&portable)
                    .filter(|(a, b)| a.to_bits() != b.to_bits());
                assert_eq!(differ.count(), 0, "{w}x{h}, {cin}->{cout}, relu {relu}");
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn tile_rows_match_the_direct_convolution_of_the_rounded_values() {
        use crate::stereo::amx::{self, Destination, Padded};
        let round = |v: &[f32]| -> Vec<f32> {
            v.iter()
                .map(|&x| f32::from_bits((amx::to_bf16(x) as u32) << 16))
                .collect()
        };
        for (w, h, cin, cout) in [(37, 23, 32, 32), (70, 5, 64, 64), (1, 3, 32, 64)] {
            let (input, layer) = random_convolution((w, h, cin, cout), 5);
            assert!(amx::fits(&layer));
            let rounded_input = FeatureMap {
                data: round(&input.data),
                ..input.clone()
            };
            let rounded_layer = ConvLayer {
                weight: round(&layer.weight),
                ..layer.clone()
            };
            let kernels = amx::pack_kernels(&layer);
            for rows in [0..h, 1..h - 1] {
                let mut padded = Padded::default();
                padded.prepare((w, h, cin), &rows);
                padded.fill_from(&input, 0);
                for relu in [false, true] {
                    let len = rows.len() * w * cout;
                    let (mut exact, mut rounded, mut tiles) =
                        (vec![0f32; len], vec![0f32; len], vec![0f32; len]);
                    let mut columns = Vec::new();
                    convolve_direct_rows(
                        &input,
                        &layer,
                        relu,
                        rows.clone(),
                        &mut exact,
                        &mut columns,
                    );
                    let direct = (&rounded_input, &rounded_layer, relu);
                    convolve_direct_rows(
                        direct.0,
                        direct.1,
                        relu,
                        rows.clone(),
                        &mut rounded,
                        &mut columns,
                    );
                    let placement = (&layer, kernels.as_slice(), relu);
                    amx::convolve_portable(&padded, placement, Destination::Values(&mut tiles));
                    // The twin is the direct convolution of the rounded values, up to the
                    // order of the f32 sums.
                    let (worst, scale) = worst_difference(&rounded, &tiles);
                    assert!(
                        worst <= 1e-5 * scale.max(1.0),
                        "{w}x{h} {cin}->{cout} twin: {worst}"
                    );
                    // The rounding moves the f32 result by about 2⁻⁹ of the terms' scale.
                    let (worst, scale) = worst_difference(&exact, &tiles);
                    assert!(
                        worst <= 2e-2 * scale.max(1.0),
                        "{w}x{h} {cin}->{cout} rounding: {worst}"
                    );
                    // Written as the next layer's input: the same values, rounded, in the
                    // rows of a layout for one row less either side.
                    let fast = crate::cpu::has_amx_bf16().then(|| {
                        let mut fast = vec![0f32; len];
                        // SAFETY: the CPU has AMX (checked) and the layer fits.
                        unsafe {
                            amx::convolve(&padded, placement, Destination::Values(&mut fast))
                        };
                        let (worst, scale) = worst_difference(&tiles, &fast);
                        assert!(
                            worst <= 1e-5 * scale.max(1.0),
                            "{w}x{h} {cin}->{cout} tiles: {worst}"
                        );
                        fast
                    });
                    if rows.len() < 3 {
                        continue;
                    }
                    // Written as the next layer's input: the same values, rounded, in the
                    // rows of a layout for one row less either side.
                    let inner = rows.start + 1..rows.end - 1;
                    let mut want = Padded::default();
                    want.prepare((w, h, cout), &inner);
                    let mut next = Padded::default();
                    next.prepare((w, h, cout), &inner);
                    amx::convolve_portable(&padded, placement, Destination::Padded(&mut next));
                    let above = |data| FeatureMap {
                        width: w,
                        height: rows.len(),
                        channels: cout,
                        data,
                    };
                    want.fill_from(&above(tiles), rows.start);
                    assert!(next == want, "{w}x{h} {cin}->{cout} as the next input");
                    if let Some(fast) = fast {
                        next.prepare((w, h, cout), &inner);
                        // SAFETY: as above.
                        unsafe {
                            amx::convolve(&padded, placement, Destination::Padded(&mut next))
                        };
                        want.fill_from(&above(fast), rows.start);
                        assert!(
                            next == want,
                            "{w}x{h} {cin}->{cout} tiles as the next input"
                        );
                    }
                }
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_first_layer_into_the_tiles_input_is_the_rounded_direct_convolution() {
        use crate::stereo::amx::{first_layer_into, Padded};
        for (w, h, rows) in [(37, 23, 0..23), (37, 23, 5..9), (1, 4, 1..3)] {
            let (input, layer) = random_convolution((w, h, 1, 64), 9);
            for relu in [false, true] {
                // The layout of the next layer's input for `inner` holds `rows`.
                let inner = rows.clone();
                let mut got = Padded::default();
                got.prepare((w, h, 64), &inner);
                first_layer_into(&input, (&layer, relu), &mut got);
                let covered = inner.start.saturating_sub(1)..(inner.end + 1).min(h);
                let mut direct = vec![0f32; covered.len() * w * 64];
                let mut columns = Vec::new();
                convolve_direct_rows(
                    &input,
                    &layer,
                    relu,
                    covered.clone(),
                    &mut direct,
                    &mut columns,
                );
                let map = FeatureMap {
                    width: w,
                    height: covered.len(),
                    channels: 64,
                    data: direct,
                };
                let mut want = Padded::default();
                want.prepare((w, h, 64), &inner);
                want.fill_from(&map, covered.start);
                // Equal, or a bfloat16 step apart where the f32 sums' order differs.
                let bits = |p: &Padded| p.values().to_vec();
                for (a, b) in bits(&got).iter().zip(&bits(&want)) {
                    assert!(
                        a.abs_diff(*b) <= 1,
                        "{w}x{h} rows {rows:?}: {a:#x} against {b:#x}"
                    );
                }
            }
        }
    }

    /// The tower with its wide layers on tiles (the portable twin where the CPU has no
    /// AMX), chained in bfloat16, against the same tower in f32.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn towers_on_tiles_give_the_f32_features_of_any_strips() {
        let network = MatchingNetwork::default_fast().expect("built-in network");
        let (w, h) = (37, 29);
        let image = noise_image(w, h, 6);
        let depth = network.conv.len();
        // The layers `on` placed on tiles where they fit.
        let tower = |on: &dyn Fn(usize) -> bool| Tower {
            layers: (network.conv.iter().enumerate())
                .map(|(i, layer)| {
                    let relu = i + 1 < depth;
                    if on(i) && crate::stereo::amx::fits(layer) {
                        PreparedLayer::on_tiles(layer, relu)
                    } else {
                        PreparedLayer::without_tiles(layer, relu)
                    }
                })
                .collect(),
            features: 64,
            normalise: true,
        };
        let input = Tower::input(&image);
        let features = |tower: &Tower, strip_rows: usize| {
            let mut scratch = StripScratch::default();
            let mut all = Vec::new();
            for first in (0..h).step_by(strip_rows) {
                let mut strip = Vec::new();
                tower.strip(
                    &input,
                    first..(first + strip_rows).min(h),
                    &mut strip,
                    &mut scratch,
                );
                all.extend(strip);
            }
            all
        };
        let want = features(&tower(&|_| false), h);
        // Every wide layer chained; the last alone (f32 in, f32 out); the second alone
        // (into an f32 map for the next layer); the last two chained after an f32 layer.
        // Strips give the whole image's features exactly where only the tiles and the first
        // layer's loop run; Winograd's f32 layers round differently in strips (about 1e-6,
        // `strips_give_the_features_of_the_whole_image`), which a bfloat16 rounding after
        // them can turn into a step of 2⁻⁸ of an activation: a strip's wrong row would
        // still be off by the features' whole scale.
        type Placement<'a> = (&'a str, &'a dyn Fn(usize) -> bool, f32);
        let placements: [Placement; 4] = [
            ("all", &|_| true, 0.0),
            ("last", &|i| i + 1 == depth, 0.01),
            ("second", &|i| i == 1, 0.01),
            ("last two", &|i| i + 2 >= depth, 0.01),
        ];
        for (name, on, strip_tolerance) in placements {
            let tiles = tower(on);
            let whole = features(&tiles, h);
            // Unit vectors: bfloat16 rounding moves them by a few thousandths.
            let (worst, _) = worst_difference(&want, &whole);
            assert!(worst <= 0.03, "{name} on tiles against f32: worst {worst}");
            for strip_rows in [1, 4, 7] {
                let (worst, _) = worst_difference(&whole, &features(&tiles, strip_rows));
                assert!(
                    worst <= strip_tolerance,
                    "{name} on tiles, strips of {strip_rows} rows: worst {worst}"
                );
            }
        }
    }

    #[test]
    fn strips_give_the_features_of_the_whole_image() {
        let network = MatchingNetwork::default_fast().expect("built-in network");
        let (w, h) = (37, 29);
        let image = noise_image(w, h, 4);
        let whole = tower_features_in_strips(&network, &image, h);
        for strip_rows in [1, 5, 8] {
            let strips = tower_features_in_strips(&network, &image, strip_rows);
            assert_eq!((strips.width, strips.height, strips.channels), (w, h, 64));
            let (worst, _) = worst_difference(&whole.data, &strips.data);
            assert!(worst <= 1e-5, "strips of {strip_rows} rows: worst {worst}");
        }
        // Unit feature vectors (the fast network's L2 normalisation).
        let norm = |f: &[f32]| f.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((norm(whole.pixel(3, 7)) - 1.0).abs() < 1e-5);
    }
}
