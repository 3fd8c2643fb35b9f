//! Training data for the matching network: rectified grey pairs with known disparity, and
//! MC-CNN's patch triplets sampled from them (a left patch, a right patch at the true
//! correspondence give or take a pixel, and one a few pixels away: [`Sampling`]), with
//! MC-CNN's geometric and photometric augmentation.
//!
//! The pairs come from the simulator: random scenes seen by two cameras behind random
//! gels from the candidate library, with random sensors, noise and exposure, as luminance
//! or single colour channels (heterogeneous, and a share homogeneous with the same gel and
//! channel so that same-filter matching does not suffer), plus channel-swapped copies of
//! the built-in textures (the paper's KITTI recipe, one channel left, another right).
//! A recipe may add pairs of monochrome cameras behind narrow-band filters
//! ([`PairSettings::narrow_band_share`]), and pairs whose cameras record the scene as real
//! ones do ([`PairSettings::camera_effects_share`], [`CameraEffects`]): defocus,
//! vignetting, pixel gains, noise at a gain and exposure of their own, saturation, and
//! gamma-encoded 8-bit files.

use anaglyph_core::builtin;
use anaglyph_core::capture::CameraNoise;
use anaglyph_core::image::gaussian_blur_plane;
use anaglyph_core::rig::{Rig, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{builtin_texture, random_scene, Scene, SceneFile, TEXTURE_NAMES};
use anaglyph_core::simulate::{RenderedView, Simulation, SimulationSettings, NOISE_FREE_EXPOSURE};
use anaglyph_core::stereo::{normalise_image, GreyImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::Path;

/// Side of a training patch (the 4-layer tower's receptive field).
pub const PATCH: usize = 9;

/// Where a triplet's right patches lie around the true match.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sampling {
    /// Positive patches lie within this many pixels of the true match.
    pub positive_offset: f32,
    /// Negative patches lie between these distances from the true match, either side.
    pub negative_offsets: (f32, f32),
}

impl Sampling {
    /// MC-CNN's KITTI values (Zbontar & LeCun 2016): positives within 1 px, negatives
    /// 4–10 px away. The shipped networks' sampling.
    pub const MC_CNN_KITTI: Sampling = Sampling {
        positive_offset: 1.0,
        negative_offsets: (4.0, 10.0),
    };
}

impl Default for Sampling {
    fn default() -> Self {
        Sampling::MC_CNN_KITTI
    }
}

/// How the two views of a pair differ.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PairKind {
    /// Different gels (or colour channels).
    Heterogeneous,
    /// Same gel and channel on both cameras.
    Homogeneous,
    /// One colour channel of a texture against another, at zero disparity.
    ChannelSwap,
}

/// A rectified pair, each image normalised by its own mean and deviation.
#[derive(Debug, Clone)]
pub struct StereoPair {
    pub left: GreyImage,
    pub right: GreyImage,
    /// Left-view disparity where the point is also seen by the right view, else NaN.
    pub disparity: Vec<f32>,
    pub kind: PairKind,
    /// What the two cameras were (for logs).
    pub label: String,
}

/// Which part of a simulated RGB capture becomes the grey image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Channel {
    Luminance,
    Colour(usize),
}

fn grey_of(capture: &[f32], channels: usize, w: usize, h: usize, channel: Channel) -> GreyImage {
    let data = capture
        .chunks_exact(channels)
        .map(|p| match (channel, channels) {
            (_, 1) => p[0],
            (Channel::Luminance, _) => 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2],
            (Channel::Colour(c), _) => p[c],
        })
        .collect();
    GreyImage {
        channels: 1,
        width: w,
        height: h,
        data,
    }
}

/// Sizes and kinds of the simulated pairs.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PairSettings {
    pub width: usize,
    pub height: usize,
    /// Share of pairs with the same gel and channel on both cameras.
    pub homogeneous_share: f64,
    /// Share of pairs seen by two monochrome cameras behind narrow-band filters
    /// ([`NARROW_BAND_CENTRES_NM`], [`NARROW_BAND_FWHM_NM`]) instead of gels on colour
    /// sensors: the research arrays' build. 0 in the recipes before it existed (absent from
    /// their checkpoints).
    #[serde(default)]
    pub narrow_band_share: f64,
    /// Share of pairs whose two cameras each record the scene through [`CameraEffects`]
    /// drawn for the pair, instead of the simulator's default camera. 0 in the recipes
    /// before it existed (absent from their checkpoints).
    #[serde(default)]
    pub camera_effects_share: f64,
}

