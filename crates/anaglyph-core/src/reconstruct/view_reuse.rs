//! Temporal reuse within a view: the pixels whose gathered measurements have not changed
//! since the previous frame keep that frame's spectra, and only the others go through the
//! per-pixel stages of the solve; the spatial stage (the guided filter) then runs on the
//! whole view, as it does for a single frame.
//!
//! A pixel is **unchanged** when the same rows measure it, the same cameras are disputed,
//! its disparity is within [`DISPARITY_TOLERANCE`] of the one its kept spectra came with,
//! and either
//! - its measurements are within noise of those its spectra came from (the per-pixel
//!   stages' result at a pixel is a function of its measurements and the view's
//!   statistics, [`crate::solve::ViewStatistics`], carried too), or
//! - no camera that measures it saw its content move there ([`CameraChanges`]: the
//!   camera's own capture, unwarped, against the reference it keeps): its 3-D point and
//!   every camera's view of it are the same. This catches the static textured surfaces
//!   the first test misses: a subpixel change of the disparity moves the interpolated
//!   samples of a texture by far more than noise.
//!
//! In: a view's gathered measurements and disputed flags, the previous frame's
//! [`CarriedView`]. Out: which pixels to solve; after the solve, the next [`CarriedView`].

use crate::image::Image;
use crate::solve::{CarriedPrior, ViewStatistics};

/// An unchanged pixel's disparity differs from its reference by at most this, px.
pub const DISPARITY_TOLERANCE: f32 = 1.0;
/// A camera's pixel moved when the mean square of its capture's difference from its
/// reference, over its channels and 3×3 neighbours, exceeds this many times the
/// difference's noise variance σ² (noise alone: a mean of 9 to 27 squared standard
/// normals, above 4 in under 0.01 % of pixels) ...
pub const MOVED_VARIANCE_FACTOR: f32 = 4.0;
/// ... σ estimated from this quantile of the camera's absolute differences (for noise
/// alone, |N(0, σ)| has its 10th percentile at 0.1257 σ), which sensor noise decides as
/// long as a few tenths of a filmed scene stay still ...
pub const NOISE_QUANTILE: f64 = 0.1;
/// (the [`NOISE_QUANTILE`] quantile of |N(0, 1)|: Φ⁻¹(0.55))
const HALF_NORMAL_QUANTILE: f32 = 0.125_661;
/// ... and a difference above this (white-normalised units) is a move whatever σ says:
/// were most of the scene in motion, the quantile would measure motion, not noise.
pub const MOVED_LIMIT: f32 = 0.02;
/// A pixel whose measurements' rms difference from its reference is at most this many
/// times σ has the same input (noise alone exceeds it in 4.6 % of pixels measured by one
/// row, 0.7 % by three, practically never by more).
pub const SAME_NOISE_FACTOR: f32 = 2.0;
/// A view pixel's measurement from a camera reads that camera's capture this far around
/// the sampled position (the Lanczos-3 warp's reach), px.
pub const WARP_REACH: usize = 3;
/// Fewer unchanged pixels than this share of the view: the whole view is solved.
pub const MIN_UNCHANGED_SHARE: f64 = 0.1;

/// Per camera, where its capture moved against the reference it keeps, dilated by
/// [`WARP_REACH`] (what a warp reading near there picks up).
#[derive(Debug, Clone)]
pub struct CameraChanges {
    pub width: usize,
    pub height: usize,
    /// Per camera (rig order), per pixel.
    pub moved: Vec<Vec<bool>>,
}

/// Where `now` moved against `reference` (one camera's captures, all channels), before
/// dilation: see [`MOVED_VARIANCE_FACTOR`].
pub fn moved_pixels(reference: &Image<f32>, now: &Image<f32>) -> Vec<bool> {
    let (w, h, c) = (now.width, now.height, now.channels);
    let squared: Vec<f32> = now
        .data
        .chunks_exact(c)
        .zip(reference.data.chunks_exact(c))
        .map(|(a, b)| {
            let sum: f32 = a
                .iter()
                .zip(b)
                .map(|(x, y)| (x - y) * (x - y))
                .filter(|d| d.is_finite())
                .sum();
            sum / c as f32
        })
        .collect();
    let sigma = difference_sigma(&now.data, &reference.data);
    let limit = (MOVED_VARIANCE_FACTOR * sigma * sigma).min(MOVED_LIMIT * MOVED_LIMIT);
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (mut sum, mut n) = (0.0f32, 0usize);
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    sum += squared[yy * w + xx];
                    n += 1;
                }
            }
            sum / n as f32 > limit
        })
        .collect()
}

