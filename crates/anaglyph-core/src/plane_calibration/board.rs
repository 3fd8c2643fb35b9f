//! Finding a checkerboard's inner corners in one camera's capture: the `calib-targets`
//! ChESS detector finds, refines and labels them on an 8-bit copy blurred by
//! [`DETECTION_BLUR`] and stretched between the 1st and 99th percentiles, so that dim
//! narrow-band captures still show the board. Each labelled corner is then moved to the
//! saddle that `chess-corners-core`'s saddle-point refiner (a quadratic surface re-centred
//! until the window is symmetric about the corner) finds within half a pixel: the ChESS
//! positions carry a bias that depends on where the corner falls between pixels (0.055 px
//! median on the `cut` board of `scripts/board_detection.py` against 0.008 after the
//! saddle fit; docs/reconstruction.md). A gradient-orthogonality refinement on the linear
//! image (OpenCV's `cornerSubPix`) was tried before and dropped: on simulated boards of
//! 17 px squares it moved the median error from 0.015 to 0.06 px.
//!
//! Where the detector labels part of the board but not all of it (the frame's edge cuts
//! the outer squares, so the ChESS ring cannot see the inner corners beside it; a corner
//! lost in low contrast), the grid is grown from the labelled part: each missing corner
//! next to known ones is predicted by their homography from grid to image and kept where
//! the saddle-point refiner of `chess-corners-core` finds, on the same 8-bit copy, a
//! saddle as strong as the labelled corners' with a point-symmetric picture around it (an
//! X-junction, not the T-junction where the outer squares meet the border). The grid may
//! not grow past the pattern; the board is found when it ends as the whole pattern.
//!
//! In: a grey linear image and the board's inner-corner count. Out: the corners in board
//! order (row by row from the top-left corner as the image shows it), or an error naming
//! the camera and the pattern.

use super::BoardPattern;
use crate::image::gaussian_blur_plane;
use crate::rectify::Homography;
use crate::stereo::GreyImage;
use crate::{Error, Result};
use calib_targets_chessboard::{
    default_chess_config, detect_corner_frame, ChessboardDetector, ChessboardParams, GrayImageView,
};
use chess_corners_core::{
    CornerRefiner, ImageView, RefineContext, RefineStatus, SaddlePointConfig, SaddlePointRefiner,
};
use std::collections::HashMap;

/// Gaussian blur (σ, px) of the copy the detector sees: on boards rendered at noise 0.03
/// and contrast 0.06 the detector labelled 52 of 54 corners with it and 11 without; on
/// clean boards its median error went from 0.015 to 0.004 px.
pub const DETECTION_BLUR: f32 = 1.5;

/// A board found in a capture: its inner corners row by row as the image shows them, and
/// the grid's size as the image shows it (the pattern's, or turned a quarter).
#[derive(Debug, Clone, PartialEq)]
pub struct DetectedBoard {
    pub corners: Vec<[f64; 2]>,
    pub cols: usize,
    pub rows: usize,
}

/// A labelled corner: its grid label (u, v) and its position in the image.
type Labelled = (i32, i32, [f64; 2]);

/// What the detector saw in a capture without the board asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardMissing {
    /// Inner corners labelled.
    pub labelled: usize,
    /// The size of the whole grid the labelled corners form, where they form one (a board
    /// of another pattern).
    pub whole_grid: Option<(usize, usize)>,
}

/// The inner corners of `pattern` in `image` (see the module docs); `camera` names the
/// camera in errors.
pub fn detect_board(
    image: &GreyImage,
    pattern: BoardPattern,
    camera: &str,
) -> Result<DetectedBoard> {
    find_board(image, pattern).map_err(|missing| not_found(&[(camera, missing)], pattern))
}

