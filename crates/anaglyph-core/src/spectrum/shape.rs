//! A uniform spectral sampling: `start`, `step` and `count` in nanometres, as
//! colour-science's `SpectralShape`. The paper's reconstruction grid is
//! `SpectralShape::new(450.0, 8.0, 24)`.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Uniform wavelength sampling in nm: `start + i * step` for `i < count`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SpectralShape {
    pub start: f64,
    pub step: f64,
    pub count: usize,
}

/// Most samples a shape may hold (0.01 nm steps over 200–2000 nm is 180 000).
const MAX_SHAPE_COUNT: usize = 1_000_000;

impl SpectralShape {
    /// The paper's 24 reconstruction bands: 450–634 nm in 8 nm steps.
    pub const PAPER_BANDS: SpectralShape = SpectralShape {
        start: 450.0,
        step: 8.0,
        count: 24,
    };

    /// A validated shape.
    pub fn new(start: f64, step: f64, count: usize) -> Result<Self> {
        let shape = SpectralShape { start, step, count };
        shape.validate()?;
        Ok(shape)
    }

    /// The shape from `start` to `end` inclusive with the given step; `end - start`
    /// must be a whole number of steps (within 1e-6 nm).
    pub fn from_range(start: f64, end: f64, step: f64) -> Result<Self> {
        if !(step.is_finite() && step > 0.0 && start.is_finite() && end.is_finite()) {
            return Err(Error::curve(
                "spectral shape",
                format!("start {start}, end {end}, step {step}"),
                "finite values and a step > 0",
            ));
        }
        let steps = (end - start) / step;
        let whole = steps.round();
        if steps < -1e-9 || (steps - whole).abs() > 1e-6 {
            return Err(Error::curve(
                "spectral shape",
                format!("{start} to {end} nm in {step} nm steps"),
                "a whole number of steps",
            ));
        }
        Self::new(start, step, whole as usize + 1)
    }

    /// Checks finiteness, a positive step and a sane count.
    pub fn validate(&self) -> Result<()> {
        if !self.start.is_finite() || !self.step.is_finite() || self.step <= 0.0 {
            return Err(Error::curve(
                "spectral shape",
                format!("start {} step {}", self.start, self.step),
                "finite values and a step > 0",
            ));
        }
        if self.count == 0 || self.count > MAX_SHAPE_COUNT {
            return Err(Error::out_of_range(
                "spectral shape count",
                self.count as f64,
                format!("1 to {MAX_SHAPE_COUNT}"),
            ));
        }
        if self.start <= 0.0 {
            return Err(Error::out_of_range(
                "spectral shape start (nm)",
                self.start,
                "> 0",
            ));
        }
        Ok(())
    }

    /// Wavelength of sample `i` in nm.
    pub fn wavelength(&self, i: usize) -> f64 {
        self.start + i as f64 * self.step
    }

    /// Last wavelength in nm.
    pub fn end(&self) -> f64 {
        self.wavelength(self.count - 1)
    }

    /// All wavelengths in nm.
    pub fn wavelengths(&self) -> Vec<f64> {
        (0..self.count).map(|i| self.wavelength(i)).collect()
    }

    /// Index of the sample at `nm`, if `nm` lies on the grid (within 1e-6 nm).
    pub fn index_of(&self, nm: f64) -> Option<usize> {
        let x = (nm - self.start) / self.step;
        let i = x.round();
        if (x - i).abs() * self.step < 1e-6 && i >= 0.0 && (i as usize) < self.count {
            Some(i as usize)
        } else {
            None
        }
    }
}

impl std::fmt::Display for SpectralShape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}–{} nm, step {} nm ({} bands)",
            self.start,
            self.end(),
            self.step,
            self.count
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_bands_end_at_634() {
        let s = SpectralShape::PAPER_BANDS;
        assert_eq!(s.end(), 634.0);
        assert_eq!(s.wavelengths().len(), 24);
        assert_eq!(s.index_of(530.0), Some(10));
        assert_eq!(s.index_of(531.0), None);
    }

    #[test]
    fn from_range_counts_inclusive_and_rejects_fractional_steps() {
        let s = SpectralShape::from_range(400.0, 700.0, 5.0).unwrap();
        assert_eq!(s.count, 61);
        assert_eq!(
            SpectralShape::from_range(400.0, 701.0, 5.0)
                .err()
                .map(|e| e.kind()),
            Some("Curve")
        );
        assert_eq!(
            SpectralShape::new(400.0, 0.0, 3).err().map(|e| e.kind()),
            Some("Curve")
        );
        assert_eq!(
            SpectralShape::new(400.0, f64::NAN, 3)
                .err()
                .map(|e| e.kind()),
            Some("Curve")
        );
        assert_eq!(
            SpectralShape::new(400.0, 1.0, 0).err().map(|e| e.kind()),
            Some("OutOfRange")
        );
    }
}
