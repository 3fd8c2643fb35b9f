//! Spectral demultiplexing (paper section 2.3, Eqs. 4–6): per pixel,
//! `ŝ = argmin ‖P − Cs‖² + λ‖Ds‖²` subject to `s ≥ 0`, with D the first-difference
//! operator and λ applied exactly as given (the paper: 0.01).
//!
//! In: C (rows × N), measurements P (pixels × rows; NaN or a false mask entry marks a
//! missing measurement: occluded, saturated). Out: the spectrum of every pixel on the
//! requested range of C's knots (NaN where no measurement is left).
//!
//! Solvers ([`Solver`]): the default exact fast path factors `H = CᵀC + λDᵀD` once per
//! measurement mask, solves all pixels with one batched product `ŝ = H⁻¹Cᵀp` (faer
//! `matmul`, `Par::Seq` inside rayon chunks), and repairs only the pixels with negative
//! entries by block principal pivoting. The paper's three methods (projected gradient
//! descent, conjugate gradient, LSQR) and a plain dense reference converge to the same
//! minimiser.

mod active_set;
mod illumination;
mod krylov;
mod normal_equations;
mod projected_gradient;

pub use illumination::{divide_by_white_spectrum, normalise_by_white};
pub use normal_equations::{difference_gram, NormalEquations};

use crate::{Error, Result};
use active_set::{
    block_principal_pivoting, subproblem_dense, subproblem_schur, tolerances, Scratch,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::ops::Range;

/// Pixels per rayon task: 8192 pixels × 24 measurements × 8 B = 1.5 MiB of input, which
/// keeps a task's working set in L2 while giving a 2-megapixel image ~250 tasks.
const PIXELS_PER_TASK: usize = 8192;
/// Tasks per rayon thread on the unmasked path: enough for load balance, few enough that
/// each task reuses one set of buffers over many chunks.
const TASKS_PER_THREAD: usize = 4;
/// Pixels gathered per pass when measurement masks differ (bounds the extra memory).
const PIXELS_PER_PASS: usize = 1 << 18;
/// Relative tolerance of the exact path's feasibility checks.
const EXACT_TOLERANCE: f64 = 1e-10;
/// Most measurement rows per pixel (masks are 128-bit sets).
pub const MAX_MEASUREMENTS: usize = 128;

/// How Eq. 6 is solved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// Batched closed form + block principal pivoting (Schur complement on H⁻¹).
    #[default]
    Exact,
    /// Accelerated projected gradient descent (the paper's "gradient descent").
    ProjectedGradient,
    /// Conjugate gradient inside the active-set loop.
    ConjugateGradient,
    /// LSQR inside the active-set loop.
    Lsqr,
    /// Plain per-pixel dense Cholesky inside the active-set loop (reference twin).
    Reference,
}

crate::choice::named_choices!(Solver, "solver" {
    Exact = "exact" "Batched closed form + exact active set (default, fastest).",
    ProjectedGradient = "gradient-descent" "Accelerated projected gradient descent.",
    ConjugateGradient = "conjugate-gradient" "Conjugate gradient inside the active-set loop.",
    Lsqr = "lsqr" "LSQR inside the active-set loop.",
    Reference = "reference" "Plain dense per-pixel reference.",
});

/// Solver settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DemuxOptions {
    /// Smoothness weight λ.
    pub lambda: f64,
    pub solver: Solver,
    /// Relative tolerance of the iterative solvers.
    pub tolerance: f64,
    /// Iteration cap of the iterative solvers, per pixel (per subproblem for CG/LSQR).
    pub max_iterations: usize,
}

impl Default for DemuxOptions {
    fn default() -> Self {
        DemuxOptions {
            lambda: 0.01,
            solver: Solver::Exact,
            tolerance: 1e-10,
            max_iterations: 200_000,
        }
    }
}