/// [`detect_board`], telling what was seen where the board was not found.
pub fn find_board(
    image: &GreyImage,
    pattern: BoardPattern,
) -> std::result::Result<DetectedBoard, BoardMissing> {
    let grey = stretched_8bit(&gaussian_blur(image, DETECTION_BLUR));
    let view = GrayImageView {
        width: image.width,
        height: image.height,
        data: &grey,
    };
    let frame = detect_corner_frame(&view, &default_chess_config());
    let detection = ChessboardDetector::new(ChessboardParams::default())
        .ok()
        .and_then(|detector| detector.detect(&frame.corners))
        .ok_or(BoardMissing {
            labelled: 0,
            whole_grid: None,
        })?;
    let labelled: Vec<Labelled> = detection
        .corners
        .iter()
        .map(|c| {
            (
                c.grid.u,
                c.grid.v,
                [f64::from(c.position.x), f64::from(c.position.y)],
            )
        })
        .collect();
    // Every corner re-refined by the saddle-point fit, then the grid completed if need be.
    let mut saddles = Saddles::new(&labelled, &grey, image.width, image.height);
    let labelled: Vec<Labelled> = match saddles.as_mut() {
        Some(c) => labelled
            .iter()
            .map(|&(u, v, p)| (u, v, c.refined(p)))
            .collect(),
        None => labelled,
    };
    // A labelled corner its neighbours do not put where it is (a saddle of the noise or
    // of the scene the detector took into the grid) is left to the completion, which
    // places and confirms it as any missing one.
    let labelled = where_neighbours_put_them(&labelled);
    in_board_order(&labelled, pattern)
        .or_else(|| {
            let completed = complete_grid(&labelled, pattern, saddles.as_mut()?)?;
            in_board_order(&completed, pattern)
        })
        .ok_or(BoardMissing {
            labelled: labelled.len(),
            whole_grid: whole_grid(&labelled),
        })
}

/// A labelled corner moves to the saddle the refiner finds only when it is this close
/// (px); farther, the detector's position is kept.
const REFINED_MOVE: f64 = 0.5;
/// Growth starts from at least this share (%) of the pattern's corners labelled.
const MIN_LABELLED_SHARE: usize = 25;
/// A missing corner is predicted from the known corners at most this many cells away.
const NEIGHBOURHOOD: i32 = 2;
/// A missing corner's saddle must be at least this share of the labelled corners' median
/// saddle strength.
const COMPLETION_STRENGTH: f32 = 0.3;
/// And lie within this share of the local square size of where the homography puts it.
const COMPLETION_OFFSET: f64 = 0.15;
/// And the image around it must be point-symmetric: opposite samples on a ring differ by
/// less than this share of the ring's mean deviation (near 0 at an X-junction; 4/3 at a
/// sharp T-junction whose border is as light as the light squares).
const MAX_ASYMMETRY: f64 = 0.5;

/// The labelled corners grown to the whole `pattern` where the image confirms the missing
/// ones: one ring at a time, each missing corner next to the known ones is predicted by
/// the homography of the known corners around it and kept where a saddle confirms it
/// ([`Saddles::confirm`]); the grid may not grow past the pattern's size. None unless
/// the known corners end as the whole pattern.
fn complete_grid(
    labelled: &[Labelled],
    pattern: BoardPattern,
    saddles: &mut Saddles<'_>,
) -> Option<Vec<Labelled>> {
    let whole = pattern.cols * pattern.rows;
    if labelled.len() < MIN_LABELLED_SHARE * whole / 100 || labelled.len() >= whole {
        return None;
    }
    let mut known: HashMap<(i32, i32), [f64; 2]> =
        labelled.iter().map(|&(u, v, p)| ((u, v), p)).collect();
    if known.len() != labelled.len() {
        return None;
    }
    let (long, short) = (
        pattern.cols.max(pattern.rows) as i32,
        pattern.cols.min(pattern.rows) as i32,
    );
    loop {
        let bounds = extent(known.keys());
        let frontier: Vec<(i32, i32)> = {
            let mut cells: Vec<(i32, i32)> = known
                .keys()
                .flat_map(|&(u, v)| [(u - 1, v), (u + 1, v), (u, v - 1), (u, v + 1)])
                .filter(|c| !known.contains_key(c))
                .filter(|&(u, v)| {
                    let (lo, hi) = (
                        (bounds.0 .0.min(u), bounds.0 .1.min(v)),
                        (bounds.1 .0.max(u), bounds.1 .1.max(v)),
                    );
                    let (w, h) = (hi.0 - lo.0 + 1, hi.1 - lo.1 + 1);
                    w.max(h) <= long && w.min(h) <= short
                })
                .collect();
            cells.sort_unstable();
            cells.dedup();
            cells
        };
        let grown: Vec<((i32, i32), [f64; 2])> = frontier
            .into_iter()
            .filter_map(|cell| Some((cell, saddles.confirm(&known, cell)?)))
            .collect();
        if grown.is_empty() {
            break;
        }
        known.extend(grown);
    }
    // Labels from 0, as the detector's.
    let (lo, _) = extent(known.keys());
    (known.len() == whole).then(|| {
        known
            .into_iter()
            .map(|((u, v), p)| (u - lo.0, v - lo.1, p))
            .collect()
    })
}