impl Default for PairSettings {
    fn default() -> Self {
        PairSettings {
            width: 256,
            height: 192,
            homogeneous_share: 0.25,
            narrow_band_share: 0.0,
            camera_effects_share: 0.0,
        }
    }
}

/// Centres (nm) a narrow-band pair's filters are drawn from, uniformly.
pub const NARROW_BAND_CENTRES_NM: (f64, f64) = (420.0, 700.0);
/// Full widths at half maximum (nm) of a narrow-band pair's filters, drawn uniformly.
pub const NARROW_BAND_FWHM_NM: (f64, f64) = (10.0, 40.0);
/// Least distance (nm) between the centres of a heterogeneous narrow-band pair's filters.
pub const NARROW_BAND_SEPARATION_NM: f64 = 30.0;

/// The filters of a narrow-band pair from scene seed `seed` (`gaussian:` references; the
/// same on both cameras for a homogeneous pair). A random stream of its own, so that the
/// gel pairs of a seed are those of the recipes without narrow-band pairs.
fn narrow_band_filters(seed: u64, homogeneous: bool) -> [String; 2] {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0a77_0b0d_0000_0000);
    let (lo, hi) = NARROW_BAND_CENTRES_NM;
    let draw = |rng: &mut ChaCha8Rng, centre: f64| {
        let fwhm = rng.random_range(NARROW_BAND_FWHM_NM.0..NARROW_BAND_FWHM_NM.1);
        format!("gaussian:{centre:.0}:{fwhm:.0}")
    };
    let first_centre = rng.random_range(lo..hi);
    let first = draw(&mut rng, first_centre);
    if homogeneous {
        return [first.clone(), first];
    }
    let second_centre = loop {
        let c = rng.random_range(lo..hi);
        if (c - first_centre).abs() >= NARROW_BAND_SEPARATION_NM {
            break c;
        }
    };
    [first, draw(&mut rng, second_centre)]
}

/// Defocus blur of a camera, px (Gaussian σ, drawn uniformly for each camera).
pub const DEFOCUS_SIGMA_PX: (f64, f64) = (0.0, 1.5);
/// Vignetting of a pair's lenses (light lost at the corners, as
/// `SimulationSettings::vignetting`), drawn uniformly.
pub const VIGNETTING: (f64, f64) = (0.0, 0.5);
/// Standard deviation of a camera's pixel gains (photo-response non-uniformity), drawn
/// uniformly.
pub const PRNU: (f64, f64) = (0.0, 0.02);
/// A camera's full well (electrons per full scale: the gain), drawn log-uniformly.
pub const FULL_WELL_ELECTRONS: (f64, f64) = (1_500.0, 20_000.0);
/// A camera's read noise, electrons, drawn uniformly.
pub const READ_NOISE_ELECTRONS: (f64, f64) = (2.0, 15.0);
/// The share of full scale a white reaches (log-uniform): from dim narrow-band captures
/// to over-exposed ones whose bright surfaces saturate.
pub const EXPOSURE: (f64, f64) = (0.05, 1.6);
/// Share of pairs written as gamma-encoded 8-bit files (as photographs and most stereo
/// datasets are), with a gamma drawn uniformly from [`GAMMA`]; the others stay linear at
/// 12 bits.
pub const GAMMA_ENCODED_SHARE: f64 = 0.5;
/// The gammas of gamma-encoded pairs, drawn uniformly.
pub const GAMMA: (f64, f64) = (1.8, 2.4);

/// How one camera of a pair records its image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraResponse {
    pub defocus_sigma_px: f32,
    pub prnu: f64,
    /// Gain, read noise and exposure (12 bits).
    pub noise: CameraNoise,
}

/// What a pair of real cameras does to the light the simulator renders, in the order it
/// happens: the lenses' vignetting (rendered by the simulator), each camera's defocus,
/// its pixels' gains, its shot and read noise at its own gain and exposure, clipping at
/// full scale, and the file's encoding (both cameras alike: one pipeline).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraEffects {
    pub vignetting: f64,
    pub cameras: [CameraResponse; 2],
    /// Gamma-encoded 8-bit values with this gamma; None: linear.
    pub gamma: Option<f64>,
}

