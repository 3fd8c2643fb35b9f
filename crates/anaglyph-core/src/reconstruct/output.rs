//! The fixed output layout of `anaglyph reconstruct`, which `anaglyph eval` and users'
//! tools rely on:
//!
//! ```text
//! OUT/views/r{row}c{col}.hdr + .img      ENVI float32 reflectance, bands with wavelengths
//! OUT/disparity/r{row}c{col}.pfm         disparity per column step (+inf: unknown)
//! OUT/disparity/r{row}c{col}.png         colour-mapped preview (near warm, far cool)
//! OUT/preview/r{row}c{col}_pseudo.png    through the camera's RGB curves (the paper)
//! OUT/preview/r{row}c{col}_srgb.png      CIE 1931 under D65
//! OUT/probes/r{row}c{col}.svg            spectra at the --probe pixels (with truth if known)
//! OUT/manifest.json                      inputs, parameters, calibration, rectification,
//!                                        visibility,
//!                                        per-stage timings, warnings, files
//! ```

use super::{plot_probe, pseudo_colour, srgb_preview, LightField, Probe, ReconstructedView};
use crate::image::Image;
use crate::io::{
    read_envi, write_atomically, write_disparity_preview, write_envi, write_pfm, EnviCube,
};
use crate::rig::Rig;
use crate::{Error, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// What to write besides the fixed layout.
#[derive(Debug, Clone, Default)]
pub struct OutputOptions {
    /// Pixels (x, y) whose spectra are plotted.
    pub probes: Vec<(usize, usize)>,
    /// A simulator output folder whose `truth/` is drawn beside the probes.
    pub truth: Option<PathBuf>,
    /// Inputs and parameters recorded in the manifest as given.
    pub parameters: serde_json::Value,
    /// Seconds spent before reconstruction (loading), recorded as a stage.
    pub loading_seconds: f64,
}

#[derive(Serialize)]
struct Manifest<'a> {
    generator: String,
    parameters: &'a serde_json::Value,
    width: usize,
    height: usize,
    bands_nm: &'a [f64],
    condition_number: f64,
    calibration: &'a [super::CameraCalibration],
    rectification: Option<&'a crate::rectify::Rectification>,
    search_range: Option<&'a crate::register::SearchRange>,
    /// The stages of each view's solve, in order, and their settings.
    solve_stages: Vec<&'static str>,
    refinement: Option<crate::refine::GuidedRefinement>,
    scene_prior: Option<crate::solve::ScenePriorSettings>,
    disputed_tolerance: Option<f64>,
    inconsistency_factor: Option<f64>,
    common_signals: Option<&'a [crate::register::CommonSignal]>,
    views: Vec<super::ViewSummary>,
    timings: Vec<(String, f64)>,
    warnings: &'a [String],
    files: Vec<String>,
}

fn create_dir(path: &Path) -> Result<()> {
    std::fs::create_dir_all(path).map_err(|e| Error::io(path, e))
}

/// Writes `field` into `dir`; returns the files written (the manifest last).
pub fn write_light_field(
    dir: &Path,
    rig: &Rig,
    field: &LightField,
    options: &OutputOptions,
) -> Result<Vec<PathBuf>> {
    let (w, h) = (field.width, field.height);
    for &(x, y) in &options.probes {
        if x >= w || y >= h {
            return Err(Error::mismatch(
                "probe",
                format!("pixel ({x}, {y})"),
                format!("a pixel inside the {w}x{h} image"),
            ));
        }
    }
    for sub in ["views", "disparity", "preview"] {
        create_dir(&dir.join(sub))?;
    }
    if !options.probes.is_empty() {
        create_dir(&dir.join("probes"))?;
    }
    let clock = std::time::Instant::now();
    // One colour scale for every view's disparity preview.
    let max_disparity = field
        .views
        .iter()
        .flat_map(|v| v.disparity.data.iter())
        .filter(|d| d.is_finite())
        .fold(0.0f32, |a, &b| a.max(b));
    let mut files = Vec::new();
    for view in &field.views {
        let name = format!("r{}c{}", view.row, view.col);
        let camera = rig
            .cameras
            .iter()
            .find(|c| (c.row, c.col) == (view.row, view.col))
            .ok_or_else(|| Error::NotFound {
                what: "camera of the view".into(),
                name: name.clone(),
                available: "the rig's cameras".into(),
            })?;
        files.extend(write_cube(dir, &name, field, view)?);
        files.extend(write_disparity(dir, &name, field, view, max_disparity)?);
        let pseudo = dir.join(format!("preview/{name}_pseudo.png"));
        pseudo_colour(&view.reflectance, w, h, &field.bands, &camera.sensor)?.save(&pseudo)?;
        let srgb = dir.join(format!("preview/{name}_srgb.png"));
        srgb_preview(&view.reflectance, w, h, &field.bands)?.save(&srgb)?;
        files.extend([pseudo, srgb]);
        if !options.probes.is_empty() {
            files.push(write_probes(dir, &name, field, view, options)?);
        }
    }
    let manifest = write_manifest(dir, field, options, &files, clock.elapsed().as_secs_f64())?;
    files.push(manifest);
    Ok(files)
}

