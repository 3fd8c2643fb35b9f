//! A camera's calibration file, of either kind: a pose (OpenCV intrinsics, distortion,
//! R and t) or a homography onto the reference camera through a plane.
//!
//! In: a path (`.json`, `.yml`, `.yaml` FileStorage, or `.npy` for a homography). Out: a
//! [`Calibration`].

use super::file_storage::read_file_storage;
use super::{CameraModel, Homography};
use crate::{Error, Result};
use std::path::Path;

/// What a camera's calibration file says.
#[derive(Debug, Clone)]
pub enum Calibration {
    Pose(CameraModel),
    /// A map onto the reference camera through a plane, and the image size its file
    /// states it was made for (`image_width`, `image_height`), where it does.
    Plane {
        homography: Homography,
        image_size: Option<(usize, usize)>,
    },
}

impl Calibration {
    /// Reads a calibration file: `.npy` holds a homography (3×3) or affine map (2×3); a
    /// FileStorage file holding `homography` or `affine` is a plane calibration, any other
    /// a pose ([`CameraModel::from_file_storage`]).
    pub fn load(path: &Path) -> Result<Self> {
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("npy"))
        {
            return Homography::read_npy(path).map(|homography| Calibration::Plane {
                homography,
                image_size: None,
            });
        }
        let storage = read_file_storage(path)?;
        let context = path.display().to_string();
        let plane = ["homography", "affine"].map(|k| storage.contains_key(k));
        let pose = ["camera_matrix", "rotation_matrix", "translation_vector"]
            .into_iter()
            .find(|k| storage.contains_key(*k));
        if plane[0] && plane[1] {
            return Err(Error::bad_field(
                &context,
                "homography and affine",
                "both",
                "one map onto the reference: a homography or an affine map",
            ));
        }
        if let (true, Some(pose)) = (plane[0] || plane[1], pose) {
            return Err(Error::bad_field(
                &context,
                format!(
                    "{} and {pose}",
                    if plane[0] { "homography" } else { "affine" }
                ),
                "both",
                "a plane calibration (homography or affine) or a pose (camera_matrix, \
                 rotation_matrix, translation_vector), not both",
            ));
        }
        match Homography::from_stored(storage.get("homography"), storage.get("affine"), &context)? {
            Some(homography) => Ok(Calibration::Plane {
                homography,
                image_size: CameraModel::stated_image_size(&storage),
            }),
            None => CameraModel::from_file_storage(&storage, &context).map(Calibration::Pose),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(path: &Path) -> Homography {
        match Calibration::load(path).unwrap() {
            Calibration::Plane { homography, .. } => homography,
            Calibration::Pose(_) => panic!("{}: read as a pose", path.display()),
        }
    }

    #[test]
    fn homographies_load_from_json_rows_file_storage_affine_and_npy() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let shift = [1.0, 0.0, 13.0, 0.0, 1.0, -2.5, 0.0, 0.0, 1.0];
        let expected = Homography::new(&shift, "test").unwrap();
        std::fs::write(
            d.join("rows.json"),
            r#"{"homography": [[1, 0, 13], [0, 1, -2.5], [0, 0, 1]]}"#,
        )
        .unwrap();
        assert_eq!(plane(&d.join("rows.json")), expected);
        std::fs::write(
            d.join("cv.yml"),
            "%YAML:1.0\n---\nhomography: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   \
             data: [ 2., 0., 26., 0., 2., -5., 0., 0., 2. ]\n",
        )
        .unwrap();
        assert_eq!(plane(&d.join("cv.yml")), expected);
        std::fs::write(
            d.join("affine.json"),
            r#"{"affine": [[1, 0, 13], [0, 1, -2.5]]}"#,
        )
        .unwrap();
        assert_eq!(plane(&d.join("affine.json")), expected);
        let array = ndarray::Array2::from_shape_vec((3, 3), shift.to_vec()).unwrap();
        ndarray_npy::write_npy(d.join("h.npy"), &array).unwrap();
        assert_eq!(plane(&d.join("h.npy")), expected);
        let flat = ndarray::Array1::from_vec(shift.to_vec());
        ndarray_npy::write_npy(d.join("flat.npy"), &flat).unwrap();
        let error = Calibration::load(&d.join("flat.npy"))
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("flat.npy") && error.contains("3x3"),
            "{error}"
        );
        std::fs::write(d.join("bare.json"), "[[1, 0, 13], [0, 1, -2.5], [0, 0, 1]]").unwrap();
        assert_eq!(plane(&d.join("bare.json")), expected);
        std::fs::write(d.join("bare_affine.json"), "[[1, 0, 13], [0, 1, -2.5]]").unwrap();
        assert_eq!(plane(&d.join("bare_affine.json")), expected);
        for (name, text, needle) in [
            ("bare4.json", "[[1, 0, 0, 0]]", "1 rows"),
            (
                "both.json",
                r#"{"homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "affine": [[1, 0, 0], [0, 1, 0]]}"#,
                "homography and affine",
            ),
            (
                "mixed.json",
                r#"{"homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "camera_matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}"#,
                "homography and camera_matrix",
            ),
        ] {
            std::fs::write(d.join(name), text).unwrap();
            let error = Calibration::load(&d.join(name)).unwrap_err().to_string();
            assert!(error.contains(name) && error.contains(needle), "{error}");
        }
        std::fs::write(d.join("bad.json"), r#"{"homography": [[1, 0], [0, 1]]}"#).unwrap();
        let error = Calibration::load(&d.join("bad.json"))
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("bad.json") && error.contains("homography"),
            "{error}"
        );
        // A file with neither is read as a pose (and needs its camera matrix).
        std::fs::write(d.join("pose.json"), r#"{"image_width": 640}"#).unwrap();
        let error = Calibration::load(&d.join("pose.json"))
            .unwrap_err()
            .to_string();
        assert!(error.contains("camera_matrix"), "{error}");
    }
}
