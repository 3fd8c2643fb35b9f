//! Temporal reuse: what one frame of a sequence hands to the next, and whether the next
//! may use it.
//!
//! A camera array filming a scene sees mostly the same surfaces from frame to frame, so a
//! frame can start from what the previous one learned:
//!
//! - **the search range**, estimated once (at the first frame and after every cut) and
//!   then narrowed to the disparities the previous frame's maps hold, widened by a margin
//!   for motion ([`FrameCarry::narrowed`]). A frame whose maps pile up at a narrowed end
//!   (a surface came closer than the margin allows) registers again over the whole range
//!   ([`at_narrowed_ends`]);
//! - **each view's scene prior** (its mixture of the scene's spectra): the materials stay
//!   while objects move, so the mixture is carried and only its estimate runs, unless it
//!   finds clearly more of the view's pixels implausible than in the frame it was learned
//!   in (a new material), when it is learned again
//!   ([`crate::solve::CarriedPrior`]);
//! - **the spectra of every pixel whose scene has not changed** (`view_reuse.rs`): only
//!   the others go through the per-pixel stages of the solve, and the guided filter runs
//!   again only near them. Each camera keeps a reference capture for this, the capture as
//!   the kept spectra saw it.
//!
//! A **cut** (another scene, a jump of the array) makes all of it unsound. Each camera's
//! image is compared with the previous frame's by the correlation of their means over
//! blocks of [`BLOCK`] pixels (block means average the sensor noise away, demosaicked or
//! not, and a correlation ignores a change of exposure); a camera whose correlation falls
//! below [`CUT_CORRELATION`] makes the frame a cut, reconstructed from nothing, as a
//! single frame is. Motion within a scene keeps the correlation high (the moving
//! tabletop's frames correlate above 0.9), and the narrowed range's own check and the
//! carried priors' own check catch what it lets through.
//!
//! In: the previous frame's [`FrameCarry`], this frame's grey images. Out: a [`Reuse`]
//! decision and, after the frame, its own carry; [`ReuseReport`] records what was reused.

use super::view_reuse::{dilated, moved_pixels, CameraChanges, CarriedView, WARP_REACH};
use crate::disparity::{DisparityMap, DisparityRange};
use crate::image::GreyImage;
use crate::image::Image;
use crate::register::{BandedSearch, PreviousMaps};
use serde::Serialize;

/// Side of the square blocks whose means the cut detection correlates, pixels.
pub const BLOCK: usize = 8;
/// A frame in which some camera's block means correlate with the previous frame's less
/// than this is a cut.
pub const CUT_CORRELATION: f64 = 0.5;
/// The narrowed range reaches this fraction of the whole range's width (at least
/// [`MIN_MARGIN`] px) beyond the previous frame's disparities, for motion in depth.
pub const MARGIN_FRACTION: f64 = 0.1;
/// The least margin of a narrowed range, px.
pub const MIN_MARGIN: i32 = 3;
/// The share of the previous frame's disparities left out of a narrowed range at each end:
/// mismatches, which pile at the whole range's ends (0.2 % of the pixels of the moving
/// tabletop's first frame at 160×120 sit at disparity 0, its nearest true one being 5.3;
/// at 0.2 % they held the range open).
pub const OUTLIER_QUANTILE: f64 = 0.005;
/// A frame registers again over the whole range when more than this fraction of some
/// view's pixels lie within half a pixel of a narrowed end.
pub const AT_END_FRACTION: f64 = 0.01;

/// What a frame hands to the next (see the module docs). Opaque: made by
/// [`super::reconstruct_next`], handed back to it with the next frame.
#[derive(Debug, Clone)]
pub struct FrameCarry {
    pub(super) greys: Vec<GreyImage>,
    /// Per camera, its calibrated capture as the kept spectra saw it (pixel by pixel,
    /// the frame each pixel last moved in).
    pub(super) references: Vec<Image<f32>>,
    pub(super) maps: Vec<DisparityMap>,
    /// The whole range of the sequence (estimated or given); None: given disparities.
    pub(super) range: Option<DisparityRange>,
    /// Per camera (rig order): what its view's solve handed on, when the view was
    /// reconstructed.
    pub(super) views: Vec<Option<CarriedView>>,
}