/// What happened during a solve.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct DemuxReport {
    pub pixels: usize,
    /// Pixels whose solution touches `s ≥ 0`.
    pub bounded_pixels: usize,
    /// Pixels with no usable measurement (output NaN).
    pub unmeasured_pixels: usize,
    /// Distinct measurement masks (one factorisation each).
    pub distinct_masks: usize,
    /// Iterations summed over pixels (pivoting exchanges for the exact path).
    pub iterations: u64,
}

impl DemuxReport {
    fn merge(mut self, other: DemuxReport) -> DemuxReport {
        self.pixels += other.pixels;
        self.bounded_pixels += other.bounded_pixels;
        self.unmeasured_pixels += other.unmeasured_pixels;
        self.iterations += other.iterations;
        self
    }
}

/// The float type measurements arrive in and spectra leave in (f32 or f64); all
/// arithmetic is f64. Reading and writing the caller's own type avoids whole-image
/// conversion copies, which cost more than the solve on large images.
pub trait Sample: Copy + Send + Sync + bytemuck::Pod + 'static {
    const NAN: Self;
    fn to_f64(self) -> f64;
    fn from_f64(value: f64) -> Self;
    /// `Ŝ = P Aᵀ` for `pixels` rows of `p`, computed in this type (f32 data: f32 GEMM).
    fn batched_product(eq: &NormalEquations, p: &[Self], pixels: usize, s_hat: &mut Vec<Self>);
}

/// `dst (pixels × n) = p (pixels × m) · a_t (m × n)`, row-major, single-threaded (the
/// caller parallelises over chunks).
fn product<T: faer::traits::ComplexField + Copy + bytemuck::Zeroable>(
    p: &[T],
    a_t: &[T],
    pixels: usize,
    m: usize,
    n: usize,
    dst: &mut Vec<T>,
) {
    dst.resize(pixels * n, T::zeroed());
    faer::linalg::matmul::matmul(
        faer::MatMut::from_row_major_slice_mut(&mut dst[..pixels * n], pixels, n),
        faer::Accum::Replace,
        faer::MatRef::from_row_major_slice(p, pixels, m),
        faer::MatRef::from_row_major_slice(a_t, m, n),
        T::one_impl(),
        faer::Par::Seq,
    );
}

impl Sample for f64 {
    const NAN: Self = f64::NAN;
    fn to_f64(self) -> f64 {
        self
    }
    fn from_f64(value: f64) -> Self {
        value
    }
    fn batched_product(eq: &NormalEquations, p: &[Self], pixels: usize, s_hat: &mut Vec<Self>) {
        product(p, &eq.a_t, pixels, eq.kept_rows.len(), eq.n, s_hat);
    }
}

impl Sample for f32 {
    const NAN: Self = f32::NAN;
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    fn from_f64(value: f64) -> Self {
        value as f32
    }
    fn batched_product(eq: &NormalEquations, p: &[Self], pixels: usize, s_hat: &mut Vec<Self>) {
        product(p, &eq.a_t32, pixels, eq.kept_rows.len(), eq.n, s_hat);
    }
}

/// Solves Eq. 6 for every pixel. `c` is row-major `rows × n`; `measurements` is
/// `pixels × rows`; `mask` (same shape, true = use) is optional; the result is
/// `pixels × output.len()` holding knots `output` of each solution.
pub fn demultiplex(
    c: &[f64],
    rows: usize,
    measurements: &[f64],
    mask: Option<&[bool]>,
    output: Range<usize>,
    options: &DemuxOptions,
) -> Result<(Vec<f64>, DemuxReport)> {
    demultiplex_as(c, rows, measurements, mask, output, options)
}

/// [`demultiplex`] for measurements of type `I`, spectra returned as type `O`.
pub fn demultiplex_as<I: Sample, O: Sample>(
    c: &[f64],
    rows: usize,
    measurements: &[I],
    mask: Option<&[bool]>,
    output: Range<usize>,
    options: &DemuxOptions,
) -> Result<(Vec<O>, DemuxReport)> {
    let pixels = measurements.len() / rows.max(1);
    let mut result = crate::io::zeroed_large::<O>(pixels * output.len());
    let report = demultiplex_into(c, rows, measurements, mask, output, options, &mut result)?;
    Ok((result, report))
}

