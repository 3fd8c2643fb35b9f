//! Which way each camera sees the board. The detector's corners come in the order the
//! image shows them (rows left to right, top to bottom), so a camera mounted turned, or
//! looking through a mirror, would pair its corners with the wrong corners of the
//! reference and be fitted as a near translation with a tiny residual. The reference's
//! image order defines the board's; every other camera's grid is matched to it by the
//! one of the grid's eight symmetries (turns by quarters, mirrors) that gives its squares
//! the reference's colours.
//!
//! The colours tell the symmetries apart only where the board is asymmetric: a board of
//! `c × r` inner corners has `(c + 1) × (r + 1)` squares, and a turn by 180° keeps its
//! colours when `c + r` is even (all four corner squares one colour, or opposite corners
//! alike). What the colours cannot tell apart is chosen as the least turned proper map
//! (no mirror), and the others are named in [`Orientation::alternatives`].
//!
//! In: a camera's corners in image order, its grid's size as seen, its grey capture and
//! the reference's colour phase. Out: the corners in the reference's order and an
//! [`Orientation`].

use super::DetectedBoard;
use crate::stereo::GreyImage;
use crate::{Error, Result};
use serde::Serialize;

/// Below this share of the squares' contrast the colours are not read (a blurred or
/// washed-out board): the camera keeps its image order.
const READABLE_PHASE: f64 = 0.5;

/// One of the eight symmetries of a grid: flips of the columns and rows as the image
/// shows them, then a transpose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct GridMap {
    flip_u: bool,
    flip_v: bool,
    transpose: bool,
}

impl GridMap {
    /// The image order kept.
    const IDENTITY: GridMap = GridMap {
        flip_u: false,
        flip_v: false,
        transpose: false,
    };

    fn all() -> impl Iterator<Item = GridMap> {
        (0..8).map(|i| GridMap {
            flip_u: i & 1 != 0,
            flip_v: i & 2 != 0,
            transpose: i & 4 != 0,
        })
    }

    fn mirrored(self) -> bool {
        self.flip_u ^ self.flip_v ^ self.transpose
    }

    /// The turn (degrees, 0 to 180) of the proper part.
    fn turn(self) -> u32 {
        match (self.transpose, self.flip_u, self.flip_v) {
            (false, false, false) | (false, true, false) | (false, false, true) => 0,
            (false, true, true) => 180,
            (true, _, _) => 90,
        }
    }

    /// How the image order relates to the board's, in words.
    fn describe(self) -> &'static str {
        match (self.transpose, self.flip_u, self.flip_v) {
            (false, false, false) => "upright",
            (false, true, true) => "turned 180°",
            (false, true, false) => "mirrored left to right",
            (false, false, true) => "mirrored top to bottom",
            (true, true, false) | (true, false, true) => "turned a quarter",
            (true, false, false) | (true, true, true) => "turned a quarter and mirrored",
        }
    }

    /// The grid (`cols × rows` as the image shows it, row-major) in the mapped order, and
    /// its size.
    fn apply(self, grid: &[[f64; 2]], cols: usize, rows: usize) -> (Vec<[f64; 2]>, usize, usize) {
        let (out_cols, out_rows) = if self.transpose {
            (rows, cols)
        } else {
            (cols, rows)
        };
        let corners = (0..cols * rows)
            .map(|i| {
                let (bu, bv) = (i % out_cols, i / out_cols);
                let (u, v) = if self.transpose { (bv, bu) } else { (bu, bv) };
                let u = if self.flip_u { cols - 1 - u } else { u };
                let v = if self.flip_v { rows - 1 - v } else { v };
                grid[v * cols + u]
            })
            .collect();
        (corners, out_cols, out_rows)
    }
}

/// How a camera sees the board against the reference.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Orientation {
    /// "upright", "turned 180°", "mirrored left to right", …
    pub seen: &'static str,
    /// What the board's colours could not tell from `seen`.
    pub alternatives: Vec<&'static str>,
    /// False when the colours could not be read: the image order was kept.
    pub colours_read: bool,
}

/// Which colour the squares of a grid (in its order) have: the sum over the squares of
/// their grey values with alternating signs, over the sum of their distances from the mean
/// (±1 for a clean board, near 0 where the colours cannot be read).
pub fn colour_phase(corners: &[[f64; 2]], cols: usize, rows: usize, image: &GreyImage) -> f64 {
    let mut samples = Vec::with_capacity(cols.saturating_sub(1) * rows.saturating_sub(1));
    for v in 0..rows.saturating_sub(1) {
        for u in 0..cols.saturating_sub(1) {
            let at = |du: usize, dv: usize| corners[(v + dv) * cols + u + du];
            let quad = [at(0, 0), at(1, 0), at(0, 1), at(1, 1)];
            let x = quad.iter().map(|p| p[0]).sum::<f64>() / 4.0;
            let y = quad.iter().map(|p| p[1]).sum::<f64>() / 4.0;
            let sign = if (u + v) % 2 == 0 { 1.0 } else { -1.0 };
            samples.push((sign, bilinear(image, x, y)));
        }
    }
    let mean = samples.iter().map(|s| s.1).sum::<f64>() / samples.len().max(1) as f64;
    let signed: f64 = samples.iter().map(|(s, g)| s * (g - mean)).sum();
    let spread: f64 = samples.iter().map(|(_, g)| (g - mean).abs()).sum();
    if spread > 0.0 {
        signed / spread
    } else {
        0.0
    }
}

