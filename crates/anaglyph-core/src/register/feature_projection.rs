//! Several matching images of a view merged into one learned feature per pixel, in
//! multi-baseline registration (`common signals -> features -> multi-view cost`).
//!
//! Each image (one per common signal, [`super::common_signals`]) goes through the network's
//! tower on its own; the concatenation of their unit features, each scaled by `1/√k`, has
//! cosines that are the mean of the images' cosines. Storing it would multiply the memory
//! and the cost-volume time by k, so it is projected onto the `dims` leading eigenvectors
//! of its second-moment matrix (fitted once, on one view, and shared by all views so that
//! cosines stay comparable) and normalised again.

use crate::stereo::FeatureMap;
use crate::{Error, Result};
use faer::{Mat, Side};
use rayon::prelude::*;

/// Every how many pixels the second-moment matrix samples.
const FIT_STRIDE: usize = 7;
/// Pixels per rayon task when projecting.
const CHUNK_PIXELS: usize = 4096;

/// The shared projection of k images' concatenated features onto `dims` dimensions.
#[derive(Debug, Clone)]
pub struct FeatureProjection {
    /// Per image j, its block of the projection: `channels × dims`, row-major, already
    /// scaled by `1/√k`.
    blocks: Vec<Vec<f32>>,
    channels: usize,
    dims: usize,
    /// Fraction of the concatenated features' energy the kept dimensions hold.
    pub energy_kept: f64,
}

impl FeatureProjection {
    /// Fits the projection to one view's feature maps (one per matching image, all of
    /// the same size and width).
    pub fn fit(maps: &[FeatureMap], dims: usize) -> Result<Self> {
        let k = maps.len();
        let c = maps.first().map_or(0, |m| m.channels);
        let pixels = maps.first().map_or(0, |m| m.width * m.height);
        if k == 0 || c == 0 || pixels == 0 || dims == 0 || dims > k * c {
            return Err(Error::raster(
                "feature projection",
                format!("{k} maps of {c} channels and {pixels} pixels onto {dims} dimensions"),
                "at least one non-empty map, and at most as many dimensions as channels",
            ));
        }
        if maps
            .iter()
            .any(|m| m.channels != c || m.width * m.height != pixels)
        {
            return Err(Error::raster(
                "feature projection",
                "maps of different sizes or widths",
                "maps of one size and width",
            ));
        }
        let total = k * c;
        let scale = 1.0 / (k as f64).sqrt();
        let sampled: Vec<usize> = (0..pixels).step_by(FIT_STRIDE).collect();
        // The second moment of the concatenated features, Xᵀ X: one product per chunk of
        // samples, summed over chunks.
        let symmetric = sampled
            .par_chunks(CHUNK_PIXELS)
            .map(|chunk| {
                let mut concatenated = vec![0f64; chunk.len() * total];
                for (row, &p) in concatenated.chunks_exact_mut(total).zip(chunk) {
                    for (j, map) in maps.iter().enumerate() {
                        for (slot, &v) in row[j * c..][..c].iter_mut().zip(&map.data[p * c..][..c])
                        {
                            *slot = v as f64 * scale;
                        }
                    }
                }
                let x = faer::MatRef::from_row_major_slice(&concatenated, chunk.len(), total);
                let mut moment = Mat::<f64>::zeros(total, total);
                faer::linalg::matmul::matmul(
                    moment.as_mut(),
                    faer::Accum::Replace,
                    x.transpose(),
                    x,
                    1.0,
                    faer::Par::Seq,
                );
                moment
            })
            .reduce(|| Mat::<f64>::zeros(total, total), |a, b| a + b);
        let eigen =
            symmetric
                .self_adjoint_eigen(Side::Lower)
                .map_err(|e| Error::LinearAlgebra {
                    op: "feature projection".into(),
                    message: format!("{e:?}"),
                })?;
        let values = eigen.S().column_vector();
        let energy: f64 = (0..total).map(|i| values[i].max(0.0)).sum();
        // Eigenvalues come in nondecreasing order: the leading ones are last.
        let kept: f64 = (0..dims).map(|r| values[total - 1 - r].max(0.0)).sum();
        let blocks = (0..k)
            .map(|j| {
                let mut block = vec![0f32; c * dims];
                for i in 0..c {
                    for r in 0..dims {
                        block[i * dims + r] =
                            (eigen.U()[(j * c + i, total - 1 - r)] * scale) as f32;
                    }
                }
                block
            })
            .collect();
        Ok(FeatureProjection {
            blocks,
            channels: c,
            dims,
            energy_kept: if energy > 0.0 { kept / energy } else { 0.0 },
        })
    }

