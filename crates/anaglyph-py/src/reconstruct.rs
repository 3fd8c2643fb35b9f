//! `anaglyph.reconstruct`: a rig's captures in memory to a multispectral light field in
//! memory, through the core's `reconstruct` (the CLI's pipeline, byte for byte).

use crate::arrays::{array, cube_array, full_scale, image, image_array};
use crate::compute::run_cancellable;
use crate::errors::{to_py, type_error, IntoPyResult};
use crate::rig::Rig;
use anaglyph_core::choice::Choice;
use anaglyph_core::demux::Solver;
use anaglyph_core::disparity::DisparityRange;
use anaglyph_core::image::Image;
use anaglyph_core::io::{read_linear_image, LightFieldStore, PendingWrite as CorePendingWrite};
use anaglyph_core::reconstruct::{
    reconstruct as core_reconstruct, reconstruct_next, ArrayCaptures, CameraCapture, Dark,
    DisparitySearch, FrameCarry as CoreFrameCarry, FrameLayout, FrameRange, FrameSequence, Preset,
    Products, ReconstructOptions, SolveTuning, Stage,
};
use anaglyph_core::rectify::{Calibration, Homography};
use anaglyph_core::register::{CoarseToFine, MatchingImage, RegistrationMode, WarpKernel};
use anaglyph_core::stereo::MatchMethod;
use anaglyph_core::Error;
use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

/// The array `pictures[name]` of each camera, or None where `pictures` has none; names
/// that are not the rig's cameras are an error.
fn per_camera<'py>(
    rig: &anaglyph_core::rig::Rig,
    pictures: Option<&Bound<'py, PyDict>>,
    what: &str,
) -> PyResult<Vec<Option<Bound<'py, PyAny>>>> {
    let Some(pictures) = pictures else {
        return Ok(vec![None; rig.cameras.len()]);
    };
    for key in pictures.keys() {
        let name: String = key
            .extract()
            .map_err(|_| type_error(format!("{what}: keys must be camera names (str)")))?;
        rig.camera_index(&name).map_err(|e| {
            to_py(Error::NotFound {
                what: format!("camera of the {what} dict"),
                name,
                available: match e {
                    Error::NotFound { available, .. } => available,
                    other => other.to_string(),
                },
            })
        })?;
    }
    rig.cameras
        .iter()
        .map(|cam| pictures.get_item(&cam.name))
        .collect()
}

