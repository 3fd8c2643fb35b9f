//! What writing one frame into a Zarr store costs (`LightFieldStore::write_frame`): the
//! tabletop through the paper's rig at 320×240 (8 views, 24 bands, 24 registered
//! channels, reconstructed from the true disparities), with cubes, and with cubes and
//! registered stacks, into a store in the system's temporary folder.

use anaglyph_core::io::{LightFieldStore, StoreLayout};
use anaglyph_core::reconstruct::{
    reconstruct, ArrayCaptures, Disparities, LightField, PipelineSettings,
};
use anaglyph_core::rig::{Rig, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{Scene, SceneFile};
use anaglyph_core::simulate::{Simulation, SimulationSettings};
use anaglyph_core::solve::SolveSettings;
use anaglyph_core::stereo::MatchingCost;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::path::Path;

fn frame(width: usize, height: usize) -> (Rig, LightField) {
    let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    file.focal_length_px = Some(1800.0 * width as f64 / 640.0);
    let rig = Rig::from_file(file, ".".into()).expect("rig");
    let scene = Scene::resolve(
        SceneFile::preset("tabletop").expect("scene"),
        Path::new("."),
    )
    .expect("scene");
    let settings = SimulationSettings {
        width,
        height,
        seed: 1,
        ..SimulationSettings::default()
    };
    let simulation = Simulation::run(&rig, &scene, settings).expect("simulation");
    let captures = ArrayCaptures::from_simulation(&simulation);
    let pipeline = PipelineSettings {
        disparities: Disparities::Given(simulation.disparity_maps()),
        solve: SolveSettings::paper(),
        keep_registered: true,
        ..PipelineSettings::new(MatchingCost::Census)
    };
    let field = reconstruct(&rig, &captures, &pipeline, &|_, _, _| {}).expect("reconstruct");
    (rig, field)
}

fn bench_store(criterion: &mut Criterion) {
    let (_rig, field) = frame(320, 240);
    let dir = tempfile::tempdir().expect("temporary folder");
    let mut group = criterion.benchmark_group("zarr_write_frame");
    group.sample_size(20);
    group.throughput(Throughput::Elements(
        (field.width * field.height * field.views.len()) as u64,
    ));
    for (name, registered) in [("cube", false), ("both", true)] {
        let layout = StoreLayout {
            frames: vec![0],
            views: field.views.iter().map(|v| v.name.clone()).collect(),
            width: field.width,
            height: field.height,
            wavelengths: field.bands.clone(),
            channels: if registered {
                field.channel_labels.clone()
            } else {
                Vec::new()
            },
            run: serde_json::json!({ "bench": name }),
        };
        let store = LightFieldStore::create(&dir.path().join(format!("{name}.zarr")), layout, true)
            .expect("store");
        group.bench_function(format!("paper-2x4_320x240_{name}"), |b| {
            b.iter(|| store.write_frame(0, &field, 1.0).expect("write"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_store);
criterion_main!(benches);
