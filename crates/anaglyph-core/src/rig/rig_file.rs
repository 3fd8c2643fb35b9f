//! The rig file: a TOML description of the array that users write by hand or with
//! `anaglyph rig init`. Curves are named `builtin:<name>` or by a CSV path relative to
//! the rig file. Loading resolves every curve and validates the whole rig (the layout,
//! [`super::layout`]; positive geometry; curves covering the sensor support).

use super::layout::{disparity_baseline_mm, place_cameras, reference_index};
use super::OutOfBand;
use crate::spectrum::{Interpolation, ResponseCurve, SpectralShape};
use crate::{builtin, io::write_atomically, Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Prefix of curve references that name compiled-in data.
pub const BUILTIN_PREFIX: &str = "builtin:";
/// Largest number of rows or columns of an array.
pub const MAX_RIG_SIDE: usize = 64;
/// Most reconstruction bands a rig may ask for (1 nm steps over 380–1403 nm).
pub const MAX_BANDS: usize = 1024;
/// The filters `anaglyph rig init` selects for the paper's 2×4 rig from the built-in gel
/// library by smallest cond(C) (Canon EOS 5D Mark II, CIE A), in row-major camera order.
/// The CLI test `rig_init_then_show_writes_the_rig_plot_and_c` checks the selection still
/// picks them.
pub const PAPER_RIG_FILTERS: [&str; 8] = [
    "gel_deep_red",
    "gel_salmon",
    "gel_magenta",
    "gel_lavender",
    "gel_violet",
    "gel_teal",
    "gel_yellow_green",
    "gel_emerald",
];
/// The rig presets besides the paper's (`anaglyph simulate --rig <name>`), as TOML.
pub const RIG_PRESETS: &[(&str, &str)] = &[
    (
        "mono-3x3",
        include_str!("../../../../data/rigs/mono-3x3.toml"),
    ),
    (
        "hexagon-7",
        include_str!("../../../../data/rigs/hexagon-7.toml"),
    ),
];
/// The name of the paper's 2×4 rig among the presets ([`Rig::preset`]).
pub const PAPER_RIG: &str = "paper-2x4";
/// Largest rig file read.
const MAX_RIG_FILE_BYTES: u64 = 1 << 20;

/// Distance between neighbouring camera centres, mm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Baseline {
    pub horizontal: f64,
    pub vertical: f64,
}

/// The spectral grid and solver settings of the reconstruction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReconstructionSettings {
    /// First band centre, nm.
    pub start_nm: f64,
    /// Band spacing, nm.
    pub step_nm: f64,
    /// Number of bands (the paper: N = 3M = 24).
    pub count: usize,
    /// How light outside the bands is modelled.
    #[serde(default)]
    pub out_of_band: OutOfBand,
    /// Smoothness weight λ of Eq. 6 (the paper: 0.01).
    #[serde(default = "default_lambda")]
    pub lambda: f64,
}

fn default_lambda() -> f64 {
    0.01
}

impl Default for ReconstructionSettings {
    fn default() -> Self {
        ReconstructionSettings {
            start_nm: 450.0,
            step_nm: 8.0,
            count: 24,
            out_of_band: OutOfBand::Extend,
            lambda: default_lambda(),
        }
    }
}

