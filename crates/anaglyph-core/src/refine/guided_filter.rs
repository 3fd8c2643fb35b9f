//! The guided filter of He, Sun and Tang (2013, "Guided image filtering", TPAMI 35(6)),
//! with a multi-channel guide and per-pixel weights: in every (2r+1)² window each output
//! band is modelled as an affine function of the guide, `q = aᵀI + b`, fitted by weighted
//! ridge regression (ε on the guide's covariance), and the fits of all windows covering a
//! pixel are averaged. Invalid pixels weigh nothing; a confidence (how well a pixel's
//! measurements agree) lets reliable pixels dominate the fits. Box sums are running sums: O(1) per pixel at
//! any radius.

use crate::image::Image;
use crate::{Error, Result};
use rayon::prelude::*;

/// Most guide channels (RGB, or RGB plus one more); the per-pixel covariance is inverted
/// in a fixed-size array.
pub const MAX_GUIDE_CHANNELS: usize = 4;

/// Window radius and regularisation of the guided filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidedFilter {
    /// Window half-width: windows are (2r+1)² pixels, clipped at the image border.
    pub radius: usize,
    /// Ridge weight ε added to the guide's covariance, in squared guide units; larger
    /// values smooth more where the guide is flat.
    pub epsilon: f64,
}

/// Weight under which a window is treated as empty (no fit): a thousandth of one pixel.
const EMPTY_WINDOW: f32 = 1e-3;

/// Filters `input` (its channels are the bands) with `guide` of the same size. `weights`
/// (one per pixel, ≥ 0; None: all 1) weigh each pixel in the fits. Pixels where the input
/// or the guide is not finite weigh nothing and keep their input value (NaN stays NaN).
/// Returns the filtered values in `input`'s layout.
pub fn guided_filter(
    guide: &Image<f32>,
    input: &Image<f32>,
    weights: Option<&[f32]>,
    filter: GuidedFilter,
) -> Result<Vec<f32>> {
    let (width, height) = (input.width, input.height);
    let (channels, bands) = (guide.channels, input.channels);
    if (guide.width, guide.height) != (width, height) {
        return Err(Error::Shape {
            op: "guided filter: guide against input".into(),
            got: vec![guide.width, guide.height],
            expected: vec![width, height],
        });
    }
    let (guide, input) = (guide.data.as_slice(), input.data.as_slice());
    let n = width * height;
    if channels == 0 || channels > MAX_GUIDE_CHANNELS {
        return Err(Error::raster(
            "guided filter",
            format!("{channels} guide channels"),
            format!("1 to {MAX_GUIDE_CHANNELS}"),
        ));
    }
    if bands == 0 || guide.len() != n * channels || input.len() != n * bands {
        return Err(Error::Shape {
            op: "guided filter: guide and input against width × height".into(),
            got: vec![guide.len(), input.len()],
            expected: vec![n * channels, n * bands],
        });
    }
    if let Some(weights) = weights {
        if weights.len() != n || weights.iter().any(|w| !(*w >= 0.0) || !w.is_finite()) {
            return Err(Error::raster(
                "guided filter weights",
                format!("{} weights", weights.len()),
                format!("{n}, one per pixel, each finite and >= 0"),
            ));
        }
    }
    if !(filter.epsilon > 0.0) || !filter.epsilon.is_finite() {
        return Err(Error::out_of_range(
            "guided filter epsilon",
            filter.epsilon,
            "a finite value > 0",
        ));
    }
    if n == 0 {
        return Ok(Vec::new());
    }
    let valid: Vec<bool> = (0..n)
        .map(|i| {
            guide[i * channels..(i + 1) * channels]
                .iter()
                .chain(&input[i * bands..(i + 1) * bands])
                .all(|v| v.is_finite())
        })
        .collect();
    let weight: Vec<f32> = (0..n)
        .map(|i| match (valid[i], weights) {
            (false, _) => 0.0,
            (true, None) => 1.0,
            (true, Some(w)) => w[i],
        })
        .collect();
    let shared = GuideStatistics::new(guide, channels, &weight, width, height, filter);

    // Band planes: each band's passes then read memory in order (the interleaved cube
    // would be read once per cache line per band and per pass).
    let mut planar = vec![0.0f32; n * bands];
    for (i, pixel) in input.chunks_exact(bands).enumerate() {
        for (band, &v) in pixel.iter().enumerate() {
            planar[band * n + i] = v;
        }
    }
    let planes: Vec<Vec<f32>> = (0..bands)
        .into_par_iter()
        .map_init(
            || BandScratch::new(n, channels, BoxSum::new(width, height, filter.radius)),
            |scratch, band| scratch.filter_band(&shared, &planar[band * n..(band + 1) * n]),
        )
        .collect();

    let mut output = input.to_vec();
    output
        .par_chunks_mut(bands * width)
        .enumerate()
        .for_each(|(y, row)| {
            for x in 0..width {
                let i = y * width + x;
                if !valid[i] {
                    continue;
                }
                for (band, plane) in planes.iter().enumerate() {
                    row[x * bands + band] = plane[i];
                }
            }
        });
    Ok(output)
}

