//! The simulator's fixed output layout, which other tools rely on:
//!
//! ```text
//! DIR/rig.toml                          the rig, with each camera's image and white filled in
//! DIR/scene.toml                        the scene that was rendered
//! DIR/captures/<camera>.png             linear 16-bit captures (RGB, or grey for monochrome)
//! DIR/white/<camera>.png                white-board captures
//! DIR/dark/<camera>.png                 master dark frames, with a dark signal (named in
//!                                       rig.toml as each camera's `dark`)
//! DIR/truth/<camera>.hdr + .img         ENVI float32 reflectance at the reconstruction bands
//! DIR/truth/<camera>_disparity.pfm      disparity per disparity baseline (Middlebury sign)
//! DIR/truth/<camera>_depth.pfm          depth along the optical axis, mm
//! DIR/manifest.json                     scene, seed, rig, noise, exposures; the run id
//!                                       and every file with its size and CRC-32 (last)
//! DIR/contact_sheet.png                 8-bit sRGB preview of all captures in their places
//! DIR/calibration/<camera>.json         the capturing camera in OpenCV FileStorage JSON:
//!                                       camera_matrix, distortion_coefficients (zero),
//!                                       rotation_matrix and translation_vector (world to
//!                                       camera, mm; world = ideal camera r0c0); named in
//!                                       rig.toml when poses are jittered
//! ```
//!
//! The folder is written through an [`OutputFolder`] (staged, then renamed into place), so
//! it is one run's complete output or absent.

use super::{RenderedView, Simulation};
use crate::image::Image;
use crate::io::{
    write_atomically, write_envi, write_pfm, write_png16, EnviCube, LinearImage, OutputFolder,
    PfmImage,
};
use crate::rectify::CameraModel;
use crate::rig::{curve_file, Rig, RigFile};
use crate::scene::SceneFile;
use crate::{Error, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};

#[derive(Serialize)]
struct ViewRecord {
    name: String,
    capture: String,
    white: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    dark: Option<String>,
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
    /// Frames of a sequence (absent: one frame); `views` are frame 0's.
    #[serde(skip_serializing_if = "Option::is_none")]
    frames: Option<usize>,
    seconds: f64,
}

fn create_dir(path: &Path) -> Result<()> {
    std::fs::create_dir_all(path).map_err(|e| Error::io(path, e))
}

/// Writes `simulation` of `scene` seen by `rig` into `folder` (the manifest last);
/// returns the number of files. The caller commits the folder.
pub fn write_simulation(
    folder: &OutputFolder,
    rig: &Rig,
    scene: &SceneFile,
    simulation: &Simulation,
    seconds: f64,
) -> Result<usize> {
    let records = write_frame(folder, scene, simulation, None)?;
    write_common(folder, rig, scene, simulation, records, None, seconds)
}

/// Writes a sequence of `frames` frames into `folder`, frame by frame (`render(k)` gives
/// frame k's simulation; none is kept): `captures/frame_KKKK/<camera>.png` and
/// `truth/frame_KKKK/` per frame, the white boards, dark frames, calibrations, rig and
/// contact sheet of frame 0 (a sequence's white board, dark frame and calibration serve
/// every frame). Returns the number of files; the caller commits the folder.
pub fn write_simulation_frames(
    folder: &OutputFolder,
    rig: &Rig,
    scene: &SceneFile,
    frames: usize,
    mut render: impl FnMut(u64) -> Result<Simulation>,
    seconds: &mut f64,
) -> Result<usize> {
    let mut first = None;
    for k in 0..frames {
        let clock = std::time::Instant::now();
        let simulation = render(k as u64)?;
        *seconds += clock.elapsed().as_secs_f64();
        let records = write_frame(folder, scene, &simulation, Some(k))?;
        if k == 0 {
            first = Some((simulation, records));
        }
    }
    let (simulation, records) = first
        .ok_or_else(|| Error::setting("simulated sequence", "no frames", "at least one frame"))?;
    write_common(
        folder,
        rig,
        scene,
        &simulation,
        records,
        Some(frames),
        *seconds,
    )
}

/// One frame's files (`frame`: its number in a sequence, None: a single frame); the
/// records of its views.
fn write_frame(
    folder: &OutputFolder,
    scene: &SceneFile,
    simulation: &Simulation,
    frame: Option<usize>,
) -> Result<Vec<ViewRecord>> {
    let dir = folder.path();
    let sub = frame.map_or(String::new(), |k| format!("/frame_{k:04}"));
    for base in ["captures", "truth"] {
        create_dir(&dir.join(format!("{base}{sub}")))?;
    }
    if frame.is_none_or(|k| k == 0) {
        for extra in ["white", "calibration"] {
            create_dir(&dir.join(extra))?;
        }
        if simulation.settings.dark.is_some() {
            create_dir(&dir.join("dark"))?;
        }
    }
    simulation
        .views
        .iter()
        .map(|view| write_view(dir, scene, simulation, view, frame))
        .collect()
}

