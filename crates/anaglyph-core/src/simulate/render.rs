//! Ray casting one view of the array and turning its reflectances into captures.

use super::dark::{master_dark, DarkSignal};
use crate::capture::CameraNoise;
use crate::disparity::{DisparityConvention, DisparityMap};
use crate::rig::{EffectiveResponses, OutOfBand, Rig, SensingMatrix};
use crate::scene::{
    rotate, rotation, MetamerVariation, PinholeCamera, Scene, SpectralUpsampler, SpectrumSampler,
    Vec3, UPSAMPLING_SHAPE,
};
use crate::spectrum::SpectralShape;
use crate::{Error, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::Arc;

/// Largest image side rendered.
const MAX_SIDE: usize = 16_384;

/// What to render and how.
#[derive(Debug, Clone, Serialize)]
pub struct SimulationSettings {
    pub width: usize,
    pub height: usize,
    /// Rays per pixel side (n × n stratified samples per pixel).
    pub supersampling: usize,
    pub seed: u64,
    /// The frame of a sequence: its sensor noise is drawn anew, while the exposures, the
    /// dark signal's fixed pattern and the pose errors stay the seed's (one white board per
    /// camera serves the whole sequence). Frame 0 is the single-frame simulation.
    pub frame: u64,
    /// None: noise-free captures (for tests).
    pub noise: Option<CameraNoise>,
    /// Each camera's exposure is `noise.exposure × (1 − jitter·u)`, u uniform in [0, 1):
    /// real arrays are not exposed alike, and reconstruction must calibrate from the white.
    pub exposure_jitter: f64,
    /// Reflectance of the white board (a calibrated white is about 0.95–0.99).
    pub white_reflectance: f64,
    /// Small random camera rotations and offsets (None: a perfectly rectified array).
    pub pose_jitter: Option<PoseJitter>,
    /// Spectral variation at fixed colour in textures and patterns (None: every colour
    /// gets the mean measured spectrum of that colour).
    pub metamers: Option<MetamerVariation>,
    /// Fraction of the light lost at the frame's corners to vignetting, falling off as
    /// `1 − v·(r / r_corner)²` from the image centre; the white board is captured through
    /// the same optics (0: none).
    pub vignetting: f64,
    /// A black level with a fixed pattern in captures and white boards, and a master dark
    /// frame per camera to subtract it (None: none).
    pub dark: Option<DarkSignal>,
}

/// The exposure of noise-free captures (`noise: None`): a white reaches this share of
/// full scale.
pub const NOISE_FREE_EXPOSURE: f64 = 0.9;

/// Largest vignetting the simulator renders (corners at 5 % of the centre).
pub const MAX_VIGNETTING: f64 = 0.95;

/// Bounds of the random pose error of each camera (uniform in ±bound, seeded). Captures
/// are taken by the perturbed cameras; the truth stays that of the ideal rectified array.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PoseJitter {
    /// Per Euler angle, degrees.
    pub rotation_deg: f64,
    /// Per axis, mm.
    pub offset_mm: f64,
}

impl Default for SimulationSettings {
    fn default() -> Self {
        SimulationSettings {
            width: 640,
            height: 480,
            supersampling: 2,
            seed: 0,
            frame: 0,
            noise: Some(CameraNoise::default()),
            exposure_jitter: 0.25,
            white_reflectance: 0.95,
            pose_jitter: None,
            metamers: None,
            vignetting: 0.0,
            dark: None,
        }
    }
}

/// One rendered view.
#[derive(Debug, Clone)]
pub struct RenderedView {
    /// The camera's name (see [`crate::rig::Camera::name`]).
    pub name: String,
    /// The camera's place in the array, mm (see [`crate::rig::Camera::position_mm`]).
    pub position_mm: [f64; 2],
    /// Linear capture in [0, 1] of full scale, `height × width × channels`.
    pub capture: Vec<f32>,
    /// The white-board capture, same layout.
    pub white: Vec<f32>,
    /// The master dark frame, same layout (with a [`DarkSignal`]).
    pub dark: Option<Vec<f32>>,
    pub channels: usize,
    /// Noise-free signal in the sensing matrix's normalised units (white peak = 1).
    pub clean: Vec<f32>,
    /// Reflectance at the reconstruction bands, `height × width × bands`.
    pub truth: Vec<f32>,
    /// Depth along the optical axis, mm (+inf where no surface).
    pub depth: Vec<f32>,
    /// Disparity in pixels per column step (`f·b_x / depth`, less `f·b_x / plane` for an
    /// array registered to a plane: the rig's `calibration_plane_mm`).
    pub disparity: Vec<f32>,
    pub exposure: f64,
    pub saturated: usize,
    /// The camera that took `capture` and `white` (perturbed when poses are jittered);
    /// truth, depth and disparity belong to the ideal rectified camera.
    pub camera: PinholeCamera,
}

