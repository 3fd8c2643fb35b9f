//! Rectification, the first geometric stage of reconstruction: the captures of an array
//! whose cameras are not exactly parallel are resampled onto one common image plane
//! (Kang et al. 2008 style), so that registration can search along rows and columns.
//!
//! ```text
//! calibrations (OpenCV FileStorage: K, distortion, R, t)
//!   -> fit the optical centres to the rig's rows × cols grid (O + c·u + r·v)
//!   -> common orientation: x along u, y along v (orthogonalised), z = x × y
//!   -> common intrinsics: mean focal length, centred principal point, no distortion
//!   -> per camera and rectified pixel: world direction -> distorted source position,
//!      one bicubic resampling (outside the source frame: NaN, i.e. not measured)
//! ```
//!
//! Rotations, intrinsics and lens distortion are removed exactly. An optical centre off the
//! fitted grid cannot be removed by any image warp (its parallax depends on depth), so it is
//! measured and reported ([`CameraRectification::grid_offset_mm`]).
//! An array calibrated to a plane instead gives each camera a [`Homography`] onto the
//! reference camera ([`Rectification::through_plane`]): the plane's points land at zero
//! disparity, and the rest keep their parallax along the baselines (signed).
//!
//! In: a [`Calibration`] per camera. Out: a [`Rectification`] that resamples each capture;
//! the rest of the pipeline then works on the rectified array.

mod calibration;
mod camera_model;
mod file_storage;
mod homography;

pub use calibration::Calibration;
pub use camera_model::{apply, identity, rodrigues, transpose, CameraModel, Matrix3};
pub use file_storage::{parse_json, parse_yaml, read_file_storage, FileStorage, StoredValue};
pub use homography::Homography;

use crate::interpolation::catmull_rom_weights;
use crate::io::LinearImage;
use crate::{Error, Result};
use faer::linalg::solvers::DenseSolveCore;
use rayon::prelude::*;
use serde::Serialize;

/// A camera whose map moves no pixel by more than this is left as it is (no resampling).
pub const IDENTITY_TOLERANCE_PX: f64 = 1e-3;
/// Optical centres further than this fraction of the baseline from the fitted grid raise a
/// warning: their parallax error is that fraction of the disparity.
pub const GRID_OFFSET_WARNING: f64 = 0.01;
/// Smallest cosine between the cameras' mean optical axis and the normal of their grid.
const MIN_AXIS_COSINE: f64 = 0.5;
/// Spacing of the pixels at which a map's largest correction is measured.
const CORRECTION_SAMPLING_PX: usize = 8;

/// How a camera's rectified pixels are found in its capture.
#[derive(Debug, Clone)]
pub enum CameraMap {
    /// Through the calibrated pose and lens onto the common image plane.
    Pose(CameraModel),
    /// Through the plane onto the reference camera: `from_reference` maps a rectified
    /// (reference) pixel to the capture.
    Plane { from_reference: Homography },
}

/// What rectification does to one camera.
#[derive(Debug, Clone, Serialize)]
pub struct CameraRectification {
    /// The camera's name (see [`crate::rig::Camera::name`]).
    pub name: String,
    /// Largest displacement of the rectifying map, pixels.
    pub max_correction_px: f64,
    /// Distance of the optical centre from where the fitted layout puts it, in the
    /// calibration's unit (mm); None for homographies, which do not tell where the camera
    /// is.
    pub grid_offset_mm: Option<f64>,
    #[serde(skip)]
    pub map: CameraMap,
}

/// The common camera that calibrated poses are rectified to.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct CommonCamera {
    /// Focal length of the rectified cameras, pixels.
    pub focal_px: f64,
    /// Principal point of the rectified cameras (OpenCV pixel coordinates).
    pub principal_point: [f64; 2],
    /// World to rectified camera: rows are the array's x, y and viewing axes.
    pub orientation: Matrix3,
    /// Calibrated distance per millimetre of the rig's layout along the array's x and y
    /// axes: 1 where the calibration agrees with the rig (0 along an axis the array does
    /// not extend in).
    pub scale: [f64; 2],
}

