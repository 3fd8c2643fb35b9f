//! Throughput of the guided spectral refinement (pixels/s): a 24-band cube filtered with a
//! three-channel guide at the default radius, at VGA and full-HD sizes. The content is a
//! seeded pseudo-random texture; the filter's cost does not depend on it. Also the scene
//! prior (learning it and filling a view's under-measured pixels, propagation rounds
//! included: `solve::fill_view`) at the paper rig's
//! shape: 24 measurement rows, 52 knots, a quarter of the pixels missing 3 to 18 rows.

use anaglyph_core::image::Image;
use anaglyph_core::refine::{guided_filter, GuidedFilter, GuidedRefinement};
use anaglyph_core::rig::SensingMatrix;
use anaglyph_core::solve::{fill_view, ScenePriorSettings};
use anaglyph_core::spectrum::SpectralShape;
use criterion::{criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion, Throughput};

fn texture(len: usize, seed: u64) -> Vec<f32> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..len)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            0.05 + 0.9 * ((state >> 40) as f32 / (1u64 << 24) as f32)
        })
        .collect()
}

fn bench_refine(criterion: &mut Criterion) {
    let mut group = criterion.benchmark_group("guided_refinement");
    group.sample_size(10);
    let defaults = GuidedRefinement::default();
    let filter = GuidedFilter {
        radius: defaults.radius,
        epsilon: defaults.epsilon,
    };
    let bands = 24;
    for (w, h) in [(640usize, 480usize), (1920, 1080)] {
        let guide = Image::new(w, h, 3, texture(w * h * 3, 1)).expect("guide");
        let cube = Image::new(w, h, bands, texture(w * h * bands, 2)).expect("cube");
        group.throughput(Throughput::Elements((w * h) as u64));
        group.bench_with_input(
            BenchmarkId::from_parameter(format!("{w}x{h}")),
            &(guide, cube),
            |b, (guide, cube)| {
                b.iter(|| guided_filter(guide, cube, None, filter).expect("filter"));
            },
        );
    }
    group.finish();
}

fn bench_scene_prior(criterion: &mut Criterion) {
    let mut group = criterion.benchmark_group("scene_prior");
    group.sample_size(10);
    let (rows, knots) = (24usize, 52usize);
    let c = texture(rows * knots, 3);
    let c: Vec<f64> = c.iter().map(|&v| v as f64).collect();
    let shape = SpectralShape::new(400.0, 5.0, knots).expect("shape");
    let sensing = SensingMatrix::from_dense(rows, shape, c.clone()).expect("C");
    for (w, h) in [(640usize, 480usize), (1920, 1080)] {
        let pixels = w * h;
        // Spectra from three texture planes (a low-rank scene), measured through C.
        let planes = texture(pixels * 3, 4);
        let mut spectra = vec![0.0f32; pixels * knots];
        let mut measurements = vec![0.0f32; pixels * rows];
        for px in 0..pixels {
            let z = &planes[px * 3..px * 3 + 3];
            let s = &mut spectra[px * knots..(px + 1) * knots];
            for (k, v) in s.iter_mut().enumerate() {
                let t = k as f32 / knots as f32;
                *v = 0.3 * z[0] + 0.3 * z[1] * t + 0.3 * z[2] * (1.0 - t) * t;
            }
            // The leftmost quarter misses the last 3, 6, ... 18 rows in six column strips.
            let x = px % w;
            let missing = if x < w / 4 {
                3 * (1 + 6 * x / (w / 4))
            } else {
                0
            };
            for r in 0..rows {
                measurements[px * rows + r] = if r >= rows - missing {
                    f32::NAN
                } else {
                    c[r * knots..(r + 1) * knots]
                        .iter()
                        .zip(s.iter())
                        .map(|(a, &b)| (a * b as f64) as f32)
                        .sum()
                };
            }
        }
        let residuals = texture(pixels, 5);
        let settings = ScenePriorSettings::default();
        // The whole stage as `reconstruct` runs it (propagation rounds included); the
        // timed work must fill pixels, not reject them all at the gate.
        let fill = |spectra: &mut [f32]| {
            fill_view(
                &sensing,
                &measurements,
                spectra,
                &mut residuals.clone(),
                &settings,
            )
            .expect("fill")
            .expect("enough samples")
        };
        let report = fill(&mut spectra.clone());
        assert!(report.filled_pixels > pixels / 8, "{report:?}");
        group.throughput(Throughput::Elements(pixels as u64));
        group.bench_function(BenchmarkId::from_parameter(format!("{w}x{h}")), |b| {
            b.iter_batched(
                || spectra.clone(),
                |mut spectra| fill(&mut spectra),
                BatchSize::LargeInput,
            );
        });
    }
    group.finish();
}

criterion_group!(benches, bench_refine, bench_scene_prior);
criterion_main!(benches);