/// One camera of the array as written in the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraEntry {
    /// The camera's name (file names of its captures and outputs); default `r<row>c<col>`
    /// on a grid, `cam<k>` for the k-th camera given by position.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Grid row (with the rig's `rows`, `cols` and `baseline_mm`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub row: Option<usize>,
    /// Grid column.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub col: Option<usize>,
    /// Optical centre in the array's plane, mm, x right and y down seen from behind the
    /// array: any layout (hexagons, irregular), instead of `row` and `col`.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "planar_position"
    )]
    pub position_mm: Option<[f64; 2]>,
    /// The camera the array is calibrated to (default: the first camera).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub reference: bool,
    /// Filter transmission curve reference; absent where it is not known, which only a
    /// registration-only run accepts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filter: Option<String>,
    /// Sensor override for this camera (default: the rig's sensor).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor: Option<String>,
    /// Linear capture of the scene.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<PathBuf>,
    /// Linear capture of a white board (illumination and gain calibration).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white: Option<PathBuf>,
    /// Exposure metadata: the fraction of full scale a perfect white reaches in this
    /// camera's brightest channel (gain × exposure time × aperture, relative to C's
    /// normalisation); used when no white board is given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure: Option<f64>,
    /// OpenCV FileStorage calibration (.json/.yml: intrinsics, distortion, R, t); when the
    /// cameras have one, reconstruction rectifies the array first.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<PathBuf>,
    /// The sensor's black level in the capture file's own units (e.g. 64 of 65535, or
    /// 256 × 16 for a 12-bit sensor stored in 16 bits), subtracted from the capture and
    /// the white board before anything else.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub black_level: Option<f64>,
    /// A dark frame (lens capped, the capture's exposure), subtracted pixel by pixel from
    /// the capture and the white board; replaces `black_level`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dark: Option<PathBuf>,
}

/// The TOML document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigFile {
    pub name: String,
    /// Rows of a grid layout (cameras with `row` and `col`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<usize>,
    /// Columns of a grid layout.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cols: Option<usize>,
    /// Spacing of a grid layout.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baseline_mm: Option<Baseline>,
    /// Focal length in pixels: what the simulator renders with (None: a rig that only
    /// reconstructs, whose captures need none; [`RigFile::focal_length`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focal_length_px: Option<f64>,
    /// Sensor curve reference (1 channel: monochrome; 3: RGB).
    pub sensor: String,
    /// How sensor curves are resampled (the paper: cubic spline).
    #[serde(default = "default_sensor_interpolation")]
    pub sensor_interpolation: Interpolation,
    /// Illuminant folded into C (reflectance out); without it C maps radiance.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub illuminant: Option<String>,
    #[serde(default)]
    pub reconstruction: ReconstructionSettings,
    /// Distance (mm) of the plane the captures are registered to, e.g. the checkerboard
    /// the array was calibrated on: that plane has zero disparity, nearer points positive
    /// and farther ones negative (down to `−f·b_x / distance` at infinity). The simulator
    /// renders captures so registered; none: an array rectified to infinity (d ≥ 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_plane_mm: Option<f64>,
    #[serde(rename = "camera")]
    pub cameras: Vec<CameraEntry>,
}

fn default_sensor_interpolation() -> Interpolation {
    Interpolation::CubicSpline
}

/// A camera with its curves resolved.
#[derive(Debug, Clone)]
pub struct Camera {
    /// The camera's name: `<name>.png` in capture folders, `<name>.hdr` in outputs.
    pub name: String,
    /// Optical centre in the array's plane, mm: x right, y down, seen from behind.
    pub position_mm: [f64; 2],
    /// Index of its `[[camera]]` entry in the rig file.
    pub entry: usize,
    /// None: not given (a registration-only run; anything spectral refuses it).
    pub filter: Option<ResponseCurve>,
    pub sensor: ResponseCurve,
    pub image: Option<PathBuf>,
    pub white: Option<PathBuf>,
    /// Exposure metadata (see [`CameraEntry::exposure`]).
    pub exposure: Option<f64>,
    /// Calibration file (see [`CameraEntry::calibration`]).
    pub calibration: Option<PathBuf>,
    /// Black level in the capture file's units (see [`CameraEntry::black_level`]).
    pub black_level: Option<f64>,
    /// Dark frame (see [`CameraEntry::dark`]).
    pub dark: Option<PathBuf>,
}

/// A loaded, validated rig: cameras in rig order (a grid row-major, free positions in
/// file order).
#[derive(Debug, Clone)]
pub struct Rig {
    pub file: RigFile,
    /// Folder relative paths are resolved against.
    pub base_dir: PathBuf,
    pub cameras: Vec<Camera>,
    pub illuminant: Option<ResponseCurve>,
    /// The camera the array is calibrated to (`reference = true`, else the first).
    pub reference: usize,
    /// Disparities are pixels per this distance between cameras, mm: the horizontal
    /// baseline of a grid, the shortest distance between two cameras of a free layout.
    pub disparity_baseline_mm: f64,
}