/// The labelled corners that lie within [`COMPLETION_OFFSET`] of a square of where the
/// homography of the other labelled corners around them ([`NEIGHBOURHOOD`]) puts them.
/// The corner farthest out is left out first and the rest judged again without it (a
/// stray corner also pulls its neighbours' predictions); a corner with fewer than six
/// such neighbours is kept as it is.
fn where_neighbours_put_them(labelled: &[Labelled]) -> Vec<Labelled> {
    let mut kept = labelled.to_vec();
    loop {
        // Per corner, its distance from the prediction in units of the allowed offset.
        let worst = kept
            .iter()
            .enumerate()
            .filter_map(|(i, &(u, v, p))| {
                let others = kept.iter().filter(|&&(ku, kv, _)| (ku, kv) != (u, v));
                let (predicted, square) =
                    local_prediction(others.map(|&(ku, kv, q)| ((ku, kv), q)), (u, v))?;
                let off = (p[0] - predicted[0]).hypot(p[1] - predicted[1]);
                Some((i, off / (COMPLETION_OFFSET * square)))
            })
            .filter(|(_, ratio)| ratio.is_finite())
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((i, ratio)) if ratio > 1.0 => {
                kept.remove(i);
            }
            _ => return kept,
        }
    }
}

/// Where the homography of the `known` corners within [`NEIGHBOURHOOD`] cells of grid
/// cell (u, v) puts it, and the local square size there (the distance to the
/// predictions of its neighbouring cells); None with fewer than six such corners.
fn local_prediction(
    known: impl Iterator<Item = ((i32, i32), [f64; 2])>,
    (u, v): (i32, i32),
) -> Option<([f64; 2], f64)> {
    let (grid, image): (Vec<[f64; 2]>, Vec<[f64; 2]>) = known
        .filter(|((ku, kv), _)| (ku - u).abs().max((kv - v).abs()) <= NEIGHBOURHOOD)
        .map(|((ku, kv), p)| ([f64::from(ku), f64::from(kv)], p))
        .unzip();
    if grid.len() < 6 {
        return None;
    }
    let map = Homography::fit(&grid, &image).ok()?;
    let at = |u: i32, v: i32| map.apply(f64::from(u), f64::from(v)).map(|(x, y)| [x, y]);
    let predicted = at(u, v)?;
    let square = [at(u + 1, v)?, at(u, v + 1)?]
        .iter()
        .map(|n| (n[0] - predicted[0]).hypot(n[1] - predicted[1]))
        .fold(f64::INFINITY, f64::min);
    Some((predicted, square))
}

/// The smallest and largest labels of `cells`.
fn extent<'a>(cells: impl Iterator<Item = &'a (i32, i32)>) -> ((i32, i32), (i32, i32)) {
    cells.fold(
        ((i32::MAX, i32::MAX), (i32::MIN, i32::MIN)),
        |(lo, hi), &(u, v)| ((lo.0.min(u), lo.1.min(v)), (hi.0.max(u), hi.1.max(v))),
    )
}

/// The saddle-point refiner on the detector's 8-bit copy: it moves labelled corners to
/// their saddles and confirms predicted ones with saddles as strong as the labelled ones'.
struct Saddles<'a> {
    grey: &'a [u8],
    view: ImageView<'a>,
    refiner: SaddlePointRefiner,
    /// The weakest saddle that confirms a corner.
    strong: f32,
    size: (usize, usize),
}

