//! Plane homographies: how an array calibrated to a plane maps each camera onto its
//! reference camera. After the map, points on the plane have zero disparity; nearer and
//! farther points keep a parallax along the baseline.
//!
//! In: a 3×3 homography or a 2×3 affine map (camera pixel → reference pixel, OpenCV pixel
//! coordinates), from a FileStorage file (`homography` or `affine`), a JSON file with a
//! plain `homography` / `affine` array of rows, or `.npy`; or point pairs to fit one to
//! (normalised DLT). Out: a checked [`Homography`] that rectification resamples with.

use super::file_storage::StoredValue;
use crate::{Error, Result};
use faer::linalg::solvers::Solve;
use std::path::Path;

/// The map of a camera's pixels onto the reference camera's: `(x', y', w) = H (x, y, 1)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Homography {
    /// Row-major, scaled so that `h[2][2] = 1` where it is not 0.
    pub h: [[f64; 3]; 3],
}

/// Smallest ratio of the Jacobian determinant's extremes over the frame: a map whose
/// local area scale varies more than this folds or nearly folds the image.
const MIN_AREA_RATIO: f64 = 0.05;
/// Largest local area scale (and smallest, its inverse) a map between two cameras of one
/// array may have: a factor of 4 in focal length. Beyond it the map is a wrong file or a
/// wrongly scaled matrix (a camera collapsing to a point).
const MAX_AREA_SCALE: f64 = 16.0;

impl Homography {
    pub const IDENTITY: Homography = Homography {
        h: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    };

    /// A homography from its 9 row-major values (finite, invertible).
    pub fn new(values: &[f64], context: &str) -> Result<Self> {
        let bad = |found: String| {
            Error::bad_field(
                context,
                "homography",
                found,
                "9 finite values of an invertible 3x3 matrix",
            )
        };
        if values.len() != 9 || values.iter().any(|v| !v.is_finite()) {
            return Err(bad(format!("{values:?}")));
        }
        let scale = if values[8] != 0.0 { values[8] } else { 1.0 };
        let m = |r: usize| [0, 1, 2].map(|c| values[3 * r + c] / scale);
        let homography = Homography {
            h: [m(0), m(1), m(2)],
        };
        if homography.determinant().abs() < 1e-12 {
            return Err(bad(format!("{values:?} (singular)")));
        }
        Ok(homography)
    }

    /// The homography of a 2×3 affine map given row-major.
    pub fn from_affine(values: &[f64], context: &str) -> Result<Self> {
        if values.len() != 6 {
            return Err(Error::bad_field(
                context,
                "affine",
                format!("{} values", values.len()),
                "a 2x3 matrix",
            ));
        }
        let mut full = values.to_vec();
        full.extend([0.0, 0.0, 1.0]);
        Self::new(&full, context)
    }

    /// Reads a `.npy` file of 3×3 (homography) or 2×3 (affine) values.
    pub fn read_npy(path: &Path) -> Result<Self> {
        let context = path.display().to_string();
        // float32 or float64 in either byte order; other element types are refused
        // naming the type found.
        let array = crate::io::read_npy_f64(path)?;
        match array.shape.as_slice() {
            [3, 3] | [9] => Self::new(&array.data, &context),
            [2, 3] | [6] => Self::from_affine(&array.data, &context),
            shape => Err(Error::bad_field(
                &context,
                "array",
                format!("shape {shape:?}"),
                "3x3 (homography) or 2x3 (affine)",
            )),
        }
    }

    /// The map of a FileStorage file's `homography` or `affine` entry (None: neither).
    pub fn from_stored(
        homography: Option<&StoredValue>,
        affine: Option<&StoredValue>,
        context: &str,
    ) -> Result<Option<Self>> {
        let matrix = |v: &StoredValue| match v {
            StoredValue::Matrix { rows, cols, data } => Ok((*rows, *cols, data.clone())),
            StoredValue::Number(n) => Err(format!("the number {n}")),
        };
        let shape_of = |found: std::result::Result<(usize, usize, Vec<f64>), String>| {
            found.map_or_else(|n| n, |(r, c, _)| format!("a {r}x{c} matrix"))
        };
        // A flat list of 9 (6) numbers is the matrix's rows one after the other.
        match (homography.map(matrix), affine.map(matrix)) {
            (Some(Ok((3, 3, data) | (1, 9, data) | (9, 1, data))), None) => {
                Self::new(&data, context).map(Some)
            }
            (None, Some(Ok((2, 3, data) | (1, 6, data) | (6, 1, data)))) => {
                Self::from_affine(&data, context).map(Some)
            }
            (None, None) => Ok(None),
            (Some(_), Some(_)) => Err(Error::bad_field(
                context,
                "homography and affine",
                "both",
                "one map onto the reference: a homography or an affine map",
            )),
            (Some(found), None) => Err(Error::bad_field(
                context,
                "homography",
                shape_of(found),
                "a 3x3 matrix (rows of 3 numbers, or 9 numbers row by row; a 2x3 map goes \
                 under 'affine')",
            )),
            (None, Some(found)) => Err(Error::bad_field(
                context,
                "affine",
                shape_of(found),
                "a 2x3 matrix (rows of 3 numbers, or 6 numbers row by row)",
            )),
        }
    }

