//! The learned features as the multi-view cost holds them (bfloat16, [`CompactFeatures`])
//! and the dot products it spends its time in, in each build the CPU may run: portable,
//! AVX2 + FMA on widened f32, and AVX-512 BF16 on the stored bfloat16, one pixel at a
//! time or sixteen at once ([`dots16_avx512_bf16`]). Used by [`super::multi_baseline`].

use crate::stereo::FeatureMap;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::{
    __m256i, __m512, __m512bh, __m512i, _mm256_loadu_si256, _mm512_add_ps, _mm512_castpd_ps,
    _mm512_castps_pd, _mm512_dpbf16_ps, _mm512_loadu_si512, _mm512_maskz_mov_ps,
    _mm512_reduce_add_ps, _mm512_setzero_ps, _mm512_shuffle_f32x4, _mm512_unpackhi_pd,
    _mm512_unpackhi_ps, _mm512_unpacklo_pd, _mm512_unpacklo_ps, _mm512_zextsi256_si512,
};

/// Learned features stored as bfloat16 (the upper half of each f32, rounded to nearest):
/// all views' features are held at once, 4.2 GB as f32 for eight 1920×1080 views, half that
/// as bf16. The cosine of unit 64-d features moves by about 1e-3, well below the cost
/// differences between disparities.
pub type CompactFeatures = crate::image::Image<u16>;

/// `v` as bfloat16, rounded to nearest even on the dropped half.
pub(super) fn to_bf16(v: f32) -> u16 {
    let bits = v.to_bits();
    ((bits + 0x7FFF + ((bits >> 16) & 1)) >> 16) as u16
}

impl From<FeatureMap> for CompactFeatures {
    fn from(map: FeatureMap) -> Self {
        let data = map.data.iter().map(|&v| to_bf16(v)).collect();
        CompactFeatures {
            width: map.width,
            height: map.height,
            channels: map.channels,
            data,
        }
    }
}

/// Per pixel of a view, the dot products of its feature with its own and with its right,
/// lower, lower-right and lower-left neighbours' (0 past the border): the norm of a
/// bilinearly interpolated feature, `|Σ kᵢ fᵢ|² = Σᵢⱼ kᵢ kⱼ fᵢ·fⱼ`, from these instead of
/// ten dot products per lookup.
#[derive(Debug, Clone)]
pub(super) struct NeighbourProducts {
    width: usize,
    products: Vec<[f32; 5]>,
}

impl NeighbourProducts {
    /// Slots of [`NeighbourProducts::at`]: own, right, lower, lower-right, lower-left.
    const OWN: usize = 0;
    const RIGHT: usize = 1;
    const LOWER: usize = 2;
    const LOWER_RIGHT: usize = 3;
    const LOWER_LEFT: usize = 4;

    /// The products of `features`, with `product` as the dot product.
    pub(super) fn of(
        features: &CompactFeatures,
        product: impl Fn(&[u16], &[u16]) -> f32 + Sync,
    ) -> Self {
        use rayon::prelude::*;
        let (w, h, c) = (features.width, features.height, features.channels);
        let feature = |x: usize, y: usize| &features.data[(y * w + x) * c..][..c];
        let mut products = vec![[0f32; 5]; w * h];
        products
            .par_chunks_mut(w.max(1))
            .enumerate()
            .for_each(|(y, row)| {
                for (x, slots) in row.iter_mut().enumerate() {
                    let f = feature(x, y);
                    slots[Self::OWN] = product(f, f);
                    if x + 1 < w {
                        slots[Self::RIGHT] = product(f, feature(x + 1, y));
                    }
                    if y + 1 < h {
                        slots[Self::LOWER] = product(f, feature(x, y + 1));
                        if x + 1 < w {
                            slots[Self::LOWER_RIGHT] = product(f, feature(x + 1, y + 1));
                        }
                        if x > 0 {
                            slots[Self::LOWER_LEFT] = product(f, feature(x - 1, y + 1));
                        }
                    }
                }
            });
        NeighbourProducts { width: w, products }
    }

    /// The products of pixel (x, y).
    #[inline(always)]
    pub(super) fn at(&self, x: usize, y: usize) -> &[f32; 5] {
        &self.products[y * self.width + x]
    }