/// The common image plane of an array and the map of every camera onto it.
#[derive(Debug, Clone, Serialize)]
pub struct Rectification {
    pub width: usize,
    pub height: usize,
    /// The common camera of pose calibrations; None: homographies through a plane onto
    /// the reference camera's image.
    pub common: Option<CommonCamera>,
    pub cameras: Vec<CameraRectification>,
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

fn normalised(v: [f64; 3]) -> [f64; 3] {
    let n = norm(v);
    v.map(|x| x / n)
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Least-squares fit of optical centres `P ≈ O + x·u + y·v` to the cameras' positions
/// (x, y) in the rig's layout (mm); returns (O, u, v), u or v zero when the array does not
/// extend along x or y.
fn fit_layout(cameras: &[([f64; 2], [f64; 3])]) -> Result<[[f64; 3]; 3]> {
    let extends = |axis: usize| {
        let first = cameras.first().map_or(0.0, |c| c.0[axis]);
        cameras.iter().any(|c| (c.0[axis] - first).abs() > 1e-9)
    };
    let (along_x, along_y) = (extends(0), extends(1));
    let regressors = |[x, y]: [f64; 2]| {
        let mut r = vec![1.0];
        if along_x {
            r.push(x);
        }
        if along_y {
            r.push(y);
        }
        r
    };
    let k = 1 + usize::from(along_x) + usize::from(along_y);
    let mut normal = faer::Mat::<f64>::zeros(k, k);
    let mut rhs = vec![[0.0; 3]; k];
    for &(position, p) in cameras {
        let x = regressors(position);
        for i in 0..k {
            for j in 0..k {
                normal[(i, j)] += x[i] * x[j];
            }
            for d in 0..3 {
                rhs[i][d] += x[i] * p[d];
            }
        }
    }
    let inverse = normal.partial_piv_lu().inverse();
    let mut coefficients = vec![[0.0; 3]; k];
    for i in 0..k {
        for d in 0..3 {
            coefficients[i][d] = (0..k).map(|j| inverse[(i, j)] * rhs[j][d]).sum();
        }
    }
    if coefficients.iter().flatten().any(|v| !v.is_finite()) {
        return Err(Error::LinearAlgebra {
            op: "rectification: fitting the camera layout".into(),
            message: "the cameras' positions do not determine the array's plane".into(),
        });
    }
    let mut it = coefficients.into_iter();
    let origin = it.next().unwrap_or([0.0; 3]);
    let u = if along_x { it.next() } else { None };
    let v = if along_y { it.next() } else { None };
    Ok([origin, u.unwrap_or([0.0; 3]), v.unwrap_or([0.0; 3])])
}

/// At least one camera, of at least 2×2 pixels.
fn check_array_size(cameras: usize, width: usize, height: usize) -> Result<()> {
    if cameras == 0 || width < 2 || height < 2 {
        return Err(Error::raster(
            "rectification",
            format!("{cameras} cameras of {width}x{height} px"),
            "at least one camera of at least 2x2 px",
        ));
    }
    Ok(())
}

impl Rectification {
    /// Plans the rectification of cameras given as (name, position in the rig's layout in
    /// mm, model), all of `width × height` pixels.
    pub fn plan(
        cameras: Vec<(String, [f64; 2], CameraModel)>,
        width: usize,
        height: usize,
    ) -> Result<Self> {
        check_array_size(cameras.len(), width, height)?;
        for (name, _, model) in &cameras {
            if let Some((w, h)) = model.image_size {
                if (w, h) != (width, height) {
                    return Err(Error::calibration(
                        format!("calibration of camera {name}"),
                        format!("made for {w}x{h} px images"),
                        format!("the captures' {width}x{height}"),
                    ));
                }
            }
        }
        let centres: Vec<([f64; 2], [f64; 3])> =
            cameras.iter().map(|(_, at, m)| (*at, m.centre())).collect();
        let [origin, u, v] = fit_layout(&centres)?;
        let mean_axis = |k: usize| {
            normalised(cameras.iter().fold([0.0; 3], |acc, (_, _, m)| {
                let a = m.axis(k);
                [acc[0] + a[0], acc[1] + a[1], acc[2] + a[2]]
            }))
        };
        let (has_u, has_v) = (norm(u) > 0.0, norm(v) > 0.0);
        let (x_axis, y_axis) = if has_u {
            let x = normalised(u);
            let y0 = if has_v { normalised(v) } else { mean_axis(1) };
            let d = dot(y0, x);
            (
                x,
                normalised([y0[0] - d * x[0], y0[1] - d * x[1], y0[2] - d * x[2]]),
            )
        } else {
            let y = if has_v { normalised(v) } else { mean_axis(1) };
            let x0 = mean_axis(0);
            let d = dot(x0, y);
            (
                normalised([x0[0] - d * y[0], x0[1] - d * y[1], x0[2] - d * y[2]]),
                y,
            )
        };
        let z_axis = cross(x_axis, y_axis);
        let cosine = dot(z_axis, mean_axis(2));
        if !(cosine > MIN_AXIS_COSINE) {
            return Err(Error::unusable(
                "rectification",
                format!(
                    "the cameras look {:.0}° away from the normal of their layout: the rig's \
                     camera positions do not match the calibrated ones (swapped or mirrored?)",
                    cosine.clamp(-1.0, 1.0).acos().to_degrees()
                ),
            ));
        }
        let focal_px =
            cameras.iter().map(|(_, _, m)| m.focal_px()).sum::<f64>() / cameras.len() as f64;
        let plan = Rectification {
            width,
            height,
            common: Some(CommonCamera {
                focal_px,
                principal_point: [0.5 * width as f64 - 0.5, 0.5 * height as f64 - 0.5],
                orientation: [x_axis, y_axis, z_axis],
                scale: [norm(u), norm(v)],
            }),
            cameras: cameras
                .into_iter()
                .map(|(name, [x, y], model)| {
                    let p = model.centre();
                    let g = [0, 1, 2].map(|d| origin[d] + x * u[d] + y * v[d]);
                    CameraRectification {
                        name,
                        max_correction_px: 0.0,
                        grid_offset_mm: Some(norm([p[0] - g[0], p[1] - g[1], p[2] - g[2]])),
                        map: CameraMap::Pose(model),
                    }
                })
                .collect(),
        };
        Ok(plan.with_corrections())
    }

    /// Plans the rectification of an array calibrated to a plane: cameras given as (name,
    /// homography onto the reference camera), all of `width × height` pixels. Each
    /// homography is checked on the frame ([`Homography::check_frame`]).
    pub fn through_plane(
        cameras: Vec<(String, Homography)>,
        width: usize,
        height: usize,
    ) -> Result<Self> {
        check_array_size(cameras.len(), width, height)?;
        for (name, h) in &cameras {
            h.check_frame(width, height, &format!("homography of camera {name}"))?;
        }
        let plan = Rectification {
            width,
            height,
            common: None,
            cameras: cameras
                .into_iter()
                .map(|(name, h)| CameraRectification {
                    name,
                    max_correction_px: 0.0,
                    grid_offset_mm: None,
                    map: CameraMap::Plane {
                        from_reference: h.inverse(),
                    },
                })
                .collect(),
        };
        Ok(plan.with_corrections())
    }

    /// The plan with each camera's largest correction measured.
    fn with_corrections(mut self) -> Self {
        let (width, height) = (self.width, self.height);
        for k in 0..self.cameras.len() {
            let mut worst = 0.0f64;
            let xs = (0..width)
                .step_by(CORRECTION_SAMPLING_PX)
                .chain([width - 1]);
            for x in xs {
                for y in (0..height)
                    .step_by(CORRECTION_SAMPLING_PX)
                    .chain([height - 1])
                {
                    worst = worst.max(match self.source_position(k, x as f64, y as f64) {
                        Some((sx, sy)) => (sx - x as f64).hypot(sy - y as f64),
                        None => f64::INFINITY,
                    });
                }
            }
            self.cameras[k].max_correction_px = worst;
        }
        self
    }

    /// Where rectified pixel (x, y) of camera `camera` lies in its capture (OpenCV pixel
    /// coordinates, i.e. array indices); None if the camera cannot see that direction.
    pub fn source_position(&self, camera: usize, x: f64, y: f64) -> Option<(f64, f64)> {
        match (&self.cameras[camera].map, &self.common) {
            (CameraMap::Plane { from_reference }, _) => from_reference.apply(x, y),
            (CameraMap::Pose(model), Some(common)) => {
                let f = common.focal_px;
                let local = [
                    (x - common.principal_point[0]) / f,
                    (y - common.principal_point[1]) / f,
                    1.0,
                ];
                let world = apply(&transpose(&common.orientation), local);
                model.project_direction(world)
            }
            (CameraMap::Pose(_), None) => None,
        }
    }

    /// Largest distance of an optical centre from where the fitted layout puts it, in the
    /// calibration's unit (0 for homographies).
    pub fn worst_grid_offset_mm(&self) -> f64 {
        self.cameras
            .iter()
            .filter_map(|c| c.grid_offset_mm)
            .fold(0.0, f64::max)
    }

    /// Resamples capture `image` of camera `camera` onto the common plane (bicubic).
    /// Rectified pixels outside the source frame are NaN; a value interpolated from a tap
    /// at or above `saturation` takes that tap's value, so it stays marked saturated.
    /// A camera whose map is the identity is returned unchanged.
    pub fn resample(
        &self,
        camera: usize,
        image: &LinearImage,
        saturation: f32,
    ) -> Result<LinearImage> {
        let (w, h, ch) = (self.width, self.height, image.channels);
        let cam = self.cameras.get(camera).ok_or_else(|| Error::NotFound {
            what: "camera index".into(),
            name: camera.to_string(),
            available: format!("0 to {}", self.cameras.len().saturating_sub(1)),
        })?;
        if (image.width, image.height) != (w, h) {
            return Err(Error::Shape {
                op: format!("rectifying camera {}", cam.name),
                got: vec![image.width, image.height],
                expected: vec![w, h],
            });
        }
        if cam.max_correction_px < IDENTITY_TOLERANCE_PX {
            return Ok(image.clone());
        }
        let mut data = vec![0.0f32; w * h * ch];
        data.par_chunks_mut(w * ch)
            .enumerate()
            .for_each(|(y, row)| {
                for x in 0..w {
                    let out = &mut row[x * ch..(x + 1) * ch];
                    let inside =
                        self.source_position(camera, x as f64, y as f64)
                            .filter(|&(sx, sy)| {
                                (-0.5..=w as f64 - 0.5).contains(&sx)
                                    && (-0.5..=h as f64 - 0.5).contains(&sy)
                            });
                    let Some((sx, sy)) = inside else {
                        out.fill(f32::NAN);
                        continue;
                    };
                    let (fx, fy) = (sx.floor(), sy.floor());
                    let (wx, wy) = (catmull_rom_weights(sx - fx), catmull_rom_weights(sy - fy));
                    let tap = |base: f64, i: usize, size: usize| {
                        (base as isize + i as isize - 1).clamp(0, size as isize - 1) as usize
                    };
                    for (c, value) in out.iter_mut().enumerate() {
                        let (mut sum, mut flagged) = (0.0f64, None::<f32>);
                        for j in 0..4 {
                            let row_start = tap(fy, j, h) * w;
                            for i in 0..4 {
                                let weight = wx[i] * wy[j];
                                if weight == 0.0 {
                                    continue;
                                }
                                let v = image.data[(row_start + tap(fx, i, w)) * ch + c];
                                if !(v < saturation) {
                                    flagged = Some(match flagged {
                                        Some(f) if f.is_nan() => f,
                                        Some(f) => {
                                            if v.is_nan() {
                                                v
                                            } else {
                                                f.max(v)
                                            }
                                        }
                                        None => v,
                                    });
                                }
                                sum += weight * v as f64;
                            }
                        }
                        *value = flagged.unwrap_or(sum.max(0.0) as f32);
                    }
                }
            });
        Ok(LinearImage {
            width: w,
            height: h,
            channels: ch,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{rotation, PinholeCamera, Vec3};

    fn array(jitter_deg: f64, offset_mm: f64) -> Vec<(String, [f64; 2], CameraModel)> {
        (0..8)
            .map(|i| {
                let (r, c) = (i / 4, i % 4);
                let at = [c as f64 * 30.0, r as f64 * 50.0];
                let mut camera = PinholeCamera::at_position(at, 500.0, (160, 120));
                let s = (i as f64 * 1.7).sin();
                camera.rotation = rotation([jitter_deg * s, -jitter_deg * s * 0.5, jitter_deg]);
                camera.centre = camera.centre + Vec3::new(0.0, 0.0, offset_mm * s);
                (format!("r{r}c{c}"), at, CameraModel::from_pinhole(&camera))
            })
            .collect()
    }

    #[test]
    fn a_parallel_array_maps_to_itself() {
        let plan = Rectification::plan(array(0.0, 0.0), 160, 120).unwrap();
        let common = plan.common.unwrap();
        assert!((common.focal_px - 500.0).abs() < 1e-9);
        assert!((common.scale[0] - 1.0).abs() < 1e-9 && (common.scale[1] - 1.0).abs() < 1e-9);
        for (k, cam) in plan.cameras.iter().enumerate() {
            assert!(
                cam.max_correction_px < 1e-9,
                "{k}: {}",
                cam.max_correction_px
            );
            assert!(cam.grid_offset_mm.unwrap() < 1e-9);
        }
        let image = LinearImage {
            width: 160,
            height: 120,
            channels: 1,
            data: (0..160 * 120).map(|i| (i % 97) as f32 / 97.0).collect(),
        };
        assert_eq!(plan.resample(3, &image, 1.0).unwrap().data, image.data);
    }

    #[test]
    fn rotated_cameras_map_through_their_homography_and_offsets_are_reported() {
        let cameras = array(0.8, 0.0);
        let plan = Rectification::plan(cameras.clone(), 160, 120).unwrap();
        // Pure rotations about the optical centres: the ideal frame is recovered, and the map
        // is K R K⁻¹ of each camera.
        for (k, (_, _, model)) in cameras.iter().enumerate() {
            let (x, y) = (37.0, 91.0);
            let d = [(x - 79.5) / 500.0, (y - 59.5) / 500.0, 1.0];
            let p = apply(&model.rotation, d);
            let want = (500.0 * p[0] / p[2] + 79.5, 500.0 * p[1] / p[2] + 59.5);
            let (sx, sy) = plan.source_position(k, x, y).unwrap();
            assert!((sx - want.0).abs() < 1e-9 && (sy - want.1).abs() < 1e-9);
            assert!(plan.cameras[k].max_correction_px > 1.0);
        }
        assert!(plan.worst_grid_offset_mm() < 1e-9);
        let moved = Rectification::plan(array(0.0, 2.0), 160, 120).unwrap();
        let worst = moved.worst_grid_offset_mm();
        assert!(worst > 1.0 && worst < 2.0, "{worst}");
    }

    #[test]
    fn bad_layouts_and_sizes_are_refused() {
        let mut mirrored = array(0.0, 0.0);
        for (_, at, _) in &mut mirrored {
            at[1] = 50.0 - at[1]; // rows swapped: the layout's normal points backwards
        }
        let err = Rectification::plan(mirrored, 160, 120)
            .unwrap_err()
            .to_string();
        assert!(err.contains("180°") && err.contains("swapped"), "{err}");
        let err = Rectification::plan(array(0.0, 0.0), 320, 240)
            .unwrap_err()
            .to_string();
        assert!(err.contains("160x120") && err.contains("320x240"), "{err}");
    }

    #[test]
    fn samples_outside_the_frame_are_not_measured_and_saturation_survives() {
        let plan = Rectification::plan(array(2.0, 0.0), 160, 120).unwrap();
        let mut image = LinearImage {
            width: 160,
            height: 120,
            channels: 1,
            data: vec![0.5; 160 * 120],
        };
        image.data[60 * 160 + 80] = 1.0;
        let out = plan.resample(0, &image, 0.999).unwrap();
        let nan = out.data.iter().filter(|v| v.is_nan()).count();
        assert!(nan > 0 && nan < out.data.len() / 4, "{nan}");
        let saturated = out.data.iter().filter(|&&v| v >= 0.999).count();
        assert!((4..=16).contains(&saturated), "{saturated}");
        // A flat field stays flat (the weights sum to one).
        assert!(out
            .data
            .iter()
            .filter(|v| v.is_finite() && **v < 0.999)
            .all(|v| (v - 0.5).abs() < 1e-6));
    }
}