/// The standard deviation σ of a static value's difference between `now` and `before`,
/// from the [`NOISE_QUANTILE`] quantile of their nonzero finite absolute differences; 0
/// when they hold none (a noise-free render's still frame).
fn difference_sigma(now: &[f32], before: &[f32]) -> f32 {
    let mut each: Vec<f32> = now
        .iter()
        .zip(before)
        .map(|(a, b)| (a - b).abs())
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    match each.len() {
        0 => 0.0,
        n => {
            let at = ((n - 1) as f64 * NOISE_QUANTILE) as usize;
            *each.select_nth_unstable_by(at, f32::total_cmp).1 / HALF_NORMAL_QUANTILE
        }
    }
}

/// `mask` (w × h) dilated by a square of side 2·`reach` + 1.
pub fn dilated(mask: &[bool], w: usize, h: usize, reach: usize) -> Vec<bool> {
    let mut rows = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let xs = x.saturating_sub(reach)..(x + reach + 1).min(w);
            rows[y * w + x] = mask[y * w + xs.start..y * w + xs.end].iter().any(|&m| m);
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] =
                (y.saturating_sub(reach)..(y + reach + 1).min(h)).any(|yy| rows[yy * w + x]);
        }
    }
    out
}

/// What [`PixelState::unchanged`] reads of this frame's view.
pub(super) struct ViewNow<'a> {
    pub measurements: &'a [f32],
    pub disputed: &'a [bool],
    pub rows: usize,
    /// The view's disparity map now.
    pub disparity: &'a [f32],
    /// Camera k's rows of C.
    pub camera_rows: &'a [std::ops::Range<usize>],
    /// Per camera, the shift per unit disparity from this view.
    pub shifts: &'a [(f64, f64)],
    pub changes: &'a CameraChanges,
}

/// What a view's solve hands to the next frame.
#[derive(Debug, Clone)]
pub struct CarriedView {
    pub(super) prior: Option<CarriedPrior>,
    /// Per pixel, the measurements (`pixels × rows`) and disputed flags its kept spectra
    /// came from; None: the view's solve did not go through the scene prior with a
    /// mixture, so its pixels are not reused.
    pub(super) pixels: Option<PixelState>,
}

/// The per-pixel state of a view's last solve.
#[derive(Debug, Clone)]
pub(super) struct PixelState {
    pub measurements: Vec<f32>,
    pub disputed: Vec<bool>,
    /// The disparities the kept spectra were solved with.
    pub disparity: Vec<f32>,
    /// The spectra (`pixels × knots`) and weights the spatial stages started from.
    pub spectra: Vec<f32>,
    pub weights: Option<Vec<f32>>,
    pub knots: std::ops::Range<usize>,
    pub statistics: ViewStatistics,
    /// The view's output (`pixels × knots`): the spatial stages' on those spectra.
    pub refined: Vec<f32>,
}

impl PixelState {
    /// The pixels of this frame that are unchanged (see the module docs); None when too
    /// few are (or the shapes differ) to be worth a partial solve.
    pub fn unchanged(&self, now: &ViewNow<'_>) -> Option<Vec<bool>> {
        let rows = now.rows;
        let changes = now.changes;
        let (w, h) = (changes.width, changes.height);
        let pixels = w * h;
        if rows == 0
            || now.measurements.len() != pixels * rows
            || self.measurements.len() != pixels * rows
            || now.disputed.len() != self.disputed.len()
            || now.disparity.len() != pixels
            || self.disparity.len() != pixels
            || changes.moved.len() != now.camera_rows.len()
        {
            return None;
        }
        let cameras = now.disputed.len() / pixels;
        let same_measurements = self.same_measurements(now.measurements, rows);
        let unchanged: Vec<bool> = (0..pixels)
            .map(|px| {
                let (d, was) = (now.disparity[px], self.disparity[px]);
                let disparity_held =
                    (d.is_nan() && was.is_nan()) || (d - was).abs() <= DISPARITY_TOLERANCE;
                let measured = &now.measurements[px * rows..(px + 1) * rows];
                let before = &self.measurements[px * rows..(px + 1) * rows];
                let flags = px * cameras..(px + 1) * cameras;
                if !disparity_held
                    || measured
                        .iter()
                        .zip(before)
                        .any(|(a, b)| a.is_finite() != b.is_finite())
                    || now.disputed[flags.clone()] != self.disputed[flags]
                {
                    return false;
                }
                if same_measurements[px] {
                    return true;
                }
                let (x, y) = ((px % w) as f64, (px / w) as f64);
                let d = if d.is_finite() { d as f64 } else { 0.0 };
                // Every camera that measures the pixel, at the position it read.
                now.camera_rows.iter().enumerate().all(|(k, rows_of_k)| {
                    if !measured[rows_of_k.clone()].iter().any(|v| v.is_finite()) {
                        return true;
                    }
                    let (sx, sy) = now.shifts[k];
                    let (cx, cy) = ((x + d * sx).round(), (y + d * sy).round());
                    if cx < 0.0 || cy < 0.0 || cx >= w as f64 || cy >= h as f64 {
                        return false;
                    }
                    !changes.moved[k][cy as usize * w + cx as usize]
                })
            })
            .collect();
        let share = unchanged.iter().filter(|&&u| u).count() as f64 / pixels as f64;
        (share >= MIN_UNCHANGED_SHARE).then_some(unchanged)
    }

