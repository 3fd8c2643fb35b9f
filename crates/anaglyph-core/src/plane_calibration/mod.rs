//! Calibration of an array to a plane from one checkerboard capture per camera: each
//! camera's inner corners are found to subpixel precision ([`detect_board`]), and a homography (or
//! an affine map) from each camera onto the reference camera is fitted to them. The
//! checkerboard's plane then has zero disparity in the registered array; `reconstruct`
//! reads the maps as the cameras' calibrations ([`crate::rectify::Calibration::Plane`]).
//!
//! ```text
//! checkerboard captures -> corners   ChESS detector (calib-targets), subpixel   board.rs
//!   -> orient     each camera's corners in the reference's order, by the squares'
//!                 colours (a camera mounted turned or seeing a mirror)    orientation.rs
//!   -> fit        normalised DLT (or least-squares affine) onto the reference's corners
//!   -> check      no fold, the reference's centre seen (Homography::check_frame)
//!   -> write      rRcC.json (OpenCV FileStorage `homography`), report.json, corners/   output.rs
//! ```
//!
//! In: grey captures with their grid positions, the board pattern, the reference camera.
//! Out: a [`PlaneCalibration`].

mod board;
mod orientation;
mod output;

pub use board::{detect_board, DetectedBoard, DETECTION_BLUR};
pub use orientation::{colour_phase, Orientation};
pub use output::write_plane_calibration;

use crate::io::{read_image_header, read_linear_image, LinearImage};
use crate::reconstruct::{find_in, PICTURE_EXTENSIONS};
use crate::rectify::Homography;
use crate::rig::Rig;
use crate::stereo::GreyImage;
use crate::{Error, Result};
use rayon::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A checkerboard's inner corners: `cols` across, `rows` down (`9x6` for a board of
/// 10 × 7 squares).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct BoardPattern {
    pub cols: usize,
    pub rows: usize,
}

impl std::fmt::Display for BoardPattern {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{}", self.cols, self.rows)
    }
}

impl std::str::FromStr for BoardPattern {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let (cols, rows) = s
            .split_once(['x', 'X'])
            .ok_or_else(|| format!("'{s}': expected COLSxROWS inner corners, e.g. 9x6"))?;
        let parse = |v: &str| {
            v.trim()
                .parse::<usize>()
                .ok()
                .filter(|&n| (2..=100).contains(&n))
        };
        match (parse(cols), parse(rows)) {
            (Some(cols), Some(rows)) => Ok(BoardPattern { cols, rows }),
            _ => Err(format!(
                "'{s}': expected 2 to 100 inner corners each way, e.g. 9x6"
            )),
        }
    }
}

/// The kind of map fitted from each camera onto the reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlaneModel {
    /// 8 degrees of freedom: any plane, any camera rotation.
    #[default]
    Homography,
    /// 6 degrees of freedom: cameras parallel enough that perspective is negligible.
    Affine,
}

crate::choice::named_choices!(PlaneModel, "plane model" {
    Homography = "homography" "8 degrees of freedom: any plane, any camera rotation.",
    Affine = "affine" "6 degrees of freedom: cameras parallel enough that perspective is negligible.",
});

/// One camera's checkerboard capture.
#[derive(Debug, Clone)]
pub struct BoardCapture {
    /// The camera's name (see [`crate::rig::Camera::name`]).
    pub name: String,
    pub image: GreyImage,
}

impl BoardCapture {
    /// Camera `name`'s capture as grey: the mean of its channels.
    pub fn from_capture(name: &str, capture: &LinearImage) -> Self {
        let channels = capture.channels.max(1);
        let data = capture
            .data
            .chunks_exact(channels)
            .map(|p| p.iter().sum::<f32>() / channels as f32)
            .collect();
        BoardCapture {
            name: name.to_string(),
            image: GreyImage {
                channels: 1,
                width: capture.width,
                height: capture.height,
                data,
            },
        }
    }
}

