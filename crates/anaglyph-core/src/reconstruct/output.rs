//! The fixed output layout of `anaglyph reconstruct`, which `anaglyph eval` and users'
//! tools rely on:
//!
//! ```text
//! OUT/views/<camera>.hdr + .img          ENVI float32 reflectance, bands with wavelengths
//! OUT/disparity/<camera>.pfm             disparity per disparity baseline (+inf: unknown)
//! OUT/disparity/<camera>.png             colour-mapped preview (near warm, far cool)
//! OUT/preview/<camera>_pseudo.png        through the camera's RGB curves (the paper)
//! OUT/preview/<camera>_srgb.png          CIE 1931 under D65
//! OUT/probes/<camera>.svg                spectra at the --probe pixels (with truth if known)
//! OUT/registered/<camera>.hdr + .img     every camera warped into the view (with
//!                                        --output registered or both; NaN: unseen)
//! OUT/registered/<camera>_seen.png       how many cameras see each pixel (white: all)
//! OUT/manifest.json                      inputs, parameters, calibration, rectification,
//!                                        visibility, per-stage timings, warnings, the
//!                                        run id and every file with its size and CRC-32
//! ```
//!
//! The folder is written through an [`OutputFolder`] (staged, then renamed into place), so
//! it is one run's complete output or absent; [`OutputOptions::check`] is what a command
//! calls before its work to find bad probes or a missing truth first.

use super::registered_stack::write_registered_stack;
use super::{
    plot_probe, pseudo_colour, srgb_preview, FieldLayout, LightField, Probe, ReconstructedView,
};

use crate::image::Image;
use crate::io::{
    read_envi, read_envi_shape, write_disparity_preview, write_envi, write_pfm, EnviCube,
    OutputFolder,
};
use crate::rig::Rig;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Which per-view products a run writes besides the disparity maps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Products {
    /// Reflectance cubes and their previews.
    #[default]
    Cubes,
    /// Registered stacks: every camera's capture warped into the view.
    Registered,
    Both,
}

crate::choice::named_choices!(Products, "output" {
    Cubes = "cube" "A reflectance cube per view.",
    Registered = "registered" "A registered stack per view: every camera's normalised capture warped into it.",
    Both = "both" "Both the cube and the registered stack.",
});

impl Products {
    pub fn cubes(self) -> bool {
        self != Products::Registered
    }

    pub fn registered(self) -> bool {
        self != Products::Cubes
    }
}

/// What to write besides the fixed layout.
#[derive(Debug, Clone, Default)]
pub struct OutputOptions {
    /// Cubes, registered stacks or both (registered stacks need
    /// [`super::PipelineSettings::keep_registered`]).
    pub products: Products,
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
    /// The stages that ran, in order (a registration-only run lists no spectral stage).
    stages: &'a [&'static str],
    /// What a frame of a sequence took from the previous frame (absent: a single frame).
    #[serde(skip_serializing_if = "Option::is_none")]
    temporal_reuse: Option<&'a super::ReuseReport>,
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
}

fn create_dir(path: &Path) -> Result<()> {
    std::fs::create_dir_all(path).map_err(|e| Error::io(path, e))
}

impl OutputOptions {
    /// Checks, before any work, what the output will need: every probe inside the
    /// `width × height` images, and where a truth is named, a cube of `bands` bands at that
    /// size for every view in `views` (their headers and data sizes; nothing is read yet).
    pub fn check(&self, width: usize, height: usize, bands: usize, views: &[&str]) -> Result<()> {
        if !self.products.cubes() && !self.probes.is_empty() {
            return Err(Error::setting(
                "probe",
                "probes with registered stacks only".to_string(),
                "cube output (probes plot reflectance spectra)".to_string(),
            ));
        }
        for &(x, y) in &self.probes {
            if x >= width || y >= height {
                return Err(Error::ProbeOutside {
                    x,
                    y,
                    width,
                    height,
                });
            }
        }
        let Some(truth) = self.truth.as_ref().filter(|_| !self.probes.is_empty()) else {
            return Ok(());
        };
        for name in views {
            let path = truth.join(format!("truth/{name}.hdr"));
            let shape = read_envi_shape(&path)?;
            if (shape.width, shape.height, shape.bands) != (width, height, bands) {
                return Err(Error::Shape {
                    op: format!("probe truth {}", path.display()),
                    got: vec![shape.width, shape.height, shape.bands],
                    expected: vec![width, height, bands],
                });
            }
        }
        Ok(())
    }
}

