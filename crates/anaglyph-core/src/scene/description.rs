//! Scene files: a TOML description of what stands in front of the array, that users edit
//! and presets ship as (`data/scenes/*.toml`). Frame and units as [`super::geometry`]:
//! millimetres, x right, y down, z forward from camera r0c0. Example:
//!
//! ```toml
//! name = "my-scene"
//! illuminant = "builtin:cie_a"            # optional: default is the rig's
//!
//! [[object]]                              # a textured wall
//! rectangle = { centre_mm = [45, 25, 3000], size_mm = [5000, 4000] }
//! material = { texture = "brick", scale_mm = 600 }
//!
//! [[object]]                              # the verification chart (measured spectra)
//! chart = { centre_mm = [0, 0, 1200], width_mm = 280, rotation_deg = [0, 10, 0] }
//!
//! [[object]]
//! sphere = { centre_mm = [200, 50, 1500], radius_mm = 120 }
//! material = { pattern = "stripes", period_mm = 12, srgb = [0.8, 0.2, 0.1], srgb2 = [0.1, 0.3, 0.7] }
//! ```
//!
//! Materials: `texture` (a built-in name or an image path, with `scale_mm` per repeat),
//! `srgb` (flat colour), `pattern` = stripes | checker | noise | grating with `period_mm`
//! (and `srgb`, `srgb2`, `angle_deg`, `seed`), or `reflectance` = "set/sample" from the
//! built-in measured sets (e.g. "tcs_cfi2017_99/TCS12 (CIE 2017)").

use super::material::{Material, Pattern};
use super::{builtin_texture, Shape, Texture, Vec3, UPSAMPLING_SHAPE};
use crate::spectrum::Interpolation;
use crate::{builtin, Error, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Most objects in one scene.
const MAX_OBJECTS: usize = 10_000;
/// Largest scene file read.
const MAX_SCENE_BYTES: u64 = 4 << 20;
/// Nearest allowed surface point, mm in front of the camera plane.
const MIN_DEPTH_MM: f64 = 50.0;

/// The preset scenes (`anaglyph simulate --scene <name>`).
pub const PRESETS: &[(&str, &str)] = &[
    (
        "tabletop",
        include_str!("../../../../data/scenes/tabletop.toml"),
    ),
    (
        "clutter",
        include_str!("../../../../data/scenes/clutter.toml"),
    ),
    (
        "periodic",
        include_str!("../../../../data/scenes/periodic.toml"),
    ),
    (
        "checkerboard",
        include_str!("../../../../data/scenes/checkerboard.toml"),
    ),
    (
        "tabletop-moving",
        include_str!("../../../../data/scenes/tabletop-moving.toml"),
    ),
];

/// The preset scenes the quality tables and the demo reconstruct (the `checkerboard` is
/// a calibration target).
pub const TEST_SCENES: [&str; 3] = ["tabletop", "clutter", "periodic"];

/// Geometry of an object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShapeSpec {
    pub centre_mm: [f64; 3],
    /// Rectangle: [width, height]; box: [width, height, depth].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size_mm: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width_mm: Option<f64>,
    #[serde(default)]
    pub rotation_deg: [f64; 3],
    /// Motion per frame of a sequence (`simulate --frames`): the centre moves by
    /// `velocity_mm` and the rotation turns by `spin_deg` each frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity_mm: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spin_deg: Option<[f64; 3]>,
}

/// A material as written in the file.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub srgb: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub srgb2: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pattern: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub period_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angle_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reflectance: Option<String>,
}

/// One object: exactly one shape key, and a material unless it is a chart.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rectangle: Option<ShapeSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sphere: Option<ShapeSpec>,
    #[serde(default, rename = "box", skip_serializing_if = "Option::is_none")]
    pub cuboid: Option<ShapeSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chart: Option<ShapeSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material: Option<MaterialSpec>,
}

/// The scene document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub illuminant: Option<String>,
    /// The array's own motion per frame of a sequence, mm (the scene moves by its opposite).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_velocity_mm: Option<[f64; 3]>,
    #[serde(rename = "object")]
    pub objects: Vec<ObjectSpec>,
}

