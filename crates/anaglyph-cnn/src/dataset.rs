//! Training data for the matching network: rectified grey pairs with known disparity, and
//! MC-CNN's patch triplets sampled from them (a left patch, a right patch at the true
//! correspondence give or take `POSITIVE_OFFSET`, and one `NEGATIVE_OFFSETS` away), with
//! MC-CNN's geometric and photometric augmentation.
//!
//! The pairs come from the simulator: random scenes seen by two cameras behind random
//! gels from the candidate library, with random sensors, noise and exposure, as luminance
//! or single colour channels (heterogeneous, and a share homogeneous with the same gel and
//! channel so that same-filter matching does not suffer), plus channel-swapped copies of
//! the built-in textures (the paper's KITTI recipe, one channel left, another right).
//! A recipe may add pairs of monochrome cameras behind narrow-band filters
//! ([`PairSettings::narrow_band_share`]).

use anaglyph_core::builtin;
use anaglyph_core::rig::{Rig, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{builtin_texture, random_scene, Scene, SceneFile, TEXTURE_NAMES};
use anaglyph_core::simulate::{RenderedView, Simulation, SimulationSettings};
use anaglyph_core::stereo::{normalise_image, GreyImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::Path;

/// Side of a training patch (the 4-layer tower's receptive field).
pub const PATCH: usize = 9;
/// Positive patches lie within this many pixels of the true match (MC-CNN KITTI: 1).
pub const POSITIVE_OFFSET: f32 = 1.0;
/// Negative patches lie this far from the true match, either side (MC-CNN KITTI: 4, 10).
pub const NEGATIVE_OFFSETS: (f32, f32) = (4.0, 10.0);

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
}

impl Default for PairSettings {
    fn default() -> Self {
        PairSettings {
            width: 256,
            height: 192,
            homogeneous_share: 0.25,
            narrow_band_share: 0.0,
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
            return grey_pair(&camera, scene, (w, h), seed, channels, homogeneous, label);
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
    grey_pair(&camera, scene, (w, h), seed, channels, homogeneous, label)
}

/// A random pair's focal length: the paper rig's field of view at width `w`, ×0.6 to 1.4.
fn random_focal_length(w: usize, rng: &mut ChaCha8Rng) -> f64 {
    1800.0 * w as f64 / 640.0 * rng.random_range(0.6..1.4)
}

/// `scene` rendered through `camera` ([`render_pair`]) at `w × h`, each view's `channels`
/// entry as a normalised grey image.
fn grey_pair(
    camera: &RigPair<'_>,
    scene: SceneFile,
    (w, h): (usize, usize),
    seed: u64,
    channels: [Channel; 2],
    homogeneous: bool,
    label: String,
) -> anaglyph_core::Result<StereoPair> {
    let (lv, rv, disparity) = render_pair(camera, scene, w, h, seed)?;
    Ok(StereoPair {
        left: normalise_image(&grey_of(&lv.capture, lv.channels, w, h, channels[0])),
        right: normalise_image(&grey_of(&rv.capture, rv.channels, w, h, channels[1])),
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
        let positive = symmetric(rng, POSITIVE_OFFSET);
        let negative = rng.random_range(NEGATIVE_OFFSETS.0..=NEGATIVE_OFFSETS.1)
            * if rng.random::<bool>() { 1.0 } else { -1.0 };
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