/// Writes `field` into `folder` (the manifest last); returns the number of files. The
/// caller commits the folder. A run that writes as it goes hands its views to a
/// [`LightFieldWriter`] instead.
pub fn write_light_field(
    folder: &OutputFolder,
    rig: &Rig,
    field: &LightField,
    options: &OutputOptions,
) -> Result<usize> {
    let views: Vec<&str> = field.views.iter().map(|v| v.name.as_str()).collect();
    options.check(field.width, field.height, field.bands.len(), &views)?;
    let mut writer = LightFieldWriter::new(folder, rig, options)?;
    let layout = field.layout();
    let products = options.products;
    for view in &field.views {
        let stack = (products.registered())
            .then(|| view.registered_stack().cloned())
            .transpose()?;
        let cube = products.cubes().then(|| view.cube().cloned()).transpose()?;
        writer.write(&layout, &view.name, stack, cube)?;
    }
    writer.finish(field)
}

/// Writes a light field view by view as a run makes them ([`super::reconstruct_streaming`]):
/// [`LightFieldWriter::view`] writes a view's cube, previews, probes and registered stack
/// and takes those images out of the view; [`LightFieldWriter::finish`] writes what needs
/// every view (the disparity maps, on one colour scale) and the manifest last. The caller
/// checks the options before the run ([`OutputOptions::check`]) and commits the folder.
pub struct LightFieldWriter<'a> {
    folder: &'a OutputFolder,
    rig: &'a Rig,
    options: &'a OutputOptions,
    /// Seconds spent writing so far.
    seconds: f64,
}

impl<'a> LightFieldWriter<'a> {
    /// Makes the output's subfolders.
    pub fn new(folder: &'a OutputFolder, rig: &'a Rig, options: &'a OutputOptions) -> Result<Self> {
        let clock = std::time::Instant::now();
        let dir = folder.path();
        let cubes = options.products.cubes();
        let subfolders = [
            ("views", cubes),
            ("disparity", true),
            ("preview", cubes),
            ("probes", !options.probes.is_empty()),
            ("registered", options.products.registered()),
        ];
        for (sub, _) in subfolders.iter().filter(|(_, wanted)| *wanted) {
            create_dir(&dir.join(sub))?;
        }
        Ok(LightFieldWriter {
            folder,
            rig,
            options,
            seconds: clock.elapsed().as_secs_f64(),
        })
    }

    /// Writes `view`'s products and takes its reflectance cube and registered stack out of
    /// it (its disparity map stays for [`LightFieldWriter::finish`]).
    pub fn view(&mut self, layout: &FieldLayout, view: &mut ReconstructedView) -> Result<()> {
        let products = self.options.products;
        if products.registered() {
            view.registered_stack()?;
        }
        if products.cubes() {
            view.cube()?;
        }
        let stack = products.registered().then(|| view.registered.take());
        let cube = products.cubes().then(|| view.reflectance.take());
        self.write(layout, &view.name, stack.flatten(), cube.flatten())
    }

    /// Writes view `name`'s registered stack and its cube with the cube's previews and
    /// probes, each that is given (the products asked for).
    fn write(
        &mut self,
        layout: &FieldLayout,
        name: &str,
        stack: Option<Image<f32>>,
        cube: Option<Image<f32>>,
    ) -> Result<()> {
        let clock = std::time::Instant::now();
        let dir = self.folder.path();
        let camera = self
            .rig
            .cameras
            .iter()
            .find(|c| c.name == name)
            .ok_or_else(|| Error::NotFound {
                what: "camera of the view".into(),
                name: name.to_string(),
                available: "the rig's cameras".into(),
            })?;
        if let Some(stack) = stack {
            write_registered_stack(dir, name, self.rig, layout, stack)?;
        }
        if let Some(cube) = cube {
            let pseudo = dir.join(format!("preview/{name}_pseudo.png"));
            pseudo_colour(&cube, &layout.bands, &camera.sensor)?.save(&pseudo)?;
            let srgb = dir.join(format!("preview/{name}_srgb.png"));
            srgb_preview(&cube, &layout.bands)?.save(&srgb)?;
            if !self.options.probes.is_empty() {
                write_probes(dir, name, layout, &cube, self.options)?;
            }
            write_cube(dir, name, layout, cube)?;
        }
        self.seconds += clock.elapsed().as_secs_f64();
        Ok(())
    }

