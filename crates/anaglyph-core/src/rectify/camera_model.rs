//! One calibrated camera in OpenCV's model: intrinsics, lens distortion and the
//! world-to-camera pose, read from a FileStorage file and used to map rectified pixels back
//! into the camera's own image.

use super::file_storage::{read_file_storage, FileStorage, StoredValue};
use crate::scene::PinholeCamera;
use crate::{Error, Result};
use serde::Serialize;
use std::path::Path;

/// Largest deviation of `RᵀR` from the identity accepted for a rotation matrix.
const ROTATION_TOLERANCE: f64 = 1e-5;

/// A 3×3 matrix, row-major.
pub type Matrix3 = [[f64; 3]; 3];

/// A calibrated camera (OpenCV conventions: pixel centres at integer coordinates, x right,
/// y down, z along the optical axis).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CameraModel {
    /// `[fx s cx; 0 fy cy; 0 0 1]`.
    pub camera_matrix: Matrix3,
    /// k1, k2, p1, p2 [, k3 [, k4, k5, k6]] in OpenCV's order; empty for none.
    pub distortion: Vec<f64>,
    /// World to camera.
    pub rotation: Matrix3,
    /// World to camera (`x_cam = R x_world + t`), in the unit of the rig's baselines (mm).
    pub translation: [f64; 3],
    /// The image size the calibration was made at, when the file says.
    pub image_size: Option<(usize, usize)>,
}

fn matrix_entry<'a>(
    storage: &'a FileStorage,
    names: &[&'static str],
) -> Option<(&'static str, usize, usize, &'a [f64])> {
    names.iter().find_map(|&n| match storage.get(n) {
        Some(StoredValue::Matrix { rows, cols, data }) => Some((n, *rows, *cols, data.as_slice())),
        _ => None,
    })
}

fn number_entry(storage: &FileStorage, names: &[&str]) -> Option<f64> {
    names.iter().find_map(|&n| match storage.get(n) {
        Some(StoredValue::Number(v)) => Some(*v),
        _ => None,
    })
}

/// The rotation of a Rodrigues vector (axis × angle in radians).
pub fn rodrigues(r: [f64; 3]) -> Matrix3 {
    let theta = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    if theta < 1e-15 {
        return identity();
    }
    let k = r.map(|v| v / theta);
    let (s, c) = theta.sin_cos();
    let cross = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
    let mut m = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = (1.0 - c) * k[i] * k[j] + s * cross[i][j] + if i == j { c } else { 0.0 };
        }
    }
    m
}

pub fn identity() -> Matrix3 {
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
}

pub fn transpose(m: &Matrix3) -> Matrix3 {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[j][i]))
}