/// What a frame may take from the previous one.
#[derive(Debug, Clone, Copy)]
pub(super) struct Reuse<'a> {
    pub carry: &'a FrameCarry,
}

/// What a frame reused, for the manifest.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReuseReport {
    /// The frame was compared with a previous one (false: the first frame of a run).
    pub previous: bool,
    /// The frame is a cut (or its captures' shape changed): nothing was reused.
    pub cut: bool,
    /// The least correlation of a camera's block means with the previous frame's (None:
    /// no previous frame, or another shape).
    pub correlation: Option<f64>,
    /// The range searched when it was narrowed from the previous frame's maps.
    pub narrowed_range: Option<DisparityRange>,
    /// The narrowed range missed surfaces, and the frame registered again over the
    /// whole range.
    pub range_fallback: bool,
    /// Views whose solve used the previous frame's scene prior.
    pub priors_carried: usize,
    /// Views whose scene prior was learned in this frame.
    pub priors_learned: usize,
    /// Pixels (summed over views) whose measurements had not changed and kept the
    /// previous frame's spectra (the guided filter ran on every pixel).
    pub reused_pixels: usize,
    /// How registration's tiles searched around the previous frame's maps (None: over the
    /// whole range, as a single frame does).
    pub banded: Option<BandedSearch>,
}

impl ReuseReport {
    /// The report of a frame that reused nothing.
    pub(super) fn fresh(previous: bool, cut: bool, correlation: Option<f64>) -> Self {
        ReuseReport {
            previous,
            cut,
            correlation,
            narrowed_range: None,
            range_fallback: false,
            priors_carried: 0,
            priors_learned: 0,
            reused_pixels: 0,
            banded: None,
        }
    }
}

