//! Surface materials: what reflectance spectrum a surface point has. Measured spectra are
//! used as they are; RGB textures and procedural patterns (flat colour, stripes, checker,
//! value noise, fine periodic gratings) give sRGB colours that [`SpectralUpsampler`] turns
//! into bounded, plausible reflectances on [`UPSAMPLING_SHAPE`].

use super::{SpectralUpsampler, Texture};
use std::sync::Arc;

/// A resolved material.
#[derive(Debug, Clone)]
pub enum Material {
    /// One measured reflectance on [`super::UPSAMPLING_SHAPE`].
    Spectrum(Arc<Vec<f64>>),
    /// A linear-RGB texture stretched over `scale_mm` × `scale_mm` of surface, repeating.
    Texture {
        texture: Arc<Texture>,
        scale_mm: f64,
    },
    /// Linear RGB colours arranged by a pattern.
    Pattern {
        pattern: Pattern,
        colours: [[f64; 3]; 2],
    },
    /// A ColorChecker: 6 × 4 patches of measured spectra on a black frame, `width_mm` wide.
    Chart {
        patches: Arc<Vec<Vec<f64>>>,
        frame: Arc<Vec<f64>>,
        width_mm: f64,
    },
}

/// Procedural patterns (mm on the surface).
#[derive(Debug, Clone, Copy)]
pub enum Pattern {
    Flat,
    /// Bands of width `period/2` across the direction at `angle_deg`.
    Stripes {
        period_mm: f64,
        angle_deg: f64,
    },
    Checker {
        period_mm: f64,
    },
    /// Smooth value noise with features of `scale_mm`.
    Noise {
        scale_mm: f64,
        seed: u64,
    },
    /// A sinusoidal grating (fine periodic detail) blended between the two colours.
    Grating {
        period_mm: f64,
        angle_deg: f64,
    },
}

/// Spectral variation at fixed colour: textures and patterns get
/// `amplitude × Σ_k e_k g_k(u, v)` added to their spectra, with `e_k` the upsampler's
/// [`SpectralUpsampler::metameric_components`] (the spread of measured spectra of one
/// colour) and `g_k` independent smooth random fields of unit variance and feature size
/// `scale_mm`. Amplitude 1 is the full spread of the measured sets; the colour under D65
/// is unchanged (up to clipping to [0, 1]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MetamerVariation {
    pub amplitude: f64,
    pub scale_mm: f64,
}

/// Standard deviation of [`value_noise`] (uniform lattice values, smoothstep weights:
/// `sqrt((∫(1−s)² + s²)² / 12)`).
const VALUE_NOISE_SD: f64 = 0.2144;

/// Evaluates materials into spectra, with the upsampler they share.
#[derive(Debug, Clone)]
pub struct SpectrumSampler {
    pub upsampler: Arc<SpectralUpsampler>,
    /// Spectral variation at fixed colour and its seed (None: the mean spectrum).
    pub metamers: Option<(MetamerVariation, u64)>,
}

fn hash(x: i64, y: i64, seed: u64) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed;
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

fn value_noise(u: f64, v: f64, seed: u64) -> f64 {
    let (x0, y0) = (u.floor(), v.floor());
    let (fx, fy) = (u - x0, v - y0);
    let smooth = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (smooth(fx), smooth(fy));
    let (xi, yi) = (x0 as i64, y0 as i64);
    let top = hash(xi, yi, seed) * (1.0 - sx) + hash(xi + 1, yi, seed) * sx;
    let bottom = hash(xi, yi + 1, seed) * (1.0 - sx) + hash(xi + 1, yi + 1, seed) * sx;
    top * (1.0 - sy) + bottom * sy
}

impl Pattern {
    /// Weight of the second colour at surface point (u, v) mm.
    fn weight(&self, u: f64, v: f64) -> f64 {
        let along = |angle: f64| {
            let a = angle.to_radians();
            u * a.cos() + v * a.sin()
        };
        match *self {
            Pattern::Flat => 0.0,
            Pattern::Stripes {
                period_mm,
                angle_deg,
            } => f64::from((along(angle_deg) / period_mm).rem_euclid(1.0) >= 0.5),
            Pattern::Checker { period_mm } => {
                let (a, b) = (
                    (u / period_mm).floor() as i64,
                    (v / period_mm).floor() as i64,
                );
                f64::from((a + b).rem_euclid(2) == 1)
            }
            Pattern::Noise { scale_mm, seed } => {
                // Two octaves of value noise.
                0.65 * value_noise(u / scale_mm, v / scale_mm, seed)
                    + 0.35 * value_noise(2.7 * u / scale_mm, 2.7 * v / scale_mm, seed ^ 0xABCD)
            }
            Pattern::Grating {
                period_mm,
                angle_deg,
            } => 0.5 + 0.5 * (std::f64::consts::TAU * along(angle_deg) / period_mm).sin(),
        }
    }
}