/// A resolved object.
#[derive(Debug, Clone)]
pub struct SceneObject {
    pub shape: Shape,
    pub material: Material,
}

/// A resolved scene, ready to render.
#[derive(Debug, Clone)]
pub struct Scene {
    pub file: SceneFile,
    pub objects: Vec<SceneObject>,
}

impl SceneFile {
    /// Parses TOML text.
    pub fn from_toml_str(text: &str, context: &str) -> Result<Self> {
        toml::from_str(text).map_err(|e| Error::Parse {
            context: context.into(),
            line: e.span().map_or(0, |s| {
                text[..s.start.min(text.len())].lines().count().max(1)
            }),
            message: e.message().to_string(),
        })
    }

    /// A preset by name.
    pub fn preset(name: &str) -> Result<Self> {
        let (_, text) =
            PRESETS
                .iter()
                .find(|(k, _)| *k == name)
                .ok_or_else(|| Error::NotFound {
                    what: "scene preset".into(),
                    name: name.to_string(),
                    available: PRESETS
                        .iter()
                        .map(|(k, _)| *k)
                        .collect::<Vec<_>>()
                        .join(", "),
                })?;
        Self::from_toml_str(text, &format!("preset '{name}'"))
    }

    /// The scene at frame `frame` of a sequence: every object moved by its `velocity_mm`
    /// and turned by its `spin_deg` `frame` times, and by the opposite of the array's
    /// `camera_velocity_mm`. Reflectances do not change; frame 0 is the scene as written.
    pub fn at_frame(&self, frame: u64) -> SceneFile {
        let k = frame as f64;
        let camera = self.camera_velocity_mm.unwrap_or([0.0; 3]);
        let mut file = self.clone();
        for object in &mut file.objects {
            for shape in [
                &mut object.rectangle,
                &mut object.sphere,
                &mut object.cuboid,
                &mut object.chart,
            ]
            .into_iter()
            .flatten()
            {
                let v = shape.velocity_mm.unwrap_or([0.0; 3]);
                let w = shape.spin_deg.unwrap_or([0.0; 3]);
                for a in 0..3 {
                    shape.centre_mm[a] += k * (v[a] - camera[a]);
                    shape.rotation_deg[a] += k * w[a];
                }
            }
        }
        file
    }

    /// Whether anything in the scene moves between frames.
    pub fn moves(&self) -> bool {
        let nonzero = |v: Option<[f64; 3]>| v.is_some_and(|v| v.iter().any(|&x| x != 0.0));
        nonzero(self.camera_velocity_mm)
            || self.objects.iter().any(|o| {
                [&o.rectangle, &o.sphere, &o.cuboid, &o.chart]
                    .into_iter()
                    .flatten()
                    .any(|s| nonzero(s.velocity_mm) || nonzero(s.spin_deg))
            })
    }

    /// The scene a user names: a preset ([`PRESETS`]), `random` (from `seed`), or a scene
    /// file; with the folder its relative paths start from.
    pub fn named(name: &str, seed: u64) -> Result<(Self, PathBuf)> {
        if name == "random" {
            return Ok((random_scene(seed), ".".into()));
        }
        if PRESETS.iter().any(|(k, _)| *k == name) {
            return Ok((Self::preset(name)?, ".".into()));
        }
        let path = Path::new(name);
        if !path.is_file() {
            return Err(Error::NotFound {
                what: "scene preset or file".into(),
                name: name.to_string(),
                available: PRESETS
                    .iter()
                    .map(|(k, _)| *k)
                    .chain(["random"])
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Ok((Self::load(path)?, base))
    }

    /// Reads a scene file.
    pub fn load(path: &Path) -> Result<Self> {
        let size = std::fs::metadata(path)
            .map_err(|e| Error::io(path, e))?
            .len();
        if size > MAX_SCENE_BYTES {
            return Err(Error::TooLarge {
                op: format!("reading {}", path.display()),
                what: "scene file size".into(),
                size,
                limit: MAX_SCENE_BYTES,
            });
        }
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// TOML text.
    pub fn to_toml_string(&self) -> Result<String> {
        toml::to_string_pretty(self).map_err(|e| Error::output("scene file", e))
    }
}

fn finite_positive(what: &str, v: f64, ctx: &str) -> Result<f64> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(Error::out_of_range(
            format!("{ctx}: {what}"),
            v,
            "finite and > 0",
        ))
    }
}

fn finite(what: &str, v: f64, ctx: &str) -> Result<f64> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Error::NonFinite {
            what: format!("{ctx}: {what}"),
            value: v,
        })
    }
}