/// One camera's fitted map and how well it fits.
#[derive(Debug, Clone, Serialize)]
pub struct CameraPlaneFit {
    /// The camera's name (see [`crate::rig::Camera::name`]).
    pub name: String,
    /// Camera pixel → reference pixel, row-major.
    pub homography: [[f64; 3]; 3],
    /// Root-mean-square and largest distance between the mapped corners and the
    /// reference's, pixels.
    pub residual_rms_px: f64,
    pub residual_max_px: f64,
    /// The turn of the map at the image centre (degrees, −180 to 180): near 0 for cameras
    /// mounted alike. A map never mirrors: a camera that sees the board mirrored is
    /// refused ([`orientation::orient`], [`Homography::check_frame`]).
    pub rotation_deg: f64,
    /// How the camera sees the board against the reference.
    pub orientation: Orientation,
    /// The detected corners in board order.
    #[serde(skip)]
    pub corners: Vec<[f64; 2]>,
}

impl CameraPlaneFit {
    /// A camera mounted otherwise than the reference: its map turns the image by more
    /// than 90°.
    pub fn mounted_otherwise(&self) -> bool {
        self.rotation_deg.abs() > 90.0
    }
}

/// The calibration of an array to a checkerboard's plane.
#[derive(Debug, Clone, Serialize)]
pub struct PlaneCalibration {
    pub pattern: BoardPattern,
    pub model: PlaneModel,
    /// The reference camera's name.
    pub reference: String,
    pub width: usize,
    pub height: usize,
    pub cameras: Vec<CameraPlaneFit>,
    pub seconds: f64,
}

/// Reads every camera's checkerboard capture `dir/<name>.png|tif|tiff` as grey (the
/// mean of its channels), after checking that all exist and share one size.
pub fn load_board_captures(rig: &Rig, dir: &Path) -> Result<Vec<BoardCapture>> {
    let paths: Vec<PathBuf> = rig
        .cameras
        .iter()
        .map(|c| find_in(dir, &c.name, &PICTURE_EXTENSIONS, "checkerboard capture"))
        .collect::<Result<_>>()?;
    let sizes = paths
        .iter()
        .map(|p| read_image_header(p).map(|h| (h.width, h.height)))
        .collect::<Result<Vec<_>>>()?;
    if let Some((odd, (w, h))) = crate::io::odd_size_out(&sizes) {
        let (found_w, found_h) = sizes[odd];
        return Err(Error::captures(
            paths[odd].display().to_string(),
            format!("{found_w}x{found_h} px"),
            format!("{w}x{h} px like the other cameras' captures"),
        ));
    }
    rig.cameras
        .iter()
        .zip(&paths)
        .map(|(cam, path)| {
            Ok(BoardCapture::from_capture(
                &cam.name,
                &read_linear_image(path)?,
            ))
        })
        .collect()
}