/// All views of a rig, with what produced them.
#[derive(Debug, Clone)]
pub struct Simulation {
    pub views: Vec<RenderedView>,
    pub settings: SimulationSettings,
    /// Band centres of `truth`, nm.
    pub bands: Vec<f64>,
}

/// Renders camera `camera_index` of `rig` looking at `scene`.
pub fn render_view(
    rig: &Rig,
    scene: &Scene,
    camera_index: usize,
    settings: &SimulationSettings,
    sampler: &SpectrumSampler,
    render_c: &SensingMatrix,
) -> Result<RenderedView> {
    let (w, h) = (settings.width, settings.height);
    let cam = &rig.cameras[camera_index];
    let (focal, unit) = (rig.file.focal_length()?, rig.disparity_baseline_mm);
    let mut camera = PinholeCamera::at_position(cam.position_mm, focal, (w, h));
    // Disparity of the plane the captures are registered to (0: infinity).
    let mut plane_disparity = 0.0;
    if let Some(plane_mm) = rig.file.calibration_plane_mm {
        let reference = rig.cameras[rig.reference].position_mm;
        let offset = [0, 1].map(|k| cam.position_mm[k] - reference[k]);
        camera = camera.registered_to_plane(offset, plane_mm);
        plane_disparity = focal * unit / plane_mm;
    }
    let tracer = Tracer {
        scene,
        settings,
        sampler,
        render_c,
        rows_of_camera: rig.channel_rows(camera_index).collect(),
        band_taps: band_taps(&rig.reconstruction_shape()?),
    };
    let (clean_ideal, truth, depth) = tracer.trace(&camera);
    let (clean, capture_camera) = match jittered(settings, camera_index, &camera) {
        None => (clean_ideal, camera),
        Some(perturbed) => (tracer.trace(&perturbed).0, perturbed),
    };
    let disparity: Vec<f32> = depth
        .iter()
        .map(|&z| (focal * unit / z as f64 - plane_disparity) as f32)
        .collect();
    let exposed = tracer.expose(camera_index, &clean);
    Ok(RenderedView {
        name: cam.name.clone(),
        position_mm: cam.position_mm,
        capture: exposed.capture,
        white: exposed.white,
        dark: exposed.dark,
        channels: tracer.rows_of_camera.len(),
        clean,
        truth,
        depth,
        disparity,
        exposure: exposed.exposure,
        saturated: exposed.saturated,
        camera: capture_camera,
    })
}

/// Linear interpolation taps of each band centre on the 5 nm grid of the spectra.
fn band_taps(bands: &SpectralShape) -> Vec<(usize, f64)> {
    let n = UPSAMPLING_SHAPE.count;
    bands
        .wavelengths()
        .iter()
        .map(|&l| {
            let x = (l - UPSAMPLING_SHAPE.start) / UPSAMPLING_SHAPE.step;
            let i = (x.floor() as usize).min(n - 2);
            (i, x - i as f64)
        })
        .collect()
}

/// The relative illumination of pixel `i` (row-major) under the settings' vignetting.
fn vignetting_falloff(settings: &SimulationSettings) -> impl Fn(usize) -> f64 + '_ {
    let (w, h) = (settings.width, settings.height);
    let (cx, cy) = (0.5 * (w as f64 - 1.0), 0.5 * (h as f64 - 1.0));
    let corner_sq = (cx * cx + cy * cy).max(f64::MIN_POSITIVE);
    move |i: usize| {
        let (x, y) = ((i % w) as f64 - cx, (i / w) as f64 - cy);
        1.0 - settings.vignetting * (x * x + y * y) / corner_sq
    }
}

