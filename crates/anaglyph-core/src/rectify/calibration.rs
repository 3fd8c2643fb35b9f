//! A camera's calibration file, of either kind: a pose (OpenCV intrinsics, distortion,
//! R and t) or a homography onto the reference camera through a plane.
//!
//! In: a path (`.json`, `.yml`, `.yaml` FileStorage, or `.npy` for a homography). Out: a
//! [`Calibration`].

use super::camera_model::{
    CAMERA_MATRIX_NAMES, ROTATION_MATRIX_NAMES, ROTATION_VECTOR_NAMES, TRANSLATION_NAMES,
};
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
        // Every name CameraModel::from_file_storage reads a pose's parts under.
        let pose = CAMERA_MATRIX_NAMES
            .iter()
            .chain(&ROTATION_MATRIX_NAMES)
            .chain(&ROTATION_VECTOR_NAMES)
            .chain(&TRANSLATION_NAMES)
            .copied()
            .find(|k| storage.contains_key(*k));
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
            None if pose.is_none() => Err(Error::bad_field(
                &context,
                "the calibration",
                if storage.is_empty() {
                    "no numbers or matrices".to_string()
                } else {
                    format!(
                        "only {}",
                        storage.keys().cloned().collect::<Vec<_>>().join(", ")
                    )
                },
                "a plane calibration (homography or affine) or a pose (camera_matrix, \
                 rotation_matrix, translation_vector)",
            )),
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
        // 9 numbers row by row, in .npy (float32 too), JSON and YAML.
        let flat = ndarray::Array1::from_vec(shift.to_vec());
        ndarray_npy::write_npy(d.join("flat.npy"), &flat).unwrap();
        assert_eq!(plane(&d.join("flat.npy")), expected);
        ndarray_npy::write_npy(d.join("f32.npy"), &array.mapv(|v| v as f32)).unwrap();
        assert_eq!(plane(&d.join("f32.npy")), expected);
        std::fs::write(
            d.join("flat.json"),
            r#"{"homography": [1, 0, 13, 0, 1, -2.5, 0, 0, 1]}"#,
        )
        .unwrap();
        assert_eq!(plane(&d.join("flat.json")), expected);
        std::fs::write(
            d.join("flat.yml"),
            "homography: [1, 0, 13, 0, 1, -2.5, 0, 0, 1]\n",
        )
        .unwrap();
        assert_eq!(plane(&d.join("flat.yml")), expected);
        std::fs::write(
            d.join("rows.yml"),
            "homography: [[1, 0, 13], [0, 1, -2.5], [0, 0, 1]]\n",
        )
        .unwrap();
        assert_eq!(plane(&d.join("rows.yml")), expected);
        let four = ndarray::Array1::from_vec(vec![1.0, 0.0, 0.0, 1.0]);
        ndarray_npy::write_npy(d.join("four.npy"), &four).unwrap();
        let error = Calibration::load(&d.join("four.npy"))
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("four.npy") && error.contains("3x3"),
            "{error}"
        );
        let integers = ndarray::Array2::<i64>::eye(3);
        ndarray_npy::write_npy(d.join("int.npy"), &integers).unwrap();
        let error = Calibration::load(&d.join("int.npy"))
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("int.npy") && error.contains("i8") && error.contains("float64"),
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
            // A malformed map is reported as that map, with the shape found.
            (
                "bad.json",
                r#"{"homography": [[1, 0], [0, 1]]}"#,
                "homography is a 2x2 matrix",
            ),
            (
                "two.json",
                r#"{"homography": [[1, 0, 0], [0, 1, 0]]}"#,
                "under 'affine'",
            ),
            (
                "number.json",
                r#"{"homography": 3}"#,
                "homography is the number 3",
            ),
            (
                "short.json",
                r#"{"affine": [1, 0, 0, 1]}"#,
                "affine is a 1x4 matrix",
            ),
        ] {
            std::fs::write(d.join(name), text).unwrap();
            let error = Calibration::load(&d.join(name)).unwrap_err().to_string();
            assert!(error.contains(name) && error.contains(needle), "{error}");
        }
        // A file with neither map nor pose names what it holds and what was expected.
        std::fs::write(
            d.join("typo.json"),
            r#"{"homogrphy": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}"#,
        )
        .unwrap();
        let error = Calibration::load(&d.join("typo.json"))
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("only homogrphy") && error.contains("a plane calibration (homography"),
            "{error}"
        );
        // A partial pose is read as a pose (and needs its camera matrix).
        std::fs::write(
            d.join("pose.json"),
            r#"{"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}"#,
        )
        .unwrap();
        let error = Calibration::load(&d.join("pose.json"))
            .unwrap_err()
            .to_string();
        assert!(error.contains("camera_matrix (K) is absent"), "{error}");
    }
}