/// Loads a curve reference: `builtin:<name>`, a nominal narrow-band filter
/// `gaussian:CENTRE_NM:FWHM_NM[:PEAK]`, or a CSV path relative to `base`.
pub fn resolve_curve(reference: &str, base: &Path) -> Result<ResponseCurve> {
    let gaussian = crate::filters::GAUSSIAN_PREFIX;
    // The keywords in any case; without their arguments they are not file names either.
    let keyword = |prefix: &str| {
        let n = prefix.len();
        // `get`: a prefix length may fall inside a multi-byte character.
        let head = reference.get(..n)?;
        head.eq_ignore_ascii_case(prefix).then(|| &reference[n..])
    };
    let bare = [gaussian, BUILTIN_PREFIX]
        .iter()
        .any(|p| reference.eq_ignore_ascii_case(&p[..p.len() - 1]));
    if bare || reference.trim().is_empty() {
        return Err(Error::curve(
            format!("curve '{reference}'"),
            "a keyword without its arguments, or nothing",
            "gaussian:CENTRE_NM:FWHM_NM[:PEAK], builtin:<name> or the path of a CSV file",
        ));
    }
    if let Some(spec) = keyword(gaussian) {
        return crate::filters::gaussian_filter(spec);
    }
    match keyword(BUILTIN_PREFIX) {
        Some(name) => builtin::any(name),
        None => ResponseCurve::load_csv(&base.join(reference)),
    }
}

/// [`resolve_curve`], with `none` (any case) for no curve (an illuminant left out of C).
pub fn resolve_optional_curve(reference: &str, base: &Path) -> Result<Option<ResponseCurve>> {
    if reference.eq_ignore_ascii_case("none") {
        return Ok(None);
    }
    resolve_curve(reference, base).map(Some)
}

/// The CSV file a curve reference names (relative to `base`), None for `builtin:` and
/// `gaussian:` references.
pub fn curve_file(reference: &str, base: &Path) -> Option<PathBuf> {
    if reference.starts_with(BUILTIN_PREFIX)
        || reference.starts_with(crate::filters::GAUSSIAN_PREFIX)
    {
        return None;
    }
    // An absolute reference replaces `base`.
    Some(base.join(reference))
}

/// `position_mm` as exactly `[x, y]`: a third value (a depth) would be dropped, and the
/// pipeline assumes the optical centres lie in one plane.
fn planar_position<'de, D: serde::Deserializer<'de>>(
    deserializer: D,
) -> std::result::Result<Option<[f64; 2]>, D::Error> {
    let values = Vec::<f64>::deserialize(deserializer)?;
    match values[..] {
        [x, y] => Ok(Some([x, y])),
        _ => Err(serde::de::Error::custom(format!(
            "position_mm has {} values {values:?} (expected [x, y] in mm: the optical centres \
             lie in the array's plane, so there is no z)",
            values.len()
        ))),
    }
}

/// Nearest a calibration plane may lie, in disparity baselines: nearer, the cameras'
/// views of it shift by more than a tenth of the focal length between neighbours (1 mm
/// gave shifts of 40,000 px and black captures).
pub const MIN_PLANE_BASELINES: f64 = 10.0;

impl RigFile {
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

    /// TOML text with a comment header.
    pub fn to_toml_string(&self) -> Result<String> {
        let body = toml::to_string(self).map_err(|e| Error::output("rig file", e))?;
        Ok(format!(
            "# anaglyph rig file: geometry, curves and reconstruction grid of a filtered camera array.\n\
             # Curves are 'builtin:<name>' or CSV paths (wavelength_nm,...) relative to this file.\n{body}"
        ))
    }