impl CameraEffects {
    /// The effects of scene seed `seed`'s pair, from a random stream of their own.
    pub fn draw(seed: u64) -> CameraEffects {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xeffe_c750_0000_0000);
        let uniform = |rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)| rng.random_range(lo..=hi);
        let log_uniform = |rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)| {
            (rng.random_range(lo.ln()..=hi.ln())).exp()
        };
        let vignetting = uniform(&mut rng, VIGNETTING);
        let camera = |rng: &mut ChaCha8Rng| CameraResponse {
            defocus_sigma_px: uniform(rng, DEFOCUS_SIGMA_PX) as f32,
            prnu: uniform(rng, PRNU),
            noise: CameraNoise {
                full_well_electrons: log_uniform(rng, FULL_WELL_ELECTRONS),
                read_noise_electrons: uniform(rng, READ_NOISE_ELECTRONS),
                bits: 12,
                exposure: log_uniform(rng, EXPOSURE),
            },
        };
        let cameras = [camera(&mut rng), camera(&mut rng)];
        let gamma = (rng.random::<f64>() < GAMMA_ENCODED_SHARE).then(|| uniform(&mut rng, GAMMA));
        CameraEffects {
            vignetting,
            cameras,
            gamma,
        }
    }

    /// Camera `k`'s recording of `clean`, the noise-free grey signal in units of the white
    /// board's (1: a white), with noise from `seed`.
    pub fn record(&self, k: usize, clean: &GreyImage, seed: u64) -> GreyImage {
        let camera = &self.cameras[k];
        let (w, h) = (clean.width, clean.height);
        let blurred = gaussian_blur_plane(w, h, clean.data.clone(), camera.defocus_sigma_px);
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9a1e_5000 ^ k as u64);
        // Uniform gains of standard deviation `prnu`.
        let spread = camera.prnu * 3f64.sqrt();
        let signal: Vec<f64> = blurred
            .iter()
            .map(|&v| f64::from(v) * (1.0 + spread * rng.random_range(-1.0..=1.0)))
            .collect();
        let noisy = camera.noise.apply(&signal, rng.random());
        let exposure = camera.noise.exposure;
        let data = noisy
            .values
            .iter()
            .map(|&v| {
                let linear = (v * exposure).clamp(0.0, 1.0);
                match self.gamma {
                    Some(gamma) => (linear.powf(1.0 / gamma) * 255.0).round() as f32 / 255.0,
                    None => linear as f32,
                }
            })
            .collect();
        GreyImage {
            channels: 1,
            width: w,
            height: h,
            data,
        }
    }

    /// A short description for the pair's label.
    fn label(&self) -> String {
        let [a, b] = self.cameras;
        format!(
            "vignetting {:.2}, defocus {:.1}/{:.1} px, exposure {:.2}/{:.2}, {}",
            self.vignetting,
            a.defocus_sigma_px,
            b.defocus_sigma_px,
            a.noise.exposure,
            b.noise.exposure,
            match self.gamma {
                Some(g) => format!("gamma {g:.1}, 8 bits"),
                None => "linear".to_string(),
            }
        )
    }
}

/// One simulated pair from scene seed `seed`: random scene, gels, sensor and channels.
pub fn simulated_pair(seed: u64, settings: &PairSettings) -> anaglyph_core::Result<StereoPair> {
    simulated_pair_with(seed, settings, None, None)
}

