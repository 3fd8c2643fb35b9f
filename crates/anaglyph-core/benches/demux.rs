//! Throughput of spectral demultiplexing (pixels/s) on the paper's 2×4 rig: the exact
//! fast path at several image sizes, and the per-pixel reference for scale. Measurements
//! are the ColorChecker and CIE TCS reflectances rendered through the rig at 1 nm with
//! sensor noise, tiled to the image size.

use anaglyph_core::builtin;
use anaglyph_core::capture::{measure_spectra, spectra_on_grid, CameraNoise};
use anaglyph_core::demux::{demultiplex, DemuxOptions, Solver};
use anaglyph_core::rig::{EffectiveResponses, Rig, SensingMatrix, PAPER_RIG_FILTERS};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

fn measurements(pixels: usize) -> (SensingMatrix, Vec<f64>) {
    let rig =
        Rig::from_file(Rig::paper_rig_file(&PAPER_RIG_FILTERS), ".".into()).expect("paper rig");
    let responses = EffectiveResponses::of_rig(&rig).expect("responses");
    let c = SensingMatrix::of_rig(&rig).expect("C");
    let mut spectra = Vec::new();
    for set in ["colorchecker_n_ohta", "tcs_cfi2017_99"] {
        spectra.extend(
            spectra_on_grid(&builtin::reflectances(set).expect("set"), &responses).expect("grid"),
        );
    }
    let clean = measure_spectra(&spectra, &responses, &c);
    let tiled: Vec<f64> = clean
        .iter()
        .copied()
        .cycle()
        .take(pixels * c.rows())
        .collect();
    let noisy = CameraNoise::default().apply(&tiled, 7).values;
    (c, noisy)
}

fn bench_demux(criterion: &mut Criterion) {
    let mut group = criterion.benchmark_group("demux_exact");
    group.sample_size(10);
    for pixels in [16_384usize, 262_144, 1_048_576] {
        let (c, p) = measurements(pixels);
        let output = c.reported_offset..c.reported_offset + c.reported.count;
        group.throughput(Throughput::Elements(pixels as u64));
        group.bench_with_input(BenchmarkId::from_parameter(pixels), &p, |b, p| {
            b.iter(|| {
                demultiplex(
                    c.values(),
                    c.rows(),
                    p,
                    None,
                    output.clone(),
                    &DemuxOptions::default(),
                )
                .expect("solve")
            });
        });
    }
    group.finish();

    let mut group = criterion.benchmark_group("demux_reference");
    group.sample_size(10);
    let pixels = 16_384;
    let (c, p) = measurements(pixels);
    let output = c.reported_offset..c.reported_offset + c.reported.count;
    let options = DemuxOptions {
        solver: Solver::Reference,
        ..DemuxOptions::default()
    };
    group.throughput(Throughput::Elements(pixels as u64));
    group.bench_function(BenchmarkId::from_parameter(pixels), |b| {
        b.iter(|| {
            demultiplex(c.values(), c.rows(), &p, None, output.clone(), &options).expect("solve")
        });
    });
    group.finish();
}

criterion_group!(benches, bench_demux);
criterion_main!(benches);