/// Calibrates `captures` (one per camera, all of one size) to the plane of the
/// checkerboard they show (see the module docs).
pub fn calibrate_to_plane(
    captures: &[BoardCapture],
    pattern: BoardPattern,
    reference: &str,
    model: PlaneModel,
) -> Result<PlaneCalibration> {
    let clock = Instant::now();
    let first = captures
        .first()
        .ok_or_else(|| Error::captures("plane calibration", "no captures", "one per camera"))?;
    let (width, height) = (first.image.width, first.image.height);
    let sizes: Vec<_> = captures
        .iter()
        .map(|c| (c.image.width, c.image.height))
        .collect();
    if let Some((odd, (w, h))) = crate::io::odd_size_out(&sizes) {
        let capture = &captures[odd].image;
        return Err(Error::captures(
            format!("checkerboard capture of camera {}", captures[odd].name),
            format!("{}x{} px", capture.width, capture.height),
            format!("{w}x{h} px like the other cameras'"),
        ));
    }
    let reference_index = captures
        .iter()
        .position(|c| c.name == reference)
        .ok_or_else(|| Error::NotFound {
            what: "reference camera".into(),
            name: reference.to_string(),
            available: captures
                .iter()
                .map(|c| c.name.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        })?;
    // Detected in parallel, reported in rig order whichever thread finishes first.
    let detections: Vec<std::result::Result<DetectedBoard, board::BoardMissing>> = captures
        .par_iter()
        .map(|c| board::find_board(&c.image, pattern))
        .collect();
    // Every camera without the board is named, with what was seen.
    let missing: Vec<(&str, board::BoardMissing)> = captures
        .iter()
        .zip(&detections)
        .filter_map(|(c, d)| d.as_ref().err().map(|m| (c.name.as_str(), *m)))
        .collect();
    if !missing.is_empty() {
        return Err(board::not_found(&missing, pattern));
    }
    let boards: Vec<DetectedBoard> = detections.into_iter().flatten().collect();
    // The reference's image order is the board's; every camera is matched to it.
    let reference_board = &boards[reference_index];
    let grid = (reference_board.cols, reference_board.rows);
    let reference_phase = colour_phase(
        &reference_board.corners,
        grid.0,
        grid.1,
        &captures[reference_index].image,
    );
    let oriented = captures
        .iter()
        .zip(&boards)
        .map(|(c, board)| orientation::orient(board, &c.image, grid, reference_phase, &c.name))
        .collect::<Result<Vec<_>>>()?;
    let target = &oriented[reference_index].0;
    let cameras = captures
        .iter()
        .zip(oriented.iter())
        .map(|(c, (found, orientation))| {
            fit_camera(c, found, orientation, target, model, (width, height))
        })
        .collect::<Result<_>>()?;
    Ok(PlaneCalibration {
        pattern,
        model,
        reference: reference.to_string(),
        width,
        height,
        cameras,
        seconds: clock.elapsed().as_secs_f64(),
    })
}

/// The map of one camera's corners onto the reference's, checked on the frame.
fn fit_camera(
    capture: &BoardCapture,
    corners: &[[f64; 2]],
    orientation: &Orientation,
    target: &[[f64; 2]],
    model: PlaneModel,
    (width, height): (usize, usize),
) -> Result<CameraPlaneFit> {
    let name = format!("camera {}", capture.name);
    if corners.len() != target.len() {
        return Err(Error::calibration(
            name,
            format!("{} corners", corners.len()),
            format!(
                "the reference's {} (the board turned a quarter?)",
                target.len()
            ),
        ));
    }
    let homography = match model {
        PlaneModel::Homography => Homography::fit(corners, target)?,
        PlaneModel::Affine => Homography::fit_affine(corners, target)?,
    };
    homography.check_frame(width, height, &format!("{name}'s homography"))?;
    let residuals = homography.residuals(corners, target);
    let rms = (residuals.iter().map(|r| r * r).sum::<f64>() / residuals.len() as f64).sqrt();
    let rotation_deg = turn_at(&homography, width as f64 / 2.0, height as f64 / 2.0);
    Ok(CameraPlaneFit {
        name: capture.name.clone(),
        homography: homography.h,
        residual_rms_px: rms,
        residual_max_px: residuals.iter().copied().fold(0.0, f64::max),
        rotation_deg,
        orientation: orientation.clone(),
        corners: corners.to_vec(),
    })
}

/// The turn (degrees) of `homography` at (x, y): from its Jacobian there, by finite
/// differences (check_frame has made sure the map does not mirror).
fn turn_at(homography: &Homography, x: f64, y: f64) -> f64 {
    let step = 1.0;
    // check_frame has made sure the map is finite over the frame.
    let at = |x: f64, y: f64| {
        homography
            .apply(x, y)
            .map_or([f64::NAN; 2], |(x, y)| [x, y])
    };
    let (right, left) = (at(x + step, y), at(x - step, y));
    let (down, up) = (at(x, y + step), at(x, y - step));
    let j = [
        [right[0] - left[0], down[0] - up[0]],
        [right[1] - left[1], down[1] - up[1]],
    ];
    (j[1][0] - j[0][1]).atan2(j[0][0] + j[1][1]).to_degrees()
}
