//! Warping every capture to a view: the measurements of view `reference` gathered from all
//! cameras along its disparity map, the input of the per-pixel demultiplexing.
//!
//! A camera's measurement of a reference pixel with disparity d is read at
//! `(x, y) + d · shift` by bilinear interpolation. It is **visible** only if that camera's
//! own disparity map agrees within [`CONSISTENCY_PX`] at every contributing tap, so that no
//! value is interpolated across a depth edge (depth order: a nearer surface
//! in front of the point has a larger disparity; a farther one means the reference pixel is
//! wrong or the camera looks past an edge), the position lies inside the image, and no
//! interpolation tap is invalid (saturated). Anything else is NaN: masked, never invented.

use super::ArrayGeometry;
use crate::{Error, Result};
use rayon::prelude::*;
use serde::Serialize;

/// Largest disagreement (px per column step) between the reference's disparity and the
/// source camera's disparity at the warped position for a measurement to count as visible
/// (the left–right tolerance of the matcher).
pub const CONSISTENCY_PX: f32 = 1.0;

/// A capture in the sensing matrix's units (white-calibrated), NaN where unusable.
#[derive(Debug, Clone)]
pub struct NormalisedView {
    pub row: usize,
    pub col: usize,
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    /// `height × width × channels`.
    pub data: Vec<f32>,
}

/// How much of each camera a view could use.
#[derive(Debug, Clone, Serialize)]
pub struct Visibility {
    /// Per source camera (input order): the fraction of reference pixels it measured.
    pub measured_fraction: Vec<f64>,
    /// Fraction of reference pixels measured by every camera.
    pub seen_by_all: f64,
}

/// The measurements of view `reference` from every camera, `pixels × Σ channels` in camera
/// order (the row order of C), NaN where not visible; `disparities[v]` is view v's map.
pub fn gather_measurements(
    reference: usize,
    views: &[NormalisedView],
    disparities: &[Vec<f32>],
    geometry: &ArrayGeometry,
) -> Result<(Vec<f32>, Visibility)> {
    let Some(me) = views.get(reference) else {
        return Err(Error::invalid("warping", format!("no view {reference}")));
    };
    let (w, h) = (me.width, me.height);
    if disparities.len() != views.len() {
        return Err(Error::Shape {
            op: "warping: disparity maps".into(),
            got: vec![disparities.len()],
            expected: vec![views.len()],
        });
    }
    for (v, d) in views.iter().zip(disparities) {
        if v.width != w || v.height != h || v.data.len() != w * h * v.channels || d.len() != w * h {
            return Err(Error::Shape {
                op: format!("warping: view r{}c{}", v.row, v.col),
                got: vec![v.width, v.height, v.channels, d.len()],
                expected: vec![w, h, v.channels, w * h],
            });
        }
    }
    let rows: usize = views.iter().map(|v| v.channels).sum();
    let first_rows: Vec<usize> = views
        .iter()
        .scan(0, |acc, v| {
            let first = *acc;
            *acc += v.channels;
            Some(first)
        })
        .collect();
    let shifts: Vec<(f64, f64)> = views
        .iter()
        .map(|v| geometry.shift((me.row, me.col), (v.row, v.col)))
        .collect();
    let own = &disparities[reference];
    let mut measurements = crate::io::zeroed_large::<f32>(w * h * rows);
    let counts: Vec<Vec<usize>> = measurements
        .par_chunks_mut(w * rows)
        .enumerate()
        .map(|(y, out_row)| {
            let mut seen = vec![0usize; views.len() + 1];
            for x in 0..w {
                let i = y * w + x;
                let out = &mut out_row[x * rows..][..rows];
                out.fill(f32::NAN);
                let d = own[i];
                let mut all = true;
                for (v, view) in views.iter().enumerate() {
                    let ch = view.channels;
                    let dst = &mut out[first_rows[v]..][..ch];
                    if v == reference {
                        dst.copy_from_slice(&view.data[i * ch..][..ch]);
                        let ok = dst.iter().all(|m| m.is_finite());
                        seen[v] += usize::from(ok);
                        all &= ok;
                        continue;
                    }
                    let ok =
                        d.is_finite() && warp_one(view, &disparities[v], shifts[v], x, y, d, dst);
                    if !ok {
                        dst.fill(f32::NAN);
                    }
                    seen[v] += usize::from(ok);
                    all &= ok;
                }
                seen[views.len()] += usize::from(all);
            }
            seen
        })
        .collect();
    let pixels = (w * h).max(1) as f64;
    let total = |v: usize| counts.iter().map(|c| c[v]).sum::<usize>() as f64 / pixels;
    Ok((
        measurements,
        Visibility {
            measured_fraction: (0..views.len()).map(total).collect(),
            seen_by_all: total(views.len()),
        },
    ))
}