    /// `|Σ kᵢ fᵢ|²` for the features at (x0, y0), (x0 + 1, y0), (x0, y0 + 1) and
    /// (x0 + 1, y0 + 1) with weights `k`, in that order.
    #[inline(always)]
    pub(super) fn interpolated_norm2(&self, x0: usize, y0: usize, k: [f32; 4]) -> f32 {
        let (p00, p10, p01, p11) = (
            self.at(x0, y0),
            self.at(x0 + 1, y0),
            self.at(x0, y0 + 1),
            self.at(x0 + 1, y0 + 1),
        );
        // Summed tap by tap, each tap's own product before its products with the later
        // taps: the order (and so the rounding) of the sums of the ten dot products.
        let mut norm2 = k[0] * k[0] * p00[Self::OWN];
        norm2 += 2.0 * k[0] * k[1] * p00[Self::RIGHT];
        norm2 += 2.0 * k[0] * k[2] * p00[Self::LOWER];
        norm2 += 2.0 * k[0] * k[3] * p00[Self::LOWER_RIGHT];
        norm2 += k[1] * k[1] * p10[Self::OWN];
        norm2 += 2.0 * k[1] * k[2] * p10[Self::LOWER_LEFT];
        norm2 += 2.0 * k[1] * k[3] * p10[Self::LOWER];
        norm2 += k[2] * k[2] * p01[Self::OWN];
        norm2 += 2.0 * k[2] * k[3] * p01[Self::RIGHT];
        norm2 + k[3] * k[3] * p11[Self::OWN]
    }
}

/// The f32 value of a bfloat16.
#[inline(always)]
pub(super) fn widen(v: u16) -> f32 {
    f32::from_bits((v as u32) << 16)
}

/// Dot product of two bf16 vectors with eight independent f32 accumulators (vectorised by
/// the compiler).
#[inline(always)]
pub(super) fn dot(a: &[u16], b: &[u16]) -> f32 {
    let mut lanes = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(&p, &q)| widen(p) * widen(q))
        .sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            lanes[i] += widen(x[i]) * widen(y[i]);
        }
    }
    lanes.iter().sum::<f32>() + tail
}

/// [`dot`] of an f32 vector (a bf16 one widened beforehand) and a bf16 vector: the same
/// sums in the same order.
#[inline(always)]
pub(super) fn dot_widened(a: &[f32], b: &[u16]) -> f32 {
    let mut lanes = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(&p, &q)| p * widen(q))
        .sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            lanes[i] += x[i] * widen(y[i]);
        }
    }
    lanes.iter().sum::<f32>() + tail
}

/// [`dot`] with `vdpbf16ps`: 32 bfloat16 products per instruction, summed into 16 f32
/// lanes (the products are exact in f32; only the order of the sums differs from [`dot`]).
/// The length must be a multiple of 16 ([`DotKernel::for_channels`] checks it): a last
/// half vector is loaded into the low half of a zeroed one.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16")]
#[inline]
pub(super) fn dot_avx512_bf16(a: &[u16], b: &[u16]) -> f32 {
    debug_assert!(a.len() == b.len() && a.len().is_multiple_of(16));
    let mut sums = _mm512_setzero_ps();
    let (ca, cb) = (a.chunks_exact(32), b.chunks_exact(32));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (p, q) in ca.zip(cb) {
        sums = _mm512_dpbf16_ps(sums, load_bf16(p), load_bf16(q));
    }
    if ra.len() == 16 {
        sums = _mm512_dpbf16_ps(sums, load_half_bf16(ra), load_half_bf16(rb));
    }
    _mm512_reduce_add_ps(sums)
}

/// 32 bfloat16 as a vector.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16")]
#[inline]
pub(super) fn load_bf16(values: &[u16]) -> __m512bh {
    let values = &values[..32];
    // SAFETY: `values` holds 32 u16, the 64 bytes an unaligned load reads; a vector of
    // 32 bf16 has the layout of 32 u16.
    unsafe {
        std::mem::transmute::<__m512i, __m512bh>(_mm512_loadu_si512(
            values.as_ptr().cast::<__m512i>(),
        ))
    }
}

/// 16 bfloat16 in the low half of a vector whose high half is zero.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16")]
#[inline]
pub(super) fn load_half_bf16(values: &[u16]) -> __m512bh {
    let values = &values[..16];
    // SAFETY: `values` holds 16 u16, the 32 bytes an unaligned load reads; a vector of
    // 32 bf16 has the layout of 32 u16.
    unsafe {
        let low = _mm256_loadu_si256(values.as_ptr().cast::<__m256i>());
        std::mem::transmute::<__m512i, __m512bh>(_mm512_zextsi256_si512(low))
    }
}

