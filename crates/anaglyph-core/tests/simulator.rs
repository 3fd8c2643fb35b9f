//! The simulator against ground truth it does not compute itself: measured chart spectra
//! integrated at 1 nm, geometric consistency of its disparities, the noise model's
//! statistics, and determinism.

// Band and channel loops index several arrays at once.
#![allow(clippy::needless_range_loop)]

use anaglyph_core::builtin;
use anaglyph_core::capture::CameraNoise;
use anaglyph_core::io::{verify_output_folder, OutputFolder, Replace};
use anaglyph_core::rig::{EffectiveResponses, Rig, SensingMatrix, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{Scene, SceneFile, Shape};
use anaglyph_core::simulate::{
    write_simulation, PoseJitter, RenderedView, Simulation, SimulationSettings,
};
use anaglyph_core::spectrum::Interpolation;
use std::path::Path;

const WIDTH: usize = 200;
const HEIGHT: usize = 150;

/// The paper rig with the focal length scaled to the small test images (same field of view
/// as 1800 px at 640 px wide).
fn small_rig() -> Rig {
    let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    file.focal_length_px = Some(1800.0 * WIDTH as f64 / 640.0);
    Rig::from_file(file, ".".into()).unwrap()
}

fn simulate(scene: &str, noise: Option<CameraNoise>, seed: u64) -> (Rig, Scene, Simulation) {
    let rig = small_rig();
    let scene = Scene::resolve(SceneFile::preset(scene).unwrap(), Path::new(".")).unwrap();
    let settings = SimulationSettings {
        width: WIDTH,
        height: HEIGHT,
        seed,
        noise,
        ..SimulationSettings::default()
    };
    let simulation = Simulation::run(&rig, &scene, settings).unwrap();
    (rig, scene, simulation)
}

fn view(sim: &Simulation, row: usize, col: usize) -> &RenderedView {
    sim.views
        .iter()
        .find(|v| v.name == format!("r{row}c{col}"))
        .unwrap()
}

/// Bilinear sample of band-interleaved `data` at (x, y) in pixel units (centres at +0.5).
fn bilinear(data: &[f32], bands: usize, x: f64, y: f64, out: &mut [f64]) -> bool {
    let (fx, fy) = (x - 0.5, y - 0.5);
    if fx < 0.0 || fy < 0.0 || fx >= (WIDTH - 1) as f64 || fy >= (HEIGHT - 1) as f64 {
        return false;
    }
    let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
    let (ax, ay) = (fx - x0 as f64, fy - y0 as f64);
    for (b, o) in out.iter_mut().enumerate().take(bands) {
        let at = |x: usize, y: usize| data[(y * WIDTH + x) * bands + b] as f64;
        *o = (at(x0, y0) * (1.0 - ax) + at(x0 + 1, y0) * ax) * (1.0 - ay)
            + (at(x0, y0 + 1) * (1.0 - ax) + at(x0 + 1, y0 + 1) * ax) * ay;
    }
    true
}

/// Median |error| and RMSE of carrying r0c0's truth into view (row, col) with the true
/// disparity scaled by `scale` (1 = correct), over pixels away from depth edges that both
/// views see at the same depth.
fn transfer_error(sim: &Simulation, rig: &Rig, row: usize, col: usize, scale: f64) -> (f64, f64) {
    let reference = view(sim, 0, 0);
    let target = view(sim, row, col);
    let bands = sim.bands.len();
    let ratio = rig.file.baseline_mm.unwrap().vertical / rig.file.baseline_mm.unwrap().horizontal;
    let mut errors = Vec::new();
    let mut sample = vec![0.0; bands];
    let mut depth = [0.0];
    for y in 2..HEIGHT - 2 {
        for x in 2..WIDTH - 2 {
            let z = reference.depth[y * WIDTH + x];
            let near_edge = (0..9).any(|k| {
                let (dx, dy) = (k % 3, k / 3);
                let n = reference.depth[(y + dy - 1) * WIDTH + x + dx - 1];
                ((n - z) / z).abs() > 0.002
            });
            if near_edge || !z.is_finite() {
                continue;
            }
            let d = reference.disparity[y * WIDTH + x] as f64 * scale;
            let (tx, ty) = (
                x as f64 + 0.5 - col as f64 * d,
                y as f64 + 0.5 - row as f64 * d * ratio,
            );
            // Mutually visible: the target sees a surface at the same depth there.
            if !bilinear(&target.depth, 1, tx, ty, &mut depth)
                || ((depth[0] - z as f64) / z as f64).abs() > 0.002
            {
                continue;
            }
            if !bilinear(&target.truth, bands, tx, ty, &mut sample) {
                continue;
            }
            for b in 0..bands {
                errors
                    .push((sample[b] - reference.truth[(y * WIDTH + x) * bands + b] as f64).abs());
            }
        }
    }
    assert!(
        errors.len() > 20 * bands,
        "too few mutually visible pixels: {}",
        errors.len() / bands
    );
    let rmse = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    errors.sort_by(f64::total_cmp);
    (errors[errors.len() / 2], rmse)
}

#[test]
fn true_disparity_carries_reflectance_between_views() {
    let (rig, _, sim) = simulate("tabletop", None, 0);
    for (row, col) in [(0, 1), (1, 0), (1, 1), (0, 3)] {
        let (median, rmse) = transfer_error(&sim, &rig, row, col, 1.0);
        // Bilinear resampling of pixel-scale texture bounds the agreement.
        // Measured: median 0.3–1.2e-3, RMSE 0.019–0.027 at 200×150.
        assert!(
            median < 3e-3 && rmse < 4e-2,
            "view r{row}c{col}: median {median} rmse {rmse}"
        );
        // Half a pixel off, or the wrong sign, is clearly worse.
        let d = view(&sim, 0, 0).disparity[(HEIGHT / 2) * WIDTH + WIDTH / 2] as f64;
        let (half_median, _) =
            transfer_error(&sim, &rig, row, col, 1.0 + 0.5 / (d * (row + col) as f64));
        let (flip_median, _) = transfer_error(&sim, &rig, row, col, -1.0);
        assert!(
            half_median > 1.5 * median && flip_median > 3.0 * median,
            "r{row}c{col}: {median} vs half {half_median} flip {flip_median}"
        );
    }
}

/// Checks every visible chart patch of every view: captured signal against Eq. 1 at 1 nm on
/// the measured spectrum (through the camera recorded in the view), and, without pose
/// jitter, the truth cube against the data file. Returns the patches checked.
fn check_chart(sim: &Simulation, rig: &Rig, scene: &Scene, check_truth: bool) -> usize {
    let responses = EffectiveResponses::of_rig(rig).unwrap();
    let c = SensingMatrix::of_rig(rig).unwrap();
    let chart = builtin::reflectances("colorchecker_n_ohta").unwrap();
    let (lo, hi) = chart.domain();
    let fine: Vec<f64> = responses
        .grid
        .wavelengths()
        .iter()
        .map(|w| w.clamp(lo, hi))
        .collect();
    let Some(Shape::Rectangle {
        centre,
        axis_u,
        axis_v,
        half_u,
        half_v,
    }) =
        scene.objects.iter().map(|o| o.shape.clone()).find(
            |s| matches!(s, Shape::Rectangle { half_u, .. } if (*half_u - 120.0).abs() < 1e-9),
        )
    else {
        panic!("tabletop has a 240 mm chart");
    };
    let pitch = 40.0;
    let mut checked = 0;
    for (m, view) in sim.views.iter().enumerate() {
        for patch in 0..24 {
            let (r, col) = (patch / 6, patch % 6);
            let point = centre
                + axis_u * ((col as f64 + 0.5) * pitch - half_u)
                + axis_v * ((r as f64 + 0.5) * pitch - half_v);
            let (x, y, _) = view.camera.project(point).unwrap();
            if x < 0.0 || y < 0.0 {
                continue;
            }
            let (px, py) = (x.floor() as usize, y.floor() as usize);
            if px >= WIDTH || py >= HEIGHT || view.depth[py * WIDTH + px] < 1100.0 {
                continue;
            }
            if check_truth {
                let want_truth = chart
                    .sample(patch, &sim.bands, Interpolation::Linear)
                    .unwrap();
                for (b, w) in want_truth.iter().enumerate() {
                    let got = view.truth[(py * WIDTH + px) * sim.bands.len() + b] as f64;
                    assert!(
                        (got - w).abs() < 1e-5,
                        "view {m} patch {patch} band {b}: {got} vs {w}"
                    );
                }
            }
            let spectrum = chart.sample(patch, &fine, Interpolation::Linear).unwrap();
            let mut raw = vec![0.0; c.rows()];
            responses.integrate(&spectrum, &mut raw);
            for k in 0..3 {
                let row = 3 * m + k;
                let want = raw[row] / c.row_scale[row];
                let got = view.clean[(py * WIDTH + px) * 3 + k] as f64;
                assert!(
                    (got - want).abs() < 1e-5 + 1e-4 * want,
                    "view {m} patch {patch} channel {k}: {got} vs {want}"
                );
            }
            checked += 1;
        }
    }
    checked
}

#[test]
fn true_disparity_is_exact_on_smooth_textures() {
    // A fronto-parallel wall and a slanted plane with slowly varying gratings: bilinear
    // resampling is exact to second order, so the transfer error all but vanishes.
    let text = "name = 'smooth'\n\
        [[object]]\nrectangle = { centre_mm = [45, 25, 2000], size_mm = [3000, 2400] }\n\
        material = { pattern = 'grating', period_mm = 400, srgb = [0.8, 0.3, 0.2], srgb2 = [0.2, 0.5, 0.8] }\n\
        [[object]]\nrectangle = { centre_mm = [0, 0, 1300], size_mm = [500, 400], rotation_deg = [0, 25, 0] }\n\
        material = { pattern = 'grating', period_mm = 250, angle_deg = 60, srgb = [0.9, 0.9, 0.3], srgb2 = [0.3, 0.2, 0.6] }\n";
    let rig = small_rig();
    let scene = Scene::resolve(
        SceneFile::from_toml_str(text, "smooth").unwrap(),
        Path::new("."),
    )
    .unwrap();
    let settings = SimulationSettings {
        width: WIDTH,
        height: HEIGHT,
        noise: None,
        ..SimulationSettings::default()
    };
    let sim = Simulation::run(&rig, &scene, settings).unwrap();
    for (row, col) in [(0, 1), (1, 1), (0, 3)] {
        let (median, rmse) = transfer_error(&sim, &rig, row, col, 1.0);
        assert!(
            median < 1e-4 && rmse < 2e-4, // measured: median 1–4e-5, RMSE 2–8e-5
            "r{row}c{col}: median {median} rmse {rmse}"
        );
    }
}

#[test]
fn chart_captures_equal_the_measured_spectra_integrated_at_1nm() {
    let (rig, scene, sim) = simulate("tabletop", None, 0);
    let checked = check_chart(&sim, &rig, &scene, true);
    assert!(checked >= 8 * 18, "only {checked} patch views");
}

#[test]
fn jittered_cameras_see_what_their_recorded_calibration_says() {
    let rig = small_rig();
    let scene = Scene::resolve(SceneFile::preset("tabletop").unwrap(), Path::new(".")).unwrap();
    let jitter = PoseJitter {
        rotation_deg: 0.7,
        offset_mm: 1.5,
    };
    let settings = SimulationSettings {
        width: WIDTH,
        height: HEIGHT,
        noise: None,
        pose_jitter: Some(jitter),
        ..SimulationSettings::default()
    };
    let jittered = Simulation::run(&rig, &scene, settings).unwrap();
    let (_, _, ideal) = simulate("tabletop", None, 0);
    // Captures move, the (rectified) truth does not.
    assert_ne!(view(&jittered, 0, 1).clean, view(&ideal, 0, 1).clean);
    assert_eq!(
        view(&jittered, 0, 1).disparity,
        view(&ideal, 0, 1).disparity
    );
    let checked = check_chart(&jittered, &rig, &scene, false);
    assert!(checked >= 8 * 18, "only {checked} patch views");
}

#[test]
fn captures_carry_the_modelled_noise_and_the_same_seed_gives_the_same_bytes() {
    let noise = CameraNoise::default();
    let (rig, scene, sim) = simulate("tabletop", Some(noise), 5);
    let v = view(&sim, 0, 0);
    // The white board is uniform: its spread is the noise at the white level.
    for k in 0..3 {
        let values: Vec<f64> = v
            .white
            .iter()
            .skip(k)
            .step_by(3)
            .map(|&x| x as f64)
            .collect();
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        let sd =
            (values.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt();
        let signal = mean / v.exposure;
        let want = CameraNoise {
            exposure: v.exposure,
            ..noise
        }
        .sigma(signal)
            * v.exposure;
        assert!(
            (sd / want - 1.0).abs() < 0.1,
            "channel {k}: sd {sd} model {want}"
        );
    }
    let root = tempfile::tempdir().unwrap();
    let (a, b) = (root.path().join("a"), root.path().join("b"));
    write_folder(&a, &rig, &scene.file, &sim);
    let (_, _, again) = simulate("tabletop", Some(noise), 5);
    write_folder(&b, &rig, &scene.file, &again);
    let (a, b) = (
        verify_output_folder(&a).unwrap(),
        verify_output_folder(&b).unwrap(),
    );
    assert_ne!(a.run_id, b.run_id);
    assert_eq!(
        a.files, b.files,
        "every file byte-identical (sizes and CRC-32)"
    );
    let (_, _, other) = simulate("tabletop", Some(noise), 6);
    assert_ne!(view(&other, 0, 0).capture, v.capture);
}

/// The simulation written and committed as folder `dir`.
fn write_folder(dir: &Path, rig: &Rig, scene: &SceneFile, simulation: &Simulation) {
    let folder = OutputFolder::begin(dir, Replace::OwnOutput, &[]).unwrap();
    write_simulation(&folder, rig, scene, simulation, 0.0).unwrap();
    folder.commit().unwrap();
}

#[test]
fn every_preset_renders_without_clipping_and_with_positive_disparity() {
    for preset in ["clutter", "periodic"] {
        let (_, _, sim) = simulate(preset, Some(CameraNoise::default()), 1);
        for v in &sim.views {
            assert_eq!(v.saturated, 0, "{preset}");
            assert!(
                v.disparity.iter().all(|d| d.is_finite() && *d > 0.0),
                "{preset}"
            );
            assert!(v.truth.iter().all(|r| (0.0..=1.0).contains(r)), "{preset}");
        }
    }
}

#[test]
fn the_scene_light_drives_the_captures() {
    let rig = small_rig();
    let mut file = SceneFile::preset("tabletop").unwrap();
    let settings = SimulationSettings {
        width: 48,
        height: 36,
        noise: None,
        ..SimulationSettings::default()
    };
    let tungsten = Simulation::run(
        &rig,
        &Scene::resolve(file.clone(), Path::new(".")).unwrap(),
        settings.clone(),
    )
    .unwrap();
    file.illuminant = Some("builtin:cie_d65".into());
    let daylight = Simulation::run(
        &rig,
        &Scene::resolve(file, Path::new(".")).unwrap(),
        settings,
    )
    .unwrap();
    // Same reflectance truth, different light: the rig's C (CIE A) no longer fits the captures.
    assert_eq!(view(&tungsten, 0, 0).truth, view(&daylight, 0, 0).truth);
    let blue = |v: &RenderedView| {
        v.clean.iter().skip(2).step_by(3).sum::<f32>() / v.clean.iter().step_by(3).sum::<f32>()
    };
    assert!(
        blue(view(&daylight, 1, 0)) > 1.2 * blue(view(&tungsten, 1, 0)),
        "D65 is bluer than A"
    );
}

#[test]
fn bad_simulation_settings_are_errors() {
    let rig = small_rig();
    let scene = Scene::resolve(SceneFile::preset("tabletop").unwrap(), Path::new(".")).unwrap();
    let tiny = SimulationSettings {
        width: 8,
        height: 6,
        noise: None,
        ..SimulationSettings::default()
    };
    for (bad, cause) in [
        (
            SimulationSettings {
                width: 0,
                ..tiny.clone()
            },
            "Setting",
        ),
        (
            SimulationSettings {
                supersampling: 0,
                ..tiny.clone()
            },
            "OutOfRange",
        ),
        (
            SimulationSettings {
                white_reflectance: 1.5,
                ..tiny.clone()
            },
            "OutOfRange",
        ),
        (
            SimulationSettings {
                exposure_jitter: f64::NAN,
                ..tiny.clone()
            },
            "OutOfRange",
        ),
    ] {
        assert_eq!(
            Simulation::run(&rig, &scene, bad).err().map(|e| e.kind()),
            Some(cause)
        );
    }
    let mut file = rig.file.clone();
    file.reconstruction.start_nm = 360.0;
    let outside = Rig::from_file(file, ".".into()).unwrap();
    let err = Simulation::run(&outside, &scene, tiny)
        .unwrap_err()
        .to_string();
    assert!(err.contains("leave the scene spectra"), "{err}");
}

/// A moving scene's frames: objects move by their velocity per frame, the array's own
/// motion moves the scene the other way, and a later frame keeps the exposures (one white
/// board per camera serves the sequence) with new noise; frame 0 is the single frame.
#[test]
fn sequence_frames_move_the_objects_and_keep_the_exposures() {
    let file = SceneFile::preset("tabletop-moving").unwrap();
    assert!(file.moves() && !SceneFile::preset("tabletop").unwrap().moves());
    let sphere = |f: &SceneFile| f.objects[4].sphere.clone().unwrap();
    assert_eq!(sphere(&file.at_frame(0)), sphere(&file));
    let later = file.at_frame(10);
    assert_eq!(sphere(&later).centre_mm, [230.0, -140.0, 1400.0]);
    assert_eq!(sphere(&later).rotation_deg, [0.0, 0.0, 30.0]);
    let mut broken = file.clone();
    broken.camera_velocity_mm = Some([f64::NAN, 0.0, 0.0]);
    let err = Scene::resolve(broken, Path::new("."))
        .unwrap_err()
        .to_string();
    assert!(err.contains("finite velocity_mm"), "{err}");
    let mut walking = file.clone();
    walking.camera_velocity_mm = Some([0.0, 0.0, 5.0]);
    assert_eq!(sphere(&walking.at_frame(10)).centre_mm[2], 1350.0);

    let rig = small_rig();
    let settings = SimulationSettings {
        width: WIDTH,
        height: HEIGHT,
        supersampling: 1,
        seed: 7,
        ..SimulationSettings::default()
    };
    let render = |k: u64| {
        let scene = Scene::resolve(file.at_frame(k), Path::new(".")).unwrap();
        Simulation::run(
            &rig,
            &scene,
            SimulationSettings {
                frame: k,
                ..settings.clone()
            },
        )
        .unwrap()
    };
    let (first, second) = (render(0), render(1));
    let single = Simulation::run(
        &rig,
        &Scene::resolve(file.clone(), Path::new(".")).unwrap(),
        settings.clone(),
    )
    .unwrap();
    assert!(first.views[0].capture == single.views[0].capture);
    for (a, b) in first.views.iter().zip(&second.views) {
        assert_eq!(a.exposure, b.exposure, "{}", a.name);
        assert!(a.capture != b.capture, "{}: the same noise", a.name);
        // The wall does not move: its true disparity is the same in both frames.
        assert_eq!(a.disparity[0], b.disparity[0], "{}", a.name);
    }
    // The sphere, the box and the picture moved: the maps differ where they are
    let moved = first.views[0]
        .disparity
        .iter()
        .zip(&second.views[0].disparity)
        .filter(|(a, b)| (*a - *b).abs() > 0.01)
        .count();
    // (the tilted picture, box and sphere cover over half the frame at this field of view;
    // the wall's corner pixel, checked above, stays)
    assert!(moved > WIDTH * HEIGHT / 10, "{moved} pixels changed");
}
