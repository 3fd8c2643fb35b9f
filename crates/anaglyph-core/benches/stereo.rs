//! Throughput of the stereo stages on a 370×250 pair (a quarter of the 741×500
//! reference size) with 64 disparities: the learned cost (tower and cosine volume),
//! census, SGM and the disparity filters. Stages over a cost volume report pixel ×
//! disparities per second, the others pixels per second; the CLI's `match` prints the
//! same stages' times on real pairs.

use anaglyph_core::stereo::{
    bilateral_filter, census_cost_volume, learned_cost_volume, median_filter, normalise_image,
    semi_global_matching, tower_features, winner_take_all, Bilateral, DisparityRange, GreyImage,
    MatchingNetwork, SgmParameters,
};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};

const W: usize = 370;
const H: usize = 250;
const D: usize = 64;

/// The disparities searched, `[0, D)`.
fn range() -> DisparityRange {
    DisparityRange::up_to(D).expect("a non-empty range")
}

/// A textured pair: right(x) = left(x + 7) with a gain, so the costs have a real minimum.
fn pair() -> (GreyImage, GreyImage) {
    let texture = |x: f64, y: f64| {
        (0.5 + 0.2 * ((0.37 * x + 0.11 * y).sin() + 0.7 * (0.23 * y - 0.19 * x).sin())
            + 0.1 * ((x * 12.9898 + y * 78.233).sin() * 43758.5453).fract()) as f32
    };
    let make = |shift: f64, gain: f32| GreyImage {
        channels: 1,
        width: W,
        height: H,
        data: (0..W * H)
            .map(|i| gain * texture((i % W) as f64 + shift, (i / W) as f64))
            .collect(),
    };
    (make(0.0, 1.0), make(7.0, 0.6))
}

fn stages(c: &mut Criterion) {
    let (left, right) = pair();
    let network = MatchingNetwork::default_fast().expect("built-in network");
    let mut group = c.benchmark_group("stereo_370x250_64d");
    group.sample_size(10);
    let pixels = Throughput::Elements((W * H) as u64);
    let pixel_disparities = Throughput::Elements((W * H * D) as u64);
    group.throughput(pixels.clone());
    group.bench_function("mccnn_tower_one_image", |b| {
        b.iter(|| tower_features(&network, &left))
    });
    group.throughput(pixel_disparities);
    group.bench_function("mccnn_cost_volume", |b| {
        b.iter(|| learned_cost_volume(&network, &left, &right, range()))
    });
    group.bench_function("census_cost_volume", |b| {
        b.iter(|| census_cost_volume(&left, &right, range()))
    });
    let volume = census_cost_volume(&left, &right, range());
    let params = SgmParameters::MC_CNN_FAST_KITTI;
    group.bench_function("sgm_4_paths", |b| {
        b.iter(|| semi_global_matching(&volume, &left, &right, &params))
    });
    let disparity = winner_take_all(&volume);
    group.throughput(pixels);
    group.bench_function("median_5x5", |b| {
        b.iter(|| median_filter(&disparity, W, H, 2))
    });
    let normalised = normalise_image(&left);
    let bilateral = Bilateral {
        sigma: 4.64,
        threshold: 5.0,
        radius: 5,
    };
    group.bench_function("bilateral", |b| {
        b.iter(|| bilateral_filter(&disparity, &normalised, &bilateral))
    });
    group.finish();
}

criterion_group!(benches, stages);
criterion_main!(benches);