    pub fn determinant(&self) -> f64 {
        let h = &self.h;
        h[0][0] * (h[1][1] * h[2][2] - h[1][2] * h[2][1])
            - h[0][1] * (h[1][0] * h[2][2] - h[1][2] * h[2][0])
            + h[0][2] * (h[1][0] * h[2][1] - h[1][1] * h[2][0])
    }

    /// The inverse map.
    pub fn inverse(&self) -> Self {
        let h = &self.h;
        let cofactor = |r: usize, c: usize| {
            let (r0, r1) = ((r + 1) % 3, (r + 2) % 3);
            let (c0, c1) = ((c + 1) % 3, (c + 2) % 3);
            h[r0][c0] * h[r1][c1] - h[r0][c1] * h[r1][c0]
        };
        let det = self.determinant();
        // The adjugate is the transposed cofactor matrix.
        let m = |r: usize| [0, 1, 2].map(|c| cofactor(c, r) / det);
        let inverse = Homography {
            h: [m(0), m(1), m(2)],
        };
        let scale = inverse.h[2][2];
        if scale != 0.0 && scale.is_finite() {
            Homography {
                h: inverse.h.map(|row| row.map(|v| v / scale)),
            }
        } else {
            inverse
        }
    }

    /// Where pixel (x, y) goes; None when it maps to or beyond the line at infinity.
    pub fn apply(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let h = &self.h;
        let w = h[2][0] * x + h[2][1] * y + h[2][2];
        if !(w > 1e-12) {
            return None;
        }
        Some((
            (h[0][0] * x + h[0][1] * y + h[0][2]) / w,
            (h[1][0] * x + h[1][1] * y + h[1][2]) / w,
        ))
    }

    /// Determinant of the map's Jacobian at (x, y) (its local area scale).
    fn area_scale(&self, x: f64, y: f64) -> f64 {
        let h = &self.h;
        let w = h[2][0] * x + h[2][1] * y + h[2][2];
        self.determinant() / (w * w * w)
    }