impl FrameCarry {
    /// Compares this frame's grey images with the carried ones: the decision and the
    /// least correlation of a camera's block means (None: another shape).
    pub(super) fn judge<'a>(&'a self, greys: &[GreyImage]) -> (Option<Reuse<'a>>, Option<f64>) {
        let same_shape = greys.len() == self.greys.len()
            && greys
                .iter()
                .zip(&self.greys)
                .all(|(a, b)| (a.width, a.height, a.channels) == (b.width, b.height, b.channels));
        if !same_shape {
            return (None, None);
        }
        let correlation = greys
            .iter()
            .zip(&self.greys)
            .map(|(now, before)| block_correlation(before, now))
            .fold(1.0, f64::min);
        let reuse = (correlation >= CUT_CORRELATION).then_some(Reuse { carry: self });
        (reuse, Some(correlation))
    }

    /// Where each camera's capture `now` moved against the carried references (dilated
    /// by the warp's reach; None when the shapes differ), and the references for the next
    /// frame: `now` where it moved, the carried ones elsewhere.
    pub(super) fn camera_changes(
        &self,
        now: &[&Image<f32>],
    ) -> (Option<CameraChanges>, Vec<Image<f32>>) {
        let same = now.len() == self.references.len()
            && now
                .iter()
                .zip(&self.references)
                .all(|(a, b)| (a.width, a.height, a.channels) == (b.width, b.height, b.channels));
        if !same || now.is_empty() {
            return (None, now.iter().map(|&i| i.clone()).collect());
        }
        let (w, h) = (now[0].width, now[0].height);
        let mut references = Vec::with_capacity(now.len());
        let mut moved = Vec::with_capacity(now.len());
        for (&image, reference) in now.iter().zip(&self.references) {
            let here = moved_pixels(reference, image);
            let mut next = reference.clone();
            let c = image.channels;
            for (px, _) in here.iter().enumerate().filter(|(_, &m)| m) {
                next.data[px * c..(px + 1) * c].copy_from_slice(&image.data[px * c..(px + 1) * c]);
            }
            references.push(next);
            moved.push(dilated(&here, w, h, WARP_REACH));
        }
        let changes = CameraChanges {
            width: w,
            height: h,
            moved,
        };
        (Some(changes), references)
    }

    /// The range a frame after this one searches: the carried maps' disparities (less
    /// [`OUTLIER_QUANTILE`] at each end) widened by the motion margin, within `whole`.
    /// None when the maps hold too few disparities to narrow by, or the narrowed range
    /// would not be narrower.
    pub(super) fn narrowed(&self, whole: DisparityRange) -> Option<DisparityRange> {
        let mut values: Vec<f32> = self
            .maps
            .iter()
            .flat_map(|m| m.data.iter().copied())
            .filter(|d| d.is_finite())
            .collect();
        let pixels: usize = self.maps.iter().map(|m| m.data.len()).sum();
        // Fewer than half the pixels registered: the maps say too little.
        if values.is_empty() || values.len() * 2 < pixels {
            return None;
        }
        let low_at = ((values.len() - 1) as f64 * OUTLIER_QUANTILE) as usize;
        let high_at = ((values.len() - 1) as f64 * (1.0 - OUTLIER_QUANTILE)) as usize;
        let low = *values.select_nth_unstable_by(low_at, f32::total_cmp).1;
        let high = *values.select_nth_unstable_by(high_at, f32::total_cmp).1;
        let margin = motion_margin(whole);
        let min = (low.floor() as i32 - margin).max(whole.min);
        let max = (high.ceil() as i32 + margin + 1).min(whole.max);
        let narrowed = DisparityRange::new(min, max).ok()?;
        (narrowed.count() < whole.count()).then_some(narrowed)
    }
}

/// How far beyond the previous frame's disparities a frame searches (for motion in
/// depth): [`MARGIN_FRACTION`] of the whole range's width, at least [`MIN_MARGIN`] px.
pub(super) fn motion_margin(whole: DisparityRange) -> i32 {
    let width = (whole.max - whole.min) as f64;
    ((width * MARGIN_FRACTION).ceil() as i32).max(MIN_MARGIN)
}

/// The previous frame's maps that registration searches around, each tile over the
/// disparities near it ± the [`motion_margin`] ([`PreviousMaps`]), with where each camera
/// saw something move (`changes`).
pub(super) fn previous_maps<'a>(
    carry: &'a FrameCarry,
    changes: Option<&'a CameraChanges>,
    whole: DisparityRange,
) -> PreviousMaps<'a> {
    PreviousMaps {
        maps: &carry.maps,
        moved: changes.map(|c| c.moved.as_slice()),
        margin: motion_margin(whole) as f32,
    }
}

/// Whether maps registered over `narrowed` (within `whole`) pile up at one of its ends
/// that is not an end of `whole`: more than [`AT_END_FRACTION`] of some view's pixels
/// within half a pixel of it.
pub(super) fn at_narrowed_ends(
    maps: &[DisparityMap],
    narrowed: DisparityRange,
    whole: DisparityRange,
) -> bool {
    maps.iter().any(|map| {
        let at_end = narrowed.count_at_inner_ends(whole, map.data.iter().copied());
        at_end as f64 > AT_END_FRACTION * map.data.len() as f64
    })
}

/// The means of `image` over [`BLOCK`]-pixel blocks (whole blocks only), ignoring
/// values that are not finite.
fn block_means(image: &GreyImage) -> Vec<f64> {
    let (w, h) = (image.width, image.height);
    let mut means = Vec::with_capacity((w / BLOCK) * (h / BLOCK));
    for by in 0..h / BLOCK {
        for bx in 0..w / BLOCK {
            let (mut sum, mut n) = (0.0, 0usize);
            for y in by * BLOCK..(by + 1) * BLOCK {
                for &v in &image.data[y * w + bx * BLOCK..y * w + (bx + 1) * BLOCK] {
                    if v.is_finite() {
                        sum += v as f64;
                        n += 1;
                    }
                }
            }
            means.push(if n > 0 { sum / n as f64 } else { 0.0 });
        }
    }
    means
}

