//! Calibration to a plane against the simulator's geometry: the corners of a rendered
//! checkerboard (5° tilt, sensor noise, dim exposures) against their projections through
//! the cameras that rendered them, and the fitted homographies against the ones those
//! true corners give.

use anaglyph_core::capture::CameraNoise;
use anaglyph_core::io::LinearImage;
use anaglyph_core::plane_calibration::{
    calibrate_to_plane, detect_board, BoardCapture, BoardPattern, PlaneModel,
};
use anaglyph_core::rectify::Homography;
use anaglyph_core::rig::{Rig, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{Scene, SceneFile, Shape, Vec3};
use anaglyph_core::simulate::{Simulation, SimulationSettings};
use anaglyph_core::stereo::GreyImage;
use std::path::Path;

const WIDTH: usize = 320;
const HEIGHT: usize = 240;
const PATTERN: BoardPattern = BoardPattern { cols: 9, rows: 6 };
const SQUARE_MM: f64 = 40.0;

/// A 10 × 7 board of 40 mm squares, turned 5° about the vertical, in front of a grey wall
/// at about 1.5 m.
const BOARD: &str = r#"
name = "checkerboard"
[[object]]
rectangle = { centre_mm = [45, 25, 1560], size_mm = [3000, 3000] }
material = { srgb = [0.6, 0.6, 0.6] }
[[object]]
rectangle = { centre_mm = [45, 25, 1500], size_mm = [400, 280], rotation_deg = [0, 5, 0] }
material = { pattern = "checker", period_mm = 40, srgb = [0.05, 0.05, 0.05], srgb2 = [0.9, 0.9, 0.9] }
"#;

/// The board's inner corners in world coordinates, row by row.
fn board_corners(scene: &Scene) -> Vec<Vec3> {
    let Shape::Rectangle {
        centre,
        axis_u,
        axis_v,
        half_u,
        half_v,
    } = scene.objects[1].shape
    else {
        panic!("the board is not a rectangle");
    };
    (1..=PATTERN.rows)
        .flat_map(|j| (1..=PATTERN.cols).map(move |i| (i, j)))
        .map(|(i, j)| {
            let (u, v) = (i as f64 * SQUARE_MM - half_u, j as f64 * SQUARE_MM - half_v);
            centre + axis_u * u + axis_v * v
        })
        .collect()
}

/// The left 2×2 of the paper's rig at 320×240 (f = 900 px) rendered at 8×8 samples per
/// pixel (2×2 quantises edges to half pixels), with the sensor noise of an exposure that
/// puts white at `exposure` of full scale.
fn render(exposure: f64) -> (Scene, Simulation) {
    render_scene(BOARD, exposure)
}

/// [`render`] of another scene.
fn render_scene(text: &str, exposure: f64) -> (Scene, Simulation) {
    let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    file.focal_length_px = Some(900.0);
    file.cols = Some(2);
    file.cameras.retain(|c| c.col < Some(2));
    let rig = Rig::from_file(file, ".".into()).unwrap();
    let scene = Scene::resolve(
        SceneFile::from_toml_str(text, "board").unwrap(),
        Path::new("."),
    )
    .unwrap();
    let settings = SimulationSettings {
        width: WIDTH,
        height: HEIGHT,
        supersampling: 8,
        noise: Some(CameraNoise {
            exposure,
            ..CameraNoise::default()
        }),
        ..SimulationSettings::default()
    };
    let simulation = Simulation::run(&rig, &scene, settings).unwrap();
    (scene, simulation)
}

/// Every view's capture as grey (the mean of its channels).
fn board_captures(simulation: &Simulation) -> Vec<BoardCapture> {
    simulation
        .views
        .iter()
        .map(|v| {
            let capture = LinearImage::new(WIDTH, HEIGHT, v.channels, v.capture.clone()).unwrap();
            BoardCapture::from_capture(&v.name, &capture)
        })
        .collect()
}

/// Where each camera saw the corners, in pixel-index coordinates (pixel centres at
/// integers; the projection puts them at half-integers).
fn true_corners(scene: &Scene, simulation: &Simulation) -> Vec<Vec<[f64; 2]>> {
    let corners = board_corners(scene);
    simulation
        .views
        .iter()
        .map(|v| {
            corners
                .iter()
                .map(|&p| {
                    let (x, y, _) = v.camera.project(p).unwrap();
                    [x - 0.5, y - 0.5]
                })
                .collect()
        })
        .collect()
}

/// The board at a bright exposure, rendered once for the tests that share it.
fn bright() -> &'static (Scene, Simulation) {
    static BRIGHT: std::sync::OnceLock<(Scene, Simulation)> = std::sync::OnceLock::new();
    BRIGHT.get_or_init(|| render(0.7))
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

#[test]
fn checkerboard_corners_are_found_within_a_tenth_of_a_pixel() {
    // White at 70 % of full scale, and a dim narrow-band-like 7 %.
    let dim = render(0.07);
    for (exposure, (scene, simulation)) in [(0.7, bright()), (0.07, &dim)] {
        let truth = true_corners(scene, simulation);
        let mut errors = Vec::new();
        for (capture, truth) in board_captures(simulation).iter().zip(&truth) {
            let name = capture.name.clone();
            let found = detect_board(&capture.image, PATTERN, &name)
                .unwrap()
                .corners;
            // In board order: each corner is nearest its own true corner.
            errors.extend(
                found
                    .iter()
                    .zip(truth)
                    .map(|(f, t)| (f[0] - t[0]).hypot(f[1] - t[1])),
            );
        }
        let (median, worst) = (
            median(errors.clone()),
            errors.iter().copied().fold(0.0, f64::max),
        );
        eprintln!("exposure {exposure}: corner error median {median:.3} px, largest {worst:.3} px");
        // Measured: 0.038 / 0.067 px (exposure 0.7) and 0.040 / 0.107 px (0.07).
        assert!(
            median < 0.1 && worst < 0.5,
            "exposure {exposure}: {median} {worst}"
        );
    }
}

#[test]
fn the_fitted_homographies_map_the_frame_like_the_true_corners_do() {
    let (scene, simulation) = bright();
    let truth = true_corners(scene, simulation);
    let captures = board_captures(simulation);
    let fitted = calibrate_to_plane(&captures, PATTERN, "r0c0", PlaneModel::Homography).unwrap();
    let mut worst = 0.0f64;
    for (fit, corners) in fitted.cameras.iter().zip(&truth) {
        let exact = Homography::fit(corners, &truth[0]).unwrap();
        let h = Homography { h: fit.homography };
        for (x, y) in [
            (0.0, 0.0),
            (319.0, 0.0),
            (0.0, 239.0),
            (319.0, 239.0),
            (160.0, 120.0),
        ] {
            let (a, b) = (h.apply(x, y).unwrap(), exact.apply(x, y).unwrap());
            worst = worst.max((a.0 - b.0).hypot(a.1 - b.1));
        }
        assert!(fit.residual_rms_px < 0.1, "{}: {fit:?}", fit.name);
    }
    eprintln!("fitted against true homographies: {worst:.3} px at worst over the frame");
    // Measured: 0.10 px, at a frame corner well outside the board.
    assert!(worst < 0.5, "{worst}");
    // An affine map cannot follow the tilted board's perspective as closely.
    let affine = calibrate_to_plane(&captures, PATTERN, "r0c0", PlaneModel::Affine).unwrap();
    let rms = |c: &anaglyph_core::plane_calibration::PlaneCalibration| {
        c.cameras
            .iter()
            .map(|f| f.residual_rms_px)
            .fold(0.0, f64::max)
    };
    assert!(
        rms(&affine) >= rms(&fitted),
        "{} {}",
        rms(&affine),
        rms(&fitted)
    );
    // No board: the error names the camera and the pattern.
    let mut blank = captures.clone();
    blank[3].image.data.fill(0.5);
    let error = calibrate_to_plane(&blank, PATTERN, "r0c0", PlaneModel::Homography)
        .unwrap_err()
        .to_string();
    assert!(error.contains("r1c1") && error.contains("9x6"), "{error}");
}

/// The `checkerboard` scene preset lies whole in every camera of the narrow-band array
/// presets at 640×480, so `simulate --scene checkerboard --rig <preset>` then `calibrate`
/// needs nothing written by hand; every camera's 9×6 corners are found.
#[test]
fn the_checkerboard_preset_is_found_by_every_camera_of_the_array_presets() {
    let file = SceneFile::preset("checkerboard").unwrap();
    let scene = Scene::resolve(file, Path::new(".")).unwrap();
    for preset in ["mono-3x3", "hexagon-7"] {
        let rig = Rig::preset(preset).unwrap();
        let settings = SimulationSettings {
            width: 640,
            height: 480,
            supersampling: 1,
            ..SimulationSettings::default()
        };
        let simulation = Simulation::run(&rig, &scene, settings).unwrap();
        let reference = &rig.cameras[rig.reference].name;
        let captures: Vec<BoardCapture> = simulation
            .views
            .iter()
            .map(|v| {
                let capture = LinearImage::new(640, 480, v.channels, v.capture.clone()).unwrap();
                BoardCapture::from_capture(&v.name, &capture)
            })
            .collect();
        let fitted = calibrate_to_plane(&captures, PATTERN, reference, PlaneModel::Homography)
            .unwrap_or_else(|e| panic!("{preset}: {e}"));
        let worst = fitted
            .cameras
            .iter()
            .map(|c| c.residual_rms_px)
            .fold(0.0, f64::max);
        eprintln!("{preset}: every camera's board found, residuals at most {worst:.3} px RMS");
        assert!(worst < 0.15, "{preset}: {worst}");
    }
}

/// The columns of `image` from `x0` on: a frame whose left edge moved right.
fn cropped(image: &GreyImage, x0: usize) -> GreyImage {
    let width = image.width - x0;
    let data = (0..image.height)
        .flat_map(|y| {
            image.data[y * image.width + x0..(y + 1) * image.width]
                .iter()
                .copied()
        })
        .collect();
    GreyImage {
        channels: 1,
        width,
        height: image.height,
        data,
    }
}

/// A board whose outer squares the frame's left edge cuts, every inner corner in (the
/// real office capture OpenCV found and the detector did not): the detector labels all
/// but the first column, too near the edge for its ring, and the grid is completed from
/// the labelled part, each added corner confirmed by a saddle in the image.
#[test]
fn a_board_cut_by_the_frame_is_completed_from_its_labelled_part() {
    let (scene, simulation) = bright();
    let truth = true_corners(scene, simulation);
    let captures = board_captures(simulation);
    for (margin, whole) in [(4.5, true), (3.0, true), (-2.0, false)] {
        let mut errors = Vec::new();
        for (capture, truth) in captures.iter().zip(&truth) {
            // The first column of inner corners `margin` px from the new left edge.
            let left = truth.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min);
            let x0 = (left - margin).round() as usize;
            let image = cropped(&capture.image, x0);
            let found = detect_board(&image, PATTERN, &capture.name);
            if !whole {
                let error = found.unwrap_err().to_string();
                assert!(
                    error.contains(&capture.name) && error.contains("9x6"),
                    "{error}"
                );
                continue;
            }
            let found = found
                .unwrap_or_else(|e| panic!("margin {margin}: {e}"))
                .corners;
            errors.extend(
                found
                    .iter()
                    .zip(truth)
                    .map(|(f, t)| (f[0] + x0 as f64 - t[0]).hypot(f[1] - t[1])),
            );
        }
        if whole {
            let (median, worst) = (
                median(errors.clone()),
                errors.iter().copied().fold(0.0, f64::max),
            );
            eprintln!("first column {margin} px from the edge: median {median:.3} px, largest {worst:.3} px");
            // Measured: 0.038 / 0.067 px at either margin.
            assert!(
                median < 0.1 && worst < 0.5,
                "margin {margin}: {median} {worst}"
            );
        }
    }
}