fn to_vec3(a: [f64; 3], ctx: &str) -> Result<Vec3> {
    if a.iter().all(|v| v.is_finite()) {
        Ok(Vec3::new(a[0], a[1], a[2]))
    } else {
        Err(Error::NonFinite {
            what: format!("{ctx}: centre_mm {a:?}"),
            value: a
                .iter()
                .copied()
                .find(|v| !v.is_finite())
                .unwrap_or(f64::NAN),
        })
    }
}

fn linear_colour(srgb: [f64; 3], ctx: &str) -> Result<[f64; 3]> {
    if srgb.iter().all(|v| (0.0..=1.0).contains(v)) {
        Ok(srgb.map(super::srgb_to_linear))
    } else {
        Err(Error::scene(
            format!("{ctx}: srgb"),
            format!("{srgb:?}"),
            "values in [0, 1]",
        ))
    }
}

/// Caches resolved textures and measured spectra while a scene loads.
struct Resolver<'a> {
    base: &'a Path,
    textures: HashMap<String, Arc<Texture>>,
}

impl Resolver<'_> {
    fn texture(&mut self, name: &str, ctx: &str) -> Result<Arc<Texture>> {
        if let Some(t) = self.textures.get(name) {
            return Ok(t.clone());
        }
        let texture = if super::TEXTURE_NAMES.contains(&name) {
            builtin_texture(name)?
        } else {
            let path = self.base.join(name);
            if !path.is_file() {
                return Err(Error::NotFound {
                    what: format!("{ctx}: texture"),
                    name: name.to_string(),
                    available: format!(
                        "built in: {}; no file {}",
                        super::TEXTURE_NAMES.join(", "),
                        path.display()
                    ),
                });
            }
            Texture::load(&path)?
        };
        let texture = Arc::new(texture);
        self.textures.insert(name.to_string(), texture.clone());
        Ok(texture)
    }
}

/// A measured spectrum "set/sample" on [`UPSAMPLING_SHAPE`].
fn measured_spectrum(reference: &str, ctx: &str) -> Result<Vec<f64>> {
    let (set, sample) = reference.split_once('/').ok_or_else(|| {
        Error::scene(
            format!("{ctx}: reflectance"),
            format!("'{reference}'"),
            "'set/sample'",
        )
    })?;
    let curve = builtin::reflectances(set)?;
    let c = curve.channel_index(sample)?;
    let values = curve.sample(c, &UPSAMPLING_SHAPE.wavelengths(), Interpolation::Linear)?;
    Ok(values.into_iter().map(|v| v.clamp(0.0, 1.0)).collect())
}

