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
//! In: every view's image (and matching images), the array geometry, the settings.
//! Out: a disparity map per view, per-stage timings and the pixels moved to planes.

mod cost;

use super::compact_features::CompactFeatures;
use super::feature_projection::FeatureProjection;
use super::{
    apply_region_planes, confirmed_by_neighbours, fill_by_cost, region_planes,
    smooth_within_surfaces, vote_with_neighbours, Ambiguity, ArrayGeometry, RegionPlane,
    Registration, RegistrationSettings, ViewImage, SUBPIXEL_WINDOW_RADIUS,
};
use crate::disparity::{DisparityConvention, DisparityMap};
use crate::stereo::{
    median_filter, semi_global_matching, tower_features, unit_range, winner_take_all,
    DisparityRange, FeatureMap, GreyImage, MatchSettings, MatchingCost, MatchingNetwork,
};
use crate::{Error, Result};
use cost::{half_step_subpixel, PointCosts};
use std::time::Instant;

/// Multi-baseline registration of every view (see the module docs), stage by stage.
pub fn multi_baseline_disparities(
    images: &[ViewImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Registration> {
    let network = fast_network(settings)?;
    let mut timings = Vec::new();

    let clock = Instant::now();
    let features = view_features(network, images)?;
    let costs = PointCosts::new(&features, geometry);
    timings.push(("features".to_string(), clock.elapsed().as_secs_f64()));
    let matched = match_views(images, &costs, settings, &mut timings, progress);
    let clock = Instant::now();
    let smoothed: Vec<Vec<f32>> = (0..images.len())
        .map(|i| checked_filled_smoothed(&matched.raw, &costs, i))
        .collect();
    let planes = planes_by_vote(&smoothed, &matched.ambiguities, &costs, settings.range);
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
) -> MatchedViews {
    let (w, h) = (images[0].image.width, images[0].image.height);
    let chain = MatchSettings::for_cost(&settings.cost, settings.range);
    let flat = GreyImage {
        channels: 1,
        width: w,
        height: h,
        data: vec![0.0; w * h],
    };
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
        let disparity = match &chain.sgm {
            Some(p) => winner_take_all(&semi_global_matching(
                &volume,
                &unit_range(&view.image),
                &flat,
                p,
            )),
            None => winner_take_all(&volume),
        };
        let half = costs.half_steps(i, &disparity);
        matched.raw.push(DisparityMap {
            width: w,
            height: h,
            convention: DisparityConvention::ColumnStep,
            data: half_step_subpixel(&volume, &half, &disparity, SUBPIXEL_WINDOW_RADIUS),
        });
        refine_seconds += clock.elapsed().as_secs_f64();
        progress(i + 1, images.len());
    }
    timings.push(("multi-view cost".to_string(), cost_seconds));
    timings.push(("SGM + subpixel".to_string(), refine_seconds));
    matched
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
    regions
        .into_iter()
        .enumerate()
        .map(|(i, mut regions)| {
            let changed = vote_of_neighbours(&mut regions, &smoothed[i], &on_own_planes, costs, i);
            let (planar, moved) = if changed == 0 {
                on_own_planes[i].clone()
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

/// The images a view's features come from: its matching images if it has any, else its
/// grey image.
fn matching_images(view: &ViewImage) -> Vec<&GreyImage> {
    if view.matching.is_empty() {
        vec![&view.image]
    } else {
        view.matching.iter().collect()
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

/// Every view's compact features: the network's features of its matching images, merged
/// by a [`FeatureProjection`] fitted on the first view when there are several; pixels a
/// view did not measure get a zero feature (a neutral cost of 0.5).
fn view_features(network: &MatchingNetwork, images: &[ViewImage]) -> Result<Vec<CompactFeatures>> {
    // The first view's maps fit the projection and are then merged themselves, not
    // computed again (a ninth of the network's work for three signals).
    let (projection, mut first_maps) = if matching_images(&images[0]).len() > 1 {
        let maps = distinct_features(network, &matching_images(&images[0]));
        let dims = maps[0].channels;
        let fitted = FeatureProjection::fit(&maps, dims)?;
        tracing::info!(
            "feature projection keeps {:.4} of the energy",
            fitted.energy_kept
        );
        (Some(fitted), Some(maps))
    } else {
        (None, None)
    };
    images
        .iter()
        .map(|v| -> Result<CompactFeatures> {
            let map = match (&projection, first_maps.take()) {
                (Some(p), Some(maps)) => p.merged_maps(maps)?,
                (Some(p), None) => {
                    p.merged_maps(distinct_features(network, &matching_images(v)))?
                }
                (None, _) => tower_features(network, matching_images(v)[0]),
            };
            let mut compact = CompactFeatures::from(map);
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