    /// The focal length in pixels, which rendering needs (reconstruction does not); an
    /// error naming the rig where the file gives none.
    pub fn focal_length(&self) -> Result<f64> {
        self.focal_length_px.ok_or_else(|| {
            Error::rig_layout(
                format!("rig '{}'", self.name),
                "no focal_length_px",
                "focal_length_px = <pixels> to render the array (reconstruction needs none)",
            )
        })
    }

    /// Writes the file atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        let text = self.to_toml_string()?;
        write_atomically(path, |w| w.write_all(text.as_bytes()))
    }

    fn validate(&self) -> Result<()> {
        let rig = format!("rig '{}'", self.name);
        let range = |setting: &str, value: f64, expected: &str| {
            Err(Error::out_of_range(
                format!("{rig}: {setting}"),
                value,
                expected,
            ))
        };
        if let Some(focal) = self.focal_length_px {
            if !(focal.is_finite() && focal > 0.0) {
                return range("focal length (px)", focal, "positive and finite");
            }
        }
        if let Some(plane) = self.calibration_plane_mm {
            if !(plane.is_finite() && plane > 0.0) {
                return range("calibration_plane_mm", plane, "positive and finite");
            }
        }
        let lambda = self.reconstruction.lambda;
        if !(lambda.is_finite() && lambda >= 0.0) {
            return range("lambda", lambda, "finite and >= 0");
        }
        let count = self.reconstruction.count;
        if !(1..=MAX_BANDS).contains(&count) {
            return range(
                "[reconstruction] count",
                count as f64,
                &format!("1 to {MAX_BANDS} bands"),
            );
        }
        for cam in &self.cameras {
            let name = cam
                .name
                .clone()
                .unwrap_or_else(|| match (cam.row, cam.col) {
                    (Some(r), Some(c)) => super::layout::grid_name(r, c),
                    _ => "given by position_mm".into(),
                });
            if let Some(b) = cam.black_level {
                if !(b.is_finite() && b >= 0.0) {
                    return range(
                        &format!("camera {name} black_level"),
                        b,
                        "finite and >= 0, in the capture file's units",
                    );
                }
            }
            if let Some(e) = cam.exposure {
                if !(e.is_finite() && e > 0.0) {
                    return range(&format!("camera {name} exposure"), e, "positive and finite");
                }
            }
        }
        Ok(())
    }
}

impl Rig {
    /// Reads and validates a rig file.
    pub fn load(path: &Path) -> Result<Self> {
        let size = std::fs::metadata(path)
            .map_err(|e| Error::io(path, e))?
            .len();
        if size > MAX_RIG_FILE_BYTES {
            return Err(Error::TooLarge {
                op: format!("reading {}", path.display()),
                what: "rig file size".into(),
                size,
                limit: MAX_RIG_FILE_BYTES,
            });
        }
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let file = RigFile::from_toml_str(&text, &path.display().to_string())?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::from_file(file, base)
    }

