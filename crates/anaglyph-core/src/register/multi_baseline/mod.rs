//! Multi-baseline registration: one disparity per pixel of a reference view, tested
//! against every other view of the array at once.
//!
//! Each view's features come from its matching images: its common signals (merged into one
//! feature per pixel by a [`FeatureProjection`] fitted on the first view), or its grey image.
//!
//! For disparity d, pixel (x, y) of the reference is compared with the learned features of
//! view v at `(x, y) + d · shift(v)` (the array geometry, [`ArrayGeometry::shift`], along
//! each pair's own baseline); a fractional row position interpolates the two dot
//! products, which is exact for the bilinearly interpolated feature, and a fractional
//! column is rounded (the subpixel stage interpolates both). The cost of view v is `(1 − cos)/2`, as for a pair.
//! Views are grouped into half-arrays (left of, right of, above, below the reference; a
//! diagonal view belongs to two); the cost
//! of (x, y, d) is the smallest mean over a half-array that sees the point, so that a
//! surface occluded on one side is still matched on the other (Kang, Szeliski & Chai 2001,
//! "Handling occlusions in dense multi-view stereo"). Then SGM with penalties from the
//! reference's gradients and winner-take-all per view. The subpixel offset comes from the
//! raw multi-view costs at whole and half-pixel steps around the winner (the latter with
//! interpolated, renormalised features), summed over a window of the same surface, by an
//! equiangular fit ([`crate::stereo::windowed_subpixel`] on a half-pixel grid: the
//! parabola on SGM costs locks to whole pixels); finally each map is checked against its
//! neighbours' maps ([`ArrayGeometry::neighbours`]; a pixel is kept if at least one
//! neighbour agrees within [`crate::stereo::LEFT_RIGHT_TOLERANCE`]), each failure takes
//! whichever of its nearest valid neighbours left, right, above and below has the lowest
//! multi-view cost at the pixel ([`fill_by_cost`]), a 5×5 median smooths the result, and
//! regions of repetitive texture, whose costs have several equal minima, take the plane
//! most of their disparities lie on, unless most of the view's neighbours find another ([`region_planes`], [`vote_with_neighbours`], [`apply_region_planes`]).
//!
//! ```text
//! matching images -> features   the network's features, common signals merged      mod.rs
//!   -> cost        occlusion-robust multi-view cost volume per view              cost.rs
//!   -> SGM         penalties from the view's gradients, winner-take-all
//!   -> subpixel    half-step costs, equiangular fit                              cost.rs
//!   -> cross-check against the neighbours' maps                      super::agreement
//!   -> fill        by cost, from the nearest valid neighbours        super::fill_by_cost
//!   -> median      5×5, then smoothing within surfaces
//!   -> planes      RANSAC planes through ambiguous regions    super::ambiguous_planes
//!   -> vote        the neighbours' maps vote on each region's plane
//! ```
//!
//! Large views go coarse to fine ([`coarse_to_fine`], from [`COARSE_TO_FINE_PIXELS`] by
//! default): the chain above at half the resolution over half the range, then at full
//! resolution tile by tile over a band around the upsampled coarse disparities, with the
//! same subpixel fit and filters after it (docs/reconstruction.md, "Coarse to fine").
//!
//! In: every view's image (and matching images), the array geometry, the settings.
//! Out: a disparity map per view, per-stage timings and the pixels moved to planes.

mod cost;

use super::compact_features::{to_bf16, CompactFeatures};
use super::feature_projection::{normalise_features, FeatureProjection};
use super::{
    apply_region_planes, confirmed_by_neighbours, fill_by_cost, region_planes,
    smooth_within_surfaces, vote_with_neighbours, Ambiguity, ArrayGeometry, BandedSearch,
    CoarseToFine, PreviousMaps, RegionPlane, Registration, RegistrationSettings, ViewImage,
    SUBPIXEL_WINDOW_RADIUS,
};
use crate::disparity::{DisparityConvention, DisparityMap};
use crate::stereo::{
    median_filter, semi_global_matching, tower_features, tower_features_mapped, unit_range,
    winner_take_all, CostVolume, DisparityRange, FeatureMap, GreyImage, MatchSettings,
    MatchingCost, MatchingNetwork,
};
use crate::{Error, Result};
use cost::{half_step_subpixel, needed_half_steps, whole_steps, PointCosts};
use rayon::prelude::*;
use std::ops::Range;
use std::time::Instant;