pub fn apply(m: &Matrix3, v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

/// The names a pose's parts are read under, OpenCV's first.
pub(super) const CAMERA_MATRIX_NAMES: [&str; 3] = ["camera_matrix", "cameraMatrix", "K"];
pub(super) const ROTATION_MATRIX_NAMES: [&str; 2] = ["rotation_matrix", "R"];
pub(super) const ROTATION_VECTOR_NAMES: [&str; 2] = ["rvec", "rotation_vector"];
pub(super) const TRANSLATION_NAMES: [&str; 4] = ["translation_vector", "T", "t", "tvec"];

impl CameraModel {
    /// Reads a FileStorage calibration (`.json`, `.yml`, `.yaml`).
    pub fn load(path: &Path) -> Result<Self> {
        let storage = read_file_storage(path)?;
        Self::from_file_storage(&storage, &path.display().to_string())
    }

    /// Builds the model from FileStorage entries. Accepted names: `camera_matrix` (`K`,
    /// `cameraMatrix`), `distortion_coefficients` (`D`, `dist_coeffs`, `distCoeffs`),
    /// `rotation_matrix` (`R`) or a Rodrigues `rvec` (`rotation_vector`), and
    /// `translation_vector` (`T`, `t`, `tvec`); `image_width` / `image_height` when present.
    pub fn from_file_storage(storage: &FileStorage, context: &str) -> Result<Self> {
        let bad = |field: &str, found: String, expected: &str| {
            Error::bad_field(context, field, found, expected)
        };
        let (name, rows, cols, k) = matrix_entry(storage, &CAMERA_MATRIX_NAMES)
            .ok_or_else(|| bad("camera_matrix (K)", "absent".into(), "a 3x3 matrix"))?;
        if (rows, cols) != (3, 3) {
            return Err(bad(name, format!("{rows}x{cols}"), "3x3"));
        }
        let camera_matrix = [[k[0], k[1], k[2]], [k[3], k[4], k[5]], [k[6], k[7], k[8]]];
        if !(k[0] > 0.0 && k[4] > 0.0) || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
            return Err(bad(
                name,
                format!("{k:?}"),
                "[fx s cx; 0 fy cy; 0 0 1] with fx, fy > 0",
            ));
        }
        let distortion = match matrix_entry(
            storage,
            &["distortion_coefficients", "dist_coeffs", "distCoeffs", "D"],
        ) {
            None => Vec::new(),
            Some((name, _, _, d)) => match d.len() {
                0 | 4 | 5 | 8 => d.to_vec(),
                n => {
                    return Err(bad(
                        name,
                        format!("{n} coefficients"),
                        "4, 5 or 8 (thin-prism and tilted models are not supported)",
                    ))
                }
            },
        };
        let rotation = match matrix_entry(storage, &ROTATION_MATRIX_NAMES) {
            Some((_, 3, 3, r)) => [[r[0], r[1], r[2]], [r[3], r[4], r[5]], [r[6], r[7], r[8]]],
            Some((_, 3, 1, r)) | Some((_, 1, 3, r)) => rodrigues([r[0], r[1], r[2]]),
            Some((name, rows, cols, _)) => {
                return Err(bad(
                    name,
                    format!("{rows}x{cols}"),
                    "a 3x3 matrix or a 3-vector",
                ))
            }
            None => match matrix_entry(storage, &ROTATION_VECTOR_NAMES) {
                Some((_, _, _, r)) if r.len() == 3 => rodrigues([r[0], r[1], r[2]]),
                Some((name, rows, cols, _)) => {
                    return Err(bad(name, format!("{rows}x{cols}"), "3x1"))
                }
                None => {
                    return Err(bad(
                        "rotation_matrix (R) or rvec",
                        "absent".into(),
                        "a 3x3 matrix or a 3-vector",
                    ))
                }
            },
        };
        check_rotation(&rotation).map_err(|found| bad("rotation", found, "a rotation matrix"))?;
        let translation = match matrix_entry(storage, &TRANSLATION_NAMES) {
            Some((_, _, _, t)) if t.len() == 3 => [t[0], t[1], t[2]],
            Some((name, rows, cols, _)) => return Err(bad(name, format!("{rows}x{cols}"), "3x1")),
            None => return Err(bad("translation_vector (T)", "absent".into(), "3x1")),
        };
        let image_size = Self::stated_image_size(storage);
        Ok(CameraModel {
            camera_matrix,
            distortion,
            rotation,
            translation,
            image_size,
        })
    }

    /// The image size a calibration file states it was made for (`image_width` and
    /// `image_height`, or `width` and `height`), where it states one.
    pub fn stated_image_size(storage: &FileStorage) -> Option<(usize, usize)> {
        let size = |names: &[&str]| {
            number_entry(storage, names)
                .filter(|v| *v >= 1.0 && v.fract() == 0.0)
                .map(|v| v as usize)
        };
        size(&["image_width", "width"]).zip(size(&["image_height", "height"]))
    }

    /// The model of a simulated camera (no distortion; world = the ideal camera r0c0).
    pub fn from_pinhole(camera: &PinholeCamera) -> Self {
        let f = camera.focal_px;
        let r = &camera.rotation;
        // The simulator stores camera-to-world rows; world-to-camera is the transpose.
        let rotation = [
            [r[0].x, r[1].x, r[2].x],
            [r[0].y, r[1].y, r[2].y],
            [r[0].z, r[1].z, r[2].z],
        ];
        let c = [camera.centre.x, camera.centre.y, camera.centre.z];
        let rc = apply(&rotation, c);
        CameraModel {
            camera_matrix: [
                [
                    f,
                    0.0,
                    0.5 * camera.width as f64 - 0.5 + camera.principal_offset_px[0],
                ],
                [
                    0.0,
                    f,
                    0.5 * camera.height as f64 - 0.5 + camera.principal_offset_px[1],
                ],
                [0.0, 0.0, 1.0],
            ],
            distortion: vec![0.0; 5],
            rotation,
            translation: rc.map(|v| -v),
            image_size: Some((camera.width, camera.height)),
        }
    }

    /// The model in OpenCV's FileStorage JSON layout.
    pub fn to_file_storage_json(&self) -> String {
        let matrix = |rows: usize, cols: usize, data: Vec<f64>| serde_json::json!({ "type_id": "opencv-matrix", "rows": rows, "cols": cols, "dt": "d", "data": data });
        let flat = |m: &Matrix3| m.iter().flatten().copied().collect::<Vec<f64>>();
        let mut value = serde_json::json!({
            "camera_matrix": matrix(3, 3, flat(&self.camera_matrix)),
            "distortion_coefficients": matrix(self.distortion.len(), 1, self.distortion.clone()),
            "rotation_matrix": matrix(3, 3, flat(&self.rotation)),
            "translation_vector": matrix(3, 1, self.translation.to_vec()),
        });
        if let Some((w, h)) = self.image_size {
            value["image_width"] = w.into();
            value["image_height"] = h.into();
        }
        serde_json::to_string_pretty(&value).unwrap_or_default()
    }

    /// The optical centre in world coordinates, `−Rᵀt`.
    pub fn centre(&self) -> [f64; 3] {
        apply(&transpose(&self.rotation), self.translation).map(|v| -v)
    }

    /// Camera axis `k` (0: x, 1: y, 2: optical axis) in world coordinates.
    pub fn axis(&self, k: usize) -> [f64; 3] {
        self.rotation[k]
    }

    /// Mean focal length, pixels.
    pub fn focal_px(&self) -> f64 {
        0.5 * (self.camera_matrix[0][0] + self.camera_matrix[1][1])
    }

    /// Pixel position (OpenCV coordinates) at which this camera sees the world direction
    /// `direction` (a point at infinity; for a camera of the array, any point far compared
    /// with its offset from the grid), lens distortion included; None behind the camera.
    pub fn project_direction(&self, direction: [f64; 3]) -> Option<(f64, f64)> {
        let [x, y, z] = apply(&self.rotation, direction);
        if !(z > 0.0) {
            return None;
        }
        let (x, y) = self.distort(x / z, y / z);
        let k = &self.camera_matrix;
        Some((k[0][0] * x + k[0][1] * y + k[0][2], k[1][1] * y + k[1][2]))
    }

    /// OpenCV's distortion of normalised coordinates.
    fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let d = &self.distortion;
        if d.is_empty() {
            return (x, y);
        }
        let c = |i: usize| d.get(i).copied().unwrap_or(0.0);
        let r2 = x * x + y * y;
        let radial = (1.0 + r2 * (c(0) + r2 * (c(1) + r2 * c(4))))
            / (1.0 + r2 * (c(5) + r2 * (c(6) + r2 * c(7))));
        let (p1, p2) = (c(2), c(3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }
}

fn check_rotation(r: &Matrix3) -> std::result::Result<(), String> {
    let mut worst = 0.0f64;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| r[k][i] * r[k][j]).sum();
            worst = worst.max((dot - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
        - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
        + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    if !(worst < ROTATION_TOLERANCE) || !(det > 0.0) {
        return Err(format!("|RᵀR − I| = {worst:.2e}, det = {det:.4}"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{rotation, Vec3};

    #[test]
    fn a_simulated_camera_round_trips_through_file_storage_and_projects_as_it_renders() {
        let camera = PinholeCamera {
            centre: Vec3::new(31.0, 49.0, 1.5),
            rotation: rotation([0.4, -0.6, 0.3]),
            focal_px: 812.0,
            width: 320,
            height: 240,
            principal_offset_px: [3.0, -2.0],
        };
        let model = CameraModel::from_pinhole(&camera);
        let text = model.to_file_storage_json();
        let storage = super::super::file_storage::parse_json(&text, "cam.json").unwrap();
        let back = CameraModel::from_file_storage(&storage, "cam.json").unwrap();
        // JSON keeps 17 significant digits: equal to the last bit or two.
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12);
        let flat = |m: &Matrix3| m.iter().flatten().copied().collect::<Vec<f64>>();
        assert!(close(&flat(&back.rotation), &flat(&model.rotation)));
        assert!(close(&back.translation, &model.translation));
        assert_eq!(back.camera_matrix, model.camera_matrix);
        assert_eq!(back.image_size, model.image_size);
        let c = back.centre();
        assert!(
            (c[0] - 31.0).abs() < 1e-9 && (c[1] - 49.0).abs() < 1e-9 && (c[2] - 1.5).abs() < 1e-9
        );
        // A far point lands where the renderer's projection puts it (its pixel centres sit
        // at +0.5, OpenCV's at integers).
        let p = Vec3::new(400.0, -250.0, 90_000.0);
        let (u, v, _) = camera.project(p).unwrap();
        let d = p - camera.centre;
        let (x, y) = back.project_direction([d.x, d.y, d.z]).unwrap();
        assert!((x - (u - 0.5)).abs() < 1e-9 && (y - (v - 0.5)).abs() < 1e-9);

        let mut broken = storage.clone();
        broken.remove("translation_vector");
        let err = CameraModel::from_file_storage(&broken, "cam.json").unwrap_err();
        assert!(
            matches!(&err, Error::BadField { field, found, .. }
                if field == "translation_vector (T)" && found == "absent"),
            "{err}"
        );
    }

    #[test]
    fn rodrigues_vectors_and_bad_rotations() {
        let r = rodrigues([0.0, 0.0, std::f64::consts::FRAC_PI_2]);
        let v = apply(&r, [1.0, 0.0, 0.0]);
        assert!((v[0]).abs() < 1e-12 && (v[1] - 1.0).abs() < 1e-12);
        assert!(check_rotation(&r).is_ok());
        let mut scaled = identity();
        scaled[0][0] = 1.01;
        assert!(check_rotation(&scaled)
            .unwrap_err()
            .contains("|RᵀR − I| = 2.01e-2"));
        let mut mirrored = identity();
        mirrored[2][2] = -1.0;
        assert!(check_rotation(&mirrored).unwrap_err().contains("det = -1"));
    }

    #[test]
    fn radial_distortion_pushes_points_outwards_as_opencv_models_it() {
        let mut model = CameraModel::from_pinhole(&PinholeCamera {
            centre: Vec3::new(0.0, 0.0, 0.0),
            rotation: rotation([0.0; 3]),
            focal_px: 500.0,
            width: 640,
            height: 480,
            principal_offset_px: [0.0; 2],
        });
        model.distortion = vec![0.1, 0.0, 0.0, 0.0, 0.0];
        // x' = 0.4 at r² = 0.16: x'' = 0.4 (1 + 0.016) = 0.4064 → 500 · 0.4064 + 319.5.
        let (x, y) = model.project_direction([0.4, 0.0, 1.0]).unwrap();
        assert!((x - (203.2 + 319.5)).abs() < 1e-9 && (y - 239.5).abs() < 1e-9);
        model.distortion = vec![0.0, 0.0, 0.01, 0.0];
        // Tangential p1: y'' = y' + p1 (r² + 2y'²) at (0, 0.2): 0.2 + 0.01 · 0.12.
        let (_, y) = model.project_direction([0.0, 0.2, 1.0]).unwrap();
        assert!((y - (500.0 * 0.2012 + 239.5)).abs() < 1e-9);
    }
}
