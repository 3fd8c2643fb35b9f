//! Solver tests against closed forms and an independent brute-force KKT search.

use super::*;

const ALL: [Solver; 5] = [
    Solver::Exact,
    Solver::Reference,
    Solver::ConjugateGradient,
    Solver::Lsqr,
    Solver::ProjectedGradient,
];

/// Agreement each solver must reach with the exact minimiser.
fn tolerance(solver: Solver) -> f64 {
    match solver {
        Solver::Exact | Solver::Reference => 1e-9,
        Solver::ConjugateGradient | Solver::Lsqr => 1e-6,
        Solver::ProjectedGradient => 1e-5,
    }
}

fn options(solver: Solver, lambda: f64) -> DemuxOptions {
    DemuxOptions {
        lambda,
        solver,
        ..Default::default()
    }
}

/// Deterministic pseudo-random numbers in [0, 1) (SplitMix64).
fn uniform(seed: &mut u64) -> f64 {
    *seed = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *seed;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

/// Gaussian elimination with partial pivoting, written independently of the solvers.
fn gauss_solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Vec<f64> {
    let n = b.len();
    for k in 0..n {
        let p = (k..n)
            .max_by(|&i, &j| a[i][k].abs().total_cmp(&a[j][k].abs()))
            .unwrap();
        a.swap(k, p);
        b.swap(k, p);
        for i in k + 1..n {
            let f = a[i][k] / a[k][k];
            for j in k..n {
                a[i][j] -= f * a[k][j];
            }
            b[i] -= f * b[k];
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        x[i] = (b[i] - (i + 1..n).map(|j| a[i][j] * x[j]).sum::<f64>()) / a[i][i];
    }
    x
}

/// The constrained minimiser by enumerating all 2^n free sets (n ≤ 10): the feasible
/// stationary point with the smallest objective.
fn brute_force(c: &[f64], rows: usize, n: usize, p: &[f64], lambda: f64) -> Vec<f64> {
    let mut h = vec![vec![0.0; n]; n];
    let mut b = vec![0.0; n];
    for i in 0..n {
        for j in 0..n {
            h[i][j] = (0..rows).map(|r| c[r * n + i] * c[r * n + j]).sum::<f64>();
        }
        b[i] = (0..rows).map(|r| c[r * n + i] * p[r]).sum();
    }
    for i in 0..n - 1 {
        h[i][i] += lambda;
        h[i + 1][i + 1] += lambda;
        h[i][i + 1] -= lambda;
        h[i + 1][i] -= lambda;
    }
    let objective = |s: &[f64]| {
        let data: f64 = (0..rows)
            .map(|r| {
                let v = (0..n).map(|j| c[r * n + j] * s[j]).sum::<f64>() - p[r];
                v * v
            })
            .sum();
        data + lambda * s.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum::<f64>()
    };
    let mut best = (f64::INFINITY, vec![0.0; n]);
    for set in 0u32..(1 << n) {
        let free: Vec<usize> = (0..n).filter(|i| set & (1 << i) != 0).collect();
        let mut s = vec![0.0; n];
        if !free.is_empty() {
            let a = free
                .iter()
                .map(|&i| free.iter().map(|&j| h[i][j]).collect())
                .collect();
            let x = gauss_solve(a, free.iter().map(|&i| b[i]).collect());
            for (k, &i) in free.iter().enumerate() {
                s[i] = x[k];
            }
        }
        if s.iter().all(|&v| v >= -1e-12) {
            let f = objective(&s);
            if f < best.0 {
                best = (f, s);
            }
        }
    }
    best.1
}

#[test]
fn every_solver_matches_the_closed_form_when_the_bound_is_inactive() {
    // C = I (3×3), λ = 0.5: s = (I + λDᵀD)⁻¹ p. For p = (1, 2, 3):
    // (I + 0.5 DᵀD) = [[1.5, −0.5, 0], [−0.5, 2, −0.5], [0, −0.5, 1.5]]; by symmetry
    // s = (2 − a, 2, 2 + a) with 1.5(2 − a) − 1 = 1, so a = 2/3.
    let c = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    for solver in ALL {
        let (s, report) =
            demultiplex(&c, 3, &[1.0, 2.0, 3.0], None, 0..3, &options(solver, 0.5)).unwrap();
        for (got, want) in s.iter().zip([4.0 / 3.0, 2.0, 8.0 / 3.0]) {
            assert!((got - want).abs() < tolerance(solver), "{solver:?}: {s:?}");
        }
        assert_eq!(report.pixels, 1);
    }
}

#[test]
fn every_solver_matches_brute_force_kkt_on_random_bounded_problems() {
    let mut seed = 7u64;
    let (rows, n) = (4, 7);
    for trial in 0..30 {
        let c: Vec<f64> = (0..rows * n).map(|_| uniform(&mut seed)).collect();
        // Measurements of a spectrum with negative parts force active bounds.
        let p: Vec<f64> = (0..rows).map(|_| uniform(&mut seed) * 2.0 - 0.7).collect();
        let lambda = if trial % 2 == 0 { 0.01 } else { 0.3 };
        let want = brute_force(&c, rows, n, &p, lambda);
        for solver in ALL {
            let (got, _) = demultiplex(&c, rows, &p, None, 0..n, &options(solver, lambda)).unwrap();
            let err = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            let scale = want.iter().fold(1.0f64, |m, v| m.max(v.abs()));
            assert!(
                err <= tolerance(solver) * scale * 10.0,
                "trial {trial} {solver:?}: {got:?} vs {want:?}"
            );
        }
    }
}

#[test]
fn fast_path_equals_the_plain_reference_on_many_pixels() {
    let mut seed = 11u64;
    let (rows, n, pixels) = (12, 20, 3000);
    let c: Vec<f64> = (0..rows * n).map(|_| uniform(&mut seed) * 0.1).collect();
    let p: Vec<f64> = (0..rows * pixels)
        .map(|_| uniform(&mut seed) - 0.2)
        .collect();
    let (fast, rf) = demultiplex(&c, rows, &p, None, 0..n, &options(Solver::Exact, 0.01)).unwrap();
    let (plain, _) =
        demultiplex(&c, rows, &p, None, 0..n, &options(Solver::Reference, 0.01)).unwrap();
    assert!(
        rf.bounded_pixels > pixels / 4,
        "test should exercise the bound: {rf:?}"
    );
    let err = fast
        .iter()
        .zip(&plain)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-8, "max difference {err}");
    assert!(fast.iter().all(|&v| v >= 0.0));
}

#[test]
fn masked_measurements_equal_dropping_the_rows() {
    let mut seed = 3u64;
    let (rows, n) = (6, 5);
    let c: Vec<f64> = (0..rows * n).map(|_| uniform(&mut seed)).collect();
    let p: Vec<f64> = (0..rows * 4).map(|_| uniform(&mut seed)).collect();
    let mut with_nan = p.clone();
    with_nan[2] = f64::NAN; // pixel 0, row 2
    let mut mask = vec![true; p.len()];
    mask[6 + 4] = false; // pixel 1, row 4
    for v in &mut with_nan[18..24] {
        *v = f64::NAN; // pixel 3: nothing measured
    }
    let (s, report) = demultiplex(
        &c,
        rows,
        &with_nan,
        Some(&mask),
        0..n,
        &options(Solver::Exact, 0.01),
    )
    .unwrap();
    assert_eq!(report.distinct_masks, 3);
    assert_eq!(report.unmeasured_pixels, 1);
    assert!(s[15..20].iter().all(|v| v.is_nan()));
    for (px, dropped) in [(0usize, 2usize), (1, 4)] {
        let kept: Vec<usize> = (0..rows).filter(|&r| r != dropped).collect();
        let c_kept: Vec<f64> = kept
            .iter()
            .flat_map(|&r| c[r * n..(r + 1) * n].to_vec())
            .collect();
        let p_kept: Vec<f64> = kept.iter().map(|&r| p[px * rows + r]).collect();
        let want = brute_force(&c_kept, rows - 1, n, &p_kept, 0.01);
        for (a, b) in s[px * n..(px + 1) * n].iter().zip(&want) {
            assert!((a - b).abs() < 1e-9, "pixel {px}");
        }
    }
    // Pixel 2 saw everything.
    let want = brute_force(&c, rows, n, &p[12..18], 0.01);
    for (a, b) in s[10..15].iter().zip(&want) {
        assert!((a - b).abs() < 1e-9);
    }
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let c = [1.0, 0.0, 0.0, 1.0];
    let o = options(Solver::Exact, 0.01);
    assert_eq!(
        demultiplex(&c, 2, &[1.0, 2.0, 3.0], None, 0..2, &o)
            .err()
            .map(|e| e.kind()),
        Some("Shape")
    );
    let infinite = demultiplex(&c, 2, &[1.0, f64::INFINITY], None, 0..2, &o).unwrap_err();
    assert!(matches!(infinite, Error::NonFinite { .. }), "{infinite:?}");
    assert!(infinite.to_string().contains("is inf"), "{infinite}");
    assert!(matches!(
        demultiplex(&[1.0, f64::NAN, 0.0, 1.0], 2, &[1.0, 1.0], None, 0..2, &o),
        Err(Error::NonFinite { .. })
    ));
    assert!(matches!(
        demultiplex(
            &c,
            2,
            &[1.0, 1.0],
            None,
            0..2,
            &options(Solver::Exact, -1.0)
        ),
        Err(Error::OutOfRange { .. })
    ));
    assert_eq!(
        demultiplex(&c, 2, &[1.0, 1.0], Some(&[true]), 0..2, &o)
            .err()
            .map(|e| e.kind()),
        Some("Shape")
    );
    assert_eq!(
        demultiplex(&c, 2, &[1.0, 1.0], None, 0..3, &o)
            .err()
            .map(|e| e.kind()),
        Some("Setting")
    );
    let singular = demultiplex(
        &[1.0, 1.0],
        1,
        &[1.0],
        None,
        0..2,
        &options(Solver::Exact, 0.0),
    );
    assert!(matches!(singular, Err(Error::SingularNormalMatrix { .. })));
}

#[test]
fn f32_input_and_output_match_the_f64_path() {
    let mut seed = 5u64;
    let (rows, n, pixels) = (8, 12, 500);
    let c: Vec<f64> = (0..rows * n).map(|_| uniform(&mut seed) * 0.2).collect();
    let p: Vec<f64> = (0..rows * pixels)
        .map(|_| uniform(&mut seed) - 0.1)
        .collect();
    let p32: Vec<f32> = p.iter().map(|&v| v as f32).collect();
    let o = options(Solver::Exact, 0.01);
    let (wide, _) = demultiplex(
        &c,
        rows,
        &p32.iter().map(|&v| f64::from(v)).collect::<Vec<_>>(),
        None,
        2..10,
        &o,
    )
    .unwrap();
    let (narrow, report) = demultiplex_as::<f32, f32>(&c, rows, &p32, None, 2..10, &o).unwrap();
    assert_eq!(report.pixels, pixels);
    for (a, b) in wide.iter().zip(&narrow) {
        assert!(
            (a - f64::from(*b)).abs() <= 1e-6 * (1.0 + a.abs()),
            "{a} vs {b}"
        );
    }
}
