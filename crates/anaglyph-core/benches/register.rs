//! Throughput of multi-baseline registration on a synthetic 2×4 array at 320×240 with 32
//! disparities: every view's learned features, the occlusion-robust multi-view cost
//! volumes, SGM with the half-step subpixel fit, and the cross-check. The stages' own
//! times are printed once; `anaglyph reconstruct` writes the same stages' times to its
//! manifest.

use anaglyph_core::register::{
    multi_baseline_disparities, ArrayGeometry, CoarseToFine, RegistrationMode,
    RegistrationSettings, ViewImage,
};
use anaglyph_core::stereo::{DisparityRange, GreyImage, MatchingCost, MatchingNetwork};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};

const W: usize = 320;
const H: usize = 240;
const D: usize = 32;
const ROWS: usize = 2;
const COLS: usize = 4;
const BASELINE_RATIO: f64 = 5.0 / 3.0;

/// A plane at 9 px of disparity per column step: view (r, c) sees the texture shifted
/// by 9 · (c, ratio · r).
fn views() -> Vec<ViewImage> {
    let texture = |x: f64, y: f64| {
        (0.5 + 0.2 * ((0.37 * x + 0.11 * y).sin() + 0.7 * (0.23 * y - 0.19 * x).sin())
            + 0.1 * ((x * 0.9898 + y * 0.233).sin() * (0.31 * x).cos())) as f32
    };
    let disparity = 9.0;
    (0..ROWS * COLS)
        .map(|i| {
            let (row, col) = (i / COLS, i % COLS);
            let (dx, dy) = (
                disparity * col as f64,
                disparity * BASELINE_RATIO * row as f64,
            );
            let gain = 1.0 - 0.05 * i as f32;
            ViewImage {
                image: GreyImage {
                    channels: 1,
                    width: W,
                    height: H,
                    data: (0..W * H)
                        .map(|p| gain * texture((p % W) as f64 + dx, (p / W) as f64 + dy))
                        .collect(),
                },
                matching: Vec::new(),
                measured: None,
            }
        })
        .collect()
}

fn registration(c: &mut Criterion) {
    let images = views();
    let network = MatchingNetwork::default_fast().expect("built-in network");
    let geometry = ArrayGeometry::grid(ROWS, COLS, BASELINE_RATIO);
    let settings = RegistrationSettings {
        mode: RegistrationMode::MultiBaseline,
        cost: MatchingCost::Learned(&network),
        range: DisparityRange::up_to(D).unwrap(),
        coarse_to_fine: CoarseToFine::Off,
        previous: None,
    };
    let once = multi_baseline_disparities(&images, &geometry, &settings, &|_, _| {})
        .expect("registration");
    for (stage, seconds) in &once.timings {
        println!("{stage}: {seconds:.3} s");
    }
    let mut group = c.benchmark_group("multi_baseline_2x4_320x240_32d");
    group.sample_size(10);
    group.throughput(Throughput::Elements((W * H * ROWS * COLS) as u64));
    group.bench_function("registration", |b| {
        b.iter(|| multi_baseline_disparities(&images, &geometry, &settings, &|_, _| {}))
    });
    group.finish();
}

criterion_group!(benches, registration);
criterion_main!(benches);
