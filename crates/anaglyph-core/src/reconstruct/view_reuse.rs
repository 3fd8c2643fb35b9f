//! Temporal reuse within a view: the pixels whose gathered measurements have not changed
//! since the previous frame keep that frame's spectra, and only the others go through the
//! per-pixel stages of the solve; the spatial stage (the guided filter) then runs on the
//! whole view, as it does for a single frame.
//!
//! A pixel is **unchanged** when the same rows measure it, the same cameras are disputed,
//! and the rms difference of its measurements from those its kept spectra came from is
//! within [`UNCHANGED_NOISE_FACTOR`] times the standard deviation σ of a static
//! measurement's frame-to-frame difference, and at most [`UNCHANGED_LIMIT`]. σ comes from
//! the [`NOISE_QUANTILE`] quantile of all the view's measurement differences (for noise
//! alone, |N(0, σ)| has its 10th percentile at 0.1257 σ), which sensor noise decides as
//! long as a few tenths of a filmed scene stay still; the limit guards the rest. The per-pixel stages' result at a pixel is a function of its
//! measurements and the view's statistics ([`crate::solve::ViewStatistics`], carried
//! too), so the kept spectra are what a new solve would give up to that noise. Pixels
//! compare with the measurements their spectra came from, not with the previous frame's,
//! so that a slow drift cannot accumulate unnoticed.
//!
//! In: a view's gathered measurements and disputed flags, the previous frame's
//! [`CarriedView`]. Out: which pixels to solve; after the solve, the next [`CarriedView`].

use crate::solve::{CarriedPrior, ViewStatistics};

/// An unchanged pixel's rms difference from its reference is at most this many times σ
/// (noise alone exceeds it in 4.6 % of pixels measured by one row, 0.7 % by three, and
/// practically never by more) ...
pub const UNCHANGED_NOISE_FACTOR: f32 = 2.0;
/// ... σ estimated from this quantile of the view's measurement differences ...
pub const NOISE_QUANTILE: f64 = 0.1;
/// (the [`NOISE_QUANTILE`] quantile of |N(0, 1)|: Φ⁻¹(0.55))
const HALF_NORMAL_QUANTILE: f32 = 0.125_661;
/// ... and by at most this much (rms, white-normalised units): were more of the view in
/// motion than [`NOISE_QUANTILE`] allows for, the quantile would measure motion, not noise.
pub const UNCHANGED_LIMIT: f32 = 0.02;
/// Fewer unchanged pixels than this share of the view: the whole view is solved.
pub const MIN_UNCHANGED_SHARE: f64 = 0.1;

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
    /// The spectra (`pixels × knots`) and weights the spatial stages started from.
    pub spectra: Vec<f32>,
    pub weights: Option<Vec<f32>>,
    pub knots: std::ops::Range<usize>,
    pub statistics: ViewStatistics,
}

