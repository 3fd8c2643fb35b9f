//! Whitening by a Cholesky factor: one component's share of the scene prior's gains for
//! one set of measured rows, and the triangular solves its estimate needs.
//!
//! In: innovations (measurements minus the component's prediction). Out: `L⁻¹ x` and its
//! squared norm (the Mahalanobis distance), and `L⁻ᵀ z`.

/// One component's share of [`Gains`].
pub(super) struct Gain {
    pub(super) log_weight: f64,
    /// `C_a μ`, the measurements the component's mean spectrum would give.
    pub(super) offset: Vec<f64>,
    /// The Cholesky factor L of `C_a Σ C_aᵀ + R`, lower triangle packed by columns
    /// (each from its diagonal down).
    pub(super) lower: Vec<f64>,
    /// `ln det (C_a Σ C_aᵀ + R)`.
    pub(super) log_det: f64,
}

impl Gain {
    /// Replaces x by `L⁻¹ x` and returns its squared norm, the squared Mahalanobis
    /// distance `xᵀ (C_a Σ C_aᵀ + R)⁻¹ x`. Column by column, so the inner loop is an
    /// axpy that vectorises.
    #[inline(always)]
    pub(super) fn whiten(&self, x: &mut [f64]) -> f64 {
        let mut column = self.lower.as_slice();
        let mut distance = 0.0;
        for j in 0..x.len() {
            let (below, rest) = x[j..].split_at_mut(1);
            let value = below[0] / column[0];
            below[0] = value;
            distance += value * value;
            for (v, l) in rest.iter_mut().zip(&column[1..]) {
                *v -= l * value;
            }
            column = &column[x.len() - j..];
        }
        distance
    }

    /// [`Gain::whiten`] for a batch: `x` holds the innovations row by row across the
    /// batch (`a × n`), `distances` receives the n squared distances.
    #[inline(always)]
    pub(super) fn whiten_batch(&self, x: &mut [f64], distances: &mut [f64]) {
        let n = distances.len();
        let a = x.len() / n;
        distances.iter_mut().for_each(|d| *d = 0.0);
        let mut column = self.lower.as_slice();
        for j in 0..a {
            let (head, rest) = x[j * n..].split_at_mut(n);
            let inverse = 1.0 / column[0];
            for (v, d) in head.iter_mut().zip(distances.iter_mut()) {
                *v *= inverse;
                *d += *v * *v;
            }
            for (row, l) in rest.chunks_exact_mut(n).zip(&column[1..]) {
                row.iter_mut().zip(&*head).for_each(|(v, h)| *v -= l * h);
            }
            column = &column[a - j..];
        }
    }

    /// Replaces z by `L⁻ᵀ z`: after [`Gain::whiten`], x becomes `(L Lᵀ)⁻¹ x`.
    #[inline(always)]
    pub(super) fn unwhiten(&self, z: &mut [f64]) {
        let a = z.len();
        let mut end = self.lower.len();
        for j in (0..a).rev() {
            // Column j of L, from the diagonal down, is row j of Lᵀ from the diagonal on.
            let column = &self.lower[end - (a - j)..end];
            let partial: f64 = column[1..]
                .iter()
                .zip(&z[j + 1..])
                .map(|(l, v)| l * v)
                .sum();
            z[j] = (z[j] - partial) / column[0];
            end -= a - j;
        }
    }
}