/// The camera that takes the capture: `camera` moved by the seeded pose jitter (None:
/// no jitter asked; the capture is taken from the ideal pose).
fn jittered(
    settings: &SimulationSettings,
    camera_index: usize,
    camera: &PinholeCamera,
) -> Option<PinholeCamera> {
    let jitter = settings.pose_jitter?;
    let mut rng_pose = ChaCha8Rng::seed_from_u64(
        settings.seed ^ 0x05EE_D0F5 ^ (camera_index as u64).wrapping_mul(0x2545_F491),
    );
    let mut u = || rng_pose.random::<f64>() * 2.0 - 1.0;
    let angles = [
        u() * jitter.rotation_deg,
        u() * jitter.rotation_deg,
        u() * jitter.rotation_deg,
    ];
    let offset = Vec3::new(
        u() * jitter.offset_mm,
        u() * jitter.offset_mm,
        u() * jitter.offset_mm,
    );
    Some(PinholeCamera {
        centre: camera.centre + offset,
        rotation: rotation(angles),
        ..camera.clone()
    })
}

/// A camera's noisy capture and white board in [0, 1], its exposure and how many values
/// saturated.
struct Exposed {
    capture: Vec<f32>,
    white: Vec<f32>,
    /// The master dark frame (with a dark signal).
    dark: Option<Vec<f32>>,
    exposure: f64,
    saturated: usize,
}

/// What every ray of one camera needs: the scene, the spectra's sampler, the camera's rows
/// of the rendering C and the band taps of the truth.
struct Tracer<'a> {
    scene: &'a Scene,
    settings: &'a SimulationSettings,
    sampler: &'a SpectrumSampler,
    render_c: &'a SensingMatrix,
    rows_of_camera: Vec<usize>,
    band_taps: Vec<(usize, f64)>,
}

impl Tracer<'_> {
    /// Exposes the noise-free signal `clean`: the camera's seeded exposure, sensor noise
    /// (when the settings have it), clipping; the white board the same way.
    fn expose(&self, camera_index: usize, clean: &[f32]) -> Exposed {
        let settings = self.settings;
        let channels = self.rows_of_camera.len();
        let values = settings.width * settings.height * channels;
        let mut rng = ChaCha8Rng::seed_from_u64(
            settings.seed ^ (camera_index as u64).wrapping_mul(0x9E37_79B9),
        );
        let jitter: f64 = rng.random();
        if settings.frame > 0 {
            // A later frame: the same exposure (the draw above), new noise.
            rng = ChaCha8Rng::seed_from_u64(
                settings.seed
                    ^ (camera_index as u64).wrapping_mul(0x9E37_79B9)
                    ^ settings.frame.wrapping_mul(0xD1B5_4A32_D192_ED03),
            );
        }
        let white_signal: Vec<f64> = self
            .rows_of_camera
            .iter()
            .map(|&r| settings.white_reflectance * self.render_c.row(r).iter().sum::<f64>())
            .collect();
        // Both through the same lens: value i belongs to pixel i / channels.
        let falloff = vignetting_falloff(settings);
        let clean: Vec<f64> = clean
            .iter()
            .enumerate()
            .map(|(i, &v)| f64::from(v) * falloff(i / channels))
            .collect();
        let whites: Vec<f64> = (0..values)
            .map(|i| white_signal[i % channels] * falloff(i / channels))
            .collect();
        let offsets = settings
            .dark
            .map(|d| d.offsets(values, settings.seed, camera_index))
            .unwrap_or_default();
        let dark = settings.dark.map(|_| {
            master_dark(
                &offsets,
                settings.noise.as_ref(),
                settings.seed ^ camera_index as u64,
            )
        });
        let Some(noise) = settings.noise else {
            let exposure = NOISE_FREE_EXPOSURE;
            let offset = |i: usize| offsets.get(i).copied().unwrap_or(0.0);
            let expose = |v: &[f64]| -> Vec<f32> {
                v.iter()
                    .enumerate()
                    .map(|(i, &v)| (v * exposure + offset(i)).min(1.0) as f32)
                    .collect()
            };
            return Exposed {
                capture: expose(&clean),
                white: expose(&whites),
                dark,
                exposure,
                saturated: 0,
            };
        };
        let exposure = noise.exposure * (1.0 - settings.exposure_jitter * jitter);
        let camera_noise = CameraNoise { exposure, ..noise };
        let noisy = camera_noise.apply_with_offset(&clean, &offsets, rng.random());
        let white = camera_noise.apply_with_offset(&whites, &offsets, rng.random());
        let to_capture = |v: &[f64]| {
            v.iter()
                .map(|&p| (p * exposure).clamp(0.0, 1.0) as f32)
                .collect::<Vec<f32>>()
        };
        Exposed {
            capture: to_capture(&noisy.values),
            white: to_capture(&white.values),
            dark,
            exposure,
            saturated: noisy.saturated.iter().filter(|s| **s).count(),
        }
    }

    /// Casts every ray of `camera`: returns the noise-free signal (`h × w × channels`), the
    /// reflectance at the band centres (`h × w × bands`) and the depth along the optical
    /// axis.
    fn trace(&self, camera: &PinholeCamera) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        let settings = self.settings;
        let (w, h) = (settings.width, settings.height);
        let (channels, nb) = (self.rows_of_camera.len(), self.band_taps.len());
        let axis = rotate(&camera.rotation, Vec3::new(0.0, 0.0, 1.0));
        let mut clean = vec![0f32; w * h * channels];
        let mut truth = vec![0f32; w * h * nb];
        let mut depth = vec![0f32; w * h];
        clean
            .par_chunks_mut(w * channels)
            .zip(truth.par_chunks_mut(w * nb))
            .zip(depth.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, ((clean_row, truth_row), depth_row))| {
                let mut acc = vec![0.0; UPSAMPLING_SHAPE.count];
                let mut scratch = vec![0.0; UPSAMPLING_SHAPE.count];
                for x in 0..w {
                    self.pixel_spectrum(camera, x, y, &mut acc, &mut scratch);
                    for (k, &r) in self.rows_of_camera.iter().enumerate() {
                        clean_row[x * channels + k] =
                            self.render_c
                                .row(r)
                                .iter()
                                .zip(&acc)
                                .map(|(c, s)| c * s)
                                .sum::<f64>() as f32;
                    }
                    for (b, &(i, f)) in self.band_taps.iter().enumerate() {
                        truth_row[x * nb + b] = (acc[i] * (1.0 - f) + acc[i + 1] * f) as f32;
                    }
                    let centre = camera.ray(x as f64 + 0.5, y as f64 + 0.5);
                    depth_row[x] = match self.scene.trace(&centre) {
                        Some((_, hit)) => (centre.direction.dot(axis) * hit.t) as f32,
                        None => f32::INFINITY,
                    };
                }
            });
        (clean, truth, depth)
    }

    /// The mean reflectance spectrum of pixel (x, y) over its supersampled rays, on the
    /// 5 nm grid, into `acc`.
    fn pixel_spectrum(
        &self,
        camera: &PinholeCamera,
        x: usize,
        y: usize,
        acc: &mut [f64],
        scratch: &mut [f64],
    ) {
        let ss = self.settings.supersampling;
        let weight = 1.0 / (ss * ss) as f64;
        acc.fill(0.0);
        for j in 0..ss {
            for i in 0..ss {
                let ray = camera.ray(
                    x as f64 + (i as f64 + 0.5) / ss as f64,
                    y as f64 + (j as f64 + 0.5) / ss as f64,
                );
                if let Some((object, hit)) = self.scene.trace(&ray) {
                    self.sampler.accumulate(
                        &self.scene.objects[object].material,
                        hit.u,
                        hit.v,
                        weight,
                        acc,
                        scratch,
                    );
                }
            }
        }
    }
}

