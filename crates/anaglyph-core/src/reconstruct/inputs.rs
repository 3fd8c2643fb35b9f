//! The inputs of reconstruction: every camera's capture and white board, read from the
//! paths of the rig file (or from folders of `<camera name>.png|tif|tiff`), checked against
//! the rig, and calibrated into the sensing matrix's units.
//!
//! **Calibration.** Exposure differs between cameras and is unknown. With a white-board
//! capture, channel k of a camera has gain `g_k = mean(white_k) / (ρ_w · Σ_j C[r_k][j])`
//! (ρ_w the board's reflectance): dividing by it removes exposure and, to first order, the
//! illuminant, so demultiplexing returns reflectance (the paper's white-board step). The
//! board's smooth shape across the frame (vignetting, uneven light) is divided out pixel by
//! pixel as well ([`super::flat_field`]).
//! Without one, the camera's exposure metadata is used (`g_k = exposure`), which needs C
//! built with the scene's illuminant. Values at or above the saturation level are NaN.
//! Each camera may also carry its calibrated geometry, for rectification.

use super::dark_level::Dark;
use super::flat_field::flat_field;
use crate::image::Image;
use crate::io::{odd_size_out, read_image_header, read_linear_image, ImageHeader, LinearImage};
use crate::rectify::{Calibration, CameraModel};
use crate::register::{fill_from_nearest, NormalisedView};
use crate::rig::{Camera, Rig, SensingMatrix};
use crate::simulate::Simulation;
use crate::stereo::GreyImage;
use crate::{Error, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Coefficient of variation of a white board above which a warning is raised (an uneven
/// board or vignetting: the per-channel gain is then only an average).
pub const UNEVEN_WHITE_WARNING: f64 = 0.05;
/// Fraction of a camera's values brighter than a perfect white above which a warning
/// says the white board (or the exposure metadata) does not match the capture.
pub const BRIGHTER_THAN_WHITE_WARNING: f64 = 0.25;
/// Picture extensions looked for in capture folders.
pub(crate) const EXTENSIONS: [&str; 3] = ["png", "tif", "tiff"];
/// Calibration extensions looked for in calibration folders.
const CALIBRATION_EXTENSIONS: [&str; 4] = ["json", "yml", "yaml", "npy"];

/// One camera's pictures.
#[derive(Debug, Clone)]
pub struct CameraCapture {
    /// The camera's name (see [`crate::rig::Camera::name`]).
    pub name: String,
    pub capture: LinearImage,
    pub white: Option<LinearImage>,
    /// Exposure metadata (see [`crate::rig::CameraEntry::exposure`]).
    pub exposure: Option<f64>,
    /// Calibrated geometry (a pose, or a homography onto the reference camera through a
    /// plane); when the cameras have one, reconstruction rectifies first.
    pub calibration: Option<Calibration>,
}

/// The captures of the whole array, in the rig's camera order.
#[derive(Debug, Clone)]
pub struct ArrayCaptures {
    pub width: usize,
    pub height: usize,
    pub cameras: Vec<CameraCapture>,
}

/// How a camera was calibrated.
#[derive(Debug, Clone, Serialize)]
pub struct CameraCalibration {
    /// The camera's name (see [`crate::rig::Camera::name`]).
    pub name: String,
    /// "white board", "exposure metadata", or "none" (a registration-only run without
    /// either: the capture as recorded, less its dark level).
    pub method: &'static str,
    /// Capture units per sensing-matrix unit, per channel.
    pub gain: Vec<f64>,
    /// Coefficient of variation of the white board per channel (None without one).
    pub white_variation: Option<Vec<f64>>,
    /// Capture values at or above the saturation level (masked).
    pub saturated_values: usize,
    /// Fraction of the unsaturated values brighter than a perfect white would be (a
    /// reflectance above 1): a white board captured darker than the scene.
    pub brighter_than_white: f64,
}

/// `DIR/<name>.{ext}` for the first of `extensions` that exists; `what` names the file in
/// the error.
pub(crate) fn find_in(dir: &Path, name: &str, extensions: &[&str], what: &str) -> Result<PathBuf> {
    let found: Vec<PathBuf> = extensions
        .iter()
        .map(|e| dir.join(format!("{name}.{e}")))
        .filter(|p| p.is_file())
        .collect();
    if let [first, second, ..] = &found[..] {
        return Err(Error::captures(
            format!("{what} of camera {name}"),
            format!("both {} and {}", first.display(), second.display()),
            "one file per camera (move the other away)",
        ));
    }
    found.into_iter().next().ok_or_else(|| Error::MissingFile {
        path: dir.join(format!("{name}.{}", extensions[0])),
        what: format!(
            "no {what} {name}.{} for camera {name}",
            extensions.join(", .")
        ),
    })
}

/// Where a camera's capture is.
#[derive(Clone, Copy)]
enum Captures<'a> {
    /// Where the rig file names it.
    Rig,
    /// `<folder>/<camera>.png|tif|tiff`.
    Folder(&'a Path),
    /// This file.
    File(&'a Path),
}

/// The files of one camera, found.
struct CameraFiles {
    capture: PathBuf,
    white: Option<PathBuf>,
    calibration: Option<PathBuf>,
    dark: Option<PathBuf>,
    /// A dark frame of the capture alone (a sequence's frame), instead of `dark`.
    capture_dark: Option<PathBuf>,
}

impl CameraFiles {
    /// Every camera's files, in rig order.
    fn find_all(
        rig: &Rig,
        captures: &[Captures<'_>],
        whites: Option<&Path>,
        calibrations: Option<&Path>,
    ) -> Result<Vec<Self>> {
        rig.cameras
            .iter()
            .zip(captures)
            .map(|(cam, &source)| CameraFiles::find(cam, source, whites, calibrations))
            .collect()
    }

    /// `cam`'s files: its capture from `captures`, the rest in the folders given, else
    /// where the rig file names them.
    fn find(
        cam: &Camera,
        captures: Captures<'_>,
        whites: Option<&Path>,
        calibrations: Option<&Path>,
    ) -> Result<Self> {
        let capture = match captures {
            Captures::Folder(dir) => find_in(dir, &cam.name, &EXTENSIONS, "capture")?,
            Captures::File(path) => path.to_path_buf(),
            Captures::Rig => cam.image.clone().ok_or_else(|| {
                Error::captures(
                    format!("camera {}", cam.name),
                    "no image in the rig file and no --captures folder",
                    "a capture for every camera",
                )
            })?,
        };
        let white = match whites {
            Some(dir) => Some(find_in(dir, &cam.name, &EXTENSIONS, "white board")?),
            None => cam.white.clone(),
        };
        let calibration = match calibrations {
            Some(dir) => Some(find_in(
                dir,
                &cam.name,
                &CALIBRATION_EXTENSIONS,
                "calibration",
            )?),
            None => cam.calibration.clone(),
        };
        Ok(CameraFiles {
            capture,
            white,
            calibration,
            dark: cam.dark.clone(),
            capture_dark: None,
        })
    }
}

/// The camera's dark frame, or its black level in the units of its capture file.
fn dark_of(cam: &Camera, files: &CameraFiles) -> Result<Option<Dark>> {
    Ok(match (&files.dark, cam.black_level) {
        (Some(path), _) => Some(Dark::Frame(read_linear_image(path)?)),
        (None, Some(level)) => {
            let full_scale = f64::from(read_image_header(&files.capture)?.full_scale);
            Some(Dark::level(level, full_scale, &files.capture)?)
        }
        (None, None) => None,
    })
}

/// Every picture's header against its camera's sensor (channels) and against the first
/// capture (size), before anything is decoded; returns the size.
fn check_headers(rig: &Rig, files: &[CameraFiles]) -> Result<(usize, usize)> {
    let mut pictures: Vec<(&Path, ImageHeader)> = Vec::new();
    for (cam, files) in rig.cameras.iter().zip(files) {
        let channels = cam.sensor.channel_count();
        let paths = [
            Some(&files.capture),
            files.white.as_ref(),
            files.dark.as_ref(),
            files.capture_dark.as_ref(),
        ];
        for path in paths.into_iter().flatten() {
            let header = read_image_header(path)?;
            if header.channels != channels {
                return Err(Error::raster(
                    path.display().to_string(),
                    format!("{} channels", header.channels),
                    format!(
                        "{channels}, as camera {}'s sensor '{}' (the rig does not match its images)",
                        cam.name,
                        cam.sensor.name()
                    ),
                ));
            }
            pictures.push((path, header));
        }
    }
    let sizes: Vec<_> = pictures.iter().map(|(_, h)| (h.width, h.height)).collect();
    if let Some((odd, (width, height))) = odd_size_out(&sizes) {
        let (path, header) = &pictures[odd];
        let like = pictures
            .iter()
            .find(|(_, h)| (h.width, h.height) == (width, height))
            .map_or(String::new(), |(p, _)| p.display().to_string());
        return Err(Error::raster(
            path.display().to_string(),
            format!("{}x{} pixels", header.width, header.height),
            format!("{width}x{height}, as {like} and most of the array's pictures"),
        ));
    }
    Ok(sizes.first().copied().unwrap_or((0, 0)))
}

impl ArrayCaptures {
    /// Reads every camera's capture (and white board and calibration, where there is
    /// one): from `captures` / `whites` / `calibrations` folders when given, else from the
    /// paths in the rig file. Every file is found and every picture's header checked
    /// (size, channels, limits) before any picture is decoded.
    pub fn load(
        rig: &Rig,
        captures: Option<&Path>,
        whites: Option<&Path>,
        calibrations: Option<&Path>,
    ) -> Result<Self> {
        let source = captures.map_or(Captures::Rig, Captures::Folder);
        Self::load_from(rig, &vec![source; rig.cameras.len()], whites, calibrations)
    }

    /// [`ArrayCaptures::load`] of one frame of a sequence: its captures, and the white
    /// boards, dark frames and calibrations of the sequence.
    pub fn load_frame(
        rig: &Rig,
        frame: &super::FrameFiles,
        whites: Option<&Path>,
        calibrations: Option<&Path>,
    ) -> Result<Self> {
        if frame.captures.len() != rig.cameras.len() {
            return Err(Error::Shape {
                op: format!("frame {}: one capture per camera", frame.number),
                got: vec![frame.captures.len()],
                expected: vec![rig.cameras.len()],
            });
        }
        let sources: Vec<Captures<'_>> = frame.captures.iter().map(|p| Captures::File(p)).collect();
        let mut files = CameraFiles::find_all(rig, &sources, whites, calibrations)?;
        if let Some(darks) = &frame.darks {
            for (files, dark) in files.iter_mut().zip(darks) {
                files.capture_dark = Some(dark.clone());
            }
        }
        Self::load_files(rig, &files)
    }

    fn load_from(
        rig: &Rig,
        captures: &[Captures<'_>],
        whites: Option<&Path>,
        calibrations: Option<&Path>,
    ) -> Result<Self> {
        let files = CameraFiles::find_all(rig, captures, whites, calibrations)?;
        Self::load_files(rig, &files)
    }

    fn load_files(rig: &Rig, files: &[CameraFiles]) -> Result<Self> {
        let (width, height) = check_headers(rig, files)?;
        let channels = rig.channel_count() as u64;
        let bands = rig.reconstruction_shape()?.count as u64;
        // Captures and white boards, their calibrated copies, and one view's cube.
        let values = (width * height) as u64 * (3 * channels + bands);
        crate::memory::check_fits(
            &format!("reconstructing from {width}x{height} captures"),
            crate::memory::f32_bytes(values),
        )?;
        let mut cameras = Vec::with_capacity(files.len());
        for (cam, files) in rig.cameras.iter().zip(files) {
            let calibration = files
                .calibration
                .as_deref()
                .map(Calibration::load)
                .transpose()?;
            let dark = dark_of(cam, files)?;
            // A frame's own dark frame serves its capture; the white board keeps the rig's.
            let capture_dark = match &files.capture_dark {
                Some(path) => Some(Dark::Frame(read_linear_image(path)?)),
                None => dark.clone(),
            };
            let camera = format!("camera {}", cam.name);
            let read = |path: &Path,
                        picture: &str,
                        dark: &Option<Dark>,
                        dark_file: Option<&PathBuf>|
             -> Result<LinearImage> {
                let mut image = read_linear_image(path)?;
                if let Some(dark) = dark {
                    let name = match (dark_file, cam.black_level) {
                        (Some(file), _) => format!("dark frame {}", file.display()),
                        (None, level) => format!("black_level {}", level.unwrap_or(0.0)),
                    };
                    let picture = format!("{picture} ({})", path.display());
                    dark.subtract_from(&mut image, &camera, &picture, &name)?;
                }
                Ok(image)
            };
            let capture_dark_file = files.capture_dark.as_ref().or(files.dark.as_ref());
            cameras.push(CameraCapture {
                name: cam.name.clone(),
                capture: read(&files.capture, "capture", &capture_dark, capture_dark_file)?,
                white: files
                    .white
                    .as_deref()
                    .map(|w| read(w, "white board", &dark, files.dark.as_ref()))
                    .transpose()?,
                exposure: cam.exposure,
                calibration,
            });
        }
        Self::from_cameras(cameras)
    }

    /// Every camera's calibration from a folder of `<camera>.json|yml|yaml|npy` files (what
    /// `calibrate` writes), in rig order.
    pub fn load_calibrations(rig: &Rig, dir: &Path) -> Result<Vec<Calibration>> {
        rig.cameras
            .iter()
            .map(|cam| {
                let path = find_in(dir, &cam.name, &CALIBRATION_EXTENSIONS, "calibration")?;
                Calibration::load(&path)
            })
            .collect()
    }

    /// Checks that all pictures share one size.
    pub fn from_cameras(cameras: Vec<CameraCapture>) -> Result<Self> {
        let Some(first) = cameras.first() else {
            return Err(Error::captures("captures", "no cameras", "at least one"));
        };
        let (width, height) = (first.capture.width, first.capture.height);
        for cam in &cameras {
            for (what, image) in [
                ("capture", Some(&cam.capture)),
                ("white board", cam.white.as_ref()),
            ] {
                if let Some(image) = image {
                    if (image.width, image.height) != (width, height) {
                        return Err(Error::Shape {
                            op: format!("{what} of camera {}", cam.name),
                            got: vec![image.width, image.height],
                            expected: vec![width, height],
                        });
                    }
                }
            }
        }
        Ok(ArrayCaptures {
            width,
            height,
            cameras,
        })
    }

    /// The captures of a simulation (each camera's exposure kept as metadata).
    pub fn from_simulation(simulation: &Simulation) -> Self {
        let (width, height) = (simulation.settings.width, simulation.settings.height);
        let image = |data: &[f32], channels| LinearImage {
            width,
            height,
            channels,
            data: data.to_vec(),
        };
        ArrayCaptures {
            width,
            height,
            cameras: simulation
                .views
                .iter()
                .map(|v| CameraCapture {
                    name: v.name.clone(),
                    capture: image(&v.capture, v.channels),
                    white: Some(image(&v.white, v.channels)),
                    exposure: Some(v.exposure),
                    calibration: simulation
                        .settings
                        .pose_jitter
                        .map(|_| Calibration::Pose(CameraModel::from_pinhole(&v.camera))),
                })
                .collect(),
        }
    }

    /// Each capture's luminance (Rec. 709 weights for RGB), the matcher's input. Pixels
    /// without a value (NaN: outside a rectified camera's frame) take the nearest value of
    /// their row, so that matching costs stay finite.
    pub fn grey_images(&self) -> Vec<GreyImage> {
        self.cameras
            .iter()
            .map(|cam| {
                let mut data: Vec<f32> = cam
                    .capture
                    .data
                    .chunks_exact(cam.capture.channels)
                    .map(|p| match p {
                        [r, g, b] => 0.2126 * r + 0.7152 * g + 0.0722 * b,
                        _ => p[0],
                    })
                    .collect();
                for row in data.chunks_exact_mut(self.width) {
                    fill_from_nearest(row);
                }
                GreyImage {
                    channels: 1,
                    width: self.width,
                    height: self.height,
                    data,
                }
            })
            .collect()
    }
}

/// Mean and coefficient of variation of channel `c` over values below `saturation`.
fn channel_statistics(image: &LinearImage, c: usize, saturation: f32) -> Option<(f64, f64)> {
    let (mut n, mut sum, mut sum2) = (0usize, 0.0f64, 0.0f64);
    for &v in image.data.iter().skip(c).step_by(image.channels) {
        if v < saturation {
            n += 1;
            sum += v as f64;
            sum2 += (v as f64).powi(2);
        }
    }
    if n == 0 {
        return None;
    }
    let mean = sum / n as f64;
    let variance = (sum2 / n as f64 - mean * mean).max(0.0);
    Some((
        mean,
        if mean > 0.0 {
            variance.sqrt() / mean
        } else {
            0.0
        },
    ))
}

/// Calibrates every camera into C's units (see the module docs). `sensing` must be the
/// rig's C, its rows in camera order.
pub fn calibrate(
    captures: &ArrayCaptures,
    sensing: &SensingMatrix,
    white_reflectance: f64,
    saturation_level: f32,
    radiometry_required: bool,
) -> Result<(Vec<NormalisedView>, Vec<CameraCalibration>)> {
    if !(white_reflectance > 0.0 && white_reflectance <= 1.0) {
        return Err(Error::out_of_range(
            "white board reflectance",
            white_reflectance,
            "in (0, 1]",
        ));
    }
    let channels: usize = captures.cameras.iter().map(|c| c.capture.channels).sum();
    if channels != sensing.rows() {
        return Err(Error::Shape {
            op: "calibration: capture channels against the rows of C".into(),
            got: vec![channels],
            expected: vec![sensing.rows()],
        });
    }
    let mut views = Vec::with_capacity(captures.cameras.len());
    let mut records = Vec::with_capacity(captures.cameras.len());
    let mut first_row = 0;
    for cam in &captures.cameras {
        let ch = cam.capture.channels;
        let name = format!("camera {}", cam.name);
        let (method, gain, variation) = match (&cam.white, cam.exposure) {
            (Some(white), _) => {
                let mut gain = Vec::with_capacity(ch);
                let mut variation = Vec::with_capacity(ch);
                for c in 0..ch {
                    let Some((mean, cv)) = channel_statistics(white, c, saturation_level) else {
                        return Err(Error::unusable(
                            format!("{name} white board channel {c}"),
                            "saturated everywhere; expose it lower",
                        ));
                    };
                    let response: f64 = sensing.row(first_row + c).iter().sum();
                    if !(mean > 0.0) || !(response > 0.0) {
                        return Err(Error::unusable(
                            format!("{name} white board channel {c}"),
                            format!("it reads {mean} (expected > 0)"),
                        ));
                    }
                    gain.push(mean / (white_reflectance * response));
                    variation.push(cv);
                }
                ("white board", gain, Some(variation))
            }
            (None, Some(exposure)) => ("exposure metadata", vec![exposure; ch], None),
            (None, None) if !radiometry_required => ("none", vec![1.0; ch], None),
            (None, None) => {
                return Err(Error::captures(
                    &name,
                    "no white board capture and no exposure metadata",
                    "a white board (rig `white` or --white) or the camera's `exposure` with \
                     --illuminant; a registration-only run (--output registered) needs \
                     neither",
                ))
            }
        };
        let responses: Vec<f64> = (0..ch)
            .map(|c| sensing.row(first_row + c).iter().sum())
            .collect();
        // The white board's shape across the frame, divided out pixel by pixel.
        let field = cam.white.as_ref().map(|white| {
            let means: Vec<f64> = (0..ch)
                .map(|c| gain[c] * white_reflectance * responses[c])
                .collect();
            flat_field(white, &means, saturation_level)
        });
        let (mut saturated, mut brighter, mut measured) = (0, 0, 0);
        let data: Vec<f32> = cam
            .capture
            .data
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                if v >= saturation_level {
                    saturated += 1;
                    f32::NAN
                } else if !v.is_finite() || field.as_ref().is_some_and(|f| f[i].is_nan()) {
                    // Not measured (outside a rectified frame), or a white board too
                    // dark here to divide by.
                    f32::NAN
                } else {
                    let shape = field.as_ref().map_or(1.0, |f| f64::from(f[i]));
                    let value = v as f64 / (gain[i % ch] * shape);
                    measured += 1;
                    // Brighter than a perfect white: not known without radiometry.
                    brighter += usize::from(method != "none" && value > responses[i % ch]);
                    value as f32
                }
            })
            .collect();
        views.push(NormalisedView {
            image: Image {
                width: captures.width,
                height: captures.height,
                channels: ch,
                data,
            },
        });
        records.push(CameraCalibration {
            name: cam.name.clone(),
            method,
            gain,
            white_variation: variation,
            saturated_values: saturated,
            brighter_than_white: brighter as f64 / measured.max(1) as f64,
        });
        first_row += ch;
    }
    Ok((views, records))
}

#[cfg(test)]
mod tests {
    use crate::register::fill_from_nearest;

    #[test]
    fn missing_values_take_the_nearest_value_of_their_row() {
        let nan = f32::NAN;
        let mut row = [nan, nan, 1.0, nan, nan, nan, 5.0, nan];
        fill_from_nearest(&mut row);
        assert_eq!(row, [1.0, 1.0, 1.0, 1.0, 1.0, 5.0, 5.0, 5.0]);
        let mut empty = [nan; 3];
        fill_from_nearest(&mut empty);
        assert_eq!(empty, [0.0; 3]);
    }
}