/// The Pearson correlation of the block means of two images of one size: 1 for the same
/// view up to noise and exposure, near 0 for another scene. Images too small for two
/// blocks, or constant, correlate 1 with themselves and 0 with anything else.
pub fn block_correlation(before: &GreyImage, now: &GreyImage) -> f64 {
    let (a, b) = (block_means(before), block_means(now));
    let n = a.len().min(b.len());
    if n < 2 {
        return if before.data == now.data { 1.0 } else { 0.0 };
    }
    let (ma, mb) = (
        a.iter().sum::<f64>() / n as f64,
        b.iter().sum::<f64>() / n as f64,
    );
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(&b) {
        ab += (x - ma) * (y - mb);
        aa += (x - ma) * (x - ma);
        bb += (y - mb) * (y - mb);
    }
    if aa > 0.0 && bb > 0.0 {
        ab / (aa * bb).sqrt()
    } else if aa == bb {
        1.0
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A textured image plus Gaussian-ish noise of standard deviation `sigma`.
    fn textured(w: usize, h: usize, shift: usize, sigma: f32, seed: u64) -> GreyImage {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w + shift) as f32, (i / w) as f32);
                let texture = 0.5 + 0.3 * (x * 0.37).sin() * (y * 0.23).cos();
                // The sum of 12 uniforms less 6: unit variance.
                let noise: f32 = (0..12).map(|_| rng.random::<f32>()).sum::<f32>() - 6.0;
                texture + sigma * noise
            })
            .collect();
        GreyImage::new(w, h, 1, data).unwrap()
    }

    #[test]
    fn noise_and_exposure_keep_the_correlation_and_another_scene_breaks_it() {
        let before = textured(160, 120, 0, 0.02, 1);
        let again = textured(160, 120, 0, 0.02, 2);
        assert!(block_correlation(&before, &again) > 0.95);
        let mut brighter = again.clone();
        brighter.data.iter_mut().for_each(|v| *v = 1.7 * *v + 0.05);
        assert!(block_correlation(&before, &brighter) > 0.95);
        // Another scene: the texture's phase moved by about half its period everywhere.
        let other = textured(160, 120, 9, 0.02, 2);
        assert!(block_correlation(&before, &other) < CUT_CORRELATION);
    }

    #[test]
    fn a_moving_patch_is_no_cut() {
        let before = textured(160, 128, 0, 0.02, 1);
        let mut now = textured(160, 128, 0, 0.02, 2);
        for y in 32..64 {
            for x in 64..96 {
                now.data[y * 160 + x] = 0.9;
            }
        }
        let correlation = block_correlation(&before, &now);
        assert!(correlation > 0.7, "{correlation}");
    }

    fn map(values: Vec<f32>) -> DisparityMap {
        let n = values.len();
        DisparityMap::new(
            n,
            1,
            crate::disparity::DisparityConvention::ColumnStep,
            values,
        )
        .unwrap()
    }

    fn carry(maps: Vec<DisparityMap>) -> FrameCarry {
        FrameCarry {
            greys: Vec::new(),
            references: Vec::new(),
            maps,
            range: None,
            views: Vec::new(),
        }
    }

    #[test]
    fn the_narrowed_range_holds_the_maps_and_the_margin() {
        let whole = DisparityRange::new(-10, 90).unwrap();
        let values: Vec<f32> = (0..1000).map(|i| 20.0 + 20.0 * i as f32 / 999.0).collect();
        let narrowed = carry(vec![map(values.clone())]).narrowed(whole).unwrap();
        // 20..=40 widened by a tenth of 100 px either side.
        assert_eq!(narrowed, DisparityRange::new(10, 51).unwrap());
        // Mismatches stuck at the whole range's end (0.3 %) do not hold it open.
        let mut stuck = values.clone();
        stuck[..3].fill(-10.0);
        let narrowed = carry(vec![map(stuck)]).narrowed(whole).unwrap();
        assert_eq!(narrowed.min, 10);
        // Mostly unregistered maps say too little.
        let sparse: Vec<f32> = (0..100)
            .map(|i| if i < 30 { 5.0 } else { f32::NAN })
            .collect();
        assert_eq!(carry(vec![map(sparse)]).narrowed(whole), None);
        // Maps spanning the whole range cannot narrow it.
        let wide: Vec<f32> = (0..1000).map(|i| -10.0 + 99.0 * i as f32 / 999.0).collect();
        assert_eq!(carry(vec![map(wide)]).narrowed(whole), None);
    }

    #[test]
    fn maps_piling_at_a_narrowed_end_ask_for_the_whole_range() {
        let whole = DisparityRange::new(0, 60).unwrap();
        let narrowed = DisparityRange::new(10, 40).unwrap();
        let inside: Vec<f32> = (0..1000).map(|i| 12.0 + (i % 20) as f32).collect();
        assert!(!at_narrowed_ends(&[map(inside.clone())], narrowed, whole));
        let mut clipped = inside;
        clipped[..50].fill(39.0);
        assert!(at_narrowed_ends(&[map(clipped.clone())], narrowed, whole));
        // The whole range's own end is no reason to widen.
        assert!(!at_narrowed_ends(
            &[map(clipped)],
            DisparityRange::new(10, 40).unwrap(),
            DisparityRange::new(10, 40).unwrap()
        ));
    }

    #[test]
    fn maps_that_miss_the_surfaces_widen_the_range_again() {
        use crate::reconstruct::{reconstruct_next, ArrayCaptures, PipelineSettings};
        use crate::rig::{Rig, PAPER_RIG_FILTERS};
        use crate::scene::{Scene, SceneFile};
        use crate::simulate::{Simulation, SimulationSettings};
        use crate::stereo::{MatchingCost, MatchingNetwork};
        let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
        file.focal_length_px = Some(450.0);
        let rig = Rig::from_file(file, ".".into()).unwrap();
        let scene = Scene::resolve(
            SceneFile::preset("tabletop").unwrap(),
            std::path::Path::new("."),
        )
        .unwrap();
        let settings = SimulationSettings {
            width: 160,
            height: 120,
            ..SimulationSettings::default()
        };
        let simulation = Simulation::run(&rig, &scene, settings).unwrap();
        let captures = ArrayCaptures::from_simulation(&simulation);
        let network = MatchingNetwork::default_fast().unwrap();
        let pipeline = PipelineSettings::new(MatchingCost::Learned(&network));
        let (first, mut carry) =
            reconstruct_next(&rig, &captures, &pipeline, &|_, _, _| {}, None).unwrap();
        // As if every surface had been 2 px away: the narrowed range misses them.
        for map in &mut carry.maps {
            map.data.fill(2.0);
        }
        let (second, _) =
            reconstruct_next(&rig, &captures, &pipeline, &|_, _, _| {}, Some(&carry)).unwrap();
        let report = second.reuse.unwrap();
        let whole = first.search_range.unwrap().range;
        assert!(report.narrowed_range.unwrap().max < whole.max, "{report:?}");
        assert!(report.range_fallback, "{report:?}");
        // Registered again over the whole range: the same maps as the first frame's.
        let bits = |m: &DisparityMap| m.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for (a, b) in second.views.iter().zip(&first.views) {
            assert!(bits(&a.disparity) == bits(&b.disparity), "view {}", a.name);
        }
    }
}