/// What a simulation's folder holds besides its frames: rig, scene, contact sheet and the
/// manifest (last).
fn write_common(
    folder: &OutputFolder,
    rig: &Rig,
    scene: &SceneFile,
    simulation: &Simulation,
    records: Vec<ViewRecord>,
    frames: Option<usize>,
    seconds: f64,
) -> Result<usize> {
    let dir = folder.path();
    let rig_file = simulated_rig_file(rig, simulation, frames.is_some());
    rig_file.save(&dir.join("rig.toml"))?;
    let scene_text = scene.to_toml_string()?;
    write_atomically(&dir.join("scene.toml"), |w| {
        w.write_all(scene_text.as_bytes())
    })?;
    let positions: Vec<[f64; 2]> = rig.cameras.iter().map(|c| c.position_mm).collect();
    super::write_contact_sheet(&dir.join("contact_sheet.png"), simulation, &positions)?;
    folder.write_manifest(&Manifest {
        generator: format!("anaglyph {}", env!("CARGO_PKG_VERSION")),
        scene,
        rig_file: &rig_file,
        settings: &simulation.settings,
        bands_nm: &simulation.bands,
        views: records,
        frames,
        seconds,
    })
}

/// One view's capture, white board, truth cube, disparity, depth and calibration; its
/// manifest record.
fn write_view(
    dir: &Path,
    scene: &SceneFile,
    simulation: &Simulation,
    view: &RenderedView,
    frame: Option<usize>,
) -> Result<ViewRecord> {
    let (w, h) = (simulation.settings.width, simulation.settings.height);
    let name = &view.name;
    let sub = frame.map_or(String::new(), |k| format!("frame_{k:04}/"));
    let record = ViewRecord {
        name: view.name.clone(),
        capture: format!("captures/{sub}{name}.png"),
        white: format!("white/{name}.png"),
        dark: view.dark.as_ref().map(|_| format!("dark/{name}.png")),
        truth: format!("truth/{sub}{name}.hdr"),
        disparity: format!("truth/{sub}{name}_disparity.pfm"),
        depth: format!("truth/{sub}{name}_depth.pfm"),
        exposure: view.exposure,
        saturated_values: view.saturated,
        disparity_range: finite_range(&view.disparity),
    };
    let image = |data: &[f32]| LinearImage {
        width: w,
        height: h,
        channels: view.channels,
        data: data.to_vec(),
    };
    write_png16(&dir.join(&record.capture), &image(&view.capture))?;
    let first = frame.is_none_or(|k| k == 0);
    if first {
        write_png16(&dir.join(&record.white), &image(&view.white))?;
        if let (Some(path), Some(dark)) = (&record.dark, &view.dark) {
            write_png16(&dir.join(path), &image(dark))?;
        }
    }
    let cube = EnviCube {
        image: Image {
            width: w,
            height: h,
            channels: simulation.bands.len(),
            data: view.truth.clone(),
        },
        wavelengths: Some(simulation.bands.clone()),
        band_names: None,
    };
    write_envi(
        &dir.join(&record.truth),
        &cube,
        &format!("anaglyph simulated reflectance, scene {}", scene.name),
    )?;
    let plane = |data: &[f32]| PfmImage {
        width: w,
        height: h,
        channels: 1,
        data: data.to_vec(),
    };
    write_pfm(&dir.join(&record.disparity), &plane(&view.disparity))?;
    write_pfm(&dir.join(&record.depth), &plane(&view.depth))?;
    if first {
        let calibration = dir.join(format!("calibration/{name}.json"));
        let text = CameraModel::from_pinhole(&view.camera).to_file_storage_json();
        write_atomically(&calibration, |w| w.write_all(text.as_bytes()))?;
    }
    Ok(record)
}

/// Smallest and largest finite value.
fn finite_range(values: &[f32]) -> [f32; 2] {
    let finite = values.iter().filter(|v| v.is_finite());
    finite.fold([f32::INFINITY, f32::NEG_INFINITY], |[a, b], &v| {
        [a.min(v), b.max(v)]
    })
}

/// The rig file of the simulation's folder: each camera's capture, white board, exposure
/// (and calibration, with pose jitter, and dark frame, with a dark signal) filled in, the
/// input rig's dark frames and black levels dropped (the captures hold only the dark
/// signal the simulation rendered); curve references that are files made
/// absolute, so that the copied rig still finds them (built-ins stay as they are).
fn simulated_rig_file(rig: &Rig, simulation: &Simulation, sequence: bool) -> RigFile {
    let mut rig_file = rig.file.clone();
    let frame = if sequence { "frame_0000/" } else { "" };
    for (view, cam) in simulation.views.iter().zip(&rig.cameras) {
        let name = &view.name;
        if let Some(entry) = rig_file.cameras.get_mut(cam.entry) {
            entry.image = Some(PathBuf::from(format!("captures/{frame}{name}.png")));
            entry.white = Some(PathBuf::from(format!("white/{name}.png")));
            entry.exposure = Some(view.exposure);
            // The captures hold the dark signal the simulation rendered and no other: a
            // dark frame or black level of the input rig would be subtracted from captures
            // that never had it (and a relative dark path would dangle here).
            entry.dark = view
                .dark
                .as_ref()
                .map(|_| PathBuf::from(format!("dark/{name}.png")));
            entry.black_level = None;
            if simulation.settings.pose_jitter.is_some() {
                entry.calibration = Some(PathBuf::from(format!("calibration/{name}.json")));
            }
        }
    }
    let base = &rig.base_dir;
    let absolutise = |r: &str| match curve_file(r, base) {
        Some(file) => std::path::absolute(&file)
            .unwrap_or(file)
            .display()
            .to_string(),
        None => r.to_string(),
    };
    rig_file.illuminant = rig_file.illuminant.as_deref().map(absolutise);
    for cam in &mut rig_file.cameras {
        cam.filter = cam.filter.as_deref().map(absolutise);
        cam.sensor = cam.sensor.as_deref().map(absolutise);
    }
    rig_file.sensor = absolutise(&rig_file.sensor);
    rig_file
}