/// The grey value at pixel position (x, y) (pixel centres at integers), clamped to the
/// image.
fn bilinear(image: &GreyImage, x: f64, y: f64) -> f64 {
    let (w, h) = (image.width, image.height);
    if w == 0 || h == 0 {
        return 0.0;
    }
    let x = x.clamp(0.0, (w - 1) as f64);
    let y = y.clamp(0.0, (h - 1) as f64);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let g = |x: usize, y: usize| f64::from(image.data[(y * w + x) * image.channels.max(1)]);
    (g(x0, y0) * (1.0 - fx) + g(x1, y0) * fx) * (1.0 - fy)
        + (g(x0, y1) * (1.0 - fx) + g(x1, y1) * fx) * fy
}

/// The corners of `board` (found in `image`) in the reference's order (a grid of
/// `cols × rows`, the reference's size as its image shows it, whose colour phase is
/// `reference_phase`), and how the camera (`camera`, for errors) sees the board.
pub fn orient(
    board: &DetectedBoard,
    image: &GreyImage,
    (cols, rows): (usize, usize),
    reference_phase: f64,
    camera: &str,
) -> Result<(Vec<[f64; 2]>, Orientation)> {
    let candidates: Vec<(GridMap, Vec<[f64; 2]>, f64)> = GridMap::all()
        .filter_map(|map| {
            let (corners, c, r) = map.apply(&board.corners, board.cols, board.rows);
            ((c, r) == (cols, rows)).then(|| {
                let phase = colour_phase(&corners, c, r, image);
                (map, corners, phase)
            })
        })
        .collect();
    if candidates.is_empty() {
        return Err(Error::calibration(
            format!("camera {camera}"),
            format!("a board of {}x{} inner corners", board.cols, board.rows),
            format!("the reference's {cols}x{rows}"),
        ));
    }
    // Every symmetry's phase has the same magnitude (it only flips the sign): any
    // candidate's tells whether this camera's colours are readable.
    let contrast = candidates[0].2.abs();
    let colours_read = contrast >= READABLE_PHASE && reference_phase.abs() >= READABLE_PHASE;
    let mut kept: Vec<_> = candidates
        .into_iter()
        .filter(|(_, _, phase)| !colours_read || phase.signum() == reference_phase.signum())
        .collect();
    // The least turned proper map first; mirrors last.
    kept.sort_by_key(|(map, _, _)| (map.mirrored(), map.turn(), map.transpose));
    let (best, corners, _) = kept.remove(0);
    let rivals: Vec<GridMap> = kept.iter().map(|(m, _, _)| *m).collect();
    if let Some(tie) = rivals
        .iter()
        .find(|m| (m.mirrored(), m.turn()) == (best.mirrored(), best.turn()))
    {
        if best.turn() == 90 || !colours_read {
            return Err(Error::calibration(
                format!("camera {camera}"),
                format!(
                    "the board {} one way or the other ({} and {} fit its corners and \
                     colours alike)",
                    best.describe(),
                    debug_name(best),
                    debug_name(*tie)
                ),
                "a board whose colours tell the turns apart (inner corners of different \
                 parity, e.g. 9x6), or cameras mounted the same way up",
            ));
        }
    }
    if colours_read && best.mirrored() {
        return Err(Error::calibration(
            format!("camera {camera}"),
            format!(
                "the board {} (its colours fit no turn of the reference's view)",
                best.describe()
            ),
            "cameras that see the board unmirrored: flip the captures of a camera behind a \
             mirror or beam splitter before calibrating and reconstructing",
        ));
    }
    let alternatives = if best == GridMap::IDENTITY {
        Vec::new()
    } else {
        rivals.iter().map(|m| m.describe()).collect()
    };
    Ok((
        corners,
        Orientation {
            seen: best.describe(),
            alternatives,
            colours_read,
        },
    ))
}