/// A camera's calibration from `calibration`: a 3x3 homography onto the reference camera
/// (an array), or the path of a calibration file.
fn calibration_of(value: &Bound<'_, PyAny>, camera: &str) -> PyResult<Calibration> {
    if let Ok(path) = value.extract::<PathBuf>() {
        if !value.is_instance_of::<PyString>() || !path.as_os_str().is_empty() {
            return Calibration::load(&path).py();
        }
    }
    let what = format!("calibration of camera {camera}");
    let h = value
        .call_method1("astype", ("float64",))
        .and_then(|a| a.extract::<PyReadonlyArrayDyn<'_, f64>>())
        .map_err(|_| type_error(format!("{what}: expected a 3x3 array or a file path")))?;
    if h.shape() != [3, 3] {
        return Err(crate::errors::shape_error(what, h.shape(), &[3, 3]));
    }
    let v: Vec<f64> = h.as_array().iter().copied().collect();
    Ok(Calibration::Plane {
        homography: Homography::new(&v, &what).py()?,
        image_size: None,
    })
}

/// The captures (and white boards, dark frames and calibrations) as the core's.
fn array_captures(
    rig: &anaglyph_core::rig::Rig,
    captures: &Bound<'_, PyDict>,
    whites: Option<&Bound<'_, PyDict>>,
    (darks, frame_darks): (Option<&Bound<'_, PyDict>>, Option<&Bound<'_, PyDict>>),
    calibration: Option<&Bound<'_, PyAny>>,
) -> PyResult<ArrayCaptures> {
    let pictures = per_camera(rig, Some(captures), "captures")?;
    let whites = per_camera(rig, whites, "whites")?;
    let darks = per_camera(rig, darks, "darks")?;
    let frame_darks = match frame_darks {
        Some(d) => Some(per_camera(rig, Some(d), "frame_darks")?),
        None => None,
    };
    let calibrations: Vec<Option<Calibration>> = match calibration {
        None => vec![None; rig.cameras.len()],
        Some(c) => match c.cast::<PyDict>() {
            Ok(dict) => per_camera(rig, Some(dict), "calibration")?
                .iter()
                .zip(&rig.cameras)
                .map(|(v, cam)| v.as_ref().map(|v| calibration_of(v, &cam.name)).transpose())
                .collect::<PyResult<_>>()?,
            Err(_) => {
                let folder: PathBuf = c.extract().map_err(|_| {
                    type_error("calibration: expected a dict of 3x3 homographies or a folder path")
                })?;
                let loaded = ArrayCaptures::load_calibrations(rig, &folder).py()?;
                loaded.into_iter().map(Some).collect()
            }
        },
    };
    let mut cameras = Vec::with_capacity(rig.cameras.len());
    for (i, cam) in rig.cameras.iter().enumerate() {
        let channels = Some(cam.sensor.channel_count());
        let capture = pictures[i].as_ref().ok_or_else(|| {
            to_py(Error::captures(
                "captures",
                format!("no capture of camera {}", cam.name),
                format!(
                    "one per camera of rig '{}' ({})",
                    rig.file.name,
                    rig.cameras
                        .iter()
                        .map(|c| c.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ))
        })?;
        let read = |object: &Bound<'_, PyAny>, what: &str| -> PyResult<Image<f32>> {
            image(object, &format!("{what} of camera {}", cam.name), channels)
        };
        let full_scale = full_scale(capture);
        let mut capture = read(capture, "capture")?;
        let dark = match (&darks[i], &cam.dark, cam.black_level) {
            (Some(d), _, _) => Some(Dark::Frame(read(d, "dark frame")?)),
            (None, Some(path), _) => Some(Dark::Frame(read_linear_image(path).py()?)),
            (None, None, Some(level)) => {
                let what = format!("capture of camera {}", cam.name);
                Some(Dark::level(level, full_scale, std::path::Path::new(&what)).py()?)
            }
            (None, None, None) => None,
        };
        // A frame's own dark frame serves its capture; the white board keeps the others.
        let capture_dark = match frame_darks.as_ref().map(|d| &d[i]) {
            Some(Some(d)) => Some(Dark::Frame(read(d, "frame dark frame")?)),
            Some(None) => {
                return Err(to_py(Error::captures(
                    "frame_darks",
                    format!("no dark frame of camera {}", cam.name),
                    "one per camera",
                )))
            }
            None => dark.clone(),
        };
        for dark in [&dark, &capture_dark] {
            if let Some(Dark::Frame(frame)) = dark {
                let size = |i: &Image<f32>| [i.height, i.width, i.channels];
                if size(frame) != size(&capture) {
                    return Err(crate::errors::shape_error(
                        format!("dark frame of camera {} against its capture", cam.name),
                        &size(frame),
                        &size(&capture),
                    ));
                }
            }
        }
        let mut white = whites[i]
            .as_ref()
            .map(|w| read(w, "white board"))
            .transpose()?;
        let camera = format!("camera {}", cam.name);
        let dark_name = |frame_dark: bool| match (frame_dark, &cam.dark, cam.black_level) {
            (true, _, _) => "dark frame given in frame_darks".to_string(),
            (false, _, _) if darks[i].is_some() => "dark frame given in darks".to_string(),
            (false, Some(path), _) => format!("dark frame {}", path.display()),
            (false, None, level) => format!("black_level {}", level.unwrap_or(0.0)),
        };
        if let Some(dark) = &capture_dark {
            let from_frame = matches!(frame_darks.as_ref().map(|d| &d[i]), Some(Some(_)));
            dark.subtract_from(&mut capture, &camera, "capture", &dark_name(from_frame))
                .py()?;
        }
        if let (Some(dark), Some(white)) = (&dark, &mut white) {
            dark.subtract_from(white, &camera, "white board", &dark_name(false))
                .py()?;
        }
        cameras.push(CameraCapture {
            name: cam.name.clone(),
            capture,
            white,
            exposure: cam.exposure,
            calibration: calibrations[i].clone(),
        });
    }
    ArrayCaptures::from_cameras(cameras).py()
}

/// The search range: "auto" or (min, max).
fn search_range(disp_range: &Bound<'_, PyAny>) -> PyResult<DisparitySearch> {
    if let Ok(text) = disp_range.extract::<String>() {
        if text == "auto" {
            return Ok(DisparitySearch::Auto);
        }
        return Err(to_py(Error::disparity_range(
            "disp_range",
            format!("'{text}'"),
            "\"auto\" or a (min, max) pair of integers",
        )));
    }
    let (min, max): (i32, i32) = disp_range.extract().map_err(|_| {
        type_error("disp_range: expected \"auto\" or a (min, max) pair of integers")
    })?;
    DisparityRange::new(min, max)
        .py()
        .map(DisparitySearch::Fixed)
}

/// What one frame of a sequence hands to the next (`anaglyph.reconstruct_frames` passes
/// it from frame to frame; opaque to Python).
#[pyclass(module = "anaglyph._core", frozen)]
pub struct FrameCarry {
    inner: CoreFrameCarry,
}

/// A frame being written into a store on a thread of its own while the next frame is
/// computed (`anaglyph.reconstruct_frames` hands it to the next frame's call, which waits
/// for it before its own write; `wait()` for the last one). Dropped, it still waits for
/// the write to end.
#[pyclass(module = "anaglyph._core", frozen)]
pub struct PendingWrite {
    inner: Mutex<Option<CorePendingWrite>>,
}

impl PendingWrite {
    fn take(&self) -> Option<CorePendingWrite> {
        self.inner.lock().ok().and_then(|mut slot| slot.take())
    }
}

#[pymethods]
impl PendingWrite {
    /// Waits for the write to end: the seconds it took on its thread (0 when it was
    /// already waited for); its error is raised.
    fn wait(&self, py: Python<'_>) -> PyResult<f64> {
        match self.take() {
            Some(write) => py.detach(move || write.wait()).py(),
            None => Ok(0.0),
        }
    }
}

/// Reconstructs the light field of `captures` (see the Python wrapper's docs). The
/// keyword arguments fill the core's `ReconstructOptions`, the CLI's options by the same
/// names; `tuning` is a JSON object of its `SolveTuning` fields.
#[pyfunction]
#[pyo3(signature = (rig, captures, whites=None, darks=None, calibration=None, views=None,
                    preset="default", output="cube", disp_range=None, method="mccnn",
                    model=None, registration="multi-baseline", solver="exact",
                    matching_image=None, warp_kernel=None, coarse_to_fine="auto",
                    white_reflectance=None,
                    saturation=None, tuning=None, progress=None, store=None, frame=0,
                    frames=None, overwrite=false, arrays=true, skip_done=false,
                    create_only=false, reuse=true, previous=None, frame_darks=None,
                    background_write=false, previous_write=None))]