/// `views/NAME.hdr` and `.img`: the view's reflectance cube.
fn write_cube(
    dir: &Path,
    name: &str,
    field: &LightField,
    view: &ReconstructedView,
) -> Result<[PathBuf; 2]> {
    let path = dir.join(format!("views/{name}.hdr"));
    write_envi(
        &path,
        &EnviCube {
            image: Image {
                width: field.width,
                height: field.height,
                channels: field.bands.len(),
                data: view.reflectance.clone(),
            },
            wavelengths: Some(field.bands.clone()),
        },
        &format!("anaglyph reconstructed reflectance, view {name}"),
    )?;
    let raw = path.with_extension("img");
    Ok([path, raw])
}

/// `disparity/NAME.pfm` (+inf where unknown) and its colour-mapped preview.
fn write_disparity(
    dir: &Path,
    name: &str,
    field: &LightField,
    view: &ReconstructedView,
    max_disparity: f32,
) -> Result<[PathBuf; 2]> {
    let (w, h) = (field.width, field.height);
    let pfm = dir.join(format!("disparity/{name}.pfm"));
    write_pfm(&pfm, &view.disparity.to_pfm())?;
    let png = dir.join(format!("disparity/{name}.png"));
    write_disparity_preview(&png, &view.disparity.data, w, h, max_disparity)?;
    Ok([pfm, png])
}

/// `probes/NAME.svg`: the spectra at the probe pixels, beside the simulator's truth when
/// `options.truth` names a simulation.
fn write_probes(
    dir: &Path,
    name: &str,
    field: &LightField,
    view: &ReconstructedView,
    options: &OutputOptions,
) -> Result<PathBuf> {
    let (w, h, nb) = (field.width, field.height, field.bands.len());
    let truth = match &options.truth {
        Some(t) => Some(read_envi(&t.join(format!("truth/{name}.hdr")))?),
        None => None,
    };
    if let Some(t) = &truth {
        if (t.image.width, t.image.height, t.image.channels) != (w, h, nb) {
            return Err(Error::Shape {
                op: format!("probe truth of view {name}"),
                got: vec![t.image.width, t.image.height, t.image.channels],
                expected: vec![w, h, nb],
            });
        }
    }
    let probes: Vec<Probe> = options
        .probes
        .iter()
        .map(|&(x, y)| {
            let i = (y * w + x) * nb;
            Probe {
                label: format!("({x}, {y})"),
                estimate: view.reflectance[i..i + nb]
                    .iter()
                    .map(|&v| v as f64)
                    .collect(),
                truth: truth
                    .as_ref()
                    .map(|t| (0..nb).map(|b| t.at(x, y, b) as f64).collect()),
            }
        })
        .collect();
    let svg = dir.join(format!("probes/{name}.svg"));
    plot_probe(
        &svg,
        &format!("reflectance, view {name}"),
        &field.bands,
        &probes,
    )?;
    Ok(svg)
}

/// `manifest.json`, listing `files`: written last, so that a complete manifest means a
/// complete folder.
fn write_manifest(
    dir: &Path,
    field: &LightField,
    options: &OutputOptions,
    files: &[PathBuf],
    writing_seconds: f64,
) -> Result<PathBuf> {
    let mut timings = vec![("loading".to_string(), options.loading_seconds)];
    timings.extend(field.timings.iter().cloned());
    timings.push(("writing".to_string(), writing_seconds));
    let manifest_path = dir.join("manifest.json");
    let manifest = Manifest {
        generator: format!("anaglyph {}", env!("CARGO_PKG_VERSION")),
        parameters: &options.parameters,
        width: field.width,
        height: field.height,
        bands_nm: &field.bands,
        condition_number: field.condition_number,
        calibration: &field.calibration,
        rectification: field.rectification.as_ref(),
        search_range: field.search_range.as_ref(),
        solve_stages: field.solve_stages.clone(),
        refinement: field.solve.refinement,
        scene_prior: field.solve.scene_prior,
        disputed_tolerance: field.solve.disputed_tolerance,
        inconsistency_factor: field.solve.inconsistency_factor,
        common_signals: field.common_signals.as_deref(),
        views: field.views.iter().map(|v| v.summary()).collect(),
        timings,
        warnings: &field.warnings,
        files: files
            .iter()
            .map(|f| f.strip_prefix(dir).unwrap_or(f).display().to_string())
            .collect(),
    };
    let json = serde_json::to_string_pretty(&manifest).map_err(|e| Error::output("manifest", e))?;
    write_atomically(&manifest_path, |out| out.write_all(json.as_bytes()))?;
    Ok(manifest_path)
}