/// A simulated pair as [`simulated_pair`], optionally forcing the kind (the gels, sensor
/// and channels are still drawn from `seed`) and the scene (default: `random_scene(seed)`).
pub fn simulated_pair_with(
    seed: u64,
    settings: &PairSettings,
    homogeneous: Option<bool>,
    scene: Option<SceneFile>,
) -> anaglyph_core::Result<StereoPair> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_57e2_0000_0000);
    let gels = builtin::filter_names();
    let drawn = rng.random::<f64>() < settings.homogeneous_share;
    let homogeneous = homogeneous.unwrap_or(drawn);
    let (w, h) = (settings.width, settings.height);
    let scene = scene.unwrap_or_else(|| random_scene(seed));
    // Whether the pair's cameras record as real ones do, from a stream of its own (so the
    // other pairs of a seed are those of the recipes without camera effects).
    let effects = (settings.camera_effects_share > 0.0
        && ChaCha8Rng::seed_from_u64(seed ^ 0xeffe_c750_0000_0001).random::<f64>()
            < settings.camera_effects_share)
        .then(|| CameraEffects::draw(seed));
    if settings.narrow_band_share > 0.0 {
        let mut kind = ChaCha8Rng::seed_from_u64(seed ^ 0x0a77_0b0d_0000_0001);
        if kind.random::<f64>() < settings.narrow_band_share {
            // Monochrome cameras behind narrow-band filters ([`narrow_band_filters`]), the
            // focal length from a stream of its own too.
            let filters = narrow_band_filters(seed, homogeneous);
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0a77_0b0d_0000_0002);
            let camera = RigPair {
                filters: [filters[0].as_str(), filters[1].as_str()],
                sensor: builtin::PANCHROMATIC,
                focal_length_px: random_focal_length(w, &mut rng),
            };
            let label = format!("{} vs {} (panchromatic)", filters[0], filters[1]);
            let channels = [Channel::Luminance; 2];
            return grey_pair(
                &camera,
                scene,
                (w, h),
                seed,
                channels,
                homogeneous,
                label,
                effects,
            );
        }
    }
    let first = gels[rng.random_range(0..gels.len())];
    let second = if homogeneous {
        first
    } else {
        loop {
            let g = gels[rng.random_range(0..gels.len())];
            if g != first {
                break g;
            }
        }
    };
    let sensor = builtin::SENSORS[rng.random_range(0..builtin::SENSORS.len())].0;
    let pick_channel = |rng: &mut ChaCha8Rng| {
        if rng.random::<f64>() < 0.5 {
            Channel::Luminance
        } else {
            Channel::Colour(rng.random_range(0..3))
        }
    };
    let left_channel = pick_channel(&mut rng);
    let right_channel = if homogeneous {
        left_channel
    } else {
        pick_channel(&mut rng)
    };
    let camera = RigPair {
        filters: [first, second],
        sensor,
        focal_length_px: random_focal_length(w, &mut rng),
    };
    let name = |c: Channel| match c {
        Channel::Luminance => "Y".to_string(),
        Channel::Colour(c) => ["R", "G", "B"][c].to_string(),
    };
    let label = format!(
        "{first}/{} vs {second}/{} ({sensor})",
        name(left_channel),
        name(right_channel)
    );
    let channels = [left_channel, right_channel];
    grey_pair(
        &camera,
        scene,
        (w, h),
        seed,
        channels,
        homogeneous,
        label,
        effects,
    )
}

/// A random pair's focal length: the paper rig's field of view at width `w`, ×0.6 to 1.4.
fn random_focal_length(w: usize, rng: &mut ChaCha8Rng) -> f64 {
    1800.0 * w as f64 / 640.0 * rng.random_range(0.6..1.4)
}

/// `scene` rendered through `camera` ([`render_pair`]) at `w × h`, each view's `channels`
/// entry as a normalised grey image; recorded through `effects` when given (rendered
/// noise-free, then each camera's [`CameraEffects::record`]).
#[allow(clippy::too_many_arguments)]
fn grey_pair(
    camera: &RigPair<'_>,
    scene: SceneFile,
    (w, h): (usize, usize),
    seed: u64,
    channels: [Channel; 2],
    homogeneous: bool,
    label: String,
    effects: Option<CameraEffects>,
) -> anaglyph_core::Result<StereoPair> {
    let (lv, rv, disparity) = render_pair(camera, scene, w, h, seed, effects.as_ref())?;
    let mut greys = [
        grey_of(&lv.capture, lv.channels, w, h, channels[0]),
        grey_of(&rv.capture, rv.channels, w, h, channels[1]),
    ];
    let mut label = label;
    if let Some(effects) = &effects {
        for (k, grey) in greys.iter_mut().enumerate() {
            // The noise-free capture in units of the white board's signal.
            grey.data
                .iter_mut()
                .for_each(|v| *v /= NOISE_FREE_EXPOSURE as f32);
            *grey = effects.record(k, grey, seed);
        }
        label = format!("{label}; {}", effects.label());
    }
    let [left, right] = greys;
    Ok(StereoPair {
        left: normalise_image(&left),
        right: normalise_image(&right),
        disparity,
        kind: if homogeneous {
            PairKind::Homogeneous
        } else {
            PairKind::Heterogeneous
        },
        label,
    })
}