impl PixelState {
    /// The pixels of this frame (`measurements`, `disputed` as gathered) that are
    /// unchanged; None when too few are (or the shapes differ) to be worth a partial
    /// solve.
    pub fn unchanged(&self, measurements: &[f32], disputed: &[bool], rows: usize) -> Option<Vec<bool>> {
        if measurements.len() != self.measurements.len()
            || disputed.len() != self.disputed.len()
            || rows == 0
        {
            return None;
        }
        let pixels = measurements.len() / rows;
        let cameras = disputed.len() / pixels.max(1);
        let same_pattern = |px: usize| {
            let (now, then) = (
                &measurements[px * rows..(px + 1) * rows],
                &self.measurements[px * rows..(px + 1) * rows],
            );
            let flags = px * cameras..(px + 1) * cameras;
            now.iter()
                .zip(then)
                .all(|(a, b)| a.is_finite() == b.is_finite())
                && disputed[flags.clone()] == self.disputed[flags]
        };
        // rms difference over the measured rows; infinite where the pattern changed.
        let difference: Vec<f32> = (0..pixels)
            .map(|px| {
                if !same_pattern(px) {
                    return f32::INFINITY;
                }
                let (mut sum, mut n) = (0.0f32, 0usize);
                for (a, b) in measurements[px * rows..(px + 1) * rows]
                    .iter()
                    .zip(&self.measurements[px * rows..(px + 1) * rows])
                    .filter(|(a, _)| a.is_finite())
                {
                    sum += (a - b) * (a - b);
                    n += 1;
                }
                if n == 0 {
                    0.0
                } else {
                    (sum / n as f32).sqrt()
                }
            })
            .collect();
        let mut each: Vec<f32> = (0..pixels)
            .filter(|&px| difference[px].is_finite())
            .flat_map(|px| {
                measurements[px * rows..(px + 1) * rows]
                    .iter()
                    .zip(&self.measurements[px * rows..(px + 1) * rows])
                    .map(|(a, b)| (a - b).abs())
            })
            .filter(|d| d.is_finite() && *d > 0.0)
            .collect();
        // No difference at all (a noise-free render's still frame): σ = 0.
        let sigma = match each.len() {
            0 => 0.0,
            n => {
                let at = ((n - 1) as f64 * NOISE_QUANTILE) as usize;
                *each.select_nth_unstable_by(at, f32::total_cmp).1 / HALF_NORMAL_QUANTILE
            }
        };
        let limit = (UNCHANGED_NOISE_FACTOR * sigma).min(UNCHANGED_LIMIT);
        let unchanged: Vec<bool> = difference.iter().map(|&d| d <= limit).collect();
        let share = unchanged.iter().filter(|&&u| u).count() as f64 / pixels as f64;
        (share >= MIN_UNCHANGED_SHARE).then_some(unchanged)
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

    fn state(measurements: Vec<f32>) -> PixelState {
        PixelState {
            disputed: vec![false; measurements.len() / 3],
            measurements,
            spectra: Vec::new(),
            weights: None,
            knots: 0..0,
            statistics: ViewStatistics::default(),
        }
    }

    #[test]
    fn noise_leaves_pixels_unchanged_and_motion_or_another_pattern_changes_them() {
        let (rows, pixels, sigma) = (3, 2000, 0.004f32);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut noise = || sigma * ((0..12).map(|_| rng.random::<f32>()).sum::<f32>() - 6.0);
        let base: Vec<f32> = (0..pixels * rows).map(|i| 0.2 + 0.5 * ((i * 7919) % 101) as f32 / 101.0).collect();
        let before: Vec<f32> = base.iter().map(|v| v + noise()).collect();
        let mut now: Vec<f32> = base.iter().map(|v| v + noise()).collect();
        // A fifth of the pixels see something else; one loses a row.
        for px in 0..pixels / 5 {
            now[px * rows] += 0.1;
        }
        now[(pixels - 1) * rows + 2] = f32::NAN;
        let disputed = vec![false; pixels];
        let unchanged = state(before).unchanged(&now, &disputed, rows).unwrap();
        assert!(unchanged[..pixels / 5].iter().all(|u| !u));
        assert!(!unchanged[pixels - 1]);
        let kept = unchanged[pixels / 5..pixels - 1].iter().filter(|&&u| u).count();
        // Pure noise over 3 rows exceeds twice σ in 0.7 % of pixels.
        assert!(kept as f64 > 0.97 * (pixels - pixels / 5 - 1) as f64, "{kept}");
        // A disputed flag that changed makes the pixel change.
        let mut flagged = disputed.clone();
        flagged[pixels / 2] = true;
        let unchanged = state(now.clone()).unchanged(&now, &flagged, rows).unwrap();
        assert!(!unchanged[pixels / 2] && unchanged[pixels / 2 + 1]);
        assert_eq!(unchanged.iter().filter(|&&u| !u).count(), 1);
    }

    #[test]
    fn a_view_mostly_in_motion_is_solved_whole() {
        let before = vec![0.5f32; 300];
        let now: Vec<f32> = (0..300).map(|i| 0.5 + 0.2 * (i % 7) as f32).collect();
        assert_eq!(state(before).unchanged(&now, &[false; 100], 3), None);
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