/// A board asked for with one column or row more than it has is not completed with the
/// T-junctions where its outer squares meet its white border, whose saddles are as strong
/// as the inner corners': it is not found.
#[test]
fn a_board_asked_for_with_a_column_too_many_is_not_completed() {
    const BORDERED: &str = r#"
name = "bordered checkerboard"
[[object]]
rectangle = { centre_mm = [45, 25, 1560], size_mm = [3000, 3000] }
material = { srgb = [0.3, 0.3, 0.3] }
[[object]]
rectangle = { centre_mm = [45, 25, 1501], size_mm = [480, 360], rotation_deg = [0, 5, 0] }
material = { srgb = [0.9, 0.9, 0.9] }
[[object]]
rectangle = { centre_mm = [45, 25, 1500], size_mm = [400, 280], rotation_deg = [0, 5, 0] }
material = { pattern = "checker", period_mm = 40, srgb = [0.05, 0.05, 0.05], srgb2 = [0.9, 0.9, 0.9] }
"#;
    let (_, simulation) = render_scene(BORDERED, 0.7);
    for capture in board_captures(&simulation) {
        detect_board(&capture.image, PATTERN, &capture.name).unwrap();
        for (cols, rows) in [(10, 6), (9, 7)] {
            let error = detect_board(&capture.image, BoardPattern { cols, rows }, &capture.name)
                .unwrap_err()
                .to_string();
            assert!(
                error.contains(&format!("{cols}x{rows}")) && error.contains("9x6"),
                "{error}"
            );
        }
    }
}