/// Two cameras side by side (the paper rig's 30 mm baseline). Filters and sensor are
/// built-in names, or curve references with a prefix (`gaussian:550:30`).
#[derive(Debug, Clone, Copy)]
pub struct RigPair<'a> {
    pub filters: [&'a str; 2],
    pub sensor: &'a str,
    pub focal_length_px: f64,
}

/// `name` as a rig file's curve reference: built-in unless it has a prefix already.
fn curve_reference(name: &str) -> String {
    match name.contains(':') {
        true => name.to_string(),
        false => format!("builtin:{name}"),
    }
}

/// Renders a scene through two cameras: (left view, right view, left disparity where the
/// right view sees the same surface, else NaN).
fn render_pair(
    camera: &RigPair<'_>,
    scene: SceneFile,
    w: usize,
    h: usize,
    seed: u64,
    effects: Option<&CameraEffects>,
) -> anaglyph_core::Result<(RenderedView, RenderedView, Vec<f32>)> {
    let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    file.focal_length_px = Some(camera.focal_length_px);
    file.sensor = curve_reference(camera.sensor);
    file.rows = Some(1);
    file.cols = Some(2);
    file.cameras.truncate(2);
    file.cameras[0].filter = Some(curve_reference(camera.filters[0]));
    file.cameras[1].filter = Some(curve_reference(camera.filters[1]));
    let rig = Rig::from_file(file, ".".into())?;
    let scene = Scene::resolve(scene, Path::new("."))?;
    let sim = Simulation::run(
        &rig,
        &scene,
        SimulationSettings {
            width: w,
            height: h,
            seed,
            // With camera effects the pair records the noise-free light itself.
            noise: match effects {
                Some(_) => None,
                None => SimulationSettings::default().noise,
            },
            vignetting: effects.map_or(0.0, |e| e.vignetting),
            ..SimulationSettings::default()
        },
    )?;
    let mut views = sim.views.into_iter();
    let (lv, rv) = match (views.next(), views.next()) {
        (Some(l), Some(r)) => (l, r),
        _ => {
            return Err(anaglyph_core::Error::setting(
                "simulated stereo pair",
                "fewer than two views",
                "two views",
            ))
        }
    };
    // Keep the disparity where the right view sees the same surface (|d_R(x − d) − d| < 1).
    let disparity = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let d = lv.disparity[i];
            let xr = (x as f32 - d).round();
            if !d.is_finite() || xr < 0.0 || xr >= w as f32 {
                return f32::NAN;
            }
            let dr = rv.disparity[y * w + xr as usize];
            if (dr - d).abs() < 1.0 {
                d
            } else {
                f32::NAN
            }
        })
        .collect();
    Ok((lv, rv, disparity))
}

/// A pair of the paper's rig proper (Canon sensor, luminance, the rig's focal length
/// unless given): for evaluating on the camera pairs the pipeline actually matches.
pub fn rig_pair(
    scene: SceneFile,
    camera: &RigPair<'_>,
    width: usize,
    height: usize,
    seed: u64,
) -> anaglyph_core::Result<StereoPair> {
    grey_pair(
        camera,
        scene,
        (width, height),
        seed,
        [Channel::Luminance; 2],
        camera.filters[0] == camera.filters[1],
        format!("{} vs {}", camera.filters[0], camera.filters[1]),
        None,
    )
}

/// `count` simulated pairs from scene seeds `first_seed..`, rendered in parallel.
pub fn simulated_pairs(
    first_seed: u64,
    count: usize,
    settings: &PairSettings,
) -> anaglyph_core::Result<Vec<StereoPair>> {
    (0..count as u64)
        .into_par_iter()
        .map(|i| simulated_pair(first_seed + i, settings))
        .collect()
}

/// Every built-in texture as every ordered pair of distinct colour channels (zero
/// disparity: the augmentation supplies the geometric differences).
pub fn channel_swap_pairs() -> anaglyph_core::Result<Vec<StereoPair>> {
    let mut pairs = Vec::new();
    for name in TEXTURE_NAMES {
        let texture = builtin_texture(name)?;
        let rgb = &texture.image;
        let channel = |c: usize| GreyImage {
            channels: 1,
            width: rgb.width,
            height: rgb.height,
            data: rgb.data.iter().skip(c).step_by(3).copied().collect(),
        };
        for a in 0..3 {
            for b in 0..3 {
                if a != b {
                    pairs.push(StereoPair {
                        left: normalise_image(&channel(a)),
                        right: normalise_image(&channel(b)),
                        disparity: vec![0.0; rgb.pixels()],
                        kind: PairKind::ChannelSwap,
                        label: format!("{name} channel {a} vs {b}"),
                    });
                }
            }
        }
    }
    Ok(pairs)
}

