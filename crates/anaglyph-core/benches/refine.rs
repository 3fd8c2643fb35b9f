//! Throughput of the guided spectral refinement (pixels/s): a 24-band cube filtered with a
//! three-channel guide at the default radius, at VGA and full-HD sizes. The content is a
//! seeded pseudo-random texture; the filter's cost does not depend on it.

use anaglyph_core::refine::{guided_filter, GuidedFilter, GuidedRefinement};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

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
        let guide = texture(w * h * 3, 1);
        let cube = texture(w * h * bands, 2);
        group.throughput(Throughput::Elements((w * h) as u64));
        group.bench_with_input(
            BenchmarkId::from_parameter(format!("{w}x{h}")),
            &(guide, cube),
            |b, (guide, cube)| {
                b.iter(|| {
                    guided_filter(guide, 3, None, cube, bands, w, h, filter).expect("filter")
                });
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench_refine);
criterion_main!(benches);