fn material(spec: &MaterialSpec, resolver: &mut Resolver, ctx: &str) -> Result<Material> {
    let kinds = [
        spec.texture.is_some(),
        spec.pattern.is_some(),
        spec.reflectance.is_some(),
    ];
    let count = kinds.iter().filter(|k| **k).count();
    if count > 1 || (count == 0 && spec.srgb.is_none()) {
        return Err(Error::scene(
            format!("{ctx}: material"),
            format!("{count} of texture, pattern and reflectance"),
            "exactly one of texture, pattern, reflectance, or an srgb colour",
        ));
    }
    if let Some(name) = &spec.texture {
        let scale_mm = finite_positive("scale_mm", spec.scale_mm.unwrap_or(500.0), ctx)?;
        return Ok(Material::Texture {
            texture: resolver.texture(name, ctx)?,
            scale_mm,
        });
    }
    if let Some(reference) = &spec.reflectance {
        return Ok(Material::Spectrum(Arc::new(measured_spectrum(
            reference, ctx,
        )?)));
    }
    let first = linear_colour(spec.srgb.unwrap_or([0.8, 0.8, 0.8]), ctx)?;
    let second = linear_colour(spec.srgb2.unwrap_or([0.1, 0.1, 0.1]), ctx)?;
    let period = || finite_positive("period_mm", spec.period_mm.unwrap_or(10.0), ctx);
    let angle = finite("angle_deg", spec.angle_deg.unwrap_or(0.0), ctx)?;
    let pattern = match spec.pattern.as_deref() {
        None => Pattern::Flat,
        Some("stripes") => Pattern::Stripes {
            period_mm: period()?,
            angle_deg: angle,
        },
        Some("checker") => Pattern::Checker {
            period_mm: period()?,
        },
        Some("noise") => Pattern::Noise {
            scale_mm: period()?,
            seed: spec.seed.unwrap_or(0),
        },
        Some("grating") => Pattern::Grating {
            period_mm: period()?,
            angle_deg: angle,
        },
        Some(other) => {
            return Err(Error::NotFound {
                what: format!("{ctx}: pattern"),
                name: other.to_string(),
                available: "stripes, checker, noise, grating".into(),
            })
        }
    };
    Ok(Material::Pattern {
        pattern,
        colours: [first, second],
    })
}

/// One object of a scene file: its shape (exactly one of rectangle, sphere, box or chart),
/// checked to lie in front of the cameras, and its material.
fn resolve_object(
    spec: &ObjectSpec,
    resolver: &mut Resolver<'_>,
    ctx: &str,
) -> Result<SceneObject> {
    let shapes = [
        spec.rectangle.is_some(),
        spec.sphere.is_some(),
        spec.cuboid.is_some(),
        spec.chart.is_some(),
    ];
    if shapes.iter().filter(|&&s| s).count() != 1 {
        return Err(Error::scene(
            ctx,
            format!("{} shapes", shapes.iter().filter(|&&s| s).count()),
            "exactly one of rectangle, sphere, box or chart",
        ));
    }
    let material = object_material(spec, resolver, ctx)?;
    let (shape, nearest_z) = object_shape(spec, ctx)?;
    if !(nearest_z >= MIN_DEPTH_MM) {
        return Err(Error::scene(
            ctx,
            format!("reaches z = {nearest_z:.1} mm"),
            format!(
                "objects at least {MIN_DEPTH_MM} mm in front of the cameras (z > 0 is forward)"
            ),
        ));
    }
    Ok(SceneObject { shape, material })
}

/// An object's material: its own, or a chart's measured ColorChecker patches.
fn object_material(spec: &ObjectSpec, resolver: &mut Resolver<'_>, ctx: &str) -> Result<Material> {
    match (&spec.material, &spec.chart) {
        (Some(m), None) => material(m, resolver, ctx),
        (None, None) => Err(Error::scene(ctx, "no material", "a material")),
        (Some(_), Some(_)) => Err(Error::scene(
            ctx,
            "a chart with a material",
            "no material: a chart has its own measured patches",
        )),
        (None, Some(chart_spec)) => {
            let chart = builtin::reflectances("colorchecker_n_ohta")?;
            let at = UPSAMPLING_SHAPE.wavelengths();
            let patches = (0..24)
                .map(|c| chart.sample(c, &at, Interpolation::Linear))
                .collect::<Result<Vec<_>>>()?;
            // The frame is the chart's own black.
            let frame = patches[23].clone();
            let width_mm = finite_positive("width_mm", chart_spec.width_mm.unwrap_or(280.0), ctx)?;
            Ok(Material::Chart {
                patches: Arc::new(patches),
                frame: Arc::new(frame),
                width_mm,
            })
        }
    }
}