impl<'a> Saddles<'a> {
    /// None when under half the labelled corners refine to a saddle.
    fn new(labelled: &[Labelled], grey: &'a [u8], width: usize, height: usize) -> Option<Self> {
        let mut saddles = Saddles {
            grey,
            view: ImageView::from_u8_slice(width, height, grey)?,
            refiner: SaddlePointRefiner::new(SaddlePointConfig::default()),
            strong: 0.0,
            size: (width, height),
        };
        let mut strengths: Vec<f32> = labelled
            .iter()
            .filter_map(|&(_, _, p)| saddles.saddle(p).map(|(_, s)| s))
            .collect();
        if strengths.len() < labelled.len() / 2 {
            return None;
        }
        strengths.sort_by(f32::total_cmp);
        saddles.strong = COMPLETION_STRENGTH * strengths[strengths.len() / 2];
        Some(saddles)
    }

    /// `p` moved to the saddle the refiner finds near it (within [`REFINED_MOVE`]), or
    /// `p` where it finds none.
    fn refined(&mut self, p: [f64; 2]) -> [f64; 2] {
        match self.saddle(p) {
            Some((q, _)) if (q[0] - p[0]).hypot(q[1] - p[1]) < REFINED_MOVE => q,
            _ => p,
        }
    }

    /// The saddle the refiner finds from `p`, and its strength.
    fn saddle(&mut self, p: [f64; 2]) -> Option<([f64; 2], f32)> {
        let r = self.refiner.refine(
            [p[0] as f32, p[1] as f32],
            RefineContext::new(Some(self.view), None),
        );
        (r.status == RefineStatus::Accepted).then_some(([f64::from(r.x), f64::from(r.y)], r.score))
    }

    /// Whether the image around `centre` is point-symmetric as a checkerboard's X-junction
    /// is (any affine view of it too), unlike the T-junction where the board's outer
    /// squares meet its border, should the refiner accept a saddle there: the mean
    /// difference between opposite samples on a ring (a third of the square, inside the
    /// frame, at least 1.5 px) against the ring's mean deviation.
    fn point_symmetric(&self, centre: [f64; 2], square: f64) -> bool {
        let (width, height) = self.size;
        let room = centre[0]
            .min(centre[1])
            .min((width - 1) as f64 - centre[0])
            .min((height - 1) as f64 - centre[1])
            - 1.0;
        let radius = (square / 3.0).min(room);
        if radius < 1.5 {
            return false;
        }
        let grey = self.grey;
        let at = |x: f64, y: f64| {
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let (fx, fy) = (x - x0 as f64, y - y0 as f64);
            let g = |x: usize, y: usize| f64::from(grey[y * width + x]);
            (g(x0, y0) * (1.0 - fx) + g(x0 + 1, y0) * fx) * (1.0 - fy)
                + (g(x0, y0 + 1) * (1.0 - fx) + g(x0 + 1, y0 + 1) * fx) * fy
        };
        const SAMPLES: usize = 32;
        let ring: Vec<f64> = (0..SAMPLES)
            .map(|k| {
                let angle = std::f64::consts::TAU * k as f64 / SAMPLES as f64;
                at(
                    centre[0] + radius * angle.cos(),
                    centre[1] + radius * angle.sin(),
                )
            })
            .collect();
        let mean = ring.iter().sum::<f64>() / SAMPLES as f64;
        let spread = ring.iter().map(|g| (g - mean).abs()).sum::<f64>() / SAMPLES as f64;
        let asymmetry = (0..SAMPLES)
            .map(|k| (ring[k] - ring[(k + SAMPLES / 2) % SAMPLES]).abs())
            .sum::<f64>()
            / SAMPLES as f64;
        spread > 0.0 && asymmetry < MAX_ASYMMETRY * spread
    }