    /// Per pixel: every measurement within noise of its reference (rms difference at most
    /// [`SAME_NOISE_FACTOR`] σ, σ from the view's measurement differences as for a
    /// camera's, and at most [`MOVED_LIMIT`]): whatever happened in the scene, the
    /// per-pixel stages would see the same input.
    fn same_measurements(&self, measurements: &[f32], rows: usize) -> Vec<bool> {
        let pixels = measurements.len() / rows;
        let sigma = difference_sigma(measurements, &self.measurements);
        let limit = (SAME_NOISE_FACTOR * sigma).min(MOVED_LIMIT);
        (0..pixels)
            .map(|px| {
                let (mut sum, mut n) = (0.0f32, 0usize);
                for (a, b) in measurements[px * rows..(px + 1) * rows]
                    .iter()
                    .zip(&self.measurements[px * rows..(px + 1) * rows])
                {
                    if a.is_finite() && b.is_finite() {
                        sum += (a - b) * (a - b);
                        n += 1;
                    }
                }
                n > 0 && (sum / n as f32).sqrt() <= limit
            })
            .collect()
    }
}

/// The rows of `values` (`pixels × width`) at the pixels where `keep` is true.
pub(super) fn select<T: Copy>(values: &[T], width: usize, keep: &[bool]) -> Vec<T> {
    if width == 0 {
        return Vec::new();
    }
    values
        .chunks_exact(width)
        .zip(keep)
        .filter(|(_, &k)| k)
        .flat_map(|(row, _)| row.iter().copied())
        .collect()
}