/// [`demultiplex_as`] into a caller's buffer of `pixels × output.len()` values, so that
/// a streaming caller can reuse its buffers band after band.
pub fn demultiplex_into<I: Sample, O: Sample>(
    c: &[f64],
    rows: usize,
    measurements: &[I],
    mask: Option<&[bool]>,
    output: Range<usize>,
    options: &DemuxOptions,
    result: &mut [O],
) -> Result<DemuxReport> {
    let (n, complete) = validate(c, rows, measurements, mask, &output, options)?;
    let pixels = measurements.len() / rows;
    if result.len() != pixels * output.len() {
        return Err(Error::Shape {
            op: "demultiplex output buffer".into(),
            got: vec![result.len()],
            expected: vec![pixels, output.len()],
        });
    }
    if complete {
        return solve_complete(c, rows, n, measurements, &output, options, result);
    }
    let out_n = output.len();
    let key_of = |px: usize| -> u128 {
        let p = &measurements[px * rows..(px + 1) * rows];
        let mut key = 0u128;
        for (r, v) in p.iter().enumerate() {
            if !v.to_f64().is_nan() && mask.is_none_or(|m| m[px * rows + r]) {
                key |= 1 << r;
            }
        }
        key
    };
    let keys: Vec<u128> = (0..pixels).into_par_iter().map(key_of).collect();
    let mut distinct: Vec<u128> = keys.clone();
    distinct.par_sort_unstable();
    distinct.dedup();
    let systems: HashMap<u128, NormalEquations> = distinct
        .par_iter()
        .filter(|&&k| k != 0)
        .map(|&k| {
            let kept: Vec<usize> = (0..rows).filter(|&r| k & (1 << r) != 0).collect();
            NormalEquations::new(c, n, kept, options.lambda).map(|eq| (k, eq))
        })
        .collect::<Result<_>>()?;
    result.fill(O::NAN);
    let mut report = DemuxReport {
        distinct_masks: systems.len(),
        ..Default::default()
    };

    // Mixed masks: sort pixels by mask, gather, solve, scatter, one bounded pass at a time.
    let mut order: Vec<usize> = (0..pixels).collect();
    order.par_sort_unstable_by_key(|&px| keys[px]);
    for pass in order.chunks(PIXELS_PER_PASS) {
        let groups: Vec<&[usize]> = pass.chunk_by(|a, b| keys[*a] == keys[*b]).collect();
        let solved: Vec<(Vec<O>, DemuxReport)> = groups
            .par_iter()
            .flat_map_iter(|group| group.chunks(PIXELS_PER_TASK))
            .map(|chunk| -> Result<(Vec<O>, DemuxReport)> {
                let key = keys[chunk[0]];
                let mut out = vec![O::NAN; chunk.len() * out_n];
                if key == 0 {
                    let rep = DemuxReport {
                        unmeasured_pixels: chunk.len(),
                        ..Default::default()
                    };
                    return Ok((out, rep));
                }
                let eq = &systems[&key];
                let m = eq.kept_rows.len();
                let mut p = Vec::with_capacity(chunk.len() * m);
                for &px in chunk {
                    p.extend(
                        eq.kept_rows
                            .iter()
                            .map(|&r| measurements[px * rows + r].to_f64()),
                    );
                }
                let mut buffers = ChunkBuffers::<f64>::new(n, m);
                let rep = solve_chunk(eq, &p, &mut out, &output, options, &mut buffers)?;
                Ok((out, rep))
            })
            .collect::<Result<_>>()?;
        let chunks = groups.iter().flat_map(|g| g.chunks(PIXELS_PER_TASK));
        for (chunk, (out, rep)) in chunks.zip(solved) {
            for (i, &px) in chunk.iter().enumerate() {
                result[px * out_n..(px + 1) * out_n]
                    .copy_from_slice(&out[i * out_n..(i + 1) * out_n]);
            }
            report = report.merge(rep);
        }
    }
    report.pixels = pixels;
    Ok(report)
}