/// An object's shape and the smallest depth it reaches (mm).
fn object_shape(spec: &ObjectSpec, ctx: &str) -> Result<(Shape, f64)> {
    if let Some(s) = &spec.rectangle {
        let size = s.size_mm.as_deref().unwrap_or_default();
        if size.len() != 2 {
            return Err(Error::scene(
                format!("{ctx}: rectangle size_mm"),
                format!("{size:?}"),
                "[width, height]",
            ));
        }
        let (w, h) = (
            finite_positive("width", size[0], ctx)?,
            finite_positive("height", size[1], ctx)?,
        );
        let angles = finite_angles(s.rotation_deg, ctx)?;
        let shape = Shape::rectangle(to_vec3(s.centre_mm, ctx)?, w, h, angles);
        let z = corners_min_z(&shape);
        return Ok((shape, z));
    }
    if let Some(s) = &spec.chart {
        let w = finite_positive("width_mm", s.width_mm.unwrap_or(280.0), ctx)?;
        let angles = finite_angles(s.rotation_deg, ctx)?;
        let shape = Shape::rectangle(to_vec3(s.centre_mm, ctx)?, w, w * 4.0 / 6.0, angles);
        let z = corners_min_z(&shape);
        return Ok((shape, z));
    }
    if let Some(s) = &spec.sphere {
        let r = finite_positive("radius_mm", s.radius_mm.unwrap_or(0.0), ctx)?;
        let c = to_vec3(s.centre_mm, ctx)?;
        return Ok((
            Shape::Sphere {
                centre: c,
                radius: r,
            },
            c.z - r,
        ));
    }
    let s = spec
        .cuboid
        .as_ref()
        .ok_or_else(|| Error::scene(ctx, "no shape", "a shape"))?;
    let size = s.size_mm.as_deref().unwrap_or_default();
    if size.len() != 3 {
        return Err(Error::scene(
            format!("{ctx}: box size_mm"),
            format!("{size:?}"),
            "[width, height, depth]",
        ));
    }
    let half = Vec3::new(
        0.5 * finite_positive("width", size[0], ctx)?,
        0.5 * finite_positive("height", size[1], ctx)?,
        0.5 * finite_positive("depth", size[2], ctx)?,
    );
    let c = to_vec3(s.centre_mm, ctx)?;
    let rotation = super::rotation(finite_angles(s.rotation_deg, ctx)?);
    Ok((
        Shape::Cuboid {
            centre: c,
            rotation,
            half,
        },
        c.z - half.length(),
    ))
}

/// Rotation angles (degrees) that are all finite: a NaN would silently empty the scene.
fn finite_angles(angles: [f64; 3], ctx: &str) -> Result<[f64; 3]> {
    match angles.iter().find(|a| !a.is_finite()) {
        None => Ok(angles),
        Some(&value) => Err(Error::NonFinite {
            what: format!("{ctx}: rotation_deg {angles:?}"),
            value,
        }),
    }
}

impl Scene {
    /// Resolves and validates a scene file; relative texture paths are taken from `base`.
    pub fn resolve(file: SceneFile, base: &Path) -> Result<Self> {
        if file.objects.is_empty() || file.objects.len() > MAX_OBJECTS {
            return Err(Error::scene(
                format!("scene '{}'", file.name),
                format!("{} objects", file.objects.len()),
                format!("1 to {MAX_OBJECTS}"),
            ));
        }
        let finite = |v: Option<[f64; 3]>| v.is_none_or(|v| v.iter().all(|x| x.is_finite()));
        let moving = file.objects.iter().flat_map(|o| {
            [&o.rectangle, &o.sphere, &o.cuboid, &o.chart]
                .into_iter()
                .flatten()
                .flat_map(|s| [s.velocity_mm, s.spin_deg])
        });
        if let Some(bad) = std::iter::once(file.camera_velocity_mm)
            .chain(moving)
            .find(|v| !finite(*v))
        {
            return Err(Error::scene(
                format!("scene '{}'", file.name),
                format!("a motion of {bad:?} per frame"),
                "finite velocity_mm, spin_deg and camera_velocity_mm",
            ));
        }
        let mut resolver = Resolver {
            base,
            textures: HashMap::new(),
        };
        let objects = file
            .objects
            .iter()
            .enumerate()
            .map(|(i, spec)| {
                let ctx = format!("scene '{}' object {}", file.name, i + 1);
                resolve_object(spec, &mut resolver, &ctx)
            })
            .collect::<Result<_>>()?;
        Ok(Scene { file, objects })
    }