impl SpectrumSampler {
    /// Adds the metameric variation at surface point (u, v) mm to `spectrum`, clipped to
    /// [0, 1] (nothing without [`Self::metamers`]).
    fn vary(&self, u: f64, v: f64, spectrum: &mut [f64]) {
        let Some((variation, seed)) = self.metamers else {
            return;
        };
        if variation.amplitude == 0.0 {
            return;
        }
        for (k, component) in self.upsampler.metameric_components().iter().enumerate() {
            let field = (value_noise(
                u / variation.scale_mm,
                v / variation.scale_mm,
                seed ^ (0x5851_F42D_4C95_7F2D_u64.wrapping_mul(k as u64 + 1)),
            ) - 0.5)
                / VALUE_NOISE_SD;
            let weight = variation.amplitude * field;
            for (s, e) in spectrum.iter_mut().zip(component) {
                *s += weight * e;
            }
        }
        for s in spectrum.iter_mut() {
            *s = s.clamp(0.0, 1.0);
        }
    }

    /// Adds `weight ×` the reflectance of `material` at surface point (u, v) mm to `acc` (on [`super::UPSAMPLING_SHAPE`]); `scratch` holds one spectrum.
    pub fn accumulate(
        &self,
        material: &Material,
        u: f64,
        v: f64,
        weight: f64,
        acc: &mut [f64],
        scratch: &mut [f64],
    ) {
        let add =
            |acc: &mut [f64], s: &[f64]| acc.iter_mut().zip(s).for_each(|(a, b)| *a += weight * b);
        match material {
            Material::Spectrum(s) => add(acc, s),
            Material::Texture { texture, scale_mm } => {
                let rgb = texture.sample(u / scale_mm, v / scale_mm);
                self.upsampler.reflectance(rgb, scratch);
                self.vary(u, v, scratch);
                add(acc, scratch);
            }
            Material::Pattern { pattern, colours } => {
                let w = pattern.weight(u, v);
                let rgb = [0, 1, 2].map(|c| colours[0][c] * (1.0 - w) + colours[1][c] * w);
                self.upsampler.reflectance(rgb, scratch);
                self.vary(u, v, scratch);
                add(acc, scratch);
            }
            Material::Chart {
                patches,
                frame,
                width_mm,
            } => {
                // 6 columns × 4 rows of square patches with a gap of a fifth of a patch.
                let pitch = width_mm / 6.0;
                let (col, row) = ((u / pitch).floor(), (v / pitch).floor());
                let (fu, fv) = (u / pitch - col, v / pitch - row);
                let inside = (0.1..0.9).contains(&fu) && (0.1..0.9).contains(&fv);
                if inside && (0.0..6.0).contains(&col) && (0.0..4.0).contains(&row) {
                    add(acc, &patches[row as usize * 6 + col as usize]);
                } else {
                    add(acc, frame);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sampler(metamers: Option<(MetamerVariation, u64)>) -> SpectrumSampler {
        SpectrumSampler {
            upsampler: Arc::new(SpectralUpsampler::new().unwrap()),
            metamers,
        }
    }

    #[test]
    fn metameric_variation_changes_spectra_but_not_colours() {
        let plain = sampler(None);
        let varied = sampler(Some((
            MetamerVariation {
                amplitude: 0.5,
                scale_mm: 10.0,
            },
            3,
        )));
        let material = Material::Pattern {
            pattern: Pattern::Flat,
            colours: [[0.35, 0.3, 0.25], [0.0; 3]],
        };
        let n = super::super::UPSAMPLING_SHAPE.count;
        let mut scratch = vec![0.0; n];
        let mut base = vec![0.0; n];
        plain.accumulate(&material, 0.0, 0.0, 1.0, &mut base, &mut scratch);
        let base_rgb = plain.upsampler.linear_rgb(&base);
        let mut spread = Vec::new();
        for k in 0..64 {
            let (u, v) = (7.3 * k as f64, 3.1 * k as f64);
            let mut s = vec![0.0; n];
            varied.accumulate(&material, u, v, 1.0, &mut s, &mut scratch);
            let rgb = varied.upsampler.linear_rgb(&s);
            // A muted colour: nothing clips, so the colour is exact.
            assert!(s.iter().all(|v| (0.0..=1.0).contains(v)));
            for c in 0..3 {
                assert!(
                    (rgb[c] - base_rgb[c]).abs() < 1e-9,
                    "{rgb:?} vs {base_rgb:?}"
                );
            }
            let rms = (s
                .iter()
                .zip(&base)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                / n as f64)
                .sqrt();
            spread.push(rms);
        }
        let mean = spread.iter().sum::<f64>() / spread.len() as f64;
        // Amplitude 0.5 of the measured spread: a few percent of reflectance per knot.
        assert!(mean > 0.01 && mean < 0.1, "{mean}");
        // The same point gets the same spectrum (the field is a function of position).
        let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
        varied.accumulate(&material, 5.0, 6.0, 1.0, &mut a, &mut scratch);
        varied.accumulate(&material, 5.0, 6.0, 1.0, &mut b, &mut scratch);
        assert_eq!(a, b);
    }
}