    /// How many matching images the projection merges.
    pub fn images(&self) -> usize {
        self.blocks.len()
    }

    /// Adds image `j`'s projected features to `out` (`pixels × dims`, row-major), or
    /// writes them there for the first image: a product adding to a fresh buffer would
    /// read its untouched pages first (the kernel's shared zero page), and writing them
    /// then costs each page a copy-on-write fault and a flush of every core's TLB.
    fn accumulate(&self, j: usize, map: &FeatureMap, out: &mut [f32]) {
        let accum = match j {
            0 => faer::Accum::Replace,
            _ => faer::Accum::Add,
        };
        let (c, dims) = (self.channels, self.dims);
        let block = &self.blocks[j];
        out.par_chunks_mut(CHUNK_PIXELS * dims)
            .zip(map.data.par_chunks(CHUNK_PIXELS * c))
            .for_each(|(dst, src)| {
                let rows = src.len() / c;
                faer::linalg::matmul::matmul(
                    faer::MatMut::from_row_major_slice_mut(dst, rows, dims),
                    accum,
                    faer::MatRef::from_row_major_slice(src, rows, c),
                    faer::MatRef::from_row_major_slice(block, c, dims),
                    1.0f32,
                    faer::Par::Seq,
                );
            });
    }

    /// Dimensions of the projected features.
    pub fn dims(&self) -> usize {
        self.dims
    }

    /// The unit-length projection of one matching image's features (`pixels × channels`)
    /// into `out` (`pixels × dims`): [`FeatureProjection::merged_maps`] of a projection
    /// fitted on one image, a strip of pixels at a time. The caller checks that the
    /// projection has one image; the features come from the network it was fitted on.
    pub(crate) fn project_one(&self, features: &[f32], out: &mut [f32]) {
        let (c, dims) = (self.channels, self.dims);
        let pixels = (features.len() / c.max(1)).min(out.len() / dims.max(1));
        let (features, out) = (&features[..pixels * c], &mut out[..pixels * dims]);
        out.fill(0.0);
        faer::linalg::matmul::matmul(
            faer::MatMut::from_row_major_slice_mut(out, pixels, dims),
            faer::Accum::Add,
            faer::MatRef::from_row_major_slice(features, pixels, c),
            faer::MatRef::from_row_major_slice(&self.blocks[0], c, dims),
            1.0f32,
            faer::Par::Seq,
        );
        for f in out.chunks_exact_mut(dims) {
            let norm = f.iter().map(|v| v * v).sum::<f32>().sqrt();
            if norm > 0.0 {
                f.iter_mut().for_each(|v| *v /= norm);
            }
        }
    }

    /// Image `j`'s projected features into `out` (`pixels × channels` in, `pixels × dims`
    /// out, row-major, not normalised), a strip of pixels at a time: summed over the
    /// images and normalised ([`normalise_features`]), they are
    /// [`FeatureProjection::merged_maps`] without any image's whole feature map held.
    pub(crate) fn project_image(&self, j: usize, features: &[f32], out: &mut [f32]) {
        let (c, dims) = (self.channels, self.dims);
        let pixels = (features.len() / c.max(1)).min(out.len() / dims.max(1));
        let (features, out) = (&features[..pixels * c], &mut out[..pixels * dims]);
        faer::linalg::matmul::matmul(
            faer::MatMut::from_row_major_slice_mut(out, pixels, dims),
            faer::Accum::Replace,
            faer::MatRef::from_row_major_slice(features, pixels, c),
            faer::MatRef::from_row_major_slice(&self.blocks[j], c, dims),
            1.0f32,
            faer::Par::Seq,
        );
    }