/// Writes `rows` (one per pixel where `at` is true, in order) into `values`.
pub(super) fn scatter<T: Copy>(values: &mut [T], width: usize, at: &[bool], rows: &[T]) {
    if width == 0 {
        return;
    }
    let targets = values.chunks_exact_mut(width).zip(at).filter(|(_, &a)| a);
    for ((target, _), row) in targets.zip(rows.chunks_exact(width)) {
        target.copy_from_slice(row);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn noisy(w: usize, h: usize, sigma: f32, seed: u64) -> Image<f32> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let data = (0..w * h * 3)
            .map(|i| {
                let noise: f32 = (0..12).map(|_| rng.random::<f32>()).sum::<f32>() - 6.0;
                0.3 + 0.3 * ((i / 3 % w) as f32 * 0.4).sin() + sigma * noise
            })
            .collect();
        Image::new(w, h, 3, data).unwrap()
    }

    #[test]
    fn noise_moves_no_pixel_and_a_moving_patch_moves_its_own() {
        let (w, h) = (96, 64);
        let before = noisy(w, h, 0.005, 1);
        let mut now = noisy(w, h, 0.005, 2);
        assert!(moved_pixels(&before, &now).iter().all(|m| !m));
        for y in 10..20 {
            for x in 30..40 {
                now.data[(y * w + x) * 3..(y * w + x) * 3 + 3].fill(0.95);
            }
        }
        let moved = moved_pixels(&before, &now);
        assert!(moved[15 * w + 35] && !moved[40 * w + 70]);
        let count = moved.iter().filter(|&&m| m).count();
        // The 10×10 patch and its 3×3 reach.
        assert!((100..=144).contains(&count), "{count}");
        let wider = dilated(&moved, w, h, WARP_REACH);
        assert!(wider[15 * w + 43] && !wider[15 * w + 47]);
    }

    #[test]
    fn a_pixel_is_unchanged_unless_its_disparity_pattern_or_a_camera_it_reads_moved() {
        // Two cameras, one row each; the second sits a disparity's shift of (1, 0) away.
        let (w, h) = (40, 10);
        let state = PixelState {
            measurements: vec![0.5; w * h * 2],
            disputed: Vec::new(),
            disparity: vec![4.0; w * h],
            spectra: Vec::new(),
            weights: None,
            knots: 0..0,
            statistics: ViewStatistics::default(),
            refined: Vec::new(),
        };
        // Every measurement differs (a texture sampled a subpixel away): the scene decides.
        let mut measurements = vec![0.9; w * h * 2];
        measurements[(5 * w + 2) * 2 + 1] = f32::NAN; // (2, 5) loses the second camera
        let mut disparity = vec![4.0; w * h];
        disparity[5 * w + 3] = 5.5; // (3, 5) jumps by 1.5 px
        let mut moved = vec![vec![false; w * h]; 2];
        moved[1][5 * w + 24] = true; // the second camera moved at (24, 5): (20, 5) reads it
        let changes = CameraChanges {
            width: w,
            height: h,
            moved,
        };
        let now = ViewNow {
            measurements: &measurements,
            disputed: &[],
            rows: 2,
            disparity: &disparity,
            camera_rows: &[0..1, 1..2],
            shifts: &[(0.0, 0.0), (1.0, 0.0)],
            changes: &changes,
        };
        let unchanged = state.unchanged(&now).unwrap();
        let changed: Vec<usize> = (0..w * h).filter(|&p| !unchanged[p]).collect();
        // Pixels near the right edge read the second camera outside its image.
        let inside: Vec<usize> = changed.into_iter().filter(|p| p % w < w - 4).collect();
        assert_eq!(inside, vec![5 * w + 2, 5 * w + 3, 5 * w + 20]);
    }

    #[test]
    fn measurements_within_noise_keep_a_pixel_whatever_the_cameras_saw() {
        let (w, h) = (20, 10);
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut noise = || 0.003 * ((0..12).map(|_| rng.random::<f32>()).sum::<f32>() - 6.0);
        let reference: Vec<f32> = (0..w * h * 2).map(|i| 0.3 + 0.001 * i as f32).collect();
        let state = PixelState {
            measurements: reference.iter().map(|v| v + noise()).collect(),
            disputed: Vec::new(),
            disparity: vec![4.0; w * h],
            spectra: Vec::new(),
            weights: None,
            knots: 0..0,
            statistics: ViewStatistics::default(),
            refined: Vec::new(),
        };
        let mut measurements: Vec<f32> = reference.iter().map(|v| v + noise()).collect();
        measurements[(3 * w + 7) * 2] += 0.2; // (7, 3) sees something else
                                              // The disparity held; the second camera moved everywhere.
        let disparity = vec![4.3; w * h];
        let changes = CameraChanges {
            width: w,
            height: h,
            moved: vec![vec![false; w * h], vec![true; w * h]],
        };
        let now = ViewNow {
            measurements: &measurements,
            disputed: &[],
            rows: 2,
            disparity: &disparity,
            camera_rows: &[0..1, 1..2],
            shifts: &[(0.0, 0.0), (1.0, 0.0)],
            changes: &changes,
        };
        let unchanged = state.unchanged(&now).unwrap();
        assert!(!unchanged[3 * w + 7]);
        let kept = unchanged.iter().filter(|&&u| u).count();
        // Noise over two rows exceeds 2 σ in 1.8 % of pixels.
        assert!(kept >= w * h - 1 - 10, "{kept}");
    }

    #[test]
    fn select_and_scatter_are_inverse() {
        let values: Vec<u32> = (0..12).collect();
        let keep = [true, false, true, false];
        let picked = select(&values, 3, &keep);
        assert_eq!(picked, vec![0, 1, 2, 6, 7, 8]);
        let mut target = vec![0u32; 12];
        scatter(&mut target, 3, &keep, &picked);
        assert_eq!(target, vec![0, 1, 2, 0, 0, 0, 6, 7, 8, 0, 0, 0]);
    }
}