    /// The nearest hit of a ray over all objects: (object index, hit).
    pub fn trace(&self, ray: &super::Ray) -> Option<(usize, super::Hit)> {
        let mut best: Option<(usize, super::Hit)> = None;
        for (i, object) in self.objects.iter().enumerate() {
            if let Some(hit) = object.shape.intersect(ray) {
                if best.is_none_or(|(_, b)| hit.t < b.t) {
                    best = Some((i, hit));
                }
            }
        }
        best
    }
}

fn corners_min_z(shape: &Shape) -> f64 {
    match *shape {
        Shape::Rectangle {
            centre,
            axis_u,
            axis_v,
            half_u,
            half_v,
        } => [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
            .iter()
            .map(|(a, b)| (centre + axis_u * (a * half_u) + axis_v * (b * half_v)).z)
            .fold(f64::INFINITY, f64::min),
        _ => f64::NAN,
    }
}

/// A random scene for training data: a textured back wall and 4–12 objects (rectangles,
/// boxes, spheres) with random textures, patterns, colours and measured reflectances, at
/// 600–3000 mm, inside the view of an array near the origin.
pub fn random_scene(seed: u64) -> SceneFile {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let textures = super::TEXTURE_NAMES;
    let random_material = |rng: &mut ChaCha8Rng| -> MaterialSpec {
        let colour = |rng: &mut ChaCha8Rng| {
            [
                rng.random::<f64>(),
                rng.random::<f64>(),
                rng.random::<f64>(),
            ]
        };
        match rng.random_range(0..4) {
            0 => MaterialSpec {
                texture: Some(textures[rng.random_range(0..textures.len())].to_string()),
                scale_mm: Some(rng.random_range(100.0..800.0)),
                ..Default::default()
            },
            1 => MaterialSpec {
                pattern: Some(
                    ["stripes", "checker", "noise", "grating"][rng.random_range(0..4)].to_string(),
                ),
                period_mm: Some(rng.random_range(4.0..60.0)),
                angle_deg: Some(rng.random_range(0.0..180.0)),
                seed: Some(rng.random()),
                srgb: Some(colour(rng)),
                srgb2: Some(colour(rng)),
                ..Default::default()
            },
            2 => MaterialSpec {
                reflectance: Some(format!(
                    "tcs_cfi2017_99/TCS{} (CIE 2017)",
                    rng.random_range(0..99)
                )),
                ..Default::default()
            },
            _ => MaterialSpec {
                srgb: Some(colour(rng)),
                ..Default::default()
            },
        }
    };
    let mut objects = vec![ObjectSpec {
        rectangle: Some(ShapeSpec {
            centre_mm: [45.0, 25.0, 3500.0],
            size_mm: Some(vec![8000.0, 6000.0]),
            radius_mm: None,
            width_mm: None,
            rotation_deg: [0.0; 3],
            velocity_mm: None,
            spin_deg: None,
        }),
        material: Some(MaterialSpec {
            texture: Some(textures[rng.random_range(0..textures.len())].to_string()),
            scale_mm: Some(rng.random_range(400.0..2000.0)),
            ..Default::default()
        }),
        ..Default::default()
    }];
    for _ in 0..rng.random_range(4..=12) {
        let z: f64 = rng.random_range(600.0..3000.0);
        let spread = 0.18 * z;
        let centre = [
            45.0 + rng.random_range(-spread..spread),
            25.0 + rng.random_range(-0.75 * spread..0.75 * spread),
            z,
        ];
        let size = rng.random_range(0.05..0.25) * z;
        let rotation = [
            rng.random_range(-30.0..30.0),
            rng.random_range(-45.0..45.0),
            rng.random_range(-20.0..20.0),
        ];
        let shape = ShapeSpec {
            centre_mm: centre,
            size_mm: None,
            radius_mm: None,
            width_mm: None,
            rotation_deg: rotation,
            velocity_mm: None,
            spin_deg: None,
        };
        let mut object = ObjectSpec {
            material: Some(random_material(&mut rng)),
            ..Default::default()
        };
        match rng.random_range(0..3) {
            0 => {
                object.rectangle = Some(ShapeSpec {
                    size_mm: Some(vec![size, size * rng.random_range(0.5..1.5)]),
                    ..shape
                })
            }
            1 => {
                object.sphere = Some(ShapeSpec {
                    radius_mm: Some(0.5 * size),
                    ..shape
                })
            }
            _ => {
                object.cuboid = Some(ShapeSpec {
                    size_mm: Some(vec![size, size, size * rng.random_range(0.3..1.0)]),
                    ..shape
                })
            }
        }
        objects.push(object);
    }
    SceneFile {
        name: format!("random-{seed}"),
        description: Some("random training scene".into()),
        illuminant: None,
        camera_velocity_mm: None,
        objects,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_and_random_scenes_resolve() {
        for (name, _) in PRESETS {
            let file = SceneFile::preset(name).unwrap();
            let scene = Scene::resolve(file.clone(), Path::new(".")).unwrap();
            assert!(scene.objects.len() >= 2, "{name}");
            // A preset is an ordinary scene file: it survives a round trip.
            let again = SceneFile::from_toml_str(&file.to_toml_string().unwrap(), name).unwrap();
            assert_eq!(again, file);
        }
        for seed in 0..20 {
            Scene::resolve(random_scene(seed), Path::new(".")).unwrap();
        }
        assert_eq!(random_scene(3), random_scene(3));
        assert_ne!(random_scene(3), random_scene(4));
    }

    #[test]
    fn bad_scenes_are_clear_errors() {
        let cases = [
            ("name = 'x'\n[[object]]\nrectangle = { centre_mm = [0, 0, 1000], size_mm = [10, 10] }\nmaterial = { texture = 'nope' }\n", "texture 'nope'"),
            ("name = 'x'\n[[object]]\nsphere = { centre_mm = [0, 0, -500], radius_mm = 100 }\nmaterial = { srgb = [0.5, 0.5, 0.5] }\n", "in front of the cameras"),
            ("name = 'x'\n[[object]]\nrectangle = { centre_mm = [0, 0, 1000], size_mm = [-1, 10] }\nmaterial = { srgb = [0.5, 0.5, 0.5] }\n", "width is -1"),
            ("name = 'x'\n[[object]]\nrectangle = { centre_mm = [0, 0, 1000], size_mm = [10, 10] }\n", "no material"),
            ("name = 'x'\n[[object]]\nmaterial = { srgb = [0.5, 0.5, 0.5] }\n", "exactly one of rectangle"),
            ("name = 'x'\n[[object]]\nsphere = { centre_mm = [0, 0, 900], radius_mm = 100 }\nmaterial = { srgb = [1.5, 0.5, 0.5] }\n", "srgb"),
            ("name = 'x'\n[[object]]\nrectangle = { centre_mm = [0, 0, 1000], size_mm = [10, 10], rotation_deg = [nan, 0, 0] }\nmaterial = { srgb = [0.5, 0.5, 0.5] }\n", "rotation_deg"),
            ("name = 'x'\n[[object]]\nsphere = { centre_mm = [0, 0, 900], radius_mm = 100 }\nmaterial = { pattern = 'zigzag' }\n", "pattern 'zigzag'"),
            ("name = 'x'\n[[object]]\nchart = { centre_mm = [0, 0, 900] }\nmaterial = { srgb = [0.5, 0.5, 0.5] }\n", "own measured patches"),
        ];
        for (text, needle) in cases {
            let err = SceneFile::from_toml_str(text, "t")
                .and_then(|f| Scene::resolve(f, Path::new(".")))
                .unwrap_err()
                .to_string();
            assert!(err.contains(needle), "{text}: {err}");
        }
        let err = SceneFile::from_toml_str("name = 'x'\n[[object]]\ncube = {}\n", "t.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("cube"), "{err}");
        assert!(SceneFile::preset("nowhere")
            .unwrap_err()
            .to_string()
            .contains("tabletop"));
    }
}