    /// The merged, unit-length features of a view's matching images, from their feature
    /// maps (one per matching image, in the order the projection was fitted with).
    pub fn merged_maps(&self, maps: Vec<FeatureMap>) -> Result<FeatureMap> {
        if maps.len() != self.images() {
            return Err(Error::raster(
                "feature projection",
                format!("{} maps", maps.len()),
                format!("{}, as the projection was fitted on", self.images()),
            ));
        }
        self.merge(maps.into_iter())
    }

    /// Projects and sums one feature map per matching image, then normalises each pixel.
    fn merge(&self, maps: impl Iterator<Item = FeatureMap>) -> Result<FeatureMap> {
        let mut merged: Option<FeatureMap> = None;
        for (j, map) in maps.enumerate() {
            let out = merged.get_or_insert_with(|| FeatureMap {
                width: map.width,
                height: map.height,
                channels: self.dims,
                data: vec![0f32; map.width * map.height * self.dims],
            });
            if j >= self.images()
                || map.channels != self.channels
                || (map.width, map.height) != (out.width, out.height)
            {
                return Err(Error::raster(
                    "feature projection",
                    "features of another size or depth",
                    "the features the projection was fitted on",
                ));
            }
            self.accumulate(j, &map, &mut out.data);
        }
        let mut merged = merged
            .ok_or_else(|| Error::raster("feature projection", "no images", "at least one"))?;
        normalise_features(&mut merged);
        Ok(merged)
    }
}

