//! Sensor noise of one exposure. A measurement `p` in normalised units (white = 1 at the
//! brightest channel of each camera) becomes `e = p · exposure · full_well` photo-electrons;
//! shot noise is Poisson(e), read noise Gaussian, then the ADC quantises to `bits` and clips
//! at full scale. The result is mapped back to normalised units; clipped values are flagged.
//! Seeded and deterministic (ChaCha8).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson};
use serde::{Deserialize, Serialize};

/// Parameters of the noise model; defaults describe a typical 12-bit machine-vision sensor
/// (the paper's Grasshopper3 class: ~10 ke⁻ full well, a few e⁻ read noise).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraNoise {
    pub full_well_electrons: f64,
    pub read_noise_electrons: f64,
    pub bits: u32,
    /// Fraction of full scale a perfect white reaches in the brightest channel.
    pub exposure: f64,
}

impl Default for CameraNoise {
    fn default() -> Self {
        CameraNoise {
            full_well_electrons: 10_000.0,
            read_noise_electrons: 5.0,
            bits: 12,
            exposure: 0.9,
        }
    }
}

/// Noisy measurements and which ones clipped.
#[derive(Debug, Clone)]
pub struct NoisyMeasurements {
    pub values: Vec<f64>,
    pub saturated: Vec<bool>,
}

impl CameraNoise {
    /// Noise standard deviation (normalised units) at signal `p`, before quantisation.
    pub fn sigma(&self, p: f64) -> f64 {
        let e = p.max(0.0) * self.exposure * self.full_well_electrons;
        (e + self.read_noise_electrons.powi(2)).sqrt() / (self.exposure * self.full_well_electrons)
    }

    /// Applies shot noise, read noise, quantisation and clipping to `clean`.
    pub fn apply(&self, clean: &[f64], seed: u64) -> NoisyMeasurements {
        self.apply_with_offset(clean, &[], seed)
    }

    /// [`Self::apply`] with a dark offset per value (fraction of full scale: a black level
    /// and its fixed pattern; empty: none) added before the ADC, so that clipping sees it;
    /// the values returned include it.
    pub fn apply_with_offset(&self, clean: &[f64], offset: &[f64], seed: u64) -> NoisyMeasurements {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let levels = ((1u64 << self.bits) - 1) as f64;
        let electrons_per_unit = self.exposure * self.full_well_electrons;
        let read = Normal::new(0.0, self.read_noise_electrons.max(0.0)).ok();
        let mut values = Vec::with_capacity(clean.len());
        let mut saturated = Vec::with_capacity(clean.len());
        for (i, &p) in clean.iter().enumerate() {
            let mean = (p.max(0.0) * electrons_per_unit).min(4.0 * self.full_well_electrons);
            let mut e = if mean > 0.0 {
                Poisson::new(mean)
                    .map(|d| d.sample(&mut rng))
                    .unwrap_or(mean)
            } else {
                0.0
            };
            if let Some(read) = &read {
                e += read.sample(&mut rng);
            }
            let dark = offset.get(i).map_or(0.0, |o| o * levels);
            let dn = (e / self.full_well_electrons * levels + dark)
                .round()
                .clamp(0.0, levels);
            saturated.push(dn >= levels);
            values.push(dn / levels * self.full_well_electrons / electrons_per_unit);
        }
        NoisyMeasurements { values, saturated }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_has_the_modelled_variance_and_is_deterministic() {
        let noise = CameraNoise::default();
        let clean = vec![0.5; 20_000];
        let a = noise.apply(&clean, 42);
        assert_eq!(a.values, noise.apply(&clean, 42).values);
        assert_ne!(a.values, noise.apply(&clean, 43).values);
        let mean = a.values.iter().sum::<f64>() / a.values.len() as f64;
        let var = a.values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / a.values.len() as f64;
        let want = noise.sigma(0.5);
        assert!((mean - 0.5).abs() < 3e-4, "mean {mean}");
        // Quantisation adds step²/12 to the variance.
        let step =
            noise.full_well_electrons / 4095.0 / (noise.exposure * noise.full_well_electrons);
        let total = (want * want + step * step / 12.0).sqrt();
        assert!(
            (var.sqrt() / total - 1.0).abs() < 0.03,
            "sigma {} vs {total}",
            var.sqrt()
        );
        let clipped = noise.apply(&[2.0], 1);
        assert!(clipped.saturated[0]);
        assert!((clipped.values[0] - 1.0 / noise.exposure).abs() < 1e-12);
    }
}