/// Reads `view` at the warped position of reference pixel (x, y) with disparity d into
/// `dst`; false if the measurement is not visible or not usable.
fn warp_one(
    view: &NormalisedView,
    disparity: &[f32],
    (sx, sy): (f64, f64),
    x: usize,
    y: usize,
    d: f32,
    dst: &mut [f32],
) -> bool {
    let (w, h, ch) = (view.width, view.height, view.channels);
    let (px, py) = (x as f64 + sx * d as f64, y as f64 + sy * d as f64);
    if px < 0.0 || py < 0.0 || px > (w - 1) as f64 || py > (h - 1) as f64 {
        return false;
    }
    let (x0, y0) = (
        (px.floor() as usize).min(w - 2),
        (py.floor() as usize).min(h - 2),
    );
    let (fx, fy) = ((px - x0 as f64) as f32, (py - y0 as f64) as f32);
    let taps = [
        (y0 * w + x0, (1.0 - fx) * (1.0 - fy)),
        (y0 * w + x0 + 1, fx * (1.0 - fy)),
        ((y0 + 1) * w + x0, (1.0 - fx) * fy),
        ((y0 + 1) * w + x0 + 1, fx * fy),
    ];
    // Depth order and consistency at every tap that contributes: interpolating across a
    // depth edge would mix the two surfaces' spectra.
    let consistent = taps
        .iter()
        .all(|&(p, k)| k <= 0.0 || (disparity[p] - d).abs() <= CONSISTENCY_PX);
    if !consistent {
        return false;
    }
    for (c, out) in dst.iter_mut().enumerate() {
        let mut value = 0.0;
        for &(p, k) in &taps {
            if k > 0.0 {
                value += k * view.data[p * ch + c];
            }
        }
        if !value.is_finite() {
            return false;
        }
        *out = value;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two cameras on a row looking at a plane at disparity 2 with a nearer square
    /// (disparity 5) in front: the right camera's values come back where visible, and the
    /// pixels of the plane the square hides from it are masked.
    #[test]
    fn warping_restores_values_and_masks_occlusions() {
        let (w, h) = (40usize, 8usize);
        let geometry = ArrayGeometry {
            rows: 1,
            cols: 2,
            baseline_ratio: 1.0,
        };
        // Reference disparity: the square covers x in 20..26.
        let left_d: Vec<f32> = (0..w * h)
            .map(|i| {
                if (20..26).contains(&(i % w)) {
                    5.0
                } else {
                    2.0
                }
            })
            .collect();
        // The right camera sees the square at x − 5 (15..21) and the plane at x − 2.
        let right_d: Vec<f32> = (0..w * h)
            .map(|i| {
                if (15..21).contains(&(i % w)) {
                    5.0
                } else {
                    2.0
                }
            })
            .collect();
        // Scene value: a ramp over the reference's coordinates.
        let value = |x_ref: f32| 0.01 * x_ref;
        let right_data: Vec<f32> = (0..w * h)
            .map(|i| {
                let x = (i % w) as f32;
                if (15..21).contains(&(i % w)) {
                    value(x + 5.0)
                } else {
                    value(x + 2.0)
                }
            })
            .collect();
        let views = vec![
            NormalisedView {
                row: 0,
                col: 0,
                width: w,
                height: h,
                channels: 1,
                data: (0..w * h).map(|i| value((i % w) as f32)).collect(),
            },
            NormalisedView {
                row: 0,
                col: 1,
                width: w,
                height: h,
                channels: 1,
                data: right_data,
            },
        ];
        let (m, visibility) =
            gather_measurements(0, &views, &[left_d.clone(), right_d], &geometry).unwrap();
        let y = 4;
        for x in 0..w {
            let got = m[(y * w + x) * 2 + 1];
            // Plane pixels 17..20 map into the square's image (15..21 minus 2): hidden.
            let hidden = (17..20).contains(&x) || x < 2;
            if hidden {
                assert!(got.is_nan(), "x {x}: {got}");
            } else {
                assert!((got - value(x as f32)).abs() < 1e-6, "x {x}: {got}");
            }
        }
        assert_eq!(visibility.measured_fraction[0], 1.0);
        assert!((visibility.seen_by_all - (w - 5) as f64 / w as f64).abs() < 1e-9);
    }
}