#[allow(clippy::too_many_arguments)]
pub fn reconstruct<'py>(
    py: Python<'py>,
    rig: &Rig,
    captures: &Bound<'py, PyDict>,
    whites: Option<&Bound<'py, PyDict>>,
    darks: Option<&Bound<'py, PyDict>>,
    calibration: Option<&Bound<'py, PyAny>>,
    views: Option<Vec<String>>,
    preset: &str,
    output: &str,
    disp_range: Option<&Bound<'py, PyAny>>,
    method: &str,
    model: Option<PathBuf>,
    registration: &str,
    solver: &str,
    matching_image: Option<&str>,
    warp_kernel: Option<&str>,
    coarse_to_fine: &str,
    white_reflectance: Option<f64>,
    saturation: Option<f32>,
    tuning: Option<&str>,
    progress: Option<Py<PyAny>>,
    store: Option<PathBuf>,
    frame: i64,
    frames: Option<Vec<i64>>,
    overwrite: bool,
    arrays: bool,
    skip_done: bool,
    create_only: bool,
    reuse: bool,
    previous: Option<&FrameCarry>,
    frame_darks: Option<&Bound<'py, PyDict>>,
    background_write: bool,
    previous_write: Option<&PendingWrite>,
) -> PyResult<Bound<'py, PyDict>> {
    let started = std::time::Instant::now();
    let in_sequence = frames.is_some();
    let rig = &rig.inner;
    let defaults = ReconstructOptions::default();
    let options = ReconstructOptions {
        preset: Preset::parse_choice(preset).py()?,
        registration: RegistrationMode::parse_choice(registration).py()?,
        method: MatchMethod::parse_choice(method).py()?,
        model,
        disp_range: match disp_range {
            None => DisparitySearch::Auto,
            Some(r) => search_range(r)?,
        },
        output: Products::parse_choice(output).py()?,
        views,
        white_reflectance: white_reflectance.unwrap_or(defaults.white_reflectance),
        saturation: saturation.unwrap_or(defaults.saturation),
        solver: Solver::parse_choice(solver).py()?,
        matching_image: matching_image
            .map(MatchingImage::parse_choice)
            .transpose()
            .py()?,
        warp_kernel: warp_kernel.map(WarpKernel::parse_choice).transpose().py()?,
        coarse_to_fine: CoarseToFine::parse_choice(coarse_to_fine).py()?,
        tuning: tuning
            .map(SolveTuning::from_json)
            .transpose()
            .py()?
            .unwrap_or_default(),
        temporal_reuse: reuse,
    };
    if let Some(views) = &options.views {
        for name in views {
            rig.camera_index(name).py()?;
        }
    }
    options.validate().py()?;
    let captures = array_captures(rig, captures, whites, (darks, frame_darks), calibration)?;
    let loading_seconds = started.elapsed().as_secs_f64();
    let cancel = AtomicBool::new(false);
    let callback_error: Mutex<Option<PyErr>> = Mutex::new(None);
    // The store's frames written before this call (a Dask task plans its batch by them).
    let frames_done: Mutex<Option<Vec<bool>>> = Mutex::new(None);
    let report = |stage: Stage, done: usize, total: usize| {
        let Some(callback) = &progress else { return };
        Python::attach(|py| {
            if let Err(e) = callback.call1(py, (stage.name(), done, total)) {
                if let Ok(mut slot) = callback_error.lock() {
                    slot.get_or_insert(e);
                }
                cancel.store(true, Ordering::Relaxed);
            }
        });
    };
    // The previous frame's write, waited for before this frame's (or as the frame is
    // skipped): its seconds on its thread and the seconds this call waited for it.
    let previous_write = previous_write.and_then(PendingWrite::take);
    let previous_store: Mutex<Option<(f64, f64)>> = Mutex::new(None);
    let finish_previous = |write: Option<CorePendingWrite>| -> anaglyph_core::Result<()> {
        if let Some(write) = write {
            let clock = std::time::Instant::now();
            let seconds = write.wait()?;
            if let Ok(mut slot) = previous_store.lock() {
                *slot = Some((seconds, clock.elapsed().as_secs_f64()));
            }
        }
        Ok(())
    };
    let outcome = run_cancellable(py, Some(&cancel), || {
        let mut previous_write = previous_write;
        let network = options.network()?;
        let mut settings = options.settings(network.as_ref())?;
        settings.cancel = Some(&cancel);
        // The store is made (or its run checked) before any work.
        let store = match &store {
            Some(path) => {
                let frames = frames.clone().unwrap_or_else(|| vec![frame]);
                let size = (captures.width, captures.height);
                let layout = options.store_layout(&settings, rig, frames, size)?;
                let store = LightFieldStore::create(path, layout, overwrite)?;
                let index = store.frame_index(frame)?;
                let done = store.frames_done()?;
                let skip = create_only || (skip_done && done[index]);
                if let Ok(mut slot) = frames_done.lock() {
                    *slot = Some(done);
                }
                if skip {
                    finish_previous(previous_write.take())?;
                    return Ok(None);
                }
                Some(store)
            }
            None => None,
        };
        let computing = std::time::Instant::now();
        // A frame of a sequence (`frames` given) with reuse hands on what the next frame
        // takes; a single frame builds nothing of it.
        let (field, carry) = if in_sequence && options.temporal_reuse {
            let previous = previous.map(|p| &p.inner);
            let (field, carry) = reconstruct_next(rig, &captures, &settings, &report, previous)?;
            (field, Some(carry))
        } else {
            (core_reconstruct(rig, &captures, &settings, &report)?, None)
        };
        let seconds = loading_seconds + computing.elapsed().as_secs_f64();
        let mut parameters = options.record(&settings, rig);
        if let Some(record) = parameters.as_object_mut() {
            record.insert("interface".into(), "python".into());
        }
        let mut manifest = field.manifest(parameters, loading_seconds)?;
        finish_previous(previous_write.take())?;
        match &store {
            // The field goes to the write; Python gets no arrays of it, only its summary.
            Some(store) if background_write => {
                let mut field = field;
                let views = std::mem::take(&mut field.views);
                let summary = field.clone();
                field.views = views;
                let pending = store.write_frame_in_background(frame, field, seconds)?;
                return Ok(Some((summary, manifest, carry, Some(pending))));
            }
            Some(store) => {
                let writing = std::time::Instant::now();
                store.write_frame(frame, &field, seconds)?;
                manifest["store_seconds"] = writing.elapsed().as_secs_f64().into();
            }
            None => {}
        }
        Ok(Some((field, manifest, carry, None)))
    });
    if let Some(e) = callback_error.lock().ok().and_then(|mut slot| slot.take()) {
        return Err(e);
    }
    let out = PyDict::new(py);
    if let Some(done) = frames_done.lock().ok().and_then(|mut slot| slot.take()) {
        out.set_item("frames_done", done)?;
    }
    if let Some((seconds, waited)) = previous_store.lock().ok().and_then(|mut slot| slot.take()) {
        out.set_item("previous_store_seconds", seconds)?;
        out.set_item("previous_store_wait_seconds", waited)?;
    }
    let Some((field, manifest, carry, pending)) = outcome? else {
        out.set_item("skipped", true)?;
        return Ok(out);
    };
    out.set_item("skipped", false)?;
    if let Some(carry) = carry {
        out.set_item("carry", FrameCarry { inner: carry })?;
    }
    if let Some(pending) = pending {
        let pending = PendingWrite {
            inner: Mutex::new(Some(pending)),
        };
        out.set_item("pending_write", Py::new(py, pending)?)?;
    }
    let (w, h, bands) = (field.width, field.height, field.bands.len());
    let views = PyDict::new(py);
    for view in field.views.into_iter().filter(|_| arrays) {
        let v = PyDict::new(py);
        if let Some(cube) = view.reflectance {
            v.set_item("cube", cube_array(py, cube)?)?;
        }
        v.set_item("disparity", array(py, &[h, w], view.disparity.data)?)?;
        v.set_item("cameras_seeing", image_array(py, view.cameras_seeing)?)?;
        if let Some(stack) = view.registered {
            v.set_item("registered", cube_array(py, stack)?)?;
        }
        let visibility = PyDict::new(py);
        visibility.set_item("seen_by_all", view.visibility.seen_by_all)?;
        visibility.set_item("measured_fraction", view.visibility.measured_fraction)?;
        visibility.set_item("disputed_fraction", view.visibility.disputed_fraction)?;
        v.set_item("visibility", visibility)?;
        v.set_item("neighbour_agreement", view.neighbour_agreement)?;
        views.set_item(&view.name, v)?;
    }
    out.set_item("views", views)?;
    out.set_item("wavelengths", array(py, &[bands], field.bands)?)?;
    out.set_item("channel_labels", field.channel_labels)?;
    out.set_item("warnings", field.warnings)?;
    let json = py.import("json")?;
    out.set_item(
        "manifest",
        json.call_method1("loads", (manifest.to_string(),))?,
    )?;
    Ok(out)
}

/// The frames of a capture folder (see `anaglyph.read_frames`): `(number, paths)` in
/// frame order, a path per camera of `rig` in its order; every file found before any is
/// read.
#[pyfunction]
#[pyo3(signature = (rig, folder, layout=None, frames="all"))]
pub fn discover_frames(
    rig: &Rig,
    folder: PathBuf,
    layout: Option<&str>,
    frames: &str,
) -> PyResult<Vec<(i64, Vec<PathBuf>)>> {
    let layout = layout.map(FrameLayout::parse_choice).transpose().py()?;
    let range: FrameRange = frames.parse().py()?;
    let sequence = FrameSequence::discover(&rig.inner, &folder, layout, range).py()?;
    Ok(sequence
        .frames
        .into_iter()
        .map(|f| (f.number, f.captures))
        .collect())
}