/// MC-CNN's augmentation ranges (KITTI values of Zbontar & LeCun 2016, Table 3).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Augmentation {
    pub scale: f32,
    pub horizontal_scale: f32,
    pub horizontal_shear: f32,
    pub rotate_degrees: f32,
    pub brightness: f32,
    pub contrast: f32,
    pub right_horizontal_scale: f32,
    pub right_horizontal_shear: f32,
    pub right_brightness: f32,
    pub right_contrast: f32,
}

impl Augmentation {
    pub const MC_CNN_KITTI: Augmentation = Augmentation {
        scale: 0.8,
        horizontal_scale: 0.8,
        horizontal_shear: 0.1,
        rotate_degrees: 7.0,
        brightness: 0.7,
        contrast: 1.3,
        right_horizontal_scale: 0.9,
        right_horizontal_shear: 0.1,
        right_brightness: 0.3,
        right_contrast: 1.1,
    };
    pub const NONE: Augmentation = Augmentation {
        scale: 1.0,
        horizontal_scale: 1.0,
        horizontal_shear: 0.0,
        rotate_degrees: 0.0,
        brightness: 0.0,
        contrast: 1.0,
        right_horizontal_scale: 1.0,
        right_horizontal_shear: 0.0,
        right_brightness: 0.0,
        right_contrast: 1.0,
    };
}

/// An affine patch sampler: `image(centre + A·(i − 4, j − 4))·contrast + brightness`.
#[derive(Debug, Clone, Copy)]
struct Warp {
    a: [f32; 4],
    contrast: f32,
    brightness: f32,
}

impl Warp {
    fn sample(&self, image: &GreyImage, cx: f32, cy: f32, out: &mut [f32]) {
        let half = (PATCH / 2) as f32;
        for j in 0..PATCH {
            for i in 0..PATCH {
                let (u, v) = (i as f32 - half, j as f32 - half);
                let x = cx + self.a[0] * u + self.a[1] * v;
                let y = cy + self.a[2] * u + self.a[3] * v;
                out[j * PATCH + i] = bilinear(image, x, y) * self.contrast + self.brightness;
            }
        }
    }
}

