//! From an aggregated cost volume to disparities: winner-take-all, the left–right
//! consistency check (|d_L − d_R| ≤ 1; failures become NaN) and parabolic subpixel
//! refinement (as MC-CNN: a parabola through the costs at d − 1, d, d + 1).

use super::CostVolume;

/// Largest left–right disagreement (pixels) of a consistent match.
pub const LEFT_RIGHT_TOLERANCE: f32 = 1.0;

/// The disparity of least cost at every pixel.
pub fn winner_take_all(volume: &CostVolume) -> Vec<f32> {
    (0..volume.width * volume.height)
        .map(|i| {
            let costs = &volume.data[i * volume.max_disp..(i + 1) * volume.max_disp];
            let (best, _) =
                costs.iter().enumerate().fold(
                    (0, f32::INFINITY),
                    |b, (d, &c)| if c < b.1 { (d, c) } else { b },
                );
            best as f32
        })
        .collect()
}

/// Invalidates (NaN) left disparities that the right view's own winner-take-all, computed
/// from the same volume (`d_R(x) = argmin_d C(x + d, d)`), does not confirm.
pub fn left_right_check(volume: &CostVolume, left: &[f32]) -> Vec<f32> {
    let (w, dm) = (volume.width, volume.max_disp);
    let mut out = left.to_vec();
    for y in 0..volume.height {
        let right: Vec<f32> = (0..w)
            .map(|xr| {
                let (best, _) = (0..dm.min(w - xr)).fold((0, f32::INFINITY), |b, d| {
                    let c = volume.pixel(xr + d, y)[d];
                    if c < b.1 {
                        (d, c)
                    } else {
                        b
                    }
                });
                best as f32
            })
            .collect();
        for x in 0..w {
            let d = left[y * w + x];
            if !d.is_finite() {
                continue;
            }
            let xr = x as i64 - d.round() as i64;
            if xr < 0 || (right[xr as usize] - d).abs() > LEFT_RIGHT_TOLERANCE {
                out[y * w + x] = f32::NAN;
            }
        }
    }
    out
}

/// Parabolic subpixel refinement of integer disparities (NaN stays NaN).
pub fn subpixel_disparity(volume: &CostVolume, disparity: &[f32]) -> Vec<f32> {
    disparity
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            if !d.is_finite() {
                return d;
            }
            let k = d as usize;
            if k == 0 || k + 1 >= volume.max_disp {
                return d;
            }
            let c = &volume.data[i * volume.max_disp..(i + 1) * volume.max_disp];
            let denominator = c[k + 1] + c[k - 1] - 2.0 * c[k];
            if denominator <= 0.0 {
                return d;
            }
            (d - (c[k + 1] - c[k - 1]) / (2.0 * denominator)).clamp(d - 0.5, d + 0.5)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subpixel_recovers_the_vertex_of_a_parabola() {
        // Costs (d − 2.3)² at d = 0..5: vertex at 2.3.
        let data: Vec<f32> = (0..5).map(|d| (d as f32 - 2.3).powi(2)).collect();
        let v = CostVolume {
            width: 1,
            height: 1,
            max_disp: 5,
            data,
        };
        let d = winner_take_all(&v);
        assert_eq!(d, vec![2.0]);
        assert!((subpixel_disparity(&v, &d)[0] - 2.3).abs() < 1e-5);
    }
}