/// The dot products of 16 pixels' features `a` with 16 pixels' features `b` (each
/// `16 × channels`, pixel-major), pixel i's in lane i: per pixel 16 partial sums as in
/// [`dot_avx512_bf16`], then all 16 reduced together ([`sum_lanes_of_16`]), a third of
/// the shuffles that one reduction per pixel takes. `channels` must be a multiple of 32,
/// or 16: then each vector holds two pixels' features, and the low and high halves of
/// its products go to the two pixels' partial sums.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16")]
#[inline]
pub(super) fn dots16_avx512_bf16(a: &[u16], b: &[u16], channels: usize) -> __m512 {
    debug_assert!(channels.is_multiple_of(32) || channels == 16);
    let (a, b) = (&a[..16 * channels], &b[..16 * channels]);
    let mut partial = [_mm512_setzero_ps(); 16];
    if channels == 16 {
        for (pair, (p, q)) in partial
            .chunks_exact_mut(2)
            .zip(a.chunks_exact(32).zip(b.chunks_exact(32)))
        {
            let products = _mm512_dpbf16_ps(_mm512_setzero_ps(), load_bf16(p), load_bf16(q));
            pair[0] = _mm512_maskz_mov_ps(0x00FF, products);
            pair[1] = _mm512_maskz_mov_ps(0xFF00, products);
        }
        return sum_lanes_of_16(&partial);
    }
    for ((sums, p), q) in partial
        .iter_mut()
        .zip(a.chunks_exact(channels))
        .zip(b.chunks_exact(channels))
    {
        for (p, q) in p.chunks_exact(32).zip(q.chunks_exact(32)) {
            *sums = _mm512_dpbf16_ps(*sums, load_bf16(p), load_bf16(q));
        }
    }
    sum_lanes_of_16(&partial)
}

/// Lane i of the result is the sum of the 16 lanes of `v[i]`: a transpose-and-add tree,
/// pairs within 128-bit lanes first (as f32, then as f64 pairs), then across them.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub(super) fn sum_lanes_of_16(v: &[__m512; 16]) -> __m512 {
    // Per 128-bit lane: [v0 + v2, w0 + w2, v1 + v3, w1 + w3] of each pair (v, w).
    let pairs: [__m512; 8] = std::array::from_fn(|i| {
        let (p, q) = (v[2 * i], v[2 * i + 1]);
        _mm512_add_ps(_mm512_unpacklo_ps(p, q), _mm512_unpackhi_ps(p, q))
    });
    // Per 128-bit lane: the lane's sum of each of four vectors, in order.
    let quads: [__m512; 4] = std::array::from_fn(|i| {
        let (p, q) = (
            _mm512_castps_pd(pairs[2 * i]),
            _mm512_castps_pd(pairs[2 * i + 1]),
        );
        _mm512_add_ps(
            _mm512_castpd_ps(_mm512_unpacklo_pd(p, q)),
            _mm512_castpd_ps(_mm512_unpackhi_pd(p, q)),
        )
    });
    // Adjacent 128-bit lanes added: eight vectors' half sums.
    let across = |p: __m512, q: __m512| {
        _mm512_add_ps(
            _mm512_shuffle_f32x4::<0b10_00_10_00>(p, q),
            _mm512_shuffle_f32x4::<0b11_01_11_01>(p, q),
        )
    };
    let halves = [across(quads[0], quads[1]), across(quads[2], quads[3])];
    across(halves[0], halves[1])
}

/// Which build of the multi-view cost's dot products runs, chosen once per volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum DotKernel {
    /// Baseline x86-64 (or another architecture).
    Portable,
    /// AVX2 + FMA on f32 lanes.
    Avx2,
    /// AVX-512 BF16 on the stored bfloat16 (features of 16 or a multiple of 32 channels).
    Avx512Bf16,
}

