//! The Zarr store of a frame sequence: what is written is read back bit for bit, a rerun
//! resumes, and stores of other runs, files and foreign folders are refused.

use anaglyph_core::io::{LightFieldStore, StoreLayout};
use anaglyph_core::reconstruct::{
    reconstruct, ArrayCaptures, Disparities, LightField, PipelineSettings,
};
use anaglyph_core::rig::{Rig, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{Scene, SceneFile};
use anaglyph_core::simulate::{Simulation, SimulationSettings};
use anaglyph_core::solve::SolveSettings;
use anaglyph_core::stereo::MatchingCost;
use std::path::Path;
use std::sync::Arc;
use zarrs::array::Array;
use zarrs::filesystem::FilesystemStore;

/// Frame `seed` of the tabletop through the paper's rig at 64×48, reconstructed from the
/// true disparities, with registered stacks.
fn frame(rig: &Rig, seed: u64) -> LightField {
    let scene = Scene::resolve(SceneFile::preset("tabletop").unwrap(), Path::new(".")).unwrap();
    let settings = SimulationSettings {
        width: 64,
        height: 48,
        seed,
        ..SimulationSettings::default()
    };
    let simulation = Simulation::run(rig, &scene, settings).unwrap();
    let captures = ArrayCaptures::from_simulation(&simulation);
    let pipeline = PipelineSettings {
        disparities: Disparities::Given(simulation.disparity_maps()),
        solve: SolveSettings::paper(),
        keep_registered: true,
        ..PipelineSettings::new(MatchingCost::Census)
    };
    reconstruct(rig, &captures, &pipeline, &|_, _, _| {}).unwrap()
}

fn layout(field: &LightField, frames: Vec<i64>, run: &str) -> StoreLayout {
    StoreLayout {
        frames,
        views: field.views.iter().map(|v| v.name.clone()).collect(),
        width: field.width,
        height: field.height,
        wavelengths: field.bands.clone(),
        channels: field.channel_labels.clone(),
        run: serde_json::json!({ "settings": run }),
    }
}

fn read<T: zarrs::array::ElementOwned>(path: &Path, name: &str) -> Vec<T> {
    let store = Arc::new(FilesystemStore::new(path).unwrap());
    let array = Array::open(store, &format!("/{name}")).unwrap();
    array.retrieve_array_subset(&array.subset_all()).unwrap()
}

#[test]
fn frames_written_to_a_store_read_back_bit_for_bit_and_a_rerun_resumes() {
    let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    file.focal_length_px = Some(180.0);
    let rig = Rig::from_file(file, ".".into()).unwrap();
    let fields = [frame(&rig, 1), frame(&rig, 2)];
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.zarr");
    let store =
        LightFieldStore::create(&path, layout(&fields[0], vec![10, 11], "a"), false).unwrap();
    assert_eq!(store.frames_done().unwrap(), vec![false, false]);
    store.write_frame(11, &fields[1], 1.5).unwrap();
    // Reopened for the same run, the store keeps what was written: a rerun writes frame 10.
    let again =
        LightFieldStore::create(&path, layout(&fields[0], vec![10, 11], "a"), false).unwrap();
    assert_eq!(again.frames_done().unwrap(), vec![false, true]);
    again.write_frame(10, &fields[0], 1.5).unwrap();
    assert_eq!(again.frames_done().unwrap(), vec![true, true]);

    let (w, h, nb) = (64, 48, fields[0].bands.len());
    let cube: Vec<f32> = read(&path, "reflectance");
    let disparity: Vec<f32> = read(&path, "disparity");
    let visibility: Vec<u8> = read(&path, "visibility");
    let registered: Vec<f32> = read(&path, "registered");
    let channels = fields[0].channel_labels.len();
    for (f, field) in fields.iter().enumerate() {
        for (v, view) in field.views.iter().enumerate() {
            let k = f * 8 + v;
            let at = |values: &[f32], n: usize| -> Vec<u32> {
                values[k * n..(k + 1) * n]
                    .iter()
                    .map(|x| x.to_bits())
                    .collect()
            };
            let bits =
                |values: &[f32]| -> Vec<u32> { values.iter().map(|x| x.to_bits()).collect() };
            assert_eq!(
                at(&cube, w * h * nb),
                bits(&view.cube().unwrap().data),
                "{k}"
            );
            assert_eq!(at(&disparity, w * h), bits(&view.disparity.data), "{k}");
            assert_eq!(
                at(&registered, w * h * channels),
                bits(&view.registered.as_ref().unwrap().data)
            );
            assert_eq!(
                &visibility[k * w * h..(k + 1) * w * h],
                &view.cameras_seeing.data[..]
            );
        }
    }
    assert_eq!(read::<i64>(&path, "frame"), vec![10, 11]);
    assert_eq!(read::<f64>(&path, "frame_seconds"), vec![1.5, 1.5]);
    assert_eq!(read::<String>(&path, "view")[7], "r1c3");
    assert_eq!(read::<f64>(&path, "wavelength"), fields[0].bands);
    // Every array carries its dimension names (xarray needs them) and the root group the
    // consolidated metadata of all of them.
    let root: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path.join("zarr.json")).unwrap()).unwrap();
    let consolidated = &root["consolidated_metadata"]["metadata"];
    assert_eq!(
        consolidated["reflectance"]["dimension_names"],
        serde_json::json!(["frame", "view", "y", "x", "wavelength"])
    );
    assert_eq!(
        consolidated["reflectance"]["chunk_grid"]["configuration"]["chunk_shape"],
        serde_json::json!([1, 1, 48, 64, nb])
    );
    for name in [
        "disparity",
        "visibility",
        "registered",
        "frame",
        "view",
        "frame_done",
    ] {
        assert!(consolidated[name]["dimension_names"].is_array(), "{name}");
    }
}