    /// Checks that the map, used on `width × height` images, neither folds the frame nor
    /// sends it away: the frame keeps its orientation and stays on one side of the line
    /// at infinity, its area scale varies by less than a factor of 20, and the centre of
    /// the reference frame is seen by the camera.
    pub fn check_frame(&self, width: usize, height: usize, context: &str) -> Result<()> {
        let (w, h) = (width as f64 - 1.0, height as f64 - 1.0);
        let samples =
            (0..=8).flat_map(|i| (0..=8).map(move |j| (w * i as f64 / 8.0, h * j as f64 / 8.0)));
        let scales: Vec<f64> = samples.map(|(x, y)| self.area_scale(x, y)).collect();
        let (lo, hi) = scales
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &s| {
                (a.min(s), b.max(s))
            });
        let folds = !(lo > 0.0 && lo / hi > MIN_AREA_RATIO)
            || (0..=8).any(|i| {
                self.apply(w * i as f64 / 8.0, 0.0).is_none()
                    || self.apply(w * i as f64 / 8.0, h).is_none()
            });
        if folds {
            return Err(Error::unusable(
                context,
                format!(
                    "the homography folds or flips the {width}x{height} image (local area \
                     scale {lo:.3} to {hi:.3} over the frame)"
                ),
            ));
        }
        if lo < 1.0 / MAX_AREA_SCALE || hi > MAX_AREA_SCALE {
            return Err(Error::unusable(
                context,
                format!(
                    "the homography scales the {width}x{height} image's area by {lo:.3e} to \
                     {hi:.3e} (expected within 1/{MAX_AREA_SCALE} to {MAX_AREA_SCALE}, as \
                     between cameras of one array): a wrongly scaled matrix?"
                ),
            ));
        }
        let seen = self
            .inverse()
            .apply(0.5 * w, 0.5 * h)
            .filter(|&(x, y)| (-0.5..=w + 0.5).contains(&x) && (-0.5..=h + 0.5).contains(&y));
        if seen.is_none() {
            return Err(Error::unusable(
                context,
                format!(
                    "the homography maps the camera's {width}x{height} image away from the \
                     reference frame's centre"
                ),
            ));
        }
        Ok(())
    }

    /// The homography that maps `from[i]` onto `to[i]` in the least-squares sense of the
    /// normalised DLT (Hartley & Zisserman, Alg. 4.2); at least 4 pairs, not collinear.
    pub fn fit(from: &[[f64; 2]], to: &[[f64; 2]]) -> Result<Self> {
        if from.len() != to.len() || from.len() < 4 {
            return Err(Error::calibration(
                "homography fit",
                format!("{} and {} points", from.len(), to.len()),
                "as many points on both sides, at least 4",
            ));
        }
        let (tf, nf) = normalising(from);
        let (tt, nt) = normalising(to);
        let mut ata = [[0.0f64; 9]; 9];
        for (p, q) in nf.iter().zip(&nt) {
            let (x, y, u, v) = (p[0], p[1], q[0], q[1]);
            let rows = [
                [-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u],
                [0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v],
            ];
            for r in rows {
                for i in 0..9 {
                    for j in 0..9 {
                        ata[i][j] += r[i] * r[j];
                    }
                }
            }
        }
        let eigen = faer::Mat::from_fn(9, 9, |i, j| ata[i][j])
            .self_adjoint_eigen(faer::Side::Lower)
            .map_err(|e| Error::LinearAlgebra {
                op: "homography fit".into(),
                message: format!("{e:?}"),
            })?;
        // Eigenvalues come in nondecreasing order: the null vector is the first.
        let values = eigen.S().column_vector();
        if values[1] <= 1e-9 * values[8].max(1e-300) {
            return Err(Error::unusable(
                "homography fit",
                "the points are (nearly) collinear or repeated".to_string(),
            ));
        }
        let u = eigen.U();
        let normalised = Homography {
            h: [0, 1, 2].map(|r| [0, 1, 2].map(|c| u[(3 * r + c, 0)])),
        };
        let h = multiply(&tt.inverse().h, &multiply(&normalised.h, &tf.h));
        Self::new(&h.concat(), "homography fit")
    }

    /// The affine map that takes `from[i]` to `to[i]` in the least-squares sense; at least
    /// 3 pairs, not collinear.
    pub fn fit_affine(from: &[[f64; 2]], to: &[[f64; 2]]) -> Result<Self> {
        if from.len() != to.len() || from.len() < 3 {
            return Err(Error::calibration(
                "affine fit",
                format!("{} and {} points", from.len(), to.len()),
                "as many points on both sides, at least 3",
            ));
        }
        let (tf, nf) = normalising(from);
        let (tt, nt) = normalising(to);
        // Normal equations of [x y 1] a = u (and = v), shared by both rows.
        let mut normal = faer::Mat::<f64>::zeros(3, 3);
        let mut rhs = faer::Mat::<f64>::zeros(3, 2);
        for (p, q) in nf.iter().zip(&nt) {
            let x = [p[0], p[1], 1.0];
            for i in 0..3 {
                for j in 0..3 {
                    normal[(i, j)] += x[i] * x[j];
                }
                rhs[(i, 0)] += x[i] * q[0];
                rhs[(i, 1)] += x[i] * q[1];
            }
        }
        let solution = normal.partial_piv_lu().solve(&rhs);
        let row = |k: usize| [0, 1, 2].map(|i| solution[(i, k)]);
        let normalised = [row(0), row(1), [0.0, 0.0, 1.0]];
        if normalised.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::unusable(
                "affine fit",
                "the points are (nearly) collinear or repeated".to_string(),
            ));
        }
        let h = multiply(&tt.inverse().h, &multiply(&normalised, &tf.h));
        Self::new(&h.concat(), "affine fit")
    }

    /// Distances between `H(from[i])` and `to[i]`, pixels (infinite where a point maps
    /// to infinity).
    pub fn residuals(&self, from: &[[f64; 2]], to: &[[f64; 2]]) -> Vec<f64> {
        from.iter()
            .zip(to)
            .map(|(p, q)| match self.apply(p[0], p[1]) {
                Some((x, y)) => (x - q[0]).hypot(y - q[1]),
                None => f64::INFINITY,
            })
            .collect()
    }
}

fn multiply(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|r| [0, 1, 2].map(|c| (0..3).map(|k| a[r][k] * b[k][c]).sum()))
}