impl DotKernel {
    /// The fastest build this CPU runs for features of `channels` channels.
    pub(super) fn for_channels(channels: usize) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let fits = channels.is_multiple_of(32) || channels == 16;
            if fits && crate::cpu::has_avx512_bf16() {
                return DotKernel::Avx512Bf16;
            }
            if crate::cpu::has_avx2_fma() {
                return DotKernel::Avx2;
            }
        }
        let _ = channels;
        DotKernel::Portable
    }

    /// Every build this CPU runs for features of `channels` channels, fastest first.
    #[cfg(test)]
    pub(super) fn available(channels: usize) -> Vec<Self> {
        let fastest = Self::for_channels(channels);
        [DotKernel::Avx512Bf16, DotKernel::Avx2, DotKernel::Portable]
            .into_iter()
            .skip_while(|&k| k != fastest)
            .filter(|&k| k != DotKernel::Avx512Bf16 || fastest == DotKernel::Avx512Bf16)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_bf16(n: usize, seed: u64) -> Vec<u16> {
        let mut state = seed;
        let data: Vec<f32> = (0..n)
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
                ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
            })
            .collect();
        CompactFeatures::from(FeatureMap {
            width: n,
            height: 1,
            channels: 1,
            data,
        })
        .data
    }

    /// Each build's dot products, one pixel or sixteen at a time, agree with the portable
    /// one's pixel by pixel.
    #[test]
    fn every_build_gives_the_portable_dot_products() {
        for c in [16, 32, 48, 64] {
            builds_agree_at(c);
        }
    }

    fn builds_agree_at(c: usize) {
        let (a, b) = (random_bf16(16 * c, 1), random_bf16(16 * c, 2));
        let portable: Vec<f32> = (0..16)
            .map(|i| dot(&a[i * c..][..c], &b[i * c..][..c]))
            .collect();
        let widened: Vec<f32> = a.iter().map(|&v| widen(v)).collect();
        for i in 0..16 {
            let here = dot_widened(&widened[i * c..][..c], &b[i * c..][..c]);
            assert!((here - portable[i]).abs() < 1e-5, "widened, pixel {i}");
        }
        #[cfg(target_arch = "x86_64")]
        if DotKernel::for_channels(c) == DotKernel::Avx512Bf16 {
            // SAFETY: the CPU supports AVX-512F and AVX-512 BF16, and `c` is 16 or a
            // multiple of 32 (checked just above).
            let (single, sixteen) = unsafe {
                let single: Vec<f32> = (0..16)
                    .map(|i| dot_avx512_bf16(&a[i * c..][..c], &b[i * c..][..c]))
                    .collect();
                let mut sixteen = [0f32; 16];
                let lanes = dots16_avx512_bf16(&a, &b, c);
                std::ptr::copy_nonoverlapping(
                    (&lanes as *const __m512).cast::<f32>(),
                    sixteen.as_mut_ptr(),
                    16,
                );
                (single, sixteen)
            };
            for i in 0..16 {
                assert!(
                    (single[i] - portable[i]).abs() < 1e-5,
                    "one pixel, pixel {i} of {c} channels"
                );
                assert!(
                    (sixteen[i] - portable[i]).abs() < 1e-5,
                    "sixteen, pixel {i} of {c} channels"
                );
            }
        }
    }

    /// The norm of a bilinearly interpolated feature from the neighbours' products equals
    /// the norm computed from the interpolated feature itself.
    #[test]
    fn neighbour_products_give_the_norm_of_an_interpolated_feature() {
        use NeighbourProducts as P;
        let (w, h, c) = (5usize, 4usize, 8usize);
        let features = CompactFeatures {
            width: w,
            height: h,
            channels: c,
            data: random_bf16(w * h * c, 3),
        };
        let products = NeighbourProducts::of(&features, dot);
        let feature = |x: usize, y: usize| -> Vec<f32> {
            features.data[(y * w + x) * c..][..c]
                .iter()
                .map(|&v| widen(v))
                .collect()
        };
        for (x0, y0, fx, fy) in [(0, 0, 0.3f32, 0.6f32), (3, 2, 0.9, 0.1), (1, 1, 0.0, 0.5)] {
            let k = [
                (1.0 - fx) * (1.0 - fy),
                fx * (1.0 - fy),
                (1.0 - fx) * fy,
                fx * fy,
            ];
            let taps = [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)];
            let mut mixed = vec![0f32; c];
            for (&ki, &(x, y)) in k.iter().zip(&taps) {
                for (m, f) in mixed.iter_mut().zip(feature(x, y)) {
                    *m += ki * f;
                }
            }
            let direct: f32 = mixed.iter().map(|m| m * m).sum();
            let from_products = products.interpolated_norm2(x0, y0, k);
            assert!(
                (direct - from_products).abs() < 1e-5,
                "({x0}, {y0}): {direct} against {from_products}"
            );
        }
        // Past the border the products are 0.
        assert_eq!(products.at(w - 1, 0)[P::RIGHT], 0.0);
        assert_eq!(products.at(0, h - 1)[P::LOWER], 0.0);
        assert_eq!(products.at(0, 0)[P::LOWER_LEFT], 0.0);
    }
}