/// What every band's fit shares: the guide, its window means and the inverse of its
/// regularised window covariance.
struct GuideStatistics<'a> {
    guide: &'a [f32],
    channels: usize,
    /// Weight of each pixel in the fits (0: not used).
    weight: &'a [f32],
    /// Summed weight per window (below [`EMPTY_WINDOW`]: the window has no fit).
    count: Vec<f32>,
    /// Windows with a fit covering each pixel.
    windows: Vec<f32>,
    /// Window means of each guide channel, `channels` planes.
    mean: Vec<Vec<f32>>,
    /// `(Σ + εI)⁻¹` per pixel, `channels²` values each.
    inverse: Vec<f32>,
}

impl<'a> GuideStatistics<'a> {
    fn new(
        guide: &'a [f32],
        channels: usize,
        weight: &'a [f32],
        width: usize,
        height: usize,
        filter: GuidedFilter,
    ) -> Self {
        let n = width * height;
        let mut boxes = BoxSum::new(width, height, filter.radius);
        let mut count = vec![0.0f32; n];
        boxes.sum(weight, &mut count);
        let mut windows = vec![0.0f32; n];
        let has_fit: Vec<f32> = count
            .iter()
            .map(|&c| f32::from(u8::from(c > EMPTY_WINDOW)))
            .collect();
        boxes.sum(&has_fit, &mut windows);

        let mut product = vec![0.0f32; n];
        let mut mean = Vec::with_capacity(channels);
        for c in 0..channels {
            for i in 0..n {
                product[i] = if weight[i] > 0.0 {
                    weight[i] * guide[i * channels + c]
                } else {
                    0.0
                };
            }
            let mut plane = vec![0.0f32; n];
            boxes.sum(&product, &mut plane);
            divide_by_count(&mut plane, &count);
            mean.push(plane);
        }
        let g = channels;
        let mut covariance = vec![0.0f64; n * g * g];
        let mut plane = vec![0.0f32; n];
        for c in 0..g {
            for d in c..g {
                for i in 0..n {
                    product[i] = if weight[i] > 0.0 {
                        weight[i] * guide[i * g + c] * guide[i * g + d]
                    } else {
                        0.0
                    };
                }
                boxes.sum(&product, &mut plane);
                divide_by_count(&mut plane, &count);
                for i in 0..n {
                    let value = plane[i] as f64 - mean[c][i] as f64 * mean[d][i] as f64;
                    covariance[i * g * g + c * g + d] = value;
                    covariance[i * g * g + d * g + c] = value;
                }
            }
        }
        let mut inverse = vec![0.0f32; n * g * g];
        inverse
            .par_chunks_mut(g * g)
            .zip(covariance.par_chunks(g * g))
            .for_each(|(inv, cov)| {
                let mut a = [0.0f64; MAX_GUIDE_CHANNELS * MAX_GUIDE_CHANNELS];
                a[..g * g].copy_from_slice(cov);
                for c in 0..g {
                    a[c * g + c] += filter.epsilon;
                }
                invert_positive_definite(&mut a[..g * g], g, inv);
            });
        GuideStatistics {
            guide,
            channels,
            weight,
            count,
            windows,
            mean,
            inverse,
        }
    }
}

/// Per-band working planes, reused across the bands a thread filters.
struct BandScratch {
    boxes: BoxSum,
    product: Vec<f32>,
    mean: Vec<f32>,
    /// `a` per guide channel, then `b`.
    coefficients: Vec<Vec<f32>>,
    averaged: Vec<f32>,
}

impl BandScratch {
    fn new(n: usize, channels: usize, boxes: BoxSum) -> Self {
        BandScratch {
            boxes,
            product: vec![0.0; n],
            mean: vec![0.0; n],
            coefficients: vec![vec![0.0; n]; channels + 1],
            averaged: vec![0.0; n],
        }
    }