#[test]
fn stores_of_other_runs_files_and_foreign_folders_are_refused() {
    let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    file.focal_length_px = Some(180.0);
    let rig = Rig::from_file(file, ".".into()).unwrap();
    let field = frame(&rig, 1);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.zarr");
    let store = LightFieldStore::create(&path, layout(&field, vec![0, 1], "a"), false).unwrap();
    store.write_frame(0, &field, 1.5).unwrap();
    // Another run's settings: refused, the store untouched; replaced when asked.
    let other = LightFieldStore::create(&path, layout(&field, vec![0, 1], "b"), false)
        .unwrap_err()
        .to_string();
    assert!(other.contains("another rig or settings"), "{other}");
    assert_eq!(
        LightFieldStore::open(&path).unwrap().frames_done().unwrap(),
        vec![true, false]
    );
    let replaced = LightFieldStore::create(&path, layout(&field, vec![0, 1], "b"), true).unwrap();
    assert_eq!(replaced.frames_done().unwrap(), vec![false, false]);
    // A frame the store does not have, a file, a folder of someone else's.
    let missing = replaced
        .write_frame(5, &field, 1.5)
        .unwrap_err()
        .to_string();
    assert!(missing.contains("0 to 1"), "{missing}");
    let file_path = dir.path().join("notes.zarr");
    std::fs::write(&file_path, "mine").unwrap();
    assert!(LightFieldStore::create(&file_path, layout(&field, vec![0], "a"), true).is_err());
    assert_eq!(std::fs::read_to_string(&file_path).unwrap(), "mine");
    let foreign = dir.path().join("mine");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("data.csv"), "1,2").unwrap();
    let refused = LightFieldStore::create(&foreign, layout(&field, vec![0], "a"), true)
        .unwrap_err()
        .to_string();
    assert!(refused.contains("not an anaglyph Zarr store"), "{refused}");
    assert!(foreign.join("data.csv").is_file());
    // Nothing of the staging is left beside the stores.
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.starts_with('.')), "{names:?}");
}

/// Every file under `dir` (relative path, bytes), sorted.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(folder) = stack.pop() {
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let name = path.strip_prefix(dir).unwrap().display().to_string();
                out.push((name, std::fs::read(&path).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn frames_written_in_the_background_are_the_frames_written_in_place() {
    let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    file.focal_length_px = Some(180.0);
    let rig = Rig::from_file(file, ".".into()).unwrap();
    let fields = [frame(&rig, 1), frame(&rig, 2)];
    let dir = tempfile::tempdir().unwrap();
    let (in_place, background) = (dir.path().join("a.zarr"), dir.path().join("b.zarr"));
    let store = |path: &Path| {
        LightFieldStore::create(path, layout(&fields[0], vec![10, 11], "a"), false).unwrap()
    };
    let a = store(&in_place);
    a.write_frame(10, &fields[0], 1.5).unwrap();
    a.write_frame(11, &fields[1], 2.5).unwrap();
    let b = store(&background);
    let first = b
        .write_frame_in_background(10, fields[0].clone(), 1.5)
        .unwrap();
    assert_eq!(first.frame(), 10);
    let second = b
        .write_frame_in_background(11, fields[1].clone(), 2.5)
        .unwrap();
    assert!(first.wait().unwrap() > 0.0);
    // Dropped without waiting, a write still ends before the drop returns.
    drop(second);
    assert_eq!(b.frames_done().unwrap(), vec![true, true]);
    let (expected, got) = (files(&in_place), files(&background));
    assert_eq!(expected.len(), got.len());
    for ((name, bytes), (other, others)) in expected.iter().zip(&got) {
        assert_eq!(name, other);
        assert!(bytes == others, "{name} differs");
    }
    // What the store cannot take is refused before any thread starts.
    let missing = b
        .write_frame_in_background(12, fields[0].clone(), 1.5)
        .unwrap_err()
        .to_string();
    assert!(missing.contains("10 to 11"), "{missing}");
    let mut partial = fields[0].clone();
    partial.views.truncate(3);
    let views = b
        .write_frame_in_background(10, partial, 1.5)
        .unwrap_err()
        .to_string();
    assert!(views.contains("r0c3"), "{views}");
}
