//! Throughput of multi-baseline registration on a synthetic 2×4 array at 320×240 with 32
//! disparities: every view's learned features, the occlusion-robust multi-view cost
//! volumes, SGM with the half-step subpixel fit, and the cross-check. The stages' own
//! times are printed once; `anaglyph reconstruct` writes the same stages' times to its
//! manifest. The warp (`warp_3x3_640x480`) gathers a 3×3 array's nine captures into one
//! view along a slanted plane with a nearer square in front, so that most measurements
//! take the Lanczos kernel and the square's edges the occlusion tests.

use anaglyph_core::disparity::{DisparityConvention, DisparityMap};
use anaglyph_core::image::Image;
use anaglyph_core::register::{
    gather_measurements, multi_baseline_disparities, Admission, ArrayGeometry, CoarseToFine,
    NormalisedView, RegistrationMode, RegistrationSettings, ViewImage, WarpKernel,
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

/// Disparity (px per column step) of the scene at a pixel of the view at array cell
/// (row, col) of a 3×3 grid: a plane slanting from 3.3 to 6.1 px, and a square in front
/// at 11.4 px, which the view sees shifted by its disparity.
fn scene_disparity(x: f64, y: f64, (row, col): (f64, f64)) -> f64 {
    let square = 11.4;
    let (sx, sy) = (x + square * (col - 1.0), y + square * (row - 1.0));
    if (220.0..380.0).contains(&sx) && (160.0..300.0).contains(&sy) {
        square
    } else {
        3.3 + 2.8 * x / WARP_W as f64
    }
}

const WARP_W: usize = 640;
const WARP_H: usize = 480;

fn warp(c: &mut Criterion) {
    let geometry = ArrayGeometry::grid(3, 3, 1.0);
    let texture = |x: f64, y: f64| {
        (0.4 + 0.15 * ((0.41 * x + 0.13 * y).sin() + 0.6 * (0.29 * y - 0.17 * x).sin())) as f32
    };
    let cells: Vec<(f64, f64)> = (0..9).map(|i| ((i / 3) as f64, (i % 3) as f64)).collect();
    let views: Vec<NormalisedView> = cells
        .iter()
        .map(|&(row, col)| NormalisedView {
            image: Image::new(
                WARP_W,
                WARP_H,
                1,
                (0..WARP_W * WARP_H)
                    .map(|p| {
                        let (x, y) = ((p % WARP_W) as f64, (p / WARP_W) as f64);
                        let d = scene_disparity(x, y, (row, col));
                        texture(x + d * (col - 1.0), y + d * (row - 1.0))
                    })
                    .collect(),
            )
            .expect("a view"),
        })
        .collect();
    let maps: Vec<DisparityMap> = cells
        .iter()
        .map(|&cell| {
            let data = (0..WARP_W * WARP_H)
                .map(|p| scene_disparity((p % WARP_W) as f64, (p / WARP_W) as f64, cell) as f32)
                .collect();
            DisparityMap::new(WARP_W, WARP_H, DisparityConvention::ColumnStep, data).expect("a map")
        })
        .collect();
    let once = gather_measurements(
        4,
        &views,
        &maps,
        &geometry,
        Admission::DepthOrder,
        WarpKernel::Lanczos3,
    )
    .expect("gathered");
    println!(
        "warp: {:.1} % of the centre view's pixels measured by every camera",
        100.0 * once.visibility.seen_by_all
    );
    let mut group = c.benchmark_group("warp_3x3_640x480");
    group.sample_size(10);
    group.throughput(Throughput::Elements((WARP_W * WARP_H * 9) as u64));
    group.bench_function("gather_centre_view", |b| {
        b.iter(|| {
            gather_measurements(
                4,
                &views,
                &maps,
                &geometry,
                Admission::DepthOrder,
                WarpKernel::Lanczos3,
            )
        })
    });
    group.finish();
}

criterion_group!(benches, registration, warp);
criterion_main!(benches);
