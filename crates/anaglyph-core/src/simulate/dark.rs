//! The dark signal of a simulated sensor: a black level (an electronic offset added before
//! the ADC, as real sensors do so that read noise is not clipped at zero) with a fixed
//! pattern per photosite (dark-signal non-uniformity), identical in a camera's capture and
//! white board, and the master dark frame a user would average from frames taken with the
//! lens capped at the same exposure.
//!
//! In: the settings' [`DarkSignal`], a camera's index and its noise model. Out: the offset
//! of every value (fraction of full scale) and the camera's master dark frame.

use crate::capture::CameraNoise;
use crate::{Error, Result};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

/// Largest black level the simulator renders, fraction of full scale.
pub const MAX_DARK_LEVEL: f64 = 0.5;
/// Frames averaged into a master dark frame.
pub const DARK_FRAMES: usize = 16;

/// A sensor's dark signal, as fractions of full scale.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DarkSignal {
    /// The black level (e.g. 256 / 4095 for a 12-bit sensor's 256).
    pub level: f64,
    /// Standard deviation of its fixed pattern from photosite to photosite.
    pub pattern: f64,
}

impl DarkSignal {
    pub fn check(&self) -> Result<()> {
        let fits = (0.0..=MAX_DARK_LEVEL).contains(&self.level)
            && (0.0..=self.level.max(0.0)).contains(&self.pattern);
        if fits {
            Ok(())
        } else {
            Err(Error::setting(
                "simulation dark signal",
                format!("level {} with a pattern of {}", self.level, self.pattern),
                format!(
                    "a level of 0 to {MAX_DARK_LEVEL} of full scale, a pattern of 0 to the level"
                ),
            ))
        }
    }

    /// Camera `camera_index`'s offset for each of its `values` (fraction of full scale,
    /// never below 0), seeded by `seed` and the camera.
    pub fn offsets(&self, values: usize, seed: u64, camera_index: usize) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(
            seed ^ 0xDA2C ^ (camera_index as u64).wrapping_mul(0x2545_F491),
        );
        let pattern = Normal::new(0.0, self.pattern).ok();
        (0..values)
            .map(|_| {
                let fixed = pattern.as_ref().map_or(0.0, |p| p.sample(&mut rng));
                (self.level + fixed).max(0.0)
            })
            .collect()
    }
}

/// The mean of [`DARK_FRAMES`] frames with the lens capped: each value its `offset` plus
/// read noise, quantised by the ADC of `noise` (no noise: the offsets quantised once).
pub fn master_dark(offsets: &[f64], noise: Option<&CameraNoise>, seed: u64) -> Vec<f32> {
    let Some(noise) = noise else {
        return offsets.iter().map(|&o| o as f32).collect();
    };
    let levels = ((1u64 << noise.bits) - 1) as f64;
    let read = Normal::new(
        0.0,
        noise.read_noise_electrons.max(0.0) / noise.full_well_electrons,
    )
    .ok();
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xD0_0D);
    offsets
        .iter()
        .map(|&o| {
            let sum: f64 = (0..DARK_FRAMES)
                .map(|_| {
                    let noisy = o + read.as_ref().map_or(0.0, |r| r.sample(&mut rng));
                    (noisy * levels).round().clamp(0.0, levels) / levels
                })
                .sum();
            (sum / DARK_FRAMES as f64) as f32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_have_the_level_and_pattern_and_the_master_dark_averages_them() {
        let dark = DarkSignal {
            level: 0.06,
            pattern: 0.005,
        };
        let offsets = dark.offsets(20_000, 7, 2);
        assert_eq!(offsets, dark.offsets(20_000, 7, 2));
        assert_ne!(offsets, dark.offsets(20_000, 7, 3));
        let n = offsets.len() as f64;
        let mean = offsets.iter().sum::<f64>() / n;
        let sd = (offsets.iter().map(|o| (o - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!(
            (mean - 0.06).abs() < 2e-4 && (sd - 0.005).abs() < 2e-4,
            "{mean} {sd}"
        );
        let noise = CameraNoise::default();
        let master = master_dark(&offsets, Some(&noise), 1);
        // Read noise of 5 e⁻ in 10 ke⁻ and quantisation to 12 bits, averaged over 16 frames.
        let worst = master
            .iter()
            .zip(&offsets)
            .map(|(m, o)| (f64::from(*m) - o).abs())
            .fold(0.0, f64::max);
        assert!(worst < 6e-4, "{worst}");
        assert!(DarkSignal {
            level: 0.6,
            pattern: 0.0
        }
        .check()
        .is_err());
        assert!(DarkSignal {
            level: 0.01,
            pattern: 0.02
        }
        .check()
        .is_err());
    }
}