/// The similarity that moves `points` to their centroid and scales their mean distance
/// to √2, and the moved points.
fn normalising(points: &[[f64; 2]]) -> (Homography, Vec<[f64; 2]>) {
    let n = points.len() as f64;
    let (cx, cy) = points
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p[0] / n, y + p[1] / n));
    let spread = points
        .iter()
        .map(|p| (p[0] - cx).hypot(p[1] - cy))
        .sum::<f64>()
        / n;
    let s = if spread > 0.0 {
        std::f64::consts::SQRT_2 / spread
    } else {
        1.0
    };
    let t = Homography {
        h: [[s, 0.0, -s * cx], [0.0, s, -s * cy], [0.0, 0.0, 1.0]],
    };
    let moved = points
        .iter()
        .map(|p| [s * (p[0] - cx), s * (p[1] - cy)])
        .collect();
    (t, moved)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tilted() -> Homography {
        Homography::new(
            &[1.02, 0.03, 12.5, -0.02, 0.99, -4.0, 2e-5, -1e-5, 1.0],
            "test",
        )
        .unwrap()
    }

    #[test]
    fn the_fit_recovers_a_homography_from_its_points_and_the_inverse_undoes_it() {
        let h = tilted();
        let from: Vec<[f64; 2]> = (0..6)
            .flat_map(|i| (0..4).map(move |j| [40.0 + 90.0 * i as f64, 30.0 + 100.0 * j as f64]))
            .collect();
        let to: Vec<[f64; 2]> = from
            .iter()
            .map(|p| h.apply(p[0], p[1]).map(|(x, y)| [x, y]).unwrap())
            .collect();
        let fitted = Homography::fit(&from, &to).unwrap();
        assert!(fitted.residuals(&from, &to).iter().all(|r| *r < 1e-8));
        // The affine fit of an affine map is exact; of a projective one, it is not.
        let affine =
            Homography::new(&[1.01, 0.02, 5.0, -0.03, 0.98, 7.0, 0.0, 0.0, 1.0], "a").unwrap();
        let moved: Vec<[f64; 2]> = from
            .iter()
            .map(|p| affine.apply(p[0], p[1]).map(|(x, y)| [x, y]).unwrap())
            .collect();
        let fitted = Homography::fit_affine(&from, &moved).unwrap();
        assert!(fitted.residuals(&from, &moved).iter().all(|r| *r < 1e-8));
        let approximate = Homography::fit_affine(&from, &to).unwrap();
        assert!(approximate.residuals(&from, &to).iter().any(|r| *r > 0.5));
        let back = h.inverse();
        let (x, y) = back.apply(to[5][0], to[5][1]).unwrap();
        assert!((x - from[5][0]).abs() < 1e-9 && (y - from[5][1]).abs() < 1e-9);
        assert!(Homography::fit(&from[..3], &to[..3]).is_err());
        let line: Vec<[f64; 2]> = (0..6).map(|i| [i as f64, 2.0 * i as f64]).collect();
        assert!(Homography::fit(&line, &line).is_err());
    }

    #[test]
    fn a_map_that_folds_or_leaves_the_reference_is_refused() {
        tilted().check_frame(640, 480, "r0c1").unwrap();
        let mirrored =
            Homography::new(&[-1.0, 0.0, 639.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "m").unwrap();
        let folded = mirrored
            .check_frame(640, 480, "r0c1")
            .unwrap_err()
            .to_string();
        assert!(
            folded.contains("r0c1") && folded.contains("folds"),
            "{folded}"
        );
        // Projective enough that the line at infinity crosses the frame.
        let horizon =
            Homography::new(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, -0.004, 0.0, 1.0], "h").unwrap();
        assert!(horizon.check_frame(640, 480, "r0c1").is_err());
        let away = Homography::new(&[1.0, 0.0, 2000.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "a").unwrap();
        let error = away.check_frame(640, 480, "r0c1").unwrap_err().to_string();
        assert!(error.contains("away from the reference"), "{error}");
        // The upper rows scaled by 1e12: the camera would collapse the frame to a point.
        let scaled =
            Homography::new(&[1e12, 0.0, 0.0, 0.0, 1e12, 0.0, 0.0, 0.0, 1.0], "s").unwrap();
        let error = scaled
            .check_frame(640, 480, "r0c1")
            .unwrap_err()
            .to_string();
        assert!(error.contains("wrongly scaled"), "{error}");
        let zoom = Homography::new(&[2.0, 0.0, -320.0, 0.0, 2.0, -240.0, 0.0, 0.0, 1.0], "z");
        zoom.unwrap().check_frame(640, 480, "r0c1").unwrap();
        assert!(Homography::new(&[1.0, 2.0, 0.0, 2.0, 4.0, 0.0, 0.0, 0.0, 1.0], "s").is_err());
        assert!(Homography::from_affine(&[1.0, 0.0, 3.0, 0.0, 1.0], "a").is_err());
    }
}