/// Bilinear sample with edge clamping.
fn bilinear(image: &GreyImage, x: f32, y: f32) -> f32 {
    let (w, h) = (image.width as f32, image.height as f32);
    let x = x.clamp(0.0, w - 1.0);
    let y = y.clamp(0.0, h - 1.0);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (xa, ya) = (x0 as usize, y0 as usize);
    let xb = (xa + 1).min(image.width - 1);
    let yb = (ya + 1).min(image.height - 1);
    let top = image.at(xa, ya) * (1.0 - fx) + image.at(xb, ya) * fx;
    let bottom = image.at(xa, yb) * (1.0 - fx) + image.at(xb, yb) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// Uniform in `[1/r, r]` on a log scale (for r ≥ 1), or `[r, 1]` for r < 1.
fn factor(rng: &mut ChaCha8Rng, r: f32) -> f32 {
    if r >= 1.0 {
        (rng.random_range(-1.0..=1.0f32) * r.ln()).exp()
    } else {
        rng.random_range(r..=1.0)
    }
}

fn symmetric(rng: &mut ChaCha8Rng, r: f32) -> f32 {
    if r > 0.0 {
        rng.random_range(-r..=r)
    } else {
        0.0
    }
}

fn warps(rng: &mut ChaCha8Rng, aug: &Augmentation) -> (Warp, Warp) {
    let s = factor(rng, aug.scale);
    let hs = factor(rng, aug.horizontal_scale);
    let shear = symmetric(rng, aug.horizontal_shear);
    let angle = symmetric(rng, aug.rotate_degrees).to_radians();
    let (sin, cos) = angle.sin_cos();
    // A = R(angle) · [[s·hs, s·shear], [0, s]].
    let base = |hs: f32, shear: f32| {
        let m = [s * hs, s * shear, 0.0, s];
        [
            cos * m[0] - sin * m[2],
            cos * m[1] - sin * m[3],
            sin * m[0] + cos * m[2],
            sin * m[1] + cos * m[3],
        ]
    };
    let contrast = factor(rng, aug.contrast);
    let brightness = symmetric(rng, aug.brightness);
    let left = Warp {
        a: base(hs, shear),
        contrast,
        brightness,
    };
    let right = Warp {
        a: base(
            hs * factor(rng, aug.right_horizontal_scale),
            shear + symmetric(rng, aug.right_horizontal_shear),
        ),
        contrast: contrast * factor(rng, aug.right_contrast),
        brightness: brightness + symmetric(rng, aug.right_brightness),
    };
    (left, right)
}

/// A batch of triplets, each `batch × PATCH × PATCH`: left patches, their positive right
/// patches and their negative right patches.
#[derive(Debug, Clone)]
pub struct TripletBatch {
    pub batch: usize,
    pub left: Vec<f32>,
    pub positive: Vec<f32>,
    pub negative: Vec<f32>,
}

/// Draws allowed per triplet before sampling gives up (usable pixels are typically over
/// half of a pair; a thousand misses in a row mean there are none).
const MAX_ATTEMPTS_PER_TRIPLET: usize = 1000;

/// Samples `batch` triplets: a group drawn by weight, then a pair and a pixel with known
/// disparity uniformly within it.
pub fn sample_triplets(
    groups: &[(&[StereoPair], f64)],
    batch: usize,
    sampling: &Sampling,
    augmentation: &Augmentation,
    rng: &mut ChaCha8Rng,
) -> crate::Result<TripletBatch> {
    let n = PATCH * PATCH;
    let mut out = TripletBatch {
        batch,
        left: vec![0.0; batch * n],
        positive: vec![0.0; batch * n],
        negative: vec![0.0; batch * n],
    };
    let margin = (PATCH / 2) as f32 + 1.0;
    let mut filled = 0;
    // Every draw that lands on an unusable pixel costs an attempt; pairs without any
    // usable pixel would otherwise loop for ever.
    let mut attempts = 0usize;
    while filled < batch {
        attempts += 1;
        if attempts > MAX_ATTEMPTS_PER_TRIPLET * batch {
            return Err(crate::Error::NoTrainingPixels {
                attempts,
                filled,
                wanted: batch,
            });
        }
        let mut pick = rng.random::<f64>() * groups.iter().map(|g| g.1).sum::<f64>();
        let group = groups
            .iter()
            .find(|g| {
                pick -= g.1;
                pick < 0.0
            })
            .unwrap_or(&groups[0])
            .0;
        if group.is_empty() {
            continue;
        }
        let pair = &group[rng.random_range(0..group.len())];
        let (w, h) = (pair.left.width, pair.left.height);
        let (x, y) = (rng.random_range(0..w), rng.random_range(0..h));
        let d = pair.disparity[y * w + x];
        if !d.is_finite() {
            continue;
        }
        let positive = symmetric(rng, sampling.positive_offset);
        let (near, far) = sampling.negative_offsets;
        let negative = rng.random_range(near..=far) * if rng.random::<bool>() { 1.0 } else { -1.0 };
        let xr = x as f32 - d;
        let inside = |v: f32, size: usize| v >= margin && v <= size as f32 - 1.0 - margin;
        if !inside(x as f32, w)
            || !inside(y as f32, h)
            || !inside(xr + positive, w)
            || !inside(xr + negative, w)
        {
            continue;
        }
        let (lw, rw) = warps(rng, augmentation);
        let slot = filled * n..(filled + 1) * n;
        lw.sample(&pair.left, x as f32, y as f32, &mut out.left[slot.clone()]);
        rw.sample(
            &pair.right,
            xr + positive,
            y as f32,
            &mut out.positive[slot.clone()],
        );
        rw.sample(
            &pair.right,
            xr + negative,
            y as f32,
            &mut out.negative[slot],
        );
        filled += 1;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(value: f32, w: usize, h: usize) -> GreyImage {
        GreyImage {
            channels: 1,
            width: w,
            height: h,
            data: vec![value; w * h],
        }
    }

    fn plain(exposure: f64, gamma: Option<f64>) -> CameraEffects {
        let camera = CameraResponse {
            defocus_sigma_px: 0.0,
            prnu: 0.0,
            noise: CameraNoise {
                full_well_electrons: 5_000.0,
                read_noise_electrons: 5.0,
                bits: 12,
                exposure,
            },
        };
        CameraEffects {
            vignetting: 0.0,
            cameras: [camera; 2],
            gamma,
        }
    }

    fn mean_and_deviation(values: &[f32]) -> (f64, f64) {
        let n = values.len() as f64;
        let mean = values.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let var = values
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / n;
        (mean, var.sqrt())
    }

    #[test]
    fn a_recording_has_the_cameras_exposure_noise_and_encoding() {
        let clean = flat(0.5, 200, 100);
        // Linear: the mean is the exposed signal, the spread the noise model's at it.
        let effects = plain(0.4, None);
        let linear = effects.record(0, &clean, 7);
        let (mean, deviation) = mean_and_deviation(&linear.data);
        assert!((mean - 0.2).abs() < 1e-3, "mean {mean}");
        let sigma = effects.cameras[0].noise.sigma(0.5) * 0.4;
        assert!(
            (deviation / sigma - 1.0).abs() < 0.05,
            "{deviation} vs {sigma}"
        );
        // Over-exposed: a white clips at full scale.
        let bright = plain(1.6, None).record(1, &flat(1.0, 64, 64), 7);
        assert!(bright.data.iter().all(|&v| v == 1.0));
        // Gamma-encoded 8 bits: values on the 8-bit grid around the encoded mean.
        let encoded = plain(0.4, Some(2.2)).record(0, &clean, 7);
        assert!(encoded
            .data
            .iter()
            .all(|&v| ((v * 255.0).round() - v * 255.0).abs() < 1e-3));
        let (mean, _) = mean_and_deviation(&encoded.data);
        let want = 0.2f64.powf(1.0 / 2.2);
        assert!((mean - want).abs() < 3e-3, "mean {mean} against {want}");
        // Defocus spreads the light before the noise: a bright column reaches its
        // neighbours, by the Gaussian's weight at 1 px.
        let blurred = CameraEffects {
            cameras: [CameraResponse {
                defocus_sigma_px: 1.5,
                ..effects.cameras[0]
            }; 2],
            ..effects
        };
        let mut line = flat(0.0, 41, 200);
        (0..200).for_each(|y| line.data[y * 41 + 20] = 1.0);
        let spread = blurred.record(0, &line, 7);
        let column = |x: usize| {
            (0..200)
                .map(|y| spread.data[y * 41 + x])
                .collect::<Vec<_>>()
        };
        let (centre, _) = mean_and_deviation(&column(20));
        let (beside, _) = mean_and_deviation(&column(21));
        let (far, _) = mean_and_deviation(&column(30));
        let ratio = beside / centre;
        let want = (-0.5f64 / 1.5f64.powi(2)).exp();
        assert!((ratio / want - 1.0).abs() < 0.1, "{ratio} against {want}");
        assert!(far < 0.002, "{far}");
        let uneven = CameraEffects {
            cameras: [CameraResponse {
                prnu: 0.02,
                ..effects.cameras[0]
            }; 2],
            ..effects
        };
        let (_, spread) = mean_and_deviation(&uneven.record(0, &clean, 7).data);
        let want = (deviation.powi(2) + (0.02f64 * 0.2).powi(2)).sqrt();
        assert!(
            (spread / want - 1.0).abs() < 0.05,
            "{spread} against {want}"
        );
    }

    #[test]
    fn camera_effects_change_only_the_pairs_that_draw_them() {
        let plain = PairSettings {
            width: 64,
            height: 48,
            ..PairSettings::default()
        };
        let mixed = PairSettings {
            camera_effects_share: 0.5,
            ..plain
        };
        let (mut with, mut without) = (0, 0);
        for seed in 0..8 {
            let a = simulated_pair(seed, &plain).unwrap();
            let b = simulated_pair(seed, &mixed).unwrap();
            assert_eq!(a.disparity.len(), b.disparity.len());
            assert!(a
                .disparity
                .iter()
                .zip(&b.disparity)
                .all(|(x, y)| x.to_bits() == y.to_bits()));
            if b.label == a.label {
                assert_eq!(a.left.data, b.left.data, "seed {seed}");
                assert_eq!(a.right.data, b.right.data, "seed {seed}");
                without += 1;
            } else {
                assert!(b.label.starts_with(&a.label), "{}", b.label);
                assert_ne!(a.left.data, b.left.data, "seed {seed}");
                with += 1;
            }
        }
        assert!(with > 0 && without > 0, "{with} with, {without} without");
    }
}