    fn filter_band(&mut self, stats: &GuideStatistics<'_>, input: &[f32]) -> Vec<f32> {
        let g = stats.channels;
        let n = stats.weight.len();
        for i in 0..n {
            self.product[i] = if stats.weight[i] > 0.0 {
                stats.weight[i] * input[i]
            } else {
                0.0
            };
        }
        self.boxes.sum(&self.product, &mut self.mean);
        divide_by_count(&mut self.mean, &stats.count);
        // Covariance of each guide channel with the band, into the `a` planes.
        for c in 0..g {
            for i in 0..n {
                self.product[i] = if stats.weight[i] > 0.0 {
                    stats.weight[i] * input[i] * stats.guide[i * g + c]
                } else {
                    0.0
                };
            }
            self.boxes.sum(&self.product, &mut self.coefficients[c]);
            divide_by_count(&mut self.coefficients[c], &stats.count);
        }
        // a = (Σ + εI)⁻¹ cov, b = mean_p − aᵀ mean_I, per window.
        let (a_planes, b_plane) = self.coefficients.split_at_mut(g);
        let mut cov = [0.0f64; MAX_GUIDE_CHANNELS];
        for i in 0..n {
            if !(stats.count[i] > EMPTY_WINDOW) {
                for plane in a_planes.iter_mut() {
                    plane[i] = 0.0;
                }
                b_plane[0][i] = 0.0;
                continue;
            }
            let mean_p = self.mean[i] as f64;
            for c in 0..g {
                cov[c] = a_planes[c][i] as f64 - stats.mean[c][i] as f64 * mean_p;
            }
            let inv = &stats.inverse[i * g * g..(i + 1) * g * g];
            let mut b = mean_p;
            for c in 0..g {
                let a: f64 = (0..g).map(|d| inv[c * g + d] as f64 * cov[d]).sum();
                a_planes[c][i] = a as f32;
                b -= a * stats.mean[c][i] as f64;
            }
            b_plane[0][i] = b as f32;
        }
        // Average the fits of the windows covering each pixel and apply them.
        let mut output = vec![0.0f32; n];
        for (c, plane) in self.coefficients.iter().enumerate() {
            self.boxes.sum(plane, &mut self.averaged);
            for i in 0..n {
                let coefficient = if stats.windows[i] > 0.5 {
                    self.averaged[i] / stats.windows[i]
                } else {
                    0.0
                };
                output[i] += if c < g {
                    coefficient * stats.guide[i * g + c]
                } else {
                    coefficient
                };
            }
        }
        // No window around the pixel has a fit (every neighbour weighs next to nothing):
        // the pixel keeps its own value.
        for i in 0..n {
            if !(stats.windows[i] > 0.5) {
                output[i] = input[i];
            }
        }
        output
    }
}

fn divide_by_count(plane: &mut [f32], count: &[f32]) {
    for (value, &c) in plane.iter_mut().zip(count) {
        *value = if c > EMPTY_WINDOW { *value / c } else { 0.0 };
    }
}

/// Inverts the symmetric positive definite `a` (`g × g`, overwritten) into `inverse` by
/// Gauss–Jordan elimination (no pivoting is needed for a positive definite matrix).
fn invert_positive_definite(a: &mut [f64], g: usize, inverse: &mut [f32]) {
    let mut inv = [0.0f64; MAX_GUIDE_CHANNELS * MAX_GUIDE_CHANNELS];
    for c in 0..g {
        inv[c * g + c] = 1.0;
    }
    for k in 0..g {
        let pivot = a[k * g + k];
        for j in 0..g {
            a[k * g + j] /= pivot;
            inv[k * g + j] /= pivot;
        }
        for r in 0..g {
            if r == k {
                continue;
            }
            let factor = a[r * g + k];
            if factor == 0.0 {
                continue;
            }
            for j in 0..g {
                a[r * g + j] -= factor * a[k * g + j];
                inv[r * g + j] -= factor * inv[k * g + j];
            }
        }
    }
    for (dst, src) in inverse.iter_mut().zip(&inv[..g * g]) {
        *dst = *src as f32;
    }
}

/// Sums over (2r+1)² windows clipped at the border of a `width × height` plane, in one
/// pass: running column sums (f64) are moved down one row at a time and each output row
/// is a running sum along them.
struct BoxSum {
    width: usize,
    height: usize,
    radius: usize,
    columns: Vec<f64>,
}

impl BoxSum {
    fn new(width: usize, height: usize, radius: usize) -> Self {
        BoxSum {
            width,
            height,
            radius,
            columns: vec![0.0; width],
        }
    }