fn debug_name(map: GridMap) -> String {
    format!(
        "columns {}, rows {}{}",
        if map.flip_u { "reversed" } else { "kept" },
        if map.flip_v { "reversed" } else { "kept" },
        if map.transpose { ", transposed" } else { "" }
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic board of `cols × rows` inner corners, 10 px squares, rendered in image
    /// order after `map` (the camera's view of it).
    fn board(cols: usize, rows: usize) -> (GreyImage, Vec<[f64; 2]>) {
        let (w, h) = ((cols + 3) * 10, (rows + 3) * 10);
        // Inner corner (u, v) at ((u + 2) * 10 - 0.5, ...): square (i, j) spans
        // [(i + 1) * 10, (i + 2) * 10) for i in 0..=cols.
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let (i, j) = (x / 10, y / 10);
                if i == 0 || j == 0 || i > cols + 1 || j > rows + 1 {
                    0.8
                } else if (i + j) % 2 == 0 {
                    0.1
                } else {
                    0.8
                }
            })
            .collect();
        let corners = (0..cols * rows)
            .map(|k| {
                let (u, v) = (k % cols, k / cols);
                [((u + 2) * 10) as f64 - 0.5, ((v + 2) * 10) as f64 - 0.5]
            })
            .collect();
        let image = GreyImage {
            channels: 1,
            width: w,
            height: h,
            data,
        };
        (image, corners)
    }

    fn seen(corners: &[[f64; 2]], cols: usize, rows: usize) -> DetectedBoard {
        DetectedBoard {
            corners: corners.to_vec(),
            cols,
            rows,
        }
    }

    /// The image turned 180° (both axes reversed), with its corners in image order.
    fn turned(image: &GreyImage, corners: &[[f64; 2]]) -> (GreyImage, Vec<[f64; 2]>) {
        let (w, h) = (image.width, image.height);
        let data = (0..w * h).map(|i| image.data[w * h - 1 - i]).collect();
        let mut corners: Vec<[f64; 2]> = corners
            .iter()
            .map(|p| [(w - 1) as f64 - p[0], (h - 1) as f64 - p[1]])
            .collect();
        corners.reverse();
        let image = GreyImage {
            data,
            ..image.clone()
        };
        (image, corners)
    }

    #[test]
    fn a_camera_turned_180_degrees_is_told_by_the_colours_of_an_asymmetric_board() {
        let (image, corners) = board(9, 6);
        let phase = colour_phase(&corners, 9, 6, &image);
        assert!(phase.abs() > 0.9, "{phase}");
        let (same, orientation) =
            orient(&seen(&corners, 9, 6), &image, (9, 6), phase, "a").unwrap();
        assert_eq!(same, corners);
        assert_eq!(orientation.seen, "upright");
        assert!(orientation.alternatives.is_empty());
        let (image2, corners2) = turned(&image, &corners);
        let (ordered, orientation) =
            orient(&seen(&corners2, 9, 6), &image2, (9, 6), phase, "b").unwrap();
        assert_eq!(orientation.seen, "turned 180°");
        assert_eq!(orientation.alternatives, ["mirrored left to right"]);
        // Corner k of the turned camera is the reference's corner k, seen turned.
        let (w, h) = (image.width as f64, image.height as f64);
        for (o, c) in ordered.iter().zip(&corners) {
            assert_eq!(*o, [w - 1.0 - c[0], h - 1.0 - c[1]]);
        }
    }

    #[test]
    fn a_camera_that_sees_the_board_mirrored_is_refused_where_the_colours_tell() {
        // 9 x 7 inner corners: 10 x 8 squares; a turn by 180° keeps the colours, a mirror
        // left to right does not, so only mirrors fit a mirrored view.
        let (image, corners) = board(9, 7);
        let phase = colour_phase(&corners, 9, 7, &image);
        let (w, h) = (image.width, image.height);
        let data = (0..w * h)
            .map(|i| image.data[(i / w) * w + w - 1 - i % w])
            .collect();
        let mirrored = GreyImage {
            data,
            ..image.clone()
        };
        let corners: Vec<[f64; 2]> = (0..9 * 7)
            .map(|k| {
                let p = corners[(k / 9) * 9 + 8 - k % 9];
                [(w - 1) as f64 - p[0], p[1]]
            })
            .collect();
        let error = orient(&seen(&corners, 9, 7), &mirrored, (9, 7), phase, "b")
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("camera b") && error.contains("mirrored") && error.contains("flip"),
            "{error}"
        );
    }

    #[test]
    fn a_symmetric_board_keeps_the_image_order_and_says_what_it_cannot_tell() {
        // 8 x 6 inner corners: 9 x 7 squares, all four corner squares one colour.
        let (image, corners) = board(8, 6);
        let phase = colour_phase(&corners, 8, 6, &image);
        let (image2, corners2) = turned(&image, &corners);
        let (ordered, orientation) =
            orient(&seen(&corners2, 8, 6), &image2, (8, 6), phase, "b").unwrap();
        assert_eq!(orientation.seen, "upright");
        assert_eq!(ordered, corners2);
    }

    #[test]
    fn a_grid_of_another_size_is_refused_naming_both() {
        let (image, corners) = board(4, 3);
        let error = orient(&seen(&corners, 4, 3), &image, (5, 3), 1.0, "b")
            .unwrap_err()
            .to_string();
        assert!(error.contains("camera b") && error.contains("4x3") && error.contains("5x3"));
    }
}