    /// The corner of grid cell `cell`: predicted by the homography of the known corners
    /// within a few cells of it, and kept where a saddle at least [`COMPLETION_STRENGTH`]
    /// of the labelled corners' lies within [`COMPLETION_OFFSET`] of a square of the
    /// prediction and the image around it is point-symmetric.
    fn confirm(
        &mut self,
        known: &HashMap<(i32, i32), [f64; 2]>,
        (u, v): (i32, i32),
    ) -> Option<[f64; 2]> {
        let (predicted, square) = local_prediction(known.iter().map(|(&c, &p)| (c, p)), (u, v))?;
        let (width, height) = self.size;
        let inside = (0.0..=(width - 1) as f64).contains(&predicted[0])
            && (0.0..=(height - 1) as f64).contains(&predicted[1]);
        if !inside {
            return None;
        }
        let (refined, strength) = self.saddle(predicted)?;
        let moved = (refined[0] - predicted[0]).hypot(refined[1] - predicted[1]);
        (strength >= self.strong
            && moved <= COMPLETION_OFFSET * square
            && self.point_symmetric(refined, square))
        .then_some(refined)
    }
}

/// One error naming every camera (name, what was seen) whose capture lacks the board.
pub fn not_found(missing: &[(&str, BoardMissing)], pattern: BoardPattern) -> Error {
    let names: Vec<&str> = missing.iter().map(|(name, _)| *name).collect();
    let seen = |m: &BoardMissing| match m.whole_grid {
        Some((c, r)) => format!("a whole {c}x{r} grid of inner corners"),
        None => format!("{} inner corners labelled", m.labelled),
    };
    let alike = missing.iter().all(|(_, m)| *m == missing[0].1);
    let (what, found) = match missing {
        [(name, m)] => (
            format!("camera {name}"),
            format!("its calibration capture ({})", seen(m)),
        ),
        [(_, m), ..] if alike => (
            format!("cameras {}", names.join(", ")),
            format!("their calibration captures (each: {})", seen(m)),
        ),
        _ => (
            format!("cameras {}", names.join(", ")),
            format!(
                "their calibration captures ({})",
                missing
                    .iter()
                    .map(|(name, m)| format!("{name}: {}", seen(m)))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ),
    };
    // The same other grid everywhere: the pattern asked for is not the board's.
    let advice = match missing.first().and_then(|(_, m)| m.whole_grid) {
        Some((c, r)) if alike => {
            let inside = |(pc, pr): (usize, usize)| c <= pc && r <= pr;
            if inside((pattern.cols, pattern.rows)) || inside((pattern.rows, pattern.cols)) {
                format!("is the board {c}x{r}, or are some of its inner corners outside the frame?")
            } else {
                format!("is the board {c}x{r}?")
            }
        }
        _ => "every inner corner must be in the picture, sharp enough to see".to_string(),
    };
    Error::unusable(
        what,
        format!("no {pattern} checkerboard found in {found}; {advice}"),
    )
}

/// The size (columns × rows as labelled) of the labelled corners when they are a whole
/// grid, every corner of it present: a board of another pattern than the one asked for.
fn whole_grid(labelled: &[Labelled]) -> Option<(usize, usize)> {
    let (u_min, v_min) = labelled
        .iter()
        .fold((i32::MAX, i32::MAX), |(a, b), &(u, v, _)| {
            (a.min(u), b.min(v))
        });
    let (u_max, v_max) = labelled
        .iter()
        .fold((i32::MIN, i32::MIN), |(a, b), &(u, v, _)| {
            (a.max(u), b.max(v))
        });
    let (cols, rows) = ((u_max - u_min + 1) as usize, (v_max - v_min + 1) as usize);
    let mut cells: Vec<(i32, i32)> = labelled.iter().map(|&(u, v, _)| (u, v)).collect();
    cells.sort_unstable();
    cells.dedup();
    (cols >= 2 && rows >= 2 && cells.len() == labelled.len() && cells.len() == cols * rows)
        .then_some((cols, rows))
}

/// The labelled corners row by row when they are exactly the `cols × rows` grid (or the
/// `rows × cols` one, a board turned a quarter), ordered as the image shows them (see
/// [`as_the_image_shows`]); None otherwise.
fn in_board_order(labelled: &[Labelled], pattern: BoardPattern) -> Option<DetectedBoard> {
    let (u_max, v_max) = labelled
        .iter()
        .fold((-1, -1), |(a, b), &(u, v, _)| (a.max(u), b.max(v)));
    let (cols, rows) = ((u_max + 1) as usize, (v_max + 1) as usize);
    let fits = (cols, rows) == (pattern.cols, pattern.rows)
        || (cols, rows) == (pattern.rows, pattern.cols);
    if !fits || labelled.len() != cols * rows || labelled.iter().any(|&(u, v, _)| u < 0 || v < 0) {
        return None;
    }
    let mut ordered = vec![None; cols * rows];
    for &(u, v, p) in labelled {
        ordered[v as usize * cols + u as usize] = Some(p);
    }
    let ordered: Vec<[f64; 2]> = ordered.into_iter().collect::<Option<_>>()?;
    Some(as_the_image_shows(ordered, cols, rows))
}

/// A grid of corners (`cols × rows`, row-major in the detector's labels) reordered so that
/// its rows run left to right and follow each other top to bottom in the image, whatever
/// corner and direction the detector's labels started from: every camera of an array then
/// gives each corner the same place, and the maps between them stay near translations.
fn as_the_image_shows(grid: Vec<[f64; 2]>, cols: usize, rows: usize) -> DetectedBoard {
    let at = |g: &[[f64; 2]], c: usize, u: usize, v: usize| g[v * c + u];
    // Mean steps along the labels' u and v.
    let step = |g: &[[f64; 2]], c: usize, r: usize, along_u: bool| {
        let (mut dx, mut dy) = (0.0, 0.0);
        for v in 0..r {
            for u in 0..c {
                let next = if along_u { (u + 1, v) } else { (u, v + 1) };
                if next.0 < c && next.1 < r {
                    let (a, b) = (at(g, c, u, v), at(g, c, next.0, next.1));
                    dx += b[0] - a[0];
                    dy += b[1] - a[1];
                }
            }
        }
        (dx, dy)
    };
    let (mut grid, mut cols, mut rows) = (grid, cols, rows);
    let (ux, uy) = step(&grid, cols, rows, true);
    if ux.abs() < uy.abs() {
        // The labels' rows run down the image: transpose.
        grid = (0..cols * rows)
            .map(|i| at(&grid, cols, i / rows, i % rows))
            .collect();
        (cols, rows) = (rows, cols);
    }
    let (ux, _) = step(&grid, cols, rows, true);
    let (_, vy) = step(&grid, cols, rows, false);
    let corners = (0..cols * rows)
        .map(|i| {
            let (u, v) = (i % cols, i / cols);
            let u = if ux < 0.0 { cols - 1 - u } else { u };
            let v = if vy < 0.0 { rows - 1 - v } else { v };
            at(&grid, cols, u, v)
        })
        .collect();
    DetectedBoard {
        corners,
        cols,
        rows,
    }
}

/// `image` between its 1st and 99th percentiles, as 8 bits.
pub(super) fn stretched_8bit(image: &GreyImage) -> Vec<u8> {
    let mut sorted: Vec<f32> = image
        .data
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    sorted.sort_by(f32::total_cmp);
    let pick = |q: usize| sorted.get(sorted.len() * q / 100).copied().unwrap_or(0.0);
    let (lo, hi) = (pick(1), pick(99));
    let scale = if hi > lo { 255.0 / (hi - lo) } else { 0.0 };
    image
        .data
        .iter()
        .map(|&v| ((v - lo) * scale).clamp(0.0, 255.0).round() as u8)
        .collect()
}

/// `image` blurred by a Gaussian of `sigma` pixels.
fn gaussian_blur(image: &GreyImage, sigma: f32) -> GreyImage {
    GreyImage {
        channels: 1,
        width: image.width,
        height: image.height,
        data: gaussian_blur_plane(image.width, image.height, image.data.clone(), sigma),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 41 × 41 8-bit picture of `shade(x, y)` (0 or 1 at each point), 4 × 4 samples a
    /// pixel, dark 20 and light 230.
    fn picture(shade: impl Fn(f64, f64) -> f64) -> Vec<u8> {
        (0..41 * 41)
            .map(|i| {
                let (x, y) = ((i % 41) as f64, (i / 41) as f64);
                let mut sum = 0.0;
                for k in 0..16 {
                    sum += shade(
                        x - 0.375 + 0.25 * (k % 4) as f64,
                        y - 0.375 + 0.25 * (k / 4) as f64,
                    );
                }
                (20.0 + 210.0 * sum / 16.0).round() as u8
            })
            .collect()
    }

    #[test]
    fn an_x_junction_is_point_symmetric_and_a_t_junction_is_not() {
        let (cx, cy) = (20.3, 19.6);
        // A checkerboard corner, turned 20°.
        let (c, s) = (20f64.to_radians().cos(), 20f64.to_radians().sin());
        let x_junction = picture(|x, y| {
            let (u, v) = (c * (x - cx) + s * (y - cy), -s * (x - cx) + c * (y - cy));
            f64::from(u * v > 0.0)
        });
        // The board's edge: dark above and light below on the left, its white border right.
        let t_junction = picture(|x, y| f64::from(x > cx || y > cy));
        for (grey, symmetric) in [(&x_junction, true), (&t_junction, false)] {
            let saddles = Saddles {
                grey,
                view: ImageView::from_u8_slice(41, 41, grey).unwrap(),
                refiner: SaddlePointRefiner::new(SaddlePointConfig::default()),
                strong: 0.0,
                size: (41, 41),
            };
            for square in [6.0, 24.0] {
                assert_eq!(
                    saddles.point_symmetric([cx, cy], square),
                    symmetric,
                    "{square}"
                );
            }
        }
    }

    /// A labelled corner a third of a square from where its neighbours put it (the
    /// detector's stray label) is left out, and only it: every corner of a board seen in
    /// perspective, its edges and corners included, stays.
    #[test]
    fn a_corner_its_neighbours_do_not_put_there_is_left_out() {
        // 11 × 8 corners of 40-px squares, in perspective (the far side 30 % smaller).
        let at = |u: i32, v: i32| {
            let (u, v) = (f64::from(u), f64::from(v));
            let depth = 1.0 + 0.03 * u + 0.01 * v;
            [100.0 + 40.0 * u / depth, 80.0 + 40.0 * v / depth]
        };
        let board: Vec<Labelled> = (0..8)
            .flat_map(|v| (0..11).map(move |u| (u, v, at(u, v))))
            .collect();
        assert_eq!(where_neighbours_put_them(&board), board);
        for stray in [(5, 3), (0, 0), (10, 7), (0, 4)] {
            let moved: Vec<Labelled> = board
                .iter()
                .map(|&(u, v, p)| match (u, v) == stray {
                    true => (u, v, [p[0] + 9.0, p[1] - 9.0]),
                    false => (u, v, p),
                })
                .collect();
            let kept = where_neighbours_put_them(&moved);
            assert_eq!(kept.len(), board.len() - 1, "{stray:?}");
            assert!(kept.iter().all(|&(u, v, _)| (u, v) != stray), "{stray:?}");
        }
    }

    /// A 9 × 6 board (10 × 7 squares of 14 px, turned 10°) with a white border on a grey
    /// wall, 200 × 150, blurred as the detector's copy is: its 8-bit picture and its
    /// inner corners (labels, position).
    fn synthetic_board() -> (Vec<u8>, Vec<Labelled>) {
        let (w, h, square, turn) = (200, 150, 14.0, 10f64.to_radians());
        let origin = [35.3, 22.8];
        let (c, s) = (turn.cos(), turn.sin());
        let to_board = |x: f64, y: f64| {
            let (dx, dy) = (x - origin[0], y - origin[1]);
            ((c * dx + s * dy) / square, (-s * dx + c * dy) / square)
        };
        let shade = |x: f64, y: f64| {
            let (u, v) = to_board(x, y);
            if (0.0..10.0).contains(&u) && (0.0..7.0).contains(&v) {
                ((u.floor() + v.floor()) as i64 % 2) as f32 * 0.85 + 0.05
            } else if (-1.0..11.0).contains(&u) && (-1.0..8.0).contains(&v) {
                0.9
            } else {
                0.5
            }
        };
        let linear: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                (0..16)
                    .map(|k| {
                        shade(
                            x - 0.375 + 0.25 * (k % 4) as f64,
                            y - 0.375 + 0.25 * (k / 4) as f64,
                        )
                    })
                    .sum::<f32>()
                    / 16.0
            })
            .collect();
        let blurred = gaussian_blur_plane(w, h, linear, DETECTION_BLUR);
        let grey = blurred.iter().map(|v| (v * 255.0).round() as u8).collect();
        let corners = (1..=6)
            .flat_map(|j| (1..=9).map(move |i| (i, j)))
            .map(|(i, j)| {
                let (u, v) = (f64::from(i) * square, f64::from(j) * square);
                let p = [origin[0] + c * u - s * v, origin[1] + s * u + c * v];
                (i - 1, j - 1, p)
            })
            .collect();
        (grey, corners)
    }

    #[test]
    fn a_grid_grows_from_a_labelled_part_to_the_whole_board_and_no_further() {
        let (grey, truth) = synthetic_board();
        let nine_by_six = BoardPattern { cols: 9, rows: 6 };
        // A 5 × 3 block of the 54 corners labelled (as a detector misled by clutter might
        // leave it), with labels that do not start at 0.
        let part: Vec<Labelled> = truth
            .iter()
            .filter(|(u, v, _)| (2..7).contains(u) && (1..4).contains(v))
            .map(|&(u, v, p)| (u + 3, v - 1, p))
            .collect();
        assert_eq!(part.len(), 15);
        let mut saddles = Saddles::new(&part, &grey, 200, 150).unwrap();
        let grown = complete_grid(&part, nine_by_six, &mut saddles).unwrap();
        assert_eq!(grown.len(), 54);
        let board = in_board_order(&grown, nine_by_six).unwrap();
        let worst = board
            .corners
            .iter()
            .zip(&truth)
            .map(|(f, (_, _, t))| (f[0] - t[0]).hypot(f[1] - t[1]))
            .fold(0.0, f64::max);
        assert!(worst < 0.15, "{worst}");
        // The border's T-junctions do not make a 10 × 6 or 9 × 7 board of it.
        for (cols, rows) in [(10, 6), (9, 7)] {
            let pattern = BoardPattern { cols, rows };
            assert!(complete_grid(&part, pattern, &mut saddles).is_none());
        }
    }

    #[test]
    fn a_whole_grid_of_another_size_is_told() {
        let grid = |cols: i32, rows: i32, skip: usize| -> Vec<Labelled> {
            (0..cols * rows)
                .map(|i| (i % cols, i / cols, [0.0, 0.0]))
                .skip(skip)
                .collect()
        };
        assert_eq!(whole_grid(&grid(8, 5, 0)), Some((8, 5)));
        assert_eq!(whole_grid(&grid(8, 5, 1)), None);
        assert_eq!(whole_grid(&[]), None);
    }

    /// A 4 × 3 grid seen slightly rotated, labelled from each of its corners in both
    /// orders: every labelling comes out in the same image order.
    #[test]
    fn any_labelling_comes_out_in_image_order() {
        let (cols, rows) = (4usize, 3usize);
        let point = |u: usize, v: usize| {
            let (x, y) = (20.0 * u as f64, 20.0 * v as f64);
            [100.0 + x - 0.1 * y, 50.0 + y + 0.1 * x]
        };
        let expected: Vec<[f64; 2]> = (0..cols * rows)
            .map(|i| point(i % cols, i / cols))
            .collect();
        for flip_u in [false, true] {
            for flip_v in [false, true] {
                for transpose in [false, true] {
                    // The detector's labels (lu, lv) of image corner (u, v).
                    let labelled: Vec<Labelled> = (0..cols * rows)
                        .map(|i| {
                            let (u, v) = (i % cols, i / cols);
                            let u2 = if flip_u { cols - 1 - u } else { u };
                            let v2 = if flip_v { rows - 1 - v } else { v };
                            let (lu, lv) = if transpose { (v2, u2) } else { (u2, v2) };
                            (lu as i32, lv as i32, point(u, v))
                        })
                        .collect();
                    let pattern = BoardPattern { cols, rows };
                    let ordered = in_board_order(&labelled, pattern).unwrap();
                    assert_eq!(ordered.corners, expected, "{flip_u} {flip_v} {transpose}");
                    assert_eq!((ordered.cols, ordered.rows), (cols, rows));
                }
            }
        }
    }
}