/// Every pixel sees every measurement: one system, no gathering. Work is split into a few
/// tasks per thread, each solving its pixels chunk by chunk with one set of buffers.
#[allow(clippy::too_many_arguments)]
fn solve_complete<I: Sample, O: Sample>(
    c: &[f64],
    rows: usize,
    n: usize,
    measurements: &[I],
    output: &Range<usize>,
    options: &DemuxOptions,
    result: &mut [O],
) -> Result<DemuxReport> {
    let pixels = measurements.len() / rows;
    let out_n = output.len();
    let eq = NormalEquations::new(c, n, (0..rows).collect(), options.lambda)?;
    let tasks = rayon::current_num_threads() * TASKS_PER_THREAD;
    let per_task = pixels.div_ceil(tasks).div_ceil(PIXELS_PER_TASK).max(1) * PIXELS_PER_TASK;
    let mut report = result
        .par_chunks_mut(per_task * out_n)
        .zip(measurements.par_chunks(per_task * rows))
        .map(|(out, p)| {
            let mut buffers = ChunkBuffers::<I>::new(n, rows);
            let mut report = DemuxReport::default();
            let chunks = out
                .chunks_mut(PIXELS_PER_TASK * out_n)
                .zip(p.chunks(PIXELS_PER_TASK * rows));
            for (o, pc) in chunks {
                report = report.merge(solve_chunk(&eq, pc, o, output, options, &mut buffers)?);
            }
            Ok(report)
        })
        .try_reduce(DemuxReport::default, |a, b| Ok(a.merge(b)))?;
    report.pixels = pixels;
    report.distinct_masks = 1;
    Ok(report)
}

/// Checks shapes and values; returns N and whether no measurement is missing.
fn validate<I: Sample>(
    c: &[f64],
    rows: usize,
    measurements: &[I],
    mask: Option<&[bool]>,
    output: &Range<usize>,
    options: &DemuxOptions,
) -> Result<(usize, bool)> {
    if rows == 0 || rows > MAX_MEASUREMENTS || !c.len().is_multiple_of(rows) || c.is_empty() {
        return Err(Error::raster(
            "sensing matrix",
            format!("{} values in {rows} rows", c.len()),
            format!("1 to {MAX_MEASUREMENTS} full rows"),
        ));
    }
    let n = c.len() / rows;
    if let Some(v) = c.iter().find(|v| !v.is_finite()) {
        return Err(Error::NonFinite {
            what: "a value of the sensing matrix".into(),
            value: *v,
        });
    }
    if !measurements.len().is_multiple_of(rows) {
        return Err(Error::Shape {
            op: "demultiplex measurements".into(),
            got: vec![measurements.len()],
            expected: vec![measurements.len() / rows, rows],
        });
    }
    if let Some(m) = mask {
        if m.len() != measurements.len() {
            return Err(Error::Shape {
                op: "demultiplex mask".into(),
                got: vec![m.len()],
                expected: vec![measurements.len()],
            });
        }
    }
    // One pass for both checks: the first infinite value (an error) and any NaN (missing).
    const SCAN_BLOCK: usize = 1 << 16;
    let (first_infinite, any_missing) = measurements
        .par_chunks(SCAN_BLOCK)
        .enumerate()
        .map(|(block, values)| {
            let mut infinite = None;
            let mut missing = false;
            for (i, v) in values.iter().enumerate() {
                let v = v.to_f64();
                missing |= v.is_nan();
                if infinite.is_none() && v.is_infinite() {
                    infinite = Some(block * SCAN_BLOCK + i);
                }
            }
            (infinite, missing)
        })
        .reduce(
            || (None, false),
            |a, b| (a.0.min(b.0).or(a.0).or(b.0), a.1 || b.1),
        );
    if let Some(i) = first_infinite {
        return Err(Error::NonFinite {
            what: format!(
                "measurement of pixel {} channel {} (NaN marks a missing one)",
                i / rows,
                i % rows
            ),
            value: measurements[i].to_f64(),
        });
    }
    let complete = !any_missing && mask.is_none_or(|m| m.par_iter().all(|&k| k));
    if output.end > n || output.is_empty() {
        return Err(Error::setting(
            "demultiplex: output knots",
            format!("{output:?}"),
            format!("a non-empty range within the {n} knots of C"),
        ));
    }
    if !(options.lambda.is_finite() && options.lambda >= 0.0) {
        return Err(Error::out_of_range(
            "lambda",
            options.lambda,
            "finite and >= 0",
        ));
    }
    Ok((n, complete))
}