    /// A preset: [`PAPER_RIG`] (the paper's rig with [`PAPER_RIG_FILTERS`]) or one of
    /// [`RIG_PRESETS`]; their curves are all built in.
    pub fn preset(name: &str) -> Result<Self> {
        if name == PAPER_RIG {
            return Self::from_file(Self::paper_rig_file(&PAPER_RIG_FILTERS), ".".into());
        }
        let (_, text) = RIG_PRESETS
            .iter()
            .find(|(k, _)| *k == name)
            .ok_or_else(|| Error::NotFound {
                what: "rig preset".into(),
                name: name.to_string(),
                available: std::iter::once(PAPER_RIG)
                    .chain(RIG_PRESETS.iter().map(|(k, _)| *k))
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        Self::from_file(RigFile::from_toml_str(text, name)?, ".".into())
    }

    /// Resolves and validates an in-memory rig file.
    pub fn from_file(file: RigFile, base_dir: PathBuf) -> Result<Self> {
        file.validate()?;
        let placements = place_cameras(&file)?;
        let rig_sensor = resolve_curve(&file.sensor, &base_dir)?;
        let illuminant = file
            .illuminant
            .as_deref()
            .map(|r| resolve_curve(r, &base_dir))
            .transpose()?;
        let mut cameras = Vec::with_capacity(placements.len());
        for placement in &placements {
            let e = &file.cameras[placement.entry];
            let sensor = match &e.sensor {
                Some(r) => resolve_curve(r, &base_dir)?,
                None => rig_sensor.clone(),
            };
            if !(sensor.channel_count() == 1 || sensor.channel_count() == 3) {
                return Err(Error::curve(
                    format!("sensor '{}'", sensor.name()),
                    format!("{} channels", sensor.channel_count()),
                    "1 for monochrome or 3 for RGB",
                ));
            }
            let filter = e
                .filter
                .as_deref()
                .map(|f| resolve_curve(f, &base_dir))
                .transpose()?;
            let (lo, hi) = sensor.domain();
            if let Some(filter) = &filter {
                if filter.channel_count() != 1 {
                    return Err(Error::curve(
                        format!("filter '{}'", filter.name()),
                        format!("{} channels", filter.channel_count()),
                        "1 transmission column",
                    ));
                }
                filter.check_covers(lo, hi)?;
            }
            if let Some(light) = &illuminant {
                light.check_covers(lo, hi)?;
            }
            // An empty path would name the rig's own folder: refused as what it is.
            for (key, path) in [
                ("image", &e.image),
                ("white", &e.white),
                ("calibration", &e.calibration),
                ("dark", &e.dark),
            ] {
                if path.as_ref().is_some_and(|p| p.as_os_str().is_empty()) {
                    return Err(Error::bad_field(
                        format!("rig '{}'", file.name),
                        format!("camera {}: {key}", placement.name),
                        "\"\" (an empty path)",
                        "the path of a file, or no key",
                    ));
                }
            }
            // An absolute path replaces `base_dir`.
            let resolve_path = |p: &Option<PathBuf>| p.as_ref().map(|p| base_dir.join(p));
            cameras.push(Camera {
                name: placement.name.clone(),
                position_mm: placement.position_mm,
                entry: placement.entry,
                image: resolve_path(&e.image),
                white: resolve_path(&e.white),
                exposure: e.exposure,
                calibration: resolve_path(&e.calibration),
                black_level: e.black_level,
                dark: resolve_path(&e.dark),
                filter,
                sensor,
            });
        }
        let rig = Rig {
            reference: reference_index(&file, &placements),
            disparity_baseline_mm: disparity_baseline_mm(&file, &placements),
            file,
            base_dir,
            cameras,
            illuminant,
        };
        rig.reconstruction_shape()?;
        if let Some(plane) = rig.file.calibration_plane_mm {
            let nearest = MIN_PLANE_BASELINES * rig.disparity_baseline_mm;
            if rig.cameras.len() > 1 && plane < nearest {
                return Err(Error::out_of_range(
                    format!("rig '{}': calibration_plane_mm", rig.file.name),
                    plane,
                    format!(
                        "at least {nearest} mm, {MIN_PLANE_BASELINES} times the {} mm baseline \
                         (the plane the captures are registered to, in mm from the array)",
                        rig.disparity_baseline_mm
                    ),
                ));
            }
        }
        Ok(rig)
    }

    /// The reconstruction bands.
    pub fn reconstruction_shape(&self) -> Result<SpectralShape> {
        let r = &self.file.reconstruction;
        SpectralShape::new(r.start_nm, r.step_nm, r.count)
    }

    /// The index (rig order) of the camera named `name`.
    pub fn camera_index(&self, name: &str) -> Result<usize> {
        self.cameras
            .iter()
            .position(|c| c.name == name)
            .ok_or_else(|| Error::NotFound {
                what: "camera".into(),
                name: name.to_string(),
                available: self
                    .cameras
                    .iter()
                    .map(|c| c.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// Total number of camera channels (rows of C).
    pub fn channel_count(&self) -> usize {
        self.cameras.iter().map(|c| c.sensor.channel_count()).sum()
    }

    /// The rows of C (and channels of a registered stack) of camera `index`.
    pub fn channel_rows(&self, index: usize) -> std::ops::Range<usize> {
        let start: usize = self.cameras[..index]
            .iter()
            .map(|c| c.sensor.channel_count())
            .sum();
        start..start + self.cameras[index].sensor.channel_count()
    }

    /// The paper's 2×4 rig (30 mm × 50 mm baselines, a Canon 5D Mark II sensor under CIE A,
    /// the tungsten-like light of the paper's real captures) with the given filters.
    pub fn paper_rig_file(filters: &[&str]) -> RigFile {
        let cameras = filters
            .iter()
            .enumerate()
            .map(|(i, f)| CameraEntry {
                name: None,
                row: Some(i / 4),
                col: Some(i % 4),
                position_mm: None,
                reference: false,
                filter: Some(format!("{BUILTIN_PREFIX}{f}")),
                sensor: None,
                image: None,
                white: None,
                exposure: None,
                calibration: None,
                black_level: None,
                dark: None,
            })
            .collect();
        RigFile {
            name: PAPER_RIG.into(),
            rows: Some(2),
            cols: Some(4),
            baseline_mm: Some(Baseline {
                horizontal: 30.0,
                vertical: 50.0,
            }),
            focal_length_px: Some(1800.0),
            sensor: format!("{BUILTIN_PREFIX}canon_eos_5d_mark_ii"),
            sensor_interpolation: Interpolation::CubicSpline,
            illuminant: Some(format!("{BUILTIN_PREFIX}cie_a")),
            reconstruction: ReconstructionSettings::default(),
            calibration_plane_mm: None,
            cameras,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EIGHT: [&str; 8] = [
        "gel_yellow",
        "gel_red",
        "gel_magenta",
        "gel_blue",
        "gel_cyan",
        "gel_green",
        "gel_orange",
        "gel_violet",
    ];

    #[test]
    fn toml_round_trip_and_load() {
        let file = Rig::paper_rig_file(&EIGHT);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rig.toml");
        file.save(&path).unwrap();
        let rig = Rig::load(&path).unwrap();
        assert_eq!(rig.file, file);
        assert_eq!(rig.channel_count(), 24);
        assert_eq!(rig.cameras[5].name, "r1c1");
        assert_eq!(rig.cameras[5].position_mm, [30.0, 50.0]);
        assert_eq!((rig.reference, rig.disparity_baseline_mm), (0, 30.0));
    }

    #[test]
    fn every_preset_loads_with_its_reference() {
        let paper = Rig::preset(PAPER_RIG).unwrap();
        assert_eq!((paper.cameras.len(), paper.reference), (8, 0));
        let grid = Rig::preset("mono-3x3").unwrap();
        assert_eq!(grid.cameras[grid.reference].name, "r1c1");
        assert_eq!(grid.cameras[grid.reference].position_mm, [0.0, 0.0]);
        assert_eq!(grid.channel_count(), 9);
        let hexagon = Rig::preset("hexagon-7").unwrap();
        assert_eq!(hexagon.cameras[hexagon.reference].name, "nb440");
        assert!((hexagon.disparity_baseline_mm - 40.0).abs() < 1e-3);
        let error = Rig::preset("hex").unwrap_err().to_string();
        assert!(error.contains("paper-2x4, mono-3x3, hexagon-7"), "{error}");
    }

    #[test]
    fn positions_in_three_dimensions_and_planes_at_the_array_are_refused() {
        let text = "name = 'p'\nfocal_length_px = 450.0\nsensor = 'builtin:panchromatic'\n\
                    [reconstruction]\nstart_nm = 460.0\nstep_nm = 40.0\ncount = 5\n\
                    [[camera]]\nposition_mm = [0, 0, 5]\nfilter = 'gaussian:500:40'\n\
                    [[camera]]\nposition_mm = [30, 0]\nfilter = 'gaussian:600:40'\n";
        let err = RigFile::from_toml_str(text, "p.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("p.toml") && err.contains("position_mm has 3 values"),
            "{err}"
        );
        let planar = text.replace("[0, 0, 5]", "[0, 0]");
        for (plane, accepted) in [(1.0, false), (299.0, false), (300.0, true), (1500.0, true)] {
            let file = format!("calibration_plane_mm = {plane}\n{planar}");
            let rig = Rig::from_file(RigFile::from_toml_str(&file, "p").unwrap(), ".".into());
            assert_eq!(rig.is_ok(), accepted, "{plane}: {:?}", rig.err());
        }
    }

    /// A rig that only reconstructs needs no focal length; rendering it asks for one.
    #[test]
    fn the_focal_length_is_only_needed_to_render() {
        let text = "name = 'arr'\nsensor = 'builtin:panchromatic'\n\
                    [[camera]]\nposition_mm = [0, 0]\n\
                    [[camera]]\nposition_mm = [40, 0]\n";
        let file = RigFile::from_toml_str(text, "arr.toml").unwrap();
        assert_eq!(file.focal_length_px, None);
        let err = file.focal_length().unwrap_err().to_string();
        assert!(
            err.contains("rig 'arr'") && err.contains("focal_length_px"),
            "{err}"
        );
        assert!(Rig::from_file(file, ".".into()).is_ok());
        let given = format!("focal_length_px = 900.0\n{text}");
        let file = RigFile::from_toml_str(&given, "arr.toml").unwrap();
        assert_eq!(file.focal_length().unwrap(), 900.0);
        let broken = format!("focal_length_px = -1.0\n{text}");
        let file = RigFile::from_toml_str(&broken, "arr.toml").unwrap();
        assert!(Rig::from_file(file, ".".into()).is_err());
    }

    #[test]
    fn broken_rigs_are_clear_errors() {
        let mut dup = Rig::paper_rig_file(&EIGHT);
        dup.cameras[1].col = Some(0);
        let err = Rig::from_file(dup, ".".into()).unwrap_err().to_string();
        assert!(err.contains("two cameras at row 0 col 0"), "{err}");

        let mut missing = Rig::paper_rig_file(&EIGHT);
        missing.cameras.pop();
        assert!(Rig::from_file(missing, ".".into())
            .unwrap_err()
            .to_string()
            .contains("no camera at row 1 col 3"));

        let mut outside = Rig::paper_rig_file(&EIGHT);
        outside.cameras[0].row = Some(7);
        let err = Rig::from_file(outside, ".".into()).unwrap_err();
        assert!(
            matches!(&err, Error::RigLayout { found, .. } if found.contains("row 7")),
            "{err}"
        );
        assert!(err.to_string().contains("inside the 2 x 4 grid"), "{err}");

        let mut unknown = Rig::paper_rig_file(&EIGHT);
        unknown.cameras[0].filter = Some("builtin:gel_nothing".into());
        assert!(Rig::from_file(unknown, ".".into())
            .unwrap_err()
            .to_string()
            .contains("gel_nothing"));

        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("short.csv"),
            "wavelength_nm,t\n420,0.5\n700,0.5\n",
        )
        .unwrap();
        let mut short = Rig::paper_rig_file(&EIGHT);
        short.cameras[0].filter = Some("short.csv".into());
        let err = Rig::from_file(short, dir.path().into())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("covers 420 to 700 nm but 380 to 780 nm is needed"),
            "{err}"
        );

        let err = RigFile::from_toml_str("name = 'x'\nrows = 'two'\n", "t.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("t.toml"), "{err}");
        let mut empty = Rig::paper_rig_file(&EIGHT);
        empty.cameras[2].dark = Some(PathBuf::new());
        let err = Rig::from_file(empty, ".".into()).unwrap_err().to_string();
        assert!(err.contains("camera r0c2: dark is \"\""), "{err}");
        let mut zero = Rig::paper_rig_file(&EIGHT);
        zero.baseline_mm.as_mut().unwrap().vertical = 0.0;
        assert_eq!(
            Rig::from_file(zero, ".".into()).err().map(|e| e.kind()),
            Some("RigLayout")
        );
    }
}