/// Multi-baseline registration of every view (see the module docs), stage by stage;
/// coarse to fine ([`coarse_to_fine`]) as `settings.coarse_to_fine` says.
pub fn multi_baseline_disparities(
    images: &[ViewImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Registration> {
    let network = fast_network(settings)?;
    let (w, h) = (images[0].image.width, images[0].image.height);
    let coarse_to_fine_here = settings.coarse_to_fine.applies(w, h);
    // The coarse level needs room for the tower's receptive field and two disparities.
    let large = coarse_to_fine_here && w >= 2 * MIN_COARSE_SIDE && h >= 2 * MIN_COARSE_SIDE;
    if let Some(previous) = &settings.previous {
        return around_previous(
            network,
            images,
            geometry,
            settings,
            (previous, large),
            progress,
        );
    }
    if large {
        return coarse_to_fine(network, images, geometry, settings, progress);
    }
    let mut timings = Vec::new();
    let clock = Instant::now();
    let features = view_features(network, images, usize::MAX, None)?;
    let costs = PointCosts::new(&features, geometry);
    timings.push(("features".to_string(), clock.elapsed().as_secs_f64()));
    let matched = match_views(images, &costs, settings, &mut timings, progress)?;
    finish(matched, &costs, settings.range, timings)
}

/// Matching images (the leading common signals) the fine level of one-channel cameras
/// compares by (their matching images are one image up to sign; cameras of several
/// channels take [`REUSED_SIGNALS`]): the coarse level, with all of them, has told apart
/// the materials that look alike in one, and the fine level only searches a band around
/// its disparities.
const FINE_SIGNALS: usize = 1;

/// Dimensions the fine level's features are projected onto (a [`FeatureProjection`]
/// fitted on the first view): a quarter of the memory and dot products of the network's
/// 64. On the 3×3 narrow-band array at 1600×1200 (tabletop), 32 kept 98.7 % of the
/// features' energy and 16 kept 91 %; the bad-1 was 6.77 % with 64 and 32 and 6.80 %
/// with 16, the registered stacks' PSNR 44.10 dB with all three, and the peak 3.6, 2.4
/// and 1.9 GB.
const FINE_DIMS: usize = 16;

/// Matching images the fine level of coarse to fine and a reused frame's small views
/// compare by where the cameras have several channels (the leading common signals;
/// one-channel cameras' are one image up to sign, and a reused frame's large views take
/// [`FINE_SIGNALS`]). On the paper's rig at 320×240 (tabletop-moving, frames 1 to 7) a
/// reused frame took 2.86 s with two, 3.01 s with all three and 2.48 s with one, and its
/// reference view scored 0.14 to 0.23 dB above the frame alone with two, 0.09 to 0.19 dB
/// with three, and up to 0.23 dB below it with one (docs/sequence.md). Coarse to fine at
/// 1600×1200 on the same rig (tabletop): registered stacks at 44.83 dB with two against
/// 44.60 dB with one (the full search 44.79), in 83.3 instead of 76.4 s at the same peak
/// (docs/reconstruction.md).
const REUSED_SIGNALS: usize = 2;

/// Views of at least this many pixels are registered coarse to fine by default
/// ([`CoarseToFine::Auto`]): a 1600×1200 view (1.9 Mpx), not an 800×600 one.
pub const COARSE_TO_FINE_PIXELS: usize = 1_000_000;

/// Least side of a coarse level, in pixels.
const MIN_COARSE_SIDE: usize = 32;

/// Side of the square tiles the fine level searches, each over its own band of
/// disparities.
const TILE: usize = 128;
/// Pixels each tile's volume and SGM reach beyond the tile on every side, so that SGM's
/// paths do not start at the tile's edge.
const TILE_MARGIN: usize = 16;
/// Full-resolution pixels of disparity a tile's band reaches beyond the least and the
/// greatest upsampled coarse disparity over it (a coarse pixel off by one is two here).
const BAND_MARGIN: f32 = 3.0;
/// Fraction of a tile's coarse disparities that no neighbouring view confirms above
/// which the tile searches the whole range.
const UNSURE_FRACTION: f64 = 0.25;

/// Coarse-to-fine registration: every view registered at half the resolution over half
/// the range (the whole pipeline, itself coarse to fine while the views stay large),
/// then at full resolution tile by tile, each tile's cost volume and SGM over a band
/// around the upsampled coarse disparities under it (the whole range where the coarse
/// maps of the neighbouring views do not confirm them), then the same subpixel fit and
/// filters as one level. The volumes and SGM cost pixels × the bands instead of pixels ×
/// the range.
fn coarse_to_fine(
    network: &MatchingNetwork,
    images: &[ViewImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Registration> {
    let coarse_images: Vec<ViewImage> = images.iter().map(|v| v.downsampled(2, true)).collect();
    let coarse_settings = RegistrationSettings {
        range: settings.range.scaled(0.5),
        coarse_to_fine: CoarseToFine::Auto,
        previous: None,
        ..*settings
    };
    let coarse =
        multi_baseline_disparities(&coarse_images, geometry, &coarse_settings, &|_, _| {})?;
    drop(coarse_images);
    let mut timings: Vec<(String, f64)> = coarse
        .timings
        .iter()
        .map(|(name, seconds)| (format!("coarse: {name}"), *seconds))
        .collect();
    let clock = Instant::now();
    let signals = match images.iter().all(matching_up_to_sign) {
        true => FINE_SIGNALS,
        false => REUSED_SIGNALS,
    };
    let features = view_features(network, images, signals, Some(FINE_DIMS))?;
    let costs = PointCosts::new(&features, geometry);
    timings.push(("features".to_string(), clock.elapsed().as_secs_f64()));
    let guides = BandGuide::of_coarse(coarse.disparities, geometry);
    let (matched, banded) =
        match_views_in_bands(images, &costs, settings, &guides, &mut timings, progress)?;
    let mut registration = finish(matched, &costs, settings.range, timings)?;
    registration.banded = Some(banded);
    Ok(registration)
}

/// Registration of a frame of a sequence around the previous frame's maps, as the fine
/// level of coarse to fine registers around the coarse maps: features of [`FINE_DIMS`]
/// dimensions (of every matching image where the views are small and their images differ,
/// else of the leading one), then every view tile by tile over a band
/// around its previous disparities ([`BandGuide::band`]; the whole range where they were
/// unsure, or where the winners pile up at an end of the band), then the subpixel fit and
/// filters of one level. The coarse level is not needed: the previous frame's maps guide
/// instead.
fn around_previous(
    network: &MatchingNetwork,
    images: &[ViewImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
    (previous, large): (&PreviousMaps<'_>, bool),
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Registration> {
    let size = (images[0].image.width, images[0].image.height);
    // A large view's tiles are small against its surfaces: SGM's short paths in a tile
    // need the pull where the view has no texture, as at the fine level of coarse to
    // fine (on the 3×3 array at 1600×1200 a reused frame's bad-1 was 23.7 % without it,
    // 5.7 % with it). A small view's tiles span most of it, and the pull cost up to 0.14
    // dB a frame there (the 3×3 array at 320×240; docs/sequence.md).
    let guides = BandGuide::of_previous(previous, geometry, size, large)?;
    let mut timings = Vec::new();
    let clock = Instant::now();
    // The band, around surfaces the previous frame told apart, leaves the features little
    // to tell apart: with the fine level's dimensions a reused frame at 320×240 took 2.58
    // instead of 3.66 s on the 3×3 array and 3.25 instead of 3.97 s on the paper's rig
    // (medians of the first 8 frames), up to 0.2 dB below the full features' and never
    // 0.3 dB below the frame alone (docs/sequence.md). Where the views are small and
    // their matching images differ (cameras of several channels) the leading two are
    // kept ([`REUSED_SIGNALS`]).
    let signals = match large || images.iter().all(matching_up_to_sign) {
        true => FINE_SIGNALS,
        false => REUSED_SIGNALS,
    };
    let features = view_features(network, images, signals, Some(FINE_DIMS))?;
    let costs = PointCosts::new(&features, geometry);
    timings.push(("features".to_string(), clock.elapsed().as_secs_f64()));
    let (matched, banded) =
        match_views_in_bands(images, &costs, settings, &guides, &mut timings, progress)?;
    let mut registration = finish(matched, &costs, settings.range, timings)?;
    registration.banded = Some(banded);
    Ok(registration)
}

/// Whether a view's matching images are all its first one up to sign, as a one-channel
/// camera's are ([`super::common_signal_images`]): the others change only the sign of
/// some of its comparisons.
fn matching_up_to_sign(view: &ViewImage) -> bool {
    let Some((first, others)) = view.matching.split_first() else {
        return true;
    };
    others
        .iter()
        .all(|other| (other.data.iter().zip(&first.data)).all(|(&a, &b)| a == b || a == -b))
}

/// What the tiles of a banded search search around: a view's coarse map (coarse to fine)
/// or its map in the previous frame (a frame of a sequence), and which of the map's
/// pixels a neighbouring view's map confirms.
struct BandGuide<'a> {
    map: DisparityMap,
    confirmed: Vec<bool>,
    /// Full-resolution pixels per pixel of `map` (2 for a coarse map, 1 for a previous
    /// frame's).
    scale: usize,
    kind: GuideKind<'a>,
}

enum GuideKind<'a> {
    /// The same frame's map at half the resolution.
    Coarse,
    /// The previous frame's map at full resolution, with the band's margin for motion in
    /// depth and, where the costs are pulled towards it, the pixels of the view's camera
    /// that moved since (None: no pull).
    Previous {
        margin: f32,
        pulled: Option<&'a [bool]>,
    },
}

impl<'a> BandGuide<'a> {
    /// Every view's guide from its coarse map (`coarse`, in view order).
    fn of_coarse(coarse: Vec<DisparityMap>, geometry: &ArrayGeometry) -> Vec<Self> {
        let confirmed = confirmed_pixels(&coarse, geometry);
        coarse
            .into_iter()
            .zip(confirmed)
            .map(|(map, confirmed)| BandGuide {
                map,
                confirmed,
                scale: 2,
                kind: GuideKind::Coarse,
            })
            .collect()
    }

    /// Every view's guide from the previous frame's maps, checked against the views'
    /// size; with `pull`, the costs are pulled towards them where the view's camera saw
    /// nothing move.
    fn of_previous(
        previous: &PreviousMaps<'a>,
        geometry: &ArrayGeometry,
        (w, h): (usize, usize),
        pull: bool,
    ) -> Result<Vec<Self>> {
        let maps = previous.maps;
        if maps.len() != geometry.len() {
            return Err(Error::Shape {
                op: "registration around the previous frame's maps: one map per view".into(),
                got: vec![maps.len()],
                expected: vec![geometry.len()],
            });
        }
        for map in maps {
            map.check(w, h, DisparityConvention::ColumnStep)?;
        }
        if let Some(moved) = previous.moved {
            if moved.len() != maps.len() || moved.iter().any(|m| m.len() != w * h) {
                return Err(Error::Shape {
                    op: "registration around the previous frame's maps: moved pixels".into(),
                    got: vec![moved.len(), moved.first().map_or(0, Vec::len)],
                    expected: vec![maps.len(), w * h],
                });
            }
        }
        let confirmed = confirmed_pixels(maps, geometry);
        Ok(maps
            .iter()
            .zip(confirmed)
            .enumerate()
            .map(|(i, (map, confirmed))| BandGuide {
                map: map.clone(),
                confirmed,
                scale: 1,
                kind: GuideKind::Previous {
                    margin: previous.margin,
                    pulled: match (pull, previous.moved) {
                        (true, Some(moved)) => Some(moved[i].as_slice()),
                        _ => None,
                    },
                },
            })
            .collect())
    }

    /// The guide's pixel under full-resolution pixel (x, y) (the last row or column of a
    /// coarse map for a remainder the box average dropped). The coarse level is never
    /// empty ([`MIN_COARSE_SIDE`]).
    fn guide_pixel(&self, x: usize, y: usize) -> (usize, usize) {
        let (cw, ch) = (self.map.width, self.map.height);
        ((x / self.scale).min(cw - 1), (y / self.scale).min(ch - 1))
    }

    /// The disparities the tile searches over the full-resolution window `columns` ×
    /// `rows`, within `whole` ([`BandGuide::coarse_band`], [`BandGuide::previous_band`]).
    fn band(
        &self,
        columns: &Range<usize>,
        rows: &Range<usize>,
        whole: DisparityRange,
    ) -> DisparityRange {
        match self.kind {
            GuideKind::Coarse => self.coarse_band(columns, rows, whole),
            GuideKind::Previous { margin, .. } => self.previous_band(columns, rows, whole, margin),
        }
    }

    /// The upsampled coarse disparities under the window ± [`BAND_MARGIN`], or all of
    /// `whole` where the coarse map is unknown or unsure there.
    fn coarse_band(
        &self,
        columns: &Range<usize>,
        rows: &Range<usize>,
        whole: DisparityRange,
    ) -> DisparityRange {
        let cw = self.map.width;
        let (x0, y0) = self.guide_pixel(columns.start, rows.start);
        let (x1, y1) = self.guide_pixel(columns.end - 1, rows.end - 1);
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let (mut unsure, mut total) = (0usize, 0usize);
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                let i = cy * cw + cx;
                let d = self.scale as f32 * self.map.data[i];
                if !d.is_finite() {
                    return whole;
                }
                (lo, hi) = (lo.min(d), hi.max(d));
                unsure += usize::from(!self.confirmed[i]);
                total += 1;
            }
        }
        if unsure as f64 > UNSURE_FRACTION * total as f64 {
            return whole;
        }
        widened(lo, hi, BAND_MARGIN, whole)
    }

    /// The previous frame's confirmed disparities within [`MOTION_REACH`] of the window
    /// ± `margin` (its unsure ones are left out: a mismatch would hold the band open), or
    /// all of `whole` where too many are unsure or unknown.
    fn previous_band(
        &self,
        columns: &Range<usize>,
        rows: &Range<usize>,
        whole: DisparityRange,
        margin: f32,
    ) -> DisparityRange {
        let (w, h) = (self.map.width, self.map.height);
        let xs = columns.start.saturating_sub(MOTION_REACH)..(columns.end + MOTION_REACH).min(w);
        let ys = rows.start.saturating_sub(MOTION_REACH)..(rows.end + MOTION_REACH).min(h);
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut unsure = 0usize;
        for y in ys.clone() {
            for x in xs.clone() {
                let i = y * w + x;
                let d = self.map.data[i];
                if d.is_finite() && self.confirmed[i] {
                    (lo, hi) = (lo.min(d), hi.max(d));
                } else {
                    unsure += 1;
                }
            }
        }
        if unsure as f64 > UNSURE_FRACTION * (xs.len() * ys.len()) as f64 || lo > hi {
            return whole;
        }
        widened(lo, hi, margin, whole)
    }

    /// The guide's disparity (full-resolution pixels) that pixel (x, y)'s costs are
    /// pulled towards: a coarse guide's where it is known, a previous frame's where it is
    /// pulled and the view's camera saw nothing move.
    fn pull_target(&self, x: usize, y: usize) -> Option<f32> {
        if let GuideKind::Previous { pulled, .. } = self.kind {
            match pulled {
                Some(moved) if !moved[y * self.map.width + x] => {}
                _ => return None,
            }
        }
        let (cx, cy) = self.guide_pixel(x, y);
        let g = self.scale as f32 * self.map.data[cy * self.map.width + cx];
        g.is_finite().then_some(g)
    }

    /// Whether the guide pulls any costs ([`BandGuide::pull_target`]); a tile's volume is
    /// not copied when it does not.
    fn pulls(&self) -> bool {
        !matches!(self.kind, GuideKind::Previous { pulled: None, .. })
    }

    /// Whether a tile whose winners pile up at an end of its band searches again over the
    /// whole range: around a previous frame's maps, a surface may have come closer or gone
    /// farther than the margin allows (the coarse level has seen this frame's surfaces).
    fn searches_again_at_ends(&self) -> bool {
        matches!(self.kind, GuideKind::Previous { .. })
    }

    /// `volume` (of the window `columns` × `rows`) with a cost added to each disparity
    /// more than [`PULL_FREE`] from the guide's ([`BandGuide::pull_target`]): [`PULL`]
    /// per pixel, at most [`PULL_CAP`]. Where the view has no texture its costs are flat
    /// and SGM's short paths in a tile would settle anywhere in the band; the guide,
    /// whose paths crossed the whole image, decides there instead.
    fn pulled_towards(
        &self,
        volume: &CostVolume,
        columns: &Range<usize>,
        rows: &Range<usize>,
    ) -> CostVolume {
        let n = volume.count();
        let mut pulled = volume.clone();
        for (t, costs) in pulled.data.chunks_exact_mut(n.max(1)).enumerate() {
            let (x, y) = (
                columns.start + t % volume.width,
                rows.start + t / volume.width,
            );
            let Some(g) = self.pull_target(x, y) else {
                continue;
            };
            for (k, cost) in costs.iter_mut().enumerate() {
                let off = (volume.range.at(k) - g).abs() - PULL_FREE;
                if off > 0.0 {
                    *cost += (PULL * off).min(PULL_CAP);
                }
            }
        }
        pulled
    }
}

/// `lo..=hi` widened by `margin` to whole disparities, within `whole`.
fn widened(lo: f32, hi: f32, margin: f32, whole: DisparityRange) -> DisparityRange {
    let min = ((lo - margin).floor() as i32).max(whole.min);
    let max = ((hi + margin).ceil() as i32 + 1).min(whole.max);
    DisparityRange::new(min, max).unwrap_or(whole)
}

/// Per view, which pixels of its map a neighbouring view's map confirms.
fn confirmed_pixels(maps: &[DisparityMap], geometry: &ArrayGeometry) -> Vec<Vec<bool>> {
    (0..maps.len())
        .map(|i| {
            let checked = confirmed_by_neighbours(maps, geometry, i);
            checked.data.iter().map(|d| d.is_finite()).collect()
        })
        .collect()
}

/// Pixels around a tile whose previous disparities its band covers: what moves into the
/// tile within a frame (lateral motion).
const MOTION_REACH: usize = 16;
/// A tile searched around a previous frame's map whose winners lie at an end of its band
/// (one not at the whole range's end) in more than this fraction of its pixels is
/// searched again over the whole range.
const AT_BAND_END_FRACTION: f64 = 0.01;

/// Disparities within this many pixels of the upsampled coarse one cost nothing extra
/// ([`BandGuide::pulled_towards`]).
const PULL_FREE: f32 = 1.5;
/// Cost added per pixel of disparity beyond [`PULL_FREE`].
const PULL: f32 = 0.02;
/// Most cost added.
const PULL_CAP: f32 = 0.2;

/// The stages after matching, alike at one level and at the fine level: each view's map
/// checked, filled and smoothed, then its ambiguous regions moved to their planes.
fn finish(
    matched: MatchedViews,
    costs: &PointCosts<'_>,
    range: DisparityRange,
    mut timings: Vec<(String, f64)>,
) -> Result<Registration> {
    let clock = Instant::now();
    let smoothed: Vec<Vec<f32>> = (0..matched.raw.len())
        .map(|i| checked_filled_smoothed(&matched.raw, costs, i))
        .collect();
    drop(matched.raw);
    let planes = planes_by_vote(&smoothed, &matched.ambiguities, costs, range);
    timings.push((
        "cross-check, fill, median, planes".to_string(),
        clock.elapsed().as_secs_f64(),
    ));
    let (w, h) = costs.size();
    let (maps, moved): (Vec<Vec<f32>>, Vec<usize>) = planes.into_iter().unzip();
    let disparities = maps
        .into_iter()
        .map(|map| DisparityMap::new(w, h, DisparityConvention::ColumnStep, map))
        .collect::<Result<_>>()?;
    Ok(Registration {
        disparities,
        timings,
        moved_to_planes: Some(moved),
        banded: None,
    })
}

/// The network whose features every view shares: multi-baseline registration compares
/// features across views, which the fast network's cosine allows.
fn fast_network<'a>(settings: &RegistrationSettings<'a>) -> Result<&'a MatchingNetwork> {
    match settings.cost {
        MatchingCost::Learned(network) if !network.is_accurate() => Ok(network),
        other => Err(Error::setting(
            "multi-baseline registration",
            format!(
                "the {} cost (use pairwise registration for it)",
                other.name()
            ),
            "the fast learned cost, whose features compare across views",
        )),
    }
}

/// Every view's raw subpixel map and the ambiguity of its costs.
struct MatchedViews {
    raw: Vec<DisparityMap>,
    ambiguities: Vec<Ambiguity>,
}

/// Per view: the multi-view cost volume, SGM with winner-take-all, and the subpixel
/// offset from the half-step costs.
fn match_views(
    images: &[ViewImage],
    costs: &PointCosts<'_>,
    settings: &RegistrationSettings<'_>,
    timings: &mut Vec<(String, f64)>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<MatchedViews> {
    let chain = MatchSettings::for_cost(&settings.cost, settings.range);
    let (mut cost_seconds, mut refine_seconds) = (0.0, 0.0);
    let mut matched = MatchedViews {
        raw: Vec::with_capacity(images.len()),
        ambiguities: Vec::with_capacity(images.len()),
    };
    for (i, view) in images.iter().enumerate() {
        let clock = Instant::now();
        let volume = costs.volume(i, settings.range);
        cost_seconds += clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        matched.ambiguities.push(Ambiguity::of_volume(&volume));
        let disparity = winners(&volume, &chain, || Ok(unit_range(&view.image)))?;
        let whole = whole_steps(&volume, &disparity);
        drop(volume);
        matched.raw.push(subpixel_map(costs, i, &whole, &disparity));
        refine_seconds += clock.elapsed().as_secs_f64();
        progress(i + 1, images.len());
    }
    timings.push(("multi-view cost".to_string(), cost_seconds));
    timings.push(("SGM + subpixel".to_string(), refine_seconds));
    Ok(matched)
}

/// [`match_views`] at the fine level of [`coarse_to_fine`]: each view tile by tile, each
/// tile's cost volume, SGM and winner-take-all over its band ([`BandGuide::band`]) in a
/// window [`TILE_MARGIN`] wider, then the half-step subpixel fit over the whole view.
fn match_views_in_bands(
    images: &[ViewImage],
    costs: &PointCosts<'_>,
    settings: &RegistrationSettings<'_>,
    guides: &[BandGuide<'_>],
    timings: &mut Vec<(String, f64)>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(MatchedViews, BandedSearch)> {
    let (w, h) = costs.size();
    let chain = MatchSettings::for_cost(&settings.cost, settings.range);
    let tiles: Vec<(Range<usize>, Range<usize>)> = (0..h.div_ceil(TILE))
        .flat_map(|ty| {
            (0..w.div_ceil(TILE)).map(move |tx| {
                (
                    tx * TILE..((tx + 1) * TILE).min(w),
                    ty * TILE..((ty + 1) * TILE).min(h),
                )
            })
        })
        .collect();
    let widen = |r: &Range<usize>, n: usize| {
        r.start.saturating_sub(TILE_MARGIN)..(r.end + TILE_MARGIN).min(n)
    };
    let (mut band_seconds, mut refine_seconds) = (0.0, 0.0);
    let (mut searched, mut fallbacks) = (0usize, 0usize);
    let mut matched = MatchedViews {
        raw: Vec::with_capacity(images.len()),
        ambiguities: Vec::with_capacity(images.len()),
    };
    for (i, view) in images.iter().enumerate() {
        let clock = Instant::now();
        let guide_image = unit_range(&view.image);
        let mut disparity = vec![0f32; w * h];
        let mut whole = vec![[f32::NAN; 5]; w * h];
        let mut ambiguity = Ambiguity {
            width: w,
            height: h,
            ambiguous: vec![false; w * h],
            median_cost: vec![f32::NAN; w * h],
        };
        let guide = &guides[i];
        let results: Vec<TileResult> = tiles
            .par_iter()
            .map(|(columns, rows)| -> Result<TileResult> {
                let (wc, wr) = (widen(columns, w), widen(rows, h));
                let search = |band: DisparityRange| -> Result<TileResult> {
                    let volume = costs.window_volume(i, (wc.clone(), wr.clone()), band);
                    let pulled = guide
                        .pulls()
                        .then(|| guide.pulled_towards(&volume, &wc, &wr));
                    let tile_disparity =
                        winners(pulled.as_ref().unwrap_or(&volume), &chain, || {
                            guide_image.crop(wc.clone(), wr.clone())
                        })?;
                    Ok(TileResult {
                        window: (wc.clone(), wr.clone()),
                        band,
                        whole: whole_steps(&volume, &tile_disparity),
                        ambiguity: Ambiguity::of_volume(&volume),
                        disparity: tile_disparity,
                    })
                };
                let tile = search(guide.band(&wc, &wr, settings.range))?;
                match guide.searches_again_at_ends()
                    && tile.piles_at_band_ends((columns, rows), settings.range)
                {
                    true => search(settings.range),
                    false => Ok(tile),
                }
            })
            .collect::<Result<_>>()?;
        for ((columns, rows), tile) in tiles.iter().zip(results) {
            let (wc, wr) = &tile.window;
            let tw = wc.len();
            searched += tile.band.count();
            fallbacks += usize::from(tile.band == settings.range);
            for y in rows.clone() {
                for x in columns.clone() {
                    let (p, t) = (y * w + x, (y - wr.start) * tw + x - wc.start);
                    disparity[p] = tile.disparity[t];
                    whole[p] = tile.whole[t];
                    ambiguity.ambiguous[p] = tile.ambiguity.ambiguous[t];
                    ambiguity.median_cost[p] = tile.ambiguity.median_cost[t];
                }
            }
        }
        band_seconds += clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        matched.raw.push(subpixel_map(costs, i, &whole, &disparity));
        matched.ambiguities.push(ambiguity);
        refine_seconds += clock.elapsed().as_secs_f64();
        progress(i + 1, images.len());
    }
    let count = tiles.len() * images.len();
    let banded = BandedSearch {
        tiles: count,
        whole_range: fallbacks,
        mean_band: searched as f64 / count.max(1) as f64,
    };
    tracing::info!(
        "banded search: {:.1} disparities per tile on average (of {}), {fallbacks} of {count} tiles over the whole range",
        banded.mean_band,
        settings.range.count()
    );
    timings.push(("multi-view cost + SGM in bands".to_string(), band_seconds));
    timings.push(("subpixel".to_string(), refine_seconds));
    Ok((matched, banded))
}

/// Winner-take-all over `volume` after SGM where the chain has it, its penalties from the
/// gradients of `guide()` (the view's image over the volume's window, in [0, 1]).
fn winners(
    volume: &CostVolume,
    chain: &MatchSettings,
    guide: impl FnOnce() -> Result<GreyImage>,
) -> Result<Vec<f32>> {
    Ok(match &chain.sgm {
        Some(p) => {
            let guide = guide()?;
            let flat = GreyImage::filled(guide.width, guide.height, 1, 0.0);
            winner_take_all(&semi_global_matching(volume, &guide, &flat, p))
        }
        None => winner_take_all(volume),
    })
}

/// View `i`'s raw subpixel map from its whole disparities and their costs at whole steps
/// ([`whole_steps`]): the half-step costs and their fit.
fn subpixel_map(
    costs: &PointCosts<'_>,
    i: usize,
    whole: &[[f32; 5]],
    disparity: &[f32],
) -> DisparityMap {
    let size = costs.size();
    let needed = needed_half_steps(size, disparity, SUBPIXEL_WINDOW_RADIUS);
    let half = costs.half_steps(i, disparity, &needed);
    DisparityMap {
        width: size.0,
        height: size.1,
        convention: DisparityConvention::ColumnStep,
        data: half_step_subpixel(size, whole, &half, disparity, SUBPIXEL_WINDOW_RADIUS),
    }
}

/// What one tile of [`match_views_in_bands`] found, over its window.
struct TileResult {
    window: (Range<usize>, Range<usize>),
    band: DisparityRange,
    disparity: Vec<f32>,
    whole: Vec<[f32; 5]>,
    ambiguity: Ambiguity,
}

impl TileResult {
    /// Whether more than [`AT_BAND_END_FRACTION`] of the tile's own pixels (`columns` ×
    /// `rows`, within the window) won at an end of the band that is not an end of `whole`
    /// ([`DisparityRange::count_at_inner_ends`]).
    fn piles_at_band_ends(
        &self,
        (columns, rows): (&Range<usize>, &Range<usize>),
        whole: DisparityRange,
    ) -> bool {
        let (wc, wr) = &self.window;
        let own = rows.clone().flat_map(|y| {
            let row = (y - wr.start) * wc.len();
            columns
                .clone()
                .map(move |x| self.disparity[row + x - wc.start])
        });
        let at_ends = self.band.count_at_inner_ends(whole, own);
        at_ends as f64 > AT_BAND_END_FRACTION * (columns.len() * rows.len()) as f64
    }
}

/// View `i`'s raw map checked against its neighbours', the failures filled
/// by cost from their nearest valid neighbours, then a 5×5 median and smoothing within
/// surfaces.
fn checked_filled_smoothed(raw: &[DisparityMap], costs: &PointCosts<'_>, i: usize) -> Vec<f32> {
    let (w, h) = costs.size();
    let mut checked = confirmed_by_neighbours(raw, costs.geometry, i).data;
    fill_by_cost(&mut checked, w, h, &costs.at(i));
    smooth_within_surfaces(&median_filter(&checked, w, h, 2), w, h)
}

/// Each view's ambiguous regions moved to their planes, after the vote of its
/// neighbours' maps on their own planes; with the pixels moved per view.
fn planes_by_vote(
    smoothed: &[Vec<f32>],
    ambiguities: &[Ambiguity],
    costs: &PointCosts<'_>,
    range: DisparityRange,
) -> Vec<(Vec<f32>, usize)> {
    let regions: Vec<Vec<RegionPlane>> = smoothed
        .iter()
        .zip(ambiguities)
        .map(|(map, ambiguity)| region_planes(map, ambiguity))
        .collect();
    let on_planes = |i: usize, regions: &[RegionPlane]| {
        let mut planar = smoothed[i].clone();
        let moved = apply_region_planes(&mut planar, &ambiguities[i], range, regions, &costs.at(i));
        (planar, moved)
    };
    let on_own_planes: Vec<(Vec<f32>, usize)> = regions
        .iter()
        .enumerate()
        .map(|(i, regions)| on_planes(i, regions))
        .collect();
    // Every view's vote first (it reads the neighbours' maps on their own planes), then
    // each map on its own planes is kept where the vote changed nothing.
    let voted: Vec<(Vec<RegionPlane>, usize)> = regions
        .into_iter()
        .enumerate()
        .map(|(i, mut regions)| {
            let changed = vote_of_neighbours(&mut regions, &smoothed[i], &on_own_planes, costs, i);
            (regions, changed)
        })
        .collect();
    voted
        .into_iter()
        .zip(on_own_planes)
        .enumerate()
        .map(|(i, ((regions, changed), own))| {
            let (planar, moved) = if changed == 0 {
                own
            } else {
                on_planes(i, &regions)
            };
            tracing::info!(
                "view {}: {} ambiguous regions ({changed} of them changed by the \
                 neighbours' vote), {moved} pixels moved to their planes",
                costs.geometry.names[i],
                regions.len()
            );
            (planar, moved)
        })
        .collect()
}

/// Puts view `i`'s region planes to the vote of its neighbours' maps
/// (each on its own planes); returns how many regions changed.
fn vote_of_neighbours(
    regions: &mut [RegionPlane],
    map: &[f32],
    on_own_planes: &[(Vec<f32>, usize)],
    costs: &PointCosts<'_>,
    i: usize,
) -> usize {
    let (w, h) = costs.size();
    let geometry = costs.geometry;
    let voters: Vec<(&[f32], (f64, f64))> = geometry
        .neighbours(i)
        .into_iter()
        .map(|j| (on_own_planes[j].0.as_slice(), geometry.shift(j, i)))
        .collect();
    vote_with_neighbours(regions, map, w, h, &voters)
}

/// The images a view's features come from: its first `signals` matching images if it has
/// any, else its grey image.
fn matching_images(view: &ViewImage, signals: usize) -> Vec<&GreyImage> {
    if view.matching.is_empty() {
        vec![&view.image]
    } else {
        view.matching.iter().take(signals).collect()
    }
}

/// The network's features of each of `images`, computed once for images that are equal
/// (a monochrome camera's common-signal images differ only in sign,
/// [`super::common_signal_images`]).
fn distinct_features(network: &MatchingNetwork, images: &[&GreyImage]) -> Vec<FeatureMap> {
    let mut maps: Vec<FeatureMap> = Vec::with_capacity(images.len());
    for (k, image) in images.iter().enumerate() {
        let map = match images[..k]
            .iter()
            .position(|earlier| earlier.data == image.data)
        {
            Some(j) => maps[j].clone(),
            None => tower_features(network, image),
        };
        maps.push(map);
    }
    maps
}

/// Every view's compact features: the network's features of its first `signals` matching
/// images, merged by a [`FeatureProjection`] fitted on the first view when there are
/// several or `dims` asks for fewer dimensions than the network's; pixels a view did not
/// measure get a zero feature (a neutral cost of 0.5).
fn view_features(
    network: &MatchingNetwork,
    images: &[ViewImage],
    signals: usize,
    dims: Option<usize>,
) -> Result<Vec<CompactFeatures>> {
    let matching_images = |view| matching_images(view, signals);
    // The first view's maps fit the projection and are then merged themselves, not
    // computed again (a ninth of the network's work for three signals).
    let projected =
        matching_images(&images[0]).len() > 1 || dims.is_some_and(|d| d < network.feature_maps());
    let large = |v: &ViewImage| v.image.width * v.image.height >= COARSE_TO_FINE_PIXELS;
    let (projection, mut first_maps) = if projected {
        let first = matching_images(&images[0]);
        // Several images of a large view: fitted on the view's central quarter, so that
        // no whole view's maps of them are held (the first view is then projected as the
        // others are).
        let whole = first.len() == 1 || !large(&images[0]);
        let maps = match whole {
            true => distinct_features(network, &first),
            false => {
                let (w, h) = (images[0].image.width, images[0].image.height);
                let crops = first
                    .iter()
                    .map(|image| image.crop(w / 4..w - w / 4, h / 4..h - h / 4))
                    .collect::<Result<Vec<_>>>()?;
                distinct_features(network, &crops.iter().collect::<Vec<_>>())
            }
        };
        let dims = dims.unwrap_or(maps[0].channels);
        let fitted = FeatureProjection::fit(&maps, dims)?;
        tracing::info!(
            "feature projection keeps {:.4} of the energy",
            fitted.energy_kept
        );
        (Some(fitted), whole.then_some(maps))
    } else {
        (None, None)
    };
    images
        .iter()
        .map(|v| -> Result<CompactFeatures> {
            let mut compact = match (&projection, first_maps.take()) {
                (Some(p), Some(maps)) => CompactFeatures::from(p.merged_maps(maps)?),
                // One image: projected strip by strip, no whole map held.
                (Some(p), None) if p.images() == 1 => {
                    let dims = p.dims();
                    tower_features_mapped(network, matching_images(v)[0], dims, |f, out| {
                        let mut projected = vec![0f32; out.len()];
                        p.project_one(f, &mut projected);
                        for (o, &v) in out.iter_mut().zip(&projected) {
                            *o = to_bf16(v);
                        }
                    })
                }
                // Several images of a large view: each projected strip by strip and summed,
                // no whole 64-channel map held (two images' at 1600×1200 are 980 MB).
                (Some(p), None) if large(v) => {
                    let images = matching_images(v);
                    let project = |j: usize| {
                        tower_features_mapped(network, images[j], p.dims(), |f, out| {
                            p.project_image(j, f, out)
                        })
                    };
                    let mut sum = project(0);
                    for j in 1..images.len() {
                        let part = project(j);
                        sum.data
                            .par_iter_mut()
                            .zip(&part.data)
                            .for_each(|(s, &x)| *s += x);
                    }
                    normalise_features(&mut sum);
                    CompactFeatures::from(sum)
                }
                (Some(p), None) => CompactFeatures::from(
                    p.merged_maps(distinct_features(network, &matching_images(v)))?,
                ),
                (None, _) => CompactFeatures::from(tower_features(network, matching_images(v)[0])),
            };
            if let Some(measured) = &v.measured {
                let c = compact.channels;
                for (feature, _) in compact
                    .data
                    .chunks_exact_mut(c)
                    .zip(measured)
                    .filter(|(_, m)| !**m)
                {
                    feature.fill(0); // cosine 0 with everything: a neutral cost of 0.5
                }
            }
            Ok(compact)
        })
        .collect()
}