/// Copies a solution into the output type.
fn write_spectrum<O: Sample>(dst: &mut [O], values: &[f64]) {
    for (d, &v) in dst.iter_mut().zip(values) {
        *d = O::from_f64(v);
    }
}

/// Per-task buffers, reused across the chunks one rayon task solves; `C` is the type the
/// batched product is computed in.
struct ChunkBuffers<C> {
    scratch: Scratch,
    /// Unconstrained solutions of a chunk, `PIXELS_PER_TASK × n`.
    s_hat: Vec<C>,
    /// One pixel's unconstrained solution in f64 (pivoting runs in f64).
    hat64: Vec<f64>,
    /// One pixel's measurements in f64 (iterative solvers).
    p64: Vec<f64>,
}

impl<C> ChunkBuffers<C> {
    fn new(n: usize, rows: usize) -> Self {
        ChunkBuffers {
            scratch: Scratch::new(n, rows),
            s_hat: Vec::new(),
            hat64: vec![0.0; n],
            p64: vec![0.0; rows],
        }
    }
}

/// Solves one chunk of pixels that share `eq`; `p` holds their kept measurements.
fn solve_chunk<C: Sample, O: Sample>(
    eq: &NormalEquations,
    p: &[C],
    out: &mut [O],
    output: &Range<usize>,
    options: &DemuxOptions,
    buffers: &mut ChunkBuffers<C>,
) -> Result<DemuxReport> {
    if options.solver == Solver::Exact {
        solve_chunk_exact(eq, p, out, output, buffers)
    } else {
        solve_chunk_iterative(eq, p, out, output, options, buffers)
    }
}

/// [`solve_chunk`] by the exact path: the unconstrained solutions of the whole chunk in one
/// product, then block principal pivoting for the pixels with negative entries.
fn solve_chunk_exact<C: Sample, O: Sample>(
    eq: &NormalEquations,
    p: &[C],
    out: &mut [O],
    output: &Range<usize>,
    buffers: &mut ChunkBuffers<C>,
) -> Result<DemuxReport> {
    let n = eq.n;
    let m = eq.kept_rows.len();
    let pixels = p.len() / m;
    let out_n = output.len();
    let mut report = DemuxReport {
        pixels,
        ..Default::default()
    };
    let ChunkBuffers {
        scratch,
        s_hat,
        hat64,
        ..
    } = buffers;
    // Unconstrained solutions of the whole chunk in one product: Ŝ = P Aᵀ.
    C::batched_product(eq, p, pixels, s_hat);
    for px in 0..pixels {
        let hat = &s_hat[px * n..(px + 1) * n];
        let dst = &mut out[px * out_n..(px + 1) * out_n];
        if hat.iter().all(|&v| v.to_f64() >= 0.0) {
            for (d, &v) in dst.iter_mut().zip(&hat[output.clone()]) {
                *d = O::from_f64(v.to_f64());
            }
            continue;
        }
        report.bounded_pixels += 1;
        for (h, &v) in hat64.iter_mut().zip(hat) {
            *h = v.to_f64();
        }
        let hat = &hat64[..];
        let Scratch {
            free,
            s,
            y,
            b,
            dense,
            ..
        } = &mut *scratch;
        for i in 0..n {
            b[i] = eq.h[i * n..(i + 1) * n]
                .iter()
                .zip(hat)
                .map(|(h, v)| h * v)
                .sum();
            free[i] = hat[i] > 0.0;
        }
        let (ts, ty) = tolerances(eq, hat, b, EXACT_TOLERANCE);
        report.iterations += block_principal_pivoting(free, s, y, ts, ty, |f, s, y| {
            subproblem_schur(eq, hat, b, f, s, y, dense)
        })? as u64;
        write_spectrum(dst, &s[output.clone()]);
    }
    Ok(report)
}