impl Simulation {
    /// Every view's true disparity map, per column step of the array (rig order).
    pub fn disparity_maps(&self) -> Vec<DisparityMap> {
        self.views
            .iter()
            .map(|v| DisparityMap {
                width: self.settings.width,
                height: self.settings.height,
                convention: DisparityConvention::ColumnStep,
                data: v.disparity.clone(),
            })
            .collect()
    }

    /// Renders every view of `rig` looking at `scene`.
    pub fn run(rig: &Rig, scene: &Scene, settings: SimulationSettings) -> Result<Self> {
        if settings.width == 0
            || settings.height == 0
            || settings.width > MAX_SIDE
            || settings.height > MAX_SIDE
        {
            return Err(Error::setting(
                "simulation size",
                format!("{}x{}", settings.width, settings.height),
                format!("1 to {MAX_SIDE} per side"),
            ));
        }
        if !(1..=8).contains(&settings.supersampling) {
            return Err(Error::out_of_range(
                "simulation supersampling",
                settings.supersampling as f64,
                "1 to 8",
            ));
        }
        if !(settings.white_reflectance > 0.0 && settings.white_reflectance <= 1.0) {
            return Err(Error::out_of_range(
                "simulation white reflectance",
                settings.white_reflectance,
                "(0, 1]",
            ));
        }
        if !(0.0..1.0).contains(&settings.exposure_jitter) {
            return Err(Error::out_of_range(
                "simulation exposure jitter",
                settings.exposure_jitter,
                "[0, 1)",
            ));
        }
        let bands = rig.reconstruction_shape()?;
        let per_pixel = bands.count + 2 * rig.channel_count() / rig.cameras.len().max(1) + 2;
        let pixels = (settings.width * settings.height) as u64;
        crate::memory::check_fits(
            &format!(
                "simulating {} views at {}x{}",
                rig.cameras.len(),
                settings.width,
                settings.height
            ),
            crate::memory::f32_bytes(pixels * (rig.cameras.len() * per_pixel) as u64),
        )?;
        if bands.start < UPSAMPLING_SHAPE.start || bands.end() > UPSAMPLING_SHAPE.end() {
            return Err(Error::setting(
                "simulation",
                format!("reconstruction bands {bands} leave the scene spectra"),
                format!(
                    "bands within the scene spectra's {}–{} nm",
                    UPSAMPLING_SHAPE.start,
                    UPSAMPLING_SHAPE.end()
                ),
            ));
        }
        // The light of the scene (default: the one the rig assumes).
        let mut lit = rig.clone();
        if let Some(reference) = &scene.file.illuminant {
            lit.illuminant = Some(crate::rig::resolve_curve(reference, &rig.base_dir)?);
        }
        let responses = EffectiveResponses::of_rig(&lit)?;
        let (lo, hi) = (responses.grid.start, responses.grid.end());
        if lo < UPSAMPLING_SHAPE.start - 1e-9 || hi > UPSAMPLING_SHAPE.end() + 1e-9 {
            return Err(Error::setting(
                "simulation",
                format!("sensor support {lo}–{hi} nm"),
                format!(
                    "a support within the scene spectra's {}–{} nm",
                    UPSAMPLING_SHAPE.start,
                    UPSAMPLING_SHAPE.end()
                ),
            ));
        }
        // The render matrix: 5 nm knots over the support, same normalisation as C.
        let knots = crate::spectrum::SpectralShape::from_range(
            UPSAMPLING_SHAPE.start.max((lo / 5.0).ceil() * 5.0),
            UPSAMPLING_SHAPE.end().min((hi / 5.0).floor() * 5.0),
            5.0,
        )?;
        let render_c = SensingMatrix::from_responses(&responses, knots, OutOfBand::Extend)?;
        let render_c = embed_in_upsampling_grid(render_c)?;
        rig.file.focal_length()?;
        if !(0.0..=MAX_VIGNETTING).contains(&settings.vignetting) {
            return Err(Error::setting(
                "simulation vignetting",
                format!("{}", settings.vignetting),
                format!("a fraction of the light lost at the corners, 0 to {MAX_VIGNETTING}"),
            ));
        }
        if let Some(dark) = settings.dark {
            dark.check()?;
        }
        if let Some(m) = settings.metamers {
            if !(m.amplitude >= 0.0 && m.amplitude.is_finite() && m.scale_mm > 0.0) {
                return Err(Error::setting(
                    "simulation metameric variation",
                    format!("amplitude {} and scale {} mm", m.amplitude, m.scale_mm),
                    "an amplitude >= 0 and a scale > 0",
                ));
            }
        }
        let sampler = SpectrumSampler {
            upsampler: Arc::new(SpectralUpsampler::new()?),
            metamers: settings.metamers.map(|m| (m, settings.seed)),
        };
        let views = (0..rig.cameras.len())
            .map(|m| render_view(rig, scene, m, &settings, &sampler, &render_c))
            .collect::<Result<Vec<_>>>()?;
        Ok(Simulation {
            views,
            settings,
            bands: rig.reconstruction_shape()?.wavelengths(),
        })
    }
}

/// Pads a render matrix on `knots` (a sub-range of the 5 nm grid, extended by at most a
/// knot at each end) to the full [`UPSAMPLING_SHAPE`] columns.
fn embed_in_upsampling_grid(c: SensingMatrix) -> Result<SensingMatrix> {
    let n = UPSAMPLING_SHAPE.count;
    let offset =
        ((c.unknowns.start - UPSAMPLING_SHAPE.start) / UPSAMPLING_SHAPE.step).round() as i64;
    let mut values = vec![0.0; c.rows() * n];
    for r in 0..c.rows() {
        for (j, v) in c.row(r).iter().enumerate() {
            let k = (offset + j as i64).clamp(0, n as i64 - 1) as usize;
            values[r * n + k] += v;
        }
    }
    let mut padded = SensingMatrix::from_dense(c.rows(), UPSAMPLING_SHAPE, values)?;
    padded.row_scale = c.row_scale.clone();
    padded.row_labels = c.row_labels.clone();
    Ok(padded)
}
