//! The simulator's fixed output layout, which other tools rely on:
//!
//! ```text
//! DIR/rig.toml                          the rig, with each camera's image and white filled in
//! DIR/scene.toml                        the scene that was rendered
//! DIR/captures/r{row}c{col}.png         linear 16-bit captures (RGB, or grey for monochrome)
//! DIR/white/r{row}c{col}.png            white-board captures
//! DIR/truth/r{row}c{col}.hdr + .img     ENVI float32 reflectance at the reconstruction bands
//! DIR/truth/r{row}c{col}_disparity.pfm  disparity per column step (Middlebury sign)
//! DIR/truth/r{row}c{col}_depth.pfm      depth along the optical axis, mm
//! DIR/manifest.json                     scene, seed, rig, noise, exposures, files
//! DIR/contact_sheet.png                 8-bit sRGB preview of all captures on the grid
//! DIR/calibration/r{row}c{col}.json     the capturing camera in OpenCV FileStorage JSON:
//!                                       camera_matrix, distortion_coefficients (zero),
//!                                       rotation_matrix and translation_vector (world to
//!                                       camera, mm; world = ideal camera r0c0); named in
//!                                       rig.toml when poses are jittered
//! ```

use super::Simulation;
use crate::io::{
    write_atomically, write_envi, write_pfm, write_png16, EnviCube, LinearImage, PfmImage,
};
use crate::rectify::CameraModel;
use crate::rig::Rig;
use crate::scene::SceneFile;
use crate::{Error, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};

#[derive(Serialize)]
struct ViewRecord {
    row: usize,
    col: usize,
    capture: String,
    white: String,
    truth: String,
    disparity: String,
    depth: String,
    exposure: f64,
    saturated_values: usize,
    disparity_range: [f32; 2],
}

#[derive(Serialize)]
struct Manifest<'a> {
    generator: String,
    scene: &'a SceneFile,
    rig_file: &'a crate::rig::RigFile,
    settings: &'a super::SimulationSettings,
    bands_nm: &'a [f64],
    views: Vec<ViewRecord>,
    seconds: f64,
}

fn create_dir(path: &Path) -> Result<()> {
    std::fs::create_dir_all(path).map_err(|e| Error::io(path, e))
}

/// Writes `simulation` of `scene` seen by `rig` into `dir`; returns the files written.
pub fn write_simulation(
    dir: &Path,
    rig: &Rig,
    scene: &SceneFile,
    simulation: &Simulation,
    seconds: f64,
) -> Result<Vec<PathBuf>> {
    for sub in ["captures", "white", "truth", "calibration"] {
        create_dir(&dir.join(sub))?;
    }
    let (w, h) = (simulation.settings.width, simulation.settings.height);
    let mut files = Vec::new();
    let mut records = Vec::new();
    let mut rig_file = rig.file.clone();
    for view in &simulation.views {
        let name = format!("r{}c{}", view.row, view.col);
        let capture = format!("captures/{name}.png");
        let white = format!("white/{name}.png");
        let truth = format!("truth/{name}.hdr");
        let disparity = format!("truth/{name}_disparity.pfm");
        let depth = format!("truth/{name}_depth.pfm");
        let image = |data: &[f32]| LinearImage {
            width: w,
            height: h,
            channels: view.channels,
            bit_depth: 16,
            data: data.to_vec(),
        };
        write_png16(&dir.join(&capture), &image(&view.capture))?;
        write_png16(&dir.join(&white), &image(&view.white))?;
        let cube = EnviCube {
            width: w,
            height: h,
            bands: simulation.bands.len(),
            wavelengths: Some(simulation.bands.clone()),
            data: view.truth.clone(),
        };
        write_envi(
            &dir.join(&truth),
            &cube,
            &format!("anaglyph simulated reflectance, scene {}", scene.name),
        )?;
        let plane = |data: &[f32]| PfmImage {
            width: w,
            height: h,
            channels: 1,
            data: data.to_vec(),
        };
        write_pfm(&dir.join(&disparity), &plane(&view.disparity))?;
        write_pfm(&dir.join(&depth), &plane(&view.depth))?;
        if let Some(entry) = rig_file
            .cameras
            .iter_mut()
            .find(|c| c.row == view.row && c.col == view.col)
        {
            entry.image = Some(PathBuf::from(&capture));
            entry.white = Some(PathBuf::from(&white));
            entry.exposure = Some(view.exposure);
            if simulation.settings.pose_jitter.is_some() {
                entry.calibration = Some(PathBuf::from(format!("calibration/{name}.json")));
            }
        }
        let finite = view.disparity.iter().filter(|v| v.is_finite());
        let range = finite.fold([f32::INFINITY, f32::NEG_INFINITY], |[a, b], &v| {
            [a.min(v), b.max(v)]
        });
        for f in [&capture, &white, &truth, &disparity, &depth] {
            files.push(dir.join(f));
        }
        files.push(dir.join(format!("truth/{name}.img")));
        let calibration = dir.join(format!("calibration/{name}.json"));
        let text = CameraModel::from_pinhole(&view.camera).to_file_storage_json();
        write_atomically(&calibration, |w| w.write_all(text.as_bytes()))?;
        files.push(calibration);
        records.push(ViewRecord {
            row: view.row,
            col: view.col,
            capture,
            white,
            truth,
            disparity,
            depth,
            exposure: view.exposure,
            saturated_values: view.saturated,
            disparity_range: range,
        });
    }
    // Curve references in the rig file are relative to its folder; keep built-ins as they are
    // and make file paths absolute so the copied rig still finds them.
    let absolutise = |r: &str| {
        if r.starts_with(crate::rig::BUILTIN_PREFIX) || Path::new(r).is_absolute() {
            r.to_string()
        } else {
            rig.base_dir.join(r).display().to_string()
        }
    };
    rig_file.sensor = absolutise(&rig_file.sensor);
    rig_file.illuminant = rig_file.illuminant.as_deref().map(absolutise);
    for cam in &mut rig_file.cameras {
        cam.filter = absolutise(&cam.filter);
        cam.sensor = cam.sensor.as_deref().map(absolutise);
    }
    rig_file.save(&dir.join("rig.toml"))?;
    let scene_text = scene.to_toml_string()?;
    write_atomically(&dir.join("scene.toml"), |w| {
        w.write_all(scene_text.as_bytes())
    })?;
    let manifest = Manifest {
        generator: format!("anaglyph {}", env!("CARGO_PKG_VERSION")),
        scene,
        rig_file: &rig_file,
        settings: &simulation.settings,
        bands_nm: &simulation.bands,
        views: records,
        seconds,
    };
    let json = serde_json::to_string_pretty(&manifest)
        .map_err(|e| Error::invalid("manifest", e.to_string()))?;
    write_atomically(&dir.join("manifest.json"), |w| w.write_all(json.as_bytes()))?;
    super::write_contact_sheet(
        &dir.join("contact_sheet.png"),
        simulation,
        rig.file.rows,
        rig.file.cols,
    )?;
    files.extend([
        dir.join("rig.toml"),
        dir.join("scene.toml"),
        dir.join("manifest.json"),
        dir.join("contact_sheet.png"),
    ]);
    Ok(files)
}