    /// Writes every view's disparity map and preview (one colour scale for all, from 0 or
    /// the farthest, most negative, disparity to the nearest), then the manifest; returns
    /// the number of files.
    pub fn finish(self, field: &LightField) -> Result<usize> {
        let clock = std::time::Instant::now();
        let span = field
            .views
            .iter()
            .flat_map(|v| v.disparity.data.iter())
            .filter(|d| d.is_finite())
            .fold([0.0f32, 0.0f32], |[lo, hi], &d| [lo.min(d), hi.max(d)]);
        for view in &field.views {
            write_disparity(self.folder.path(), &view.name, field, view, span)?;
        }
        let seconds = self.seconds + clock.elapsed().as_secs_f64();
        let manifest = manifest(field, self.options, Some(seconds));
        self.folder.write_manifest(&manifest)
    }
}

impl LightField {
    /// What `manifest.json` records of the run (less the file list and run id), as JSON:
    /// `parameters` as given, the calibration, rectification, search range, solve stages,
    /// per-view summaries, timings (with `loading_seconds` first) and warnings. For a
    /// caller that keeps the light field in memory (the Python package).
    pub fn manifest(
        &self,
        parameters: serde_json::Value,
        loading_seconds: f64,
    ) -> Result<serde_json::Value> {
        let options = OutputOptions {
            parameters,
            loading_seconds,
            ..OutputOptions::default()
        };
        serde_json::to_value(manifest(self, &options, None))
            .map_err(|e| Error::output("manifest", e))
    }
}

/// `views/NAME.hdr` and `.img`: the view's reflectance cube.
fn write_cube(dir: &Path, name: &str, layout: &FieldLayout, cube: Image<f32>) -> Result<()> {
    let path = dir.join(format!("views/{name}.hdr"));
    write_envi(
        &path,
        &EnviCube {
            image: cube,
            wavelengths: Some(layout.bands.clone()),
            band_names: None,
        },
        &format!("anaglyph reconstructed reflectance, view {name}"),
    )?;
    Ok(())
}

/// `disparity/NAME.pfm` (+inf where unknown) and its colour-mapped preview.
fn write_disparity(
    dir: &Path,
    name: &str,
    field: &LightField,
    view: &ReconstructedView,
    span: [f32; 2],
) -> Result<()> {
    let (w, h) = (field.width, field.height);
    let pfm = dir.join(format!("disparity/{name}.pfm"));
    write_pfm(&pfm, &view.disparity.to_pfm())?;
    let png = dir.join(format!("disparity/{name}.png"));
    write_disparity_preview(&png, &view.disparity.data, w, h, span)?;
    Ok(())
}

/// `probes/NAME.svg`: the spectra at the probe pixels, beside the simulator's truth when
/// `options.truth` names a simulation.
fn write_probes(
    dir: &Path,
    name: &str,
    layout: &FieldLayout,
    cube: &Image<f32>,
    options: &OutputOptions,
) -> Result<()> {
    let (w, h, nb) = (layout.width, layout.height, layout.bands.len());
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
        .map(|&(x, y)| Probe {
            label: format!("({x}, {y})"),
            estimate: cube.pixel(x, y).iter().map(|&v| v as f64).collect(),
            truth: truth
                .as_ref()
                .map(|t| (0..nb).map(|b| t.at(x, y, b) as f64).collect()),
        })
        .collect();
    let svg = dir.join(format!("probes/{name}.svg"));
    plot_probe(
        &svg,
        &format!("reflectance, view {name}"),
        &layout.bands,
        &probes,
    )
}

/// What `manifest.json` says besides the run id and the files, which the folder adds.
/// The manifest of `field`; `writing_seconds` is recorded as a stage when the run wrote
/// files.
fn manifest<'a>(
    field: &'a LightField,
    options: &'a OutputOptions,
    writing_seconds: Option<f64>,
) -> Manifest<'a> {
    let mut timings = vec![("loading".to_string(), options.loading_seconds)];
    timings.extend(field.timings.iter().cloned());
    timings.extend(writing_seconds.map(|s| ("writing".to_string(), s)));
    Manifest {
        generator: format!("anaglyph {}", env!("CARGO_PKG_VERSION")),
        parameters: &options.parameters,
        width: field.width,
        height: field.height,
        bands_nm: &field.bands,
        condition_number: field.condition_number,
        calibration: &field.calibration,
        rectification: field.rectification.as_ref(),
        search_range: field.search_range.as_ref(),
        stages: &field.stages,
        temporal_reuse: field.reuse.as_ref(),
        solve_stages: field.solve_stages.clone(),
        refinement: field.solve.refinement,
        scene_prior: field.solve.scene_prior,
        disputed_tolerance: field.solve.disputed_tolerance,
        inconsistency_factor: field.solve.inconsistency_factor,
        common_signals: field.common_signals.as_deref(),
        views: field.views.iter().map(|v| v.summary()).collect(),
        timings,
        warnings: &field.warnings,
    }
}
