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

/// Evaluates materials into spectra, with the upsampler they share.
#[derive(Debug, Clone)]
pub struct SpectrumSampler {
    pub upsampler: Arc<SpectralUpsampler>,
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
                add(acc, scratch);
            }
            Material::Pattern { pattern, colours } => {
                let w = pattern.weight(u, v);
                let rgb = [0, 1, 2].map(|c| colours[0][c] * (1.0 - w) + colours[1][c] * w);
                self.upsampler.reflectance(rgb, scratch);
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