    fn sum(&mut self, src: &[f32], dst: &mut [f32]) {
        let (w, h, r) = (self.width, self.height, self.radius);
        let columns = &mut self.columns;
        columns.fill(0.0);
        for y in 0..(r + 1).min(h) {
            for (acc, v) in columns.iter_mut().zip(&src[y * w..(y + 1) * w]) {
                *acc += *v as f64;
            }
        }
        for y in 0..h {
            running_sum(columns, r, &mut dst[y * w..(y + 1) * w]);
            if y + r + 1 < h {
                let add = &src[(y + r + 1) * w..(y + r + 2) * w];
                for (acc, v) in columns.iter_mut().zip(add) {
                    *acc += *v as f64;
                }
            }
            if y >= r {
                let remove = &src[(y - r) * w..(y - r + 1) * w];
                for (acc, v) in columns.iter_mut().zip(remove) {
                    *acc -= *v as f64;
                }
            }
        }
    }
}

/// `out[x] = Σ values[x − r ..= x + r]` (clipped), in three branch-free stretches.
fn running_sum(values: &[f64], r: usize, out: &mut [f32]) {
    let w = values.len();
    let mut running: f64 = values[..(r + 1).min(w)].iter().sum();
    // x + r + 1 < w and x < r: the window only grows.
    let grow_end = r.min(w.saturating_sub(r + 1));
    for x in 0..grow_end {
        out[x] = running as f32;
        running += values[x + r + 1];
    }
    if w > 2 * r + 1 {
        // Full windows: one value enters, one leaves.
        for x in grow_end..w - r - 1 {
            out[x] = running as f32;
            running += values[x + r + 1] - values[x - r];
        }
        for x in w - r - 1..w {
            out[x] = running as f32;
            running -= values[x - r];
        }
    } else {
        for x in grow_end..w {
            out[x] = running as f32;
            if x + r + 1 < w {
                running += values[x + r + 1];
            }
            if x >= r {
                running -= values[x - r];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An image over `data` without the constructor's checks (bad sizes are under test).
    fn img(data: &[f32], width: usize, height: usize, channels: usize) -> Image<f32> {
        Image {
            width,
            height,
            channels,
            data: data.to_vec(),
        }
    }

    fn brute_box_sum(src: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
        let mut out = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0f64;
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        s += src[yy * w + xx] as f64;
                    }
                }
                out[y * w + x] = s as f32;
            }
        }
        out
    }

    #[test]
    fn running_box_sums_match_brute_force_at_every_radius() {
        let (w, h) = (13, 7);
        let src: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32 - 3.5).collect();
        for r in [0, 1, 3, 6, 20] {
            let mut boxes = BoxSum::new(w, h, r);
            let mut dst = vec![0.0; w * h];
            boxes.sum(&src, &mut dst);
            let expected = brute_box_sum(&src, w, h, r);
            for (a, b) in dst.iter().zip(&expected) {
                assert!((a - b).abs() < 1e-4, "radius {r}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn an_input_affine_in_the_guide_passes_unchanged() {
        // q = aᵀI + b exactly: every window's fit recovers it (up to the ridge ε).
        let (w, h, g, bands) = (24, 16, 3, 2);
        let guide: Vec<f32> = (0..w * h * g)
            .map(|i| 0.2 + 0.6 * (((i * 7919) % 101) as f32 / 101.0))
            .collect();
        let input: Vec<f32> = (0..w * h)
            .flat_map(|i| {
                let p = &guide[i * g..(i + 1) * g];
                [
                    0.5 * p[0] - 0.2 * p[1] + 0.1 * p[2] + 0.05,
                    0.3 * p[1] + 0.4 * p[2] - 0.02,
                ]
            })
            .collect();
        let filter = GuidedFilter {
            radius: 3,
            epsilon: 1e-8,
        };
        let output = guided_filter(
            &img(&guide, w, h, g),
            &img(&input, w, h, bands),
            None,
            filter,
        )
        .unwrap();
        for (a, b) in output.iter().zip(&input) {
            assert!((a - b).abs() < 1e-4, "{a} vs {b}");
        }
    }

    #[test]
    fn noise_on_a_flat_patch_is_averaged_and_edges_of_the_guide_survive() {
        // Two regions split by a guide edge; the input is the region's value plus
        // alternating noise. The output keeps the step and removes most of the noise.
        let (w, h) = (40, 20);
        let guide: Vec<f32> = (0..w * h)
            .map(|i| if i % w < w / 2 { 0.2 } else { 0.8 })
            .collect();
        let truth = |i: usize| if i % w < w / 2 { 0.1f32 } else { 0.6 };
        let input: Vec<f32> = (0..w * h)
            .map(|i| truth(i) + if (i + i / w) % 2 == 0 { 0.05 } else { -0.05 })
            .collect();
        let filter = GuidedFilter {
            radius: 2,
            epsilon: 1e-4,
        };
        let output =
            guided_filter(&img(&guide, w, h, 1), &img(&input, w, h, 1), None, filter).unwrap();
        let rms = |v: &[f32]| {
            let s: f32 = v
                .iter()
                .enumerate()
                .map(|(i, x)| (x - truth(i)).powi(2))
                .sum();
            (s / v.len() as f32).sqrt()
        };
        assert!((rms(&input) - 0.05).abs() < 1e-6);
        assert!(rms(&output) < 0.005, "rms {}", rms(&output));
    }

    #[test]
    fn invalid_pixels_keep_their_value_and_stay_out_of_the_fits() {
        let (w, h) = (10, 10);
        let guide = vec![0.5f32; w * h];
        let mut input = vec![0.3f32; w * h];
        input[11] = f32::NAN;
        input[55] = 100.0;
        let mut guide_with_gap = guide.clone();
        guide_with_gap[55] = f32::NAN; // a saturated guide pixel: its input is not used
        let filter = GuidedFilter {
            radius: 2,
            epsilon: 1e-4,
        };
        let output = guided_filter(
            &img(&guide_with_gap, w, h, 1),
            &img(&input, w, h, 1),
            None,
            filter,
        )
        .unwrap();
        assert!(output[11].is_nan());
        assert_eq!(output[55], 100.0);
        for (i, v) in output.iter().enumerate() {
            if i != 11 && i != 55 {
                assert!((v - 0.3).abs() < 1e-5, "pixel {i}: {v}");
            }
        }
    }

    #[test]
    fn pixels_without_any_trusted_neighbour_keep_their_value() {
        // A block weighing (almost) nothing: its windows have no fit, so it is left alone
        // instead of being set to zero; the rest is filtered as usual.
        let (w, h) = (12, 12);
        let guide: Vec<f32> = (0..w * h).map(|i| 0.1 + 0.05 * (i % 7) as f32).collect();
        let input: Vec<f32> = (0..w * h).map(|i| 0.4 + 0.01 * (i % 5) as f32).collect();
        let weights: Vec<f32> = (0..w * h)
            .map(|i| if i % w < 6 { 1e-6 } else { 1.0 })
            .collect();
        let filter = GuidedFilter {
            radius: 1,
            epsilon: 1e-4,
        };
        let output = guided_filter(
            &img(&guide, w, h, 1),
            &img(&input, w, h, 1),
            Some(&weights),
            filter,
        )
        .unwrap();
        for y in 0..h {
            for x in 0..4 {
                assert_eq!(output[y * w + x], input[y * w + x], "({x}, {y})");
            }
            for x in 4..w {
                let v = output[y * w + x];
                assert!(v > 0.3 && v < 0.55, "({x}, {y}): {v}");
            }
        }
        let negative = vec![-1.0f32; w * h];
        assert_eq!(
            guided_filter(
                &img(&guide, w, h, 1),
                &img(&input, w, h, 1),
                Some(&negative),
                filter
            )
            .err()
            .map(|e| e.kind()),
            Some("Raster")
        );
    }

    #[test]
    fn bad_settings_and_sizes_are_refused() {
        let filter = GuidedFilter {
            radius: 1,
            epsilon: 1e-4,
        };
        assert_eq!(
            guided_filter(
                &img(&[0.0; 4], 2, 2, 1),
                &img(&[0.0; 3], 2, 2, 1),
                None,
                filter
            )
            .err()
            .map(|e| e.kind()),
            Some("Shape")
        );
        assert_eq!(
            guided_filter(
                &img(&[0.0; 20], 2, 2, 5),
                &img(&[0.0; 4], 2, 2, 1),
                None,
                filter
            )
            .err()
            .map(|e| e.kind()),
            Some("Raster")
        );
        let zero = GuidedFilter {
            epsilon: 0.0,
            ..filter
        };
        assert_eq!(
            guided_filter(
                &img(&[0.0; 4], 2, 2, 1),
                &img(&[0.0; 4], 2, 2, 1),
                None,
                zero
            )
            .err()
            .map(|e| e.kind()),
            Some("OutOfRange")
        );
    }
}