/// Scales every pixel's features to unit length (zero features stay zero).
pub(crate) fn normalise_features(map: &mut FeatureMap) {
    map.data.par_chunks_mut(map.channels.max(1)).for_each(|f| {
        let norm = f.iter().map(|v| v * v).sum::<f32>().sqrt();
        if norm > 0.0 {
            f.iter_mut().for_each(|v| *v /= norm);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random unit features (xorshift), `pixels` of `c` channels.
    fn unit_features(pixels: usize, c: usize, seed: u64) -> FeatureMap {
        let mut state = seed;
        let mut data = Vec::with_capacity(pixels * c);
        for _ in 0..pixels {
            let f: Vec<f32> = (0..c)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
                })
                .collect();
            let norm = f.iter().map(|v| v * v).sum::<f32>().sqrt();
            data.extend(f.iter().map(|v| v / norm));
        }
        FeatureMap {
            width: pixels,
            height: 1,
            channels: c,
            data,
        }
    }

    fn cosine(a: &[f32], b: &[f32]) -> f32 {
        a.iter().zip(b).map(|(x, y)| x * y).sum()
    }

    /// Keeping every dimension, the merged cosine is the mean of the images' cosines.
    #[test]
    fn a_full_projection_averages_the_cosines_of_the_images() {
        let (pixels, c) = (200, 6);
        let view_a = [unit_features(pixels, c, 1), unit_features(pixels, c, 2)];
        let view_b = [unit_features(pixels, c, 3), unit_features(pixels, c, 4)];
        let projection = FeatureProjection::fit(&view_a, 2 * c).unwrap();
        assert!((projection.energy_kept - 1.0).abs() < 1e-9);
        let a = projection.merge(view_a.iter().cloned()).unwrap();
        let b = projection.merge(view_b.iter().cloned()).unwrap();
        // Merging maps already computed is the same merge; a wrong count is refused.
        assert_eq!(projection.merged_maps(view_b.to_vec()).unwrap(), b);
        assert_eq!(
            projection
                .merged_maps(view_b[..1].to_vec())
                .err()
                .map(|e| e.kind()),
            Some("Raster")
        );
        for p in [0, 17, 199] {
            let expected = 0.5
                * (cosine(view_a[0].pixel(p, 0), view_b[0].pixel(p, 0))
                    + cosine(view_a[1].pixel(p, 0), view_b[1].pixel(p, 0)));
            let got = cosine(a.pixel(p, 0), b.pixel(p, 0));
            assert!(
                (got - expected).abs() < 1e-5,
                "pixel {p}: {got} against {expected}"
            );
        }
    }

    /// Each image projected a strip at a time, summed and normalised, is the merge of the
    /// whole maps (a large view's path, which holds no whole map), fitted elsewhere.
    #[test]
    fn images_projected_strip_by_strip_and_summed_are_the_merged_maps() {
        let (pixels, c, dims) = (240, 8, 5);
        let fitted_on = [unit_features(pixels, c, 11), unit_features(pixels, c, 12)];
        let projection = FeatureProjection::fit(&fitted_on, dims).unwrap();
        let view = [unit_features(pixels, c, 13), unit_features(pixels, c, 14)];
        let merged = projection.merged_maps(view.to_vec()).unwrap();
        let mut sum = FeatureMap {
            width: pixels,
            height: 1,
            channels: dims,
            data: vec![0.0; pixels * dims],
        };
        for (j, map) in view.iter().enumerate() {
            let strip = 37; // not a divisor of the pixels: a short last strip
            for (src, dst) in map
                .data
                .chunks(strip * c)
                .zip(sum.data.chunks_mut(strip * dims))
            {
                let mut part = vec![f32::NAN; dst.len()];
                projection.project_image(j, src, &mut part);
                dst.iter_mut().zip(&part).for_each(|(s, x)| *s += x);
            }
        }
        normalise_features(&mut sum);
        for (p, (got, expected)) in sum
            .data
            .chunks(dims)
            .zip(merged.data.chunks(dims))
            .enumerate()
        {
            let norm = got.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!((norm - 1.0).abs() < 1e-5, "pixel {p}: norm {norm}");
            for (a, b) in got.iter().zip(expected) {
                assert!(
                    (a - b).abs() < 1e-5,
                    "pixel {p}: {got:?} against {expected:?}"
                );
            }
        }
    }

    /// Two identical images span only one image's dimensions: projecting onto that many
    /// loses nothing, and the cosines are the single image's.
    #[test]
    fn a_projection_onto_the_features_rank_loses_nothing() {
        let (pixels, c) = (300, 5);
        let a = unit_features(pixels, c, 7);
        let b = unit_features(pixels, c, 8);
        let projection = FeatureProjection::fit(&[a.clone(), a.clone()], c).unwrap();
        assert!(
            projection.energy_kept > 1.0 - 1e-9,
            "{}",
            projection.energy_kept
        );
        let merged_a = projection
            .merge([a.clone(), a.clone()].into_iter())
            .unwrap();
        let merged_b = projection
            .merge([b.clone(), b.clone()].into_iter())
            .unwrap();
        for p in [3, 150, 299] {
            let expected = cosine(a.pixel(p, 0), b.pixel(p, 0));
            let got = cosine(merged_a.pixel(p, 0), merged_b.pixel(p, 0));
            assert!(
                (got - expected).abs() < 1e-5,
                "pixel {p}: {got} against {expected}"
            );
        }
        // Fewer dimensions than the rank keep less than all of the energy.
        let smaller = FeatureProjection::fit(&[a.clone(), b.clone()], c).unwrap();
        assert!(smaller.energy_kept < 0.99, "{}", smaller.energy_kept);
        assert_eq!(
            FeatureProjection::fit(std::slice::from_ref(&a), c + 1)
                .err()
                .map(|e| e.kind()),
            Some("Raster")
        );
        assert_eq!(
            projection
                .merge([a.clone(), a.clone(), a].into_iter())
                .err()
                .map(|e| e.kind()),
            Some("Raster")
        );
    }

    /// One image's features projected a strip at a time equal the whole map merged.
    #[test]
    fn projecting_one_image_by_strips_equals_merging_its_map() {
        let (c, dims) = (64, 32);
        let map = unit_features(500, c, 11);
        let projection = FeatureProjection::fit(std::slice::from_ref(&map), dims).unwrap();
        let merged = projection.merged_maps(vec![map.clone()]).unwrap();
        let mut strips = vec![0f32; 500 * dims];
        for (src, dst) in map.data.chunks(123 * c).zip(strips.chunks_mut(123 * dims)) {
            projection.project_one(src, dst);
        }
        let off = strips
            .iter()
            .zip(&merged.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(off < 1e-5, "{off}");
    }
}