/// [`solve_chunk`] by an iterative solver (or the dense reference), pixel by pixel.
fn solve_chunk_iterative<C: Sample, O: Sample>(
    eq: &NormalEquations,
    p: &[C],
    out: &mut [O],
    output: &Range<usize>,
    options: &DemuxOptions,
    buffers: &mut ChunkBuffers<C>,
) -> Result<DemuxReport> {
    let n = eq.n;
    let m = eq.kept_rows.len();
    let pixels = p.len() / m;
    let out_n = output.len();
    let mut report = DemuxReport {
        pixels,
        ..Default::default()
    };
    let ChunkBuffers {
        scratch,
        hat64,
        p64,
        ..
    } = buffers;
    let lipschitz = if options.solver == Solver::ProjectedGradient {
        eq.largest_eigenvalue()
    } else {
        0.0
    };
    for px in 0..pixels {
        for (d, &v) in p64.iter_mut().zip(&p[px * m..(px + 1) * m]) {
            *d = v.to_f64();
        }
        let pv = &p64[..m];
        let dst = &mut out[px * out_n..(px + 1) * out_n];
        let Scratch {
            free,
            s,
            y,
            b,
            dense,
            work,
        } = &mut *scratch;
        eq.rhs(pv, b);
        let mut iterations = 0usize;
        match options.solver {
            Solver::ProjectedGradient => {
                iterations = projected_gradient::projected_gradient(
                    eq,
                    b,
                    lipschitz,
                    options.tolerance,
                    options.max_iterations,
                    s,
                    work,
                );
            }
            Solver::Exact | Solver::Reference | Solver::ConjugateGradient | Solver::Lsqr => {
                free.fill(true);
                s.fill(0.0);
                let (tol, tol_rel) = (options.tolerance, options.tolerance.max(EXACT_TOLERANCE));
                // Unconstrained start, then pivoting from its sign pattern.
                let mut inner =
                    |f: &[bool], s: &mut [f64], y: &mut [f64], it: &mut usize| -> Result<()> {
                        match options.solver {
                            Solver::ConjugateGradient => krylov::subproblem_conjugate_gradient(
                                eq,
                                b,
                                f,
                                s,
                                y,
                                tol,
                                options.max_iterations,
                                work,
                                it,
                            ),
                            Solver::Lsqr => krylov::subproblem_lsqr(
                                eq,
                                pv,
                                b,
                                f,
                                s,
                                y,
                                tol,
                                options.max_iterations,
                                it,
                            ),
                            _ => subproblem_dense(eq, b, f, s, y, dense),
                        }
                    };
                inner(free, s, y, &mut iterations)?;
                if s.iter().any(|&v| v < 0.0) {
                    for i in 0..n {
                        free[i] = s[i] > 0.0;
                    }
                    hat64.copy_from_slice(s);
                    let (ts, ty) = tolerances(eq, hat64, b, tol_rel.max(1e-8));
                    block_principal_pivoting(free, s, y, ts, ty, |f, s, y| {
                        inner(f, s, y, &mut iterations)
                    })?;
                }
                for v in s.iter_mut() {
                    *v = v.max(0.0);
                }
            }
        }
        if s.contains(&0.0) {
            report.bounded_pixels += 1;
        }
        report.iterations += iterations as u64;
        write_spectrum(dst, &s[output.clone()]);
    }
    Ok(report)
}

#[cfg(test)]
mod tests;
