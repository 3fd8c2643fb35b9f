//! Rectification against the simulator: cameras rendered with small known rotations (their
//! OpenCV calibrations written by the simulator and read back from disk) are resampled onto
//! the ideal array's image plane, where the true disparities hold again.

// `!(x <= t)` on purpose: it also counts NaN as a failure.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use anaglyph_core::evaluation::score_cube;
use anaglyph_core::io::{OutputFolder, Replace};
use anaglyph_core::reconstruct::{
    reconstruct, ArrayCaptures, Disparities, DisparitySearch, PipelineSettings,
};
use anaglyph_core::rectify::{Calibration, CameraModel, Rectification};
use anaglyph_core::register::RegistrationMode;
use anaglyph_core::rig::{Rig, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{Scene, SceneFile};
use anaglyph_core::simulate::{write_simulation, PoseJitter, Simulation, SimulationSettings};
use anaglyph_core::solve::SolveSettings;
use anaglyph_core::stereo::{DisparityRange, MatchingCost};
use std::path::Path;

const WIDTH: usize = 160;
const HEIGHT: usize = 120;
const JITTER: PoseJitter = PoseJitter {
    rotation_deg: 1.0,
    offset_mm: 0.0,
};

fn rig() -> Rig {
    let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    file.focal_length_px = Some(450.0); // the paper rig's field of view at 160 px
    Rig::from_file(file, ".".into()).unwrap()
}

fn simulate(jitter: Option<PoseJitter>, noisy: bool) -> Simulation {
    let scene = Scene::resolve(SceneFile::preset("tabletop").unwrap(), Path::new(".")).unwrap();
    let mut settings = SimulationSettings {
        width: WIDTH,
        height: HEIGHT,
        seed: 3,
        // 4×4 rays per pixel: less aliasing between the rotated and the ideal renders.
        supersampling: 4,
        pose_jitter: jitter,
        ..SimulationSettings::default()
    };
    if !noisy {
        settings.noise = None;
    }
    Simulation::run(&rig(), &scene, settings).unwrap()
}

/// Luminance of a capture (RGB, `h × w × 3`).
fn grey(data: &[f32]) -> Vec<f64> {
    data.chunks_exact(3)
        .map(|p| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
        .collect()
}

/// Lucas–Kanade displacement `(x, y, dx, dy)` of `moved` against `reference` in 16×16
/// blocks with enough texture (the smaller eigenvalue of the structure tensor above a
/// threshold): one linearised step, accurate for displacements well below a pixel.
fn block_displacements(reference: &[f64], moved: &[f64]) -> Vec<[f64; 4]> {
    const BLOCK: usize = 16;
    const MARGIN: usize = 8;
    let mut out = Vec::new();
    for by in (MARGIN..HEIGHT - MARGIN - BLOCK).step_by(BLOCK) {
        for bx in (MARGIN..WIDTH - MARGIN - BLOCK).step_by(BLOCK) {
            let (mut sxx, mut sxy, mut syy, mut sxt, mut syt) = (0.0, 0.0, 0.0, 0.0, 0.0);
            let mut complete = true;
            for y in by..by + BLOCK {
                for x in bx..bx + BLOCK {
                    let i = y * WIDTH + x;
                    let gx = 0.5 * (reference[i + 1] - reference[i - 1]);
                    let gy = 0.5 * (reference[i + WIDTH] - reference[i - WIDTH]);
                    let gt = moved[i] - reference[i];
                    complete &= gt.is_finite();
                    sxx += gx * gx;
                    sxy += gx * gy;
                    syy += gy * gy;
                    sxt += gx * gt;
                    syt += gy * gt;
                }
            }
            let det = sxx * syy - sxy * sxy;
            let trace = sxx + syy;
            let smaller = 0.5 * (trace - (trace * trace - 4.0 * det).max(0.0).sqrt());
            if !complete || smaller < 0.02 {
                continue;
            }
            let dx = -(syy * sxt - sxy * syt) / det;
            let dy = -(sxx * syt - sxy * sxt) / det;
            let half = BLOCK as f64 / 2.0;
            out.push([bx as f64 + half, by as f64 + half, dx, dy]);
        }
    }
    out
}

/// The mean displacement in each quadrant of the image: a residual rotation, scale or
/// shift moves whole quadrants coherently, while resampling and aliasing noise averages out.
fn quadrant_means(blocks: &[[f64; 4]]) -> Vec<(usize, f64)> {
    (0..4)
        .map(|q| {
            let inside: Vec<&[f64; 4]> = blocks
                .iter()
                .filter(|b| {
                    usize::from(b[0] >= WIDTH as f64 / 2.0)
                        + 2 * usize::from(b[1] >= HEIGHT as f64 / 2.0)
                        == q
                })
                .collect();
            let n = inside.len().max(1) as f64;
            let (dx, dy) = inside
                .iter()
                .fold((0.0, 0.0), |(x, y), b| (x + b[2] / n, y + b[3] / n));
            (inside.len(), dx.hypot(dy))
        })
        .collect()
}

/// Every camera's calibrated pose (each must have one).
fn pose_models(rig: &Rig, captures: &ArrayCaptures) -> Vec<(String, [f64; 2], CameraModel)> {
    captures
        .cameras
        .iter()
        .zip(&rig.cameras)
        .map(|(c, cam)| match &c.calibration {
            Some(Calibration::Pose(model)) => (c.name.clone(), cam.position_mm, model.clone()),
            other => panic!("{}: not a pose calibration: {other:?}", c.name),
        })
        .collect()
}

#[test]
fn rotated_cameras_are_resampled_onto_the_ideal_image_plane() {
    let jittered = simulate(Some(JITTER), false);
    let ideal = simulate(None, false);
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("sim");
    let scene = SceneFile::preset("tabletop").unwrap();
    let folder = OutputFolder::begin(&dir, Replace::OwnOutput, &[]).unwrap();
    write_simulation(&folder, &rig(), &scene, &jittered, 0.0).unwrap();
    folder.commit().unwrap();
    // The rig file the simulator wrote names each camera's calibration file.
    let loaded = Rig::load(&dir.join("rig.toml")).unwrap();
    let captures = ArrayCaptures::load(&loaded, None, None, None).unwrap();
    let plan = Rectification::plan(pose_models(&loaded, &captures), WIDTH, HEIGHT).unwrap();
    let common = plan.common.unwrap();
    assert!((common.focal_px - 450.0).abs() < 1e-6);
    assert!((common.scale[0] - 1.0).abs() < 1e-6 && (common.scale[1] - 1.0).abs() < 1e-6);
    let (mut worst, mut sum, mut count) = (0.0f64, 0.0, 0.0);
    for (k, (cam, view)) in captures.cameras.iter().zip(&ideal.views).enumerate() {
        let rectified = plan.resample(k, &cam.capture, 0.999).unwrap();
        let blocks = block_displacements(&grey(&view.capture), &grey(&rectified.data));
        for (n, shift) in quadrant_means(&blocks) {
            assert!(n >= 4, "{}: {n} textured blocks", cam.name);
            worst = worst.max(shift);
            sum += shift;
            count += 1.0;
        }
        assert!(plan.cameras[k].max_correction_px > 1.0);
    }
    // Measured with 4×4 supersampling: mean 0.041 px, worst quadrant 0.104 px. What is
    // left is aliasing of pixel-scale texture (it shrinks with supersampling: 0.035 at
    // 8×8), not geometry; the captures as taken are off by 1.5–4.4 px, and a 0.05° error
    // in a rotation would move a quadrant by 0.4 px.
    let mean = sum / count;
    eprintln!("quadrant displacement after rectification: mean {mean:.3} px, worst {worst:.3} px");
    assert!(
        mean < 0.06 && worst < 0.16,
        "mean {mean:.3} px, worst {worst:.3} px"
    );
}

#[test]
fn true_disparities_hold_again_after_rectification() {
    let jittered = simulate(Some(JITTER), true);
    let ideal = simulate(None, true);
    let settings = PipelineSettings {
        registration: RegistrationMode::Pairwise,
        disparities: Disparities::Given(ideal.disparity_maps()),
        solve: SolveSettings::paper(),
        views: Some(vec!["r0c0".into(), "r1c2".into()]),
        ..PipelineSettings::new(MatchingCost::Census)
    };
    let rig = rig();
    let psnr = |simulation: &Simulation, rectify: bool| {
        let mut captures = ArrayCaptures::from_simulation(simulation);
        if !rectify {
            for cam in &mut captures.cameras {
                cam.calibration = None;
            }
        }
        let field = reconstruct(&rig, &captures, &settings, &|_, _, _| {}).unwrap();
        assert_eq!(
            field.rectification.is_some(),
            rectify && simulation.settings.pose_jitter.is_some()
        );
        [0, 1].map(|k| {
            let v = &field.views[k];
            let t = simulation.views.iter().find(|s| s.name == v.name).unwrap();
            score_cube(
                &t.truth,
                &v.cube().unwrap().data,
                WIDTH,
                HEIGHT,
                field.bands.len(),
                None,
            )
            .unwrap()
            .psnr
        })
    };
    let reference = psnr(&ideal, true);
    let rectified = psnr(&jittered, true);
    let raw = psnr(&jittered, false);
    eprintln!("PSNR ideal {reference:.2?}, rectified {rectified:.2?}, unrectified {raw:.2?}");
    for k in 0..2 {
        // Measured: rectified 2.0 dB below the ideal array (one more resampling of
        // pixel-scale texture, and a border outside some frames); unrectified 16 dB below.
        assert!(
            rectified[k] > reference[k] - 2.4 && raw[k] < reference[k] - 10.0,
            "view {k}: ideal {:.2}, rectified {:.2}, unrectified {:.2}",
            reference[k],
            rectified[k],
            raw[k]
        );
    }
}

#[test]
fn a_rectified_array_registers_almost_as_well_as_an_ideal_one() {
    let network = anaglyph_core::stereo::MatchingNetwork::default_fast().unwrap();
    let settings = PipelineSettings {
        registration: RegistrationMode::MultiBaseline,
        cost: MatchingCost::Learned(&network),
        disparities: Disparities::Search(DisparitySearch::Fixed(
            DisparityRange::up_to(16).unwrap(),
        )),
        solve: SolveSettings::paper(),
        views: Some(vec!["r0c0".into()]),
        ..PipelineSettings::new(MatchingCost::Census)
    };
    let rig = rig();
    // Bad-2 (%) of view r0c0 against the ideal array's truth, over the pixels inside its
    // own rectified frame (outside it, the disparity is only SGM's propagation).
    let bad = |simulation: &Simulation| {
        let captures = ArrayCaptures::from_simulation(simulation);
        let inside: Vec<bool> = match &captures.cameras[0].calibration {
            None => vec![true; WIDTH * HEIGHT],
            Some(_) => {
                let plan =
                    Rectification::plan(pose_models(&rig, &captures), WIDTH, HEIGHT).unwrap();
                (0..WIDTH * HEIGHT)
                    .map(|i| {
                        let (x, y) = plan
                            .source_position(0, (i % WIDTH) as f64, (i / WIDTH) as f64)
                            .unwrap();
                        x >= 0.0 && y >= 0.0 && x <= WIDTH as f64 - 1.0 && y <= HEIGHT as f64 - 1.0
                    })
                    .collect()
            }
        };
        let field = reconstruct(&rig, &captures, &settings, &|_, _, _| {}).unwrap();
        let truth = &simulation.views[0].disparity;
        let (mut wrong, mut counted) = (0, 0);
        for ((e, t), &inside) in field.views[0].disparity.data.iter().zip(truth).zip(&inside) {
            if inside {
                counted += 1;
                wrong += usize::from(!((*e - *t).abs() <= 2.0));
            }
        }
        100.0 * wrong as f64 / counted as f64
    };
    let ideal = bad(&simulate(None, true));
    let rectified = bad(&simulate(Some(JITTER), true));
    eprintln!("r0c0 bad-2: ideal array {ideal:.1} %, rectified {rectified:.1} %");
    // Measured: ideal 7.0 %, rectified 11.0 % (14.2 % over all pixels without giving
    // unmeasured pixels empty features). The rest is the frame border that other rotated
    // cameras do not cover; away from the borders the two agree (docs/reconstruction.md, "Rectification").
    assert!(
        rectified < ideal + 5.5 && rectified < 13.0,
        "ideal {ideal:.1} %, rectified {rectified:.1} %"
    );
}
