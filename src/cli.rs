//! Command-line interface: one subcommand per user task, choices as enums, every
//! argument validated before any computation starts.

use anaglyph_core::demux::Solver;
use anaglyph_core::disparity::DisparityRange;
use anaglyph_core::filters::SelectionCriterion;
use anaglyph_core::plane_calibration::BoardPattern;
use anaglyph_core::reconstruct::{
    DisparitySearch, FrameLayout, FrameRange, Preset, Products, DEFAULT_SATURATION_LEVEL,
    DEFAULT_WHITE_REFLECTANCE,
};
use anaglyph_core::register::{CoarseToFine, MatchingImage, RegistrationMode, WarpKernel};
use anaglyph_core::rig::OutOfBand;
use anaglyph_core::stereo::{Contrast, GreyChannel, LeftRight, MatchMethod};
use clap::{Parser, Subcommand, ValueEnum};
use std::path::PathBuf;

#[derive(Debug, Parser)]
#[command(
    name = "anaglyph",
    version,
    about = "Multispectral light fields from a camera array behind wide-band colour filters"
)]
pub struct Args {
    /// More log output on standard error (-v info, -vv debug).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the pipeline end to end on built-in data and print what it measured.
    Demo(DemoArgs),
    /// Create or inspect a rig file.
    #[command(subcommand)]
    Rig(RigCommand),
    /// Choose the filters that make the sensing matrix best conditioned (or least noisy).
    SelectFilters(SelectFiltersArgs),
    /// Calibrate the array to a plane from one checkerboard capture per camera: each
    /// camera's homography onto the reference camera, for `reconstruct --calibration`.
    Calibrate(CalibrateArgs),
    /// Compute a filter's transmission from spectrometer readings without (s0) and with (s1) it.
    CalibrateFilter(CalibrateFilterArgs),
    /// Solve Eq. 6 for every pixel of a measurement array.
    Demux(DemuxArgs),
    /// Render a scene through a rig: captures, white boards and ground truth.
    Simulate(SimulateArgs),
    /// Train the cross-spectral matching network (MC-CNN) on simulated pairs.
    Train(TrainArgs),
    /// Disparity of a rectified pair (left is the reference), for any pair of filters.
    Match(MatchArgs),
    /// A rig's captures to a multispectral light field: a reflectance cube per view.
    Reconstruct(Box<ReconstructArgs>),
    /// Score a reconstruction against the simulator's truth (the paper's Table 1).
    Eval(EvalArgs),
}

#[derive(Debug, clap::Args)]
pub struct MatchArgs {
    /// Left (reference) image: 8- or 16-bit PNG or TIFF, grey or RGB.
    #[arg(long)]
    pub left: PathBuf,
    /// Right image, same size.
    #[arg(long)]
    pub right: PathBuf,
    /// Disparities searched: [0, N); x_right = x_left − d. Shorthand for
    /// `--disp-range 0:N`.
    #[arg(
        long,
        value_parser = clap::value_parser!(u64).range(2..=4096),
        required_unless_present = "disp_range",
        conflicts_with = "disp_range"
    )]
    pub max_disp: Option<u64>,
    /// Signed disparities searched, MIN ≤ d < MAX (e.g. `-24:8` for a pair calibrated to
    /// a plane: points beyond it have d < 0); x_right = x_left − d.
    #[arg(long, value_parser = parse_disparity_range, allow_hyphen_values = true)]
    pub disp_range: Option<DisparityRange>,
    /// Output disparity (PFM; +inf where invalid).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, value_enum, default_value_t = MatchMethod::Mccnn)]
    pub method: MatchMethod,
    /// Network weights (safetensors from `anaglyph train`); default: the built-in fast model.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Colour-mapped preview PNG of the disparity.
    #[arg(long)]
    pub preview: Option<PathBuf>,
    #[arg(long, value_enum, default_value_t = GreyChannel::Luminance)]
    pub channel: GreyChannel,
    /// Whether the pair's contrast is inverted (bright in one filter, dark in the other).
    #[arg(long, value_enum, default_value_t = Contrast::Auto)]
    pub contrast: Contrast,
    /// Skip cross-based cost aggregation (only the accurate chain uses it).
    #[arg(long, help_heading = "Ablation")]
    pub no_aggregation: bool,
    /// Skip semi-global matching.
    #[arg(long, help_heading = "Ablation")]
    pub no_sgm: bool,
    /// SGM path directions.
    #[arg(long, help_heading = "Ablation", default_value_t = 4, value_parser = clap::value_parser!(u8).range(4..=8))]
    pub sgm_paths: u8,
    #[arg(long, help_heading = "Ablation", value_enum, default_value_t = LeftRight::CheckAndFill)]
    pub left_right: LeftRight,
    /// Skip parabolic subpixel refinement.
    #[arg(long, help_heading = "Ablation")]
    pub no_subpixel: bool,
    /// Skip the 5×5 median filter.
    #[arg(long, help_heading = "Ablation")]
    pub no_median: bool,
    /// Skip the bilateral filter.
    #[arg(long, help_heading = "Ablation")]
    pub no_bilateral: bool,
    /// Winner-take-all on the raw cost: every refinement stage off.
    #[arg(long, help_heading = "Ablation")]
    pub raw: bool,
    /// Start from MC-CNN's published KITTI 2015 values instead of anaglyph's tuned chain.
    #[arg(long, help_heading = "Ablation", conflicts_with = "raw")]
    pub published: bool,
    /// Write per-stage timings and settings as JSON here.
    #[arg(long)]
    pub report: Option<PathBuf>,
}

/// Matching-network architecture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ArchitectureChoice {
    /// 4 conv layers × 64 maps, cosine similarity (the default matcher).
    Fast,
    /// 4 conv layers × 112 maps, 4 FC layers × 384 units (the paper's network).
    Accurate,
}

/// `anaglyph train`. The recipe options are optional so that a resumed run can check the
/// ones given against its checkpoint's; `commands::train` applies the defaults.
#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    /// Architecture [default: fast].
    #[arg(long, value_enum)]
    pub arch: Option<ArchitectureChoice>,
    /// Feature maps of every convolution layer [default: 64 fast, 112 accurate]: fewer
    /// make a network whose tower costs about their square as much.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1024))]
    pub feature_maps: Option<u64>,
    /// Output safetensors file (written atomically, with the recipe in its metadata).
    #[arg(long)]
    pub out: PathBuf,
    /// Optimisation steps [default: 20000].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
    pub steps: Option<u64>,
    /// Seed of initialisation, training scenes and sampling [default: 1].
    #[arg(long)]
    pub seed: Option<u64>,
    /// Triplets per step [default: 128].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=65_536))]
    pub batch: Option<u64>,
    /// Simulated training scenes (each a pair of random gels, sensor and channels)
    /// [default: 96].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub scenes: Option<u64>,
    /// Peak learning rate [default: 2e-3 fast, 5e-4 accurate].
    #[arg(long, allow_hyphen_values = true)]
    pub learning_rate: Option<f64>,
    /// Steps between validations [default: 500].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub validate_every: Option<u64>,
    /// Share of the training and validation pairs seen by two monochrome cameras behind
    /// narrow-band filters (420-700 nm, 10-40 nm wide) instead of gels on colour sensors
    /// [default: 0].
    #[arg(long, allow_hyphen_values = true)]
    pub narrow_band_share: Option<f64>,
    /// Share of the training and validation pairs whose cameras record as real ones do:
    /// defocus, vignetting, pixel gains, noise at a gain and exposure of their own,
    /// saturation, and (half of them) gamma-encoded 8-bit files [default: 0].
    #[arg(long, allow_hyphen_values = true)]
    pub camera_effects_share: Option<f64>,
    /// Distance of a triplet's negative patch from the true match, NEAR:FAR px, either
    /// side [default: 4:10, MC-CNN's KITTI values].
    #[arg(long, value_name = "NEAR:FAR", value_parser = parse_negatives)]
    pub negatives: Option<(f32, f32)>,
    /// Largest distance of a triplet's positive patch from the true match, px [default: 1].
    #[arg(long)]
    pub positive_offset: Option<f32>,
    /// Also write the validation curve as CSV here.
    #[arg(long)]
    pub curve: Option<PathBuf>,
    /// Save the run's whole state (weights, optimiser moments, random stream, curve) in
    /// this folder every --checkpoint-minutes and when the run stops, so that --resume
    /// continues it bit for bit.
    #[arg(long, help_heading = "Segments", conflicts_with = "resume")]
    pub checkpoint: Option<PathBuf>,
    /// Continue the run checkpointed in this folder, with its recipe (recipe options given
    /// here must agree); checkpoints go on into the folder.
    #[arg(long, help_heading = "Segments")]
    pub resume: Option<PathBuf>,
    /// Minutes between checkpoints.
    #[arg(
        long,
        help_heading = "Segments",
        default_value_t = 5.0,
        allow_hyphen_values = true
    )]
    pub checkpoint_minutes: f64,
    /// Stop after this many minutes of training, checkpointed: one segment of a run that
    /// --resume continues.
    #[arg(long, help_heading = "Segments", allow_hyphen_values = true)]
    pub segment_minutes: Option<f64>,
    /// Stop once this step is done, checkpointed.
    #[arg(long, help_heading = "Segments", value_parser = clap::value_parser!(u64).range(1..))]
    pub stop_at_step: Option<u64>,
}

/// Parses `DEG,MM`.
fn parse_pose_jitter(text: &str) -> Result<(f64, f64), String> {
    let (a, b) = text.split_once(',').ok_or("expected DEG,MM, e.g. 0.5,1")?;
    let deg: f64 = a
        .trim()
        .parse()
        .map_err(|_| format!("'{a}' is not a number"))?;
    let mm: f64 = b
        .trim()
        .parse()
        .map_err(|_| format!("'{b}' is not a number"))?;
    if !(deg.is_finite()
        && mm.is_finite()
        && (0.0..=10.0).contains(&deg)
        && (0.0..=100.0).contains(&mm))
    {
        return Err(format!(
            "{deg} degrees, {mm} mm (expected 0–10 degrees and 0–100 mm)"
        ));
    }
    Ok((deg, mm))
}

/// Parses `WIDTHxHEIGHT`.
fn parse_metamers(text: &str) -> Result<(f64, f64), String> {
    let mut parts = text.split(',').map(|p| p.trim().parse::<f64>());
    let amplitude = parts.next();
    let scale = parts.next().unwrap_or(Ok(10.0));
    match (amplitude, scale, parts.next()) {
        (Some(Ok(a)), Ok(s), None) if a >= 0.0 && a.is_finite() && s > 0.0 && s.is_finite() => {
            Ok((a, s))
        }
        _ => Err(format!(
            "'{text}' (expected AMPLITUDE[,SCALE_MM] with AMPLITUDE >= 0 and SCALE_MM > 0)"
        )),
    }
}

fn parse_dark(text: &str) -> Result<(f64, f64), String> {
    let mut parts = text.split(',').map(|p| p.trim().parse::<f64>());
    let level = parts.next();
    let pattern = parts.next().unwrap_or(Ok(0.0));
    match (level, pattern, parts.next()) {
        (Some(Ok(l)), Ok(p), None) if (0.0..=0.5).contains(&l) && (0.0..=l).contains(&p) => {
            Ok((l, p))
        }
        _ => Err(format!(
            "'{text}' (expected LEVEL[,PATTERN] as fractions of full scale, LEVEL 0 to 0.5, \
             PATTERN 0 to LEVEL)"
        )),
    }
}

fn parse_size(text: &str) -> Result<(usize, usize), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or("expected WIDTHxHEIGHT, e.g. 640x480")?;
    let w: usize = w
        .trim()
        .parse()
        .map_err(|_| format!("width '{w}' is not a whole number"))?;
    let h: usize = h
        .trim()
        .parse()
        .map_err(|_| format!("height '{h}' is not a whole number"))?;
    if w == 0 || h == 0 {
        return Err("width and height must be positive".into());
    }
    Ok((w, h))
}

#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// A preset (tabletop, clutter, periodic, checkerboard, tabletop-moving), `random`
    /// (seeded by --seed) or a scene TOML file.
    #[arg(long)]
    pub scene: String,
    /// Render a sequence of N frames: objects move by their `velocity_mm` and turn by their
    /// `spin_deg` each frame (the array by the scene's `camera_velocity_mm`), new noise per
    /// frame, the same exposures; captures/frame_KKKK/ and truth/frame_KKKK/ per frame, one
    /// white board per camera (`reconstruct --frames all` reads it).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10000))]
    pub frames: Option<u32>,
    /// A rig file, or a preset: paper-2x4 (the paper's rig with the selected gels),
    /// mono-3x3 or hexagon-7 (narrow-band monochrome arrays, data/rigs/).
    #[arg(long, default_value = "paper-2x4")]
    pub rig: String,
    /// Image size.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub size: (usize, usize),
    /// Seed of the noise, the exposures and random scenes.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Rays per pixel side (n × n per pixel).
    #[arg(long, default_value_t = 2)]
    pub supersampling: usize,
    /// Render without sensor noise.
    #[arg(long)]
    pub noise_free: bool,
    /// Perturb each camera by random rotations and offsets up to DEG,MM (captures only; the
    /// truth stays rectified; poses go to DIR/calibration/).
    #[arg(long, value_parser = parse_pose_jitter)]
    pub pose_jitter: Option<(f64, f64)>,
    /// Fraction of the light lost at the frame corners to lens vignetting (0 to 0.95;
    /// captures and white boards alike, as real optics do).
    #[arg(long, default_value_t = 0.0)]
    pub vignetting: f64,
    /// A sensor dark signal LEVEL[,PATTERN] (fractions of full scale: the black level and
    /// the standard deviation of its fixed pattern) in captures and white boards; each
    /// camera's master dark frame goes to DIR/dark/ and is named in rig.toml.
    #[arg(long, value_parser = parse_dark)]
    pub dark: Option<(f64, f64)>,
    /// Vary texture and pattern spectra at fixed colour: AMPLITUDE[,SCALE_MM] (1 = the
    /// full spread of measured spectra of one colour; features of SCALE_MM, default 10).
    /// Without it every colour gets the mean measured spectrum of that colour.
    #[arg(long, value_parser = parse_metamers)]
    pub metamers: Option<(f64, f64)>,
    /// Output folder, written whole at the end (a killed run leaves the previous folder
    /// as it was).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the output folder even if anaglyph did not write it (a folder anaglyph
    /// wrote is replaced whole without asking; one holding the inputs never is).
    #[arg(long)]
    pub force: bool,
}

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Number of extra reflectances mixed from the vendored measured sets.
    #[arg(long, default_value_t = 3000)]
    pub mixtures: usize,
    /// Seed of the noise and of the mixtures.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write the measured figures as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Output folder of the simulations, reconstructions and report.html, written whole
    /// at the end.
    #[arg(long, default_value = "anaglyph-demo")]
    pub out: PathBuf,
    /// Replace the output folder even if anaglyph did not write it (a folder anaglyph
    /// wrote is replaced whole without asking; one holding the inputs never is).
    #[arg(long)]
    pub force: bool,
    /// Image size of the simulated scenes (the focal length follows, keeping the field of
    /// view of the paper rig at 640×480).
    #[arg(long, default_value = "320x240", value_parser = parse_size)]
    pub size: (usize, usize),
}

#[derive(Debug, Subcommand)]
pub enum RigCommand {
    /// Write the paper's 2×4 rig, its filters chosen by `select-filters` over the built-in library.
    Init(RigInitArgs),
    /// Print a rig with cond(C) and plot its effective responses.
    Show(RigShowArgs),
}

#[derive(Debug, clap::Args)]
pub struct RigInitArgs {
    /// Where to write the rig.
    #[arg(long, default_value = "rig.toml")]
    pub out: PathBuf,
    /// Overwrite an existing file.
    #[arg(long)]
    pub force: bool,
    #[arg(long, value_enum, default_value_t = SelectionCriterion::Condition)]
    pub criterion: SelectionCriterion,
    /// Sensor curve ("builtin:<name>" or CSV path).
    #[arg(long, default_value = "builtin:canon_eos_5d_mark_ii")]
    pub sensor: String,
    /// Illuminant folded into C ("builtin:<name>", CSV path, or "none").
    #[arg(long, default_value = "builtin:cie_a")]
    pub illuminant: String,
}

#[derive(Debug, clap::Args)]
pub struct RigShowArgs {
    /// The rig file.
    pub rig: PathBuf,
    /// Where to write the response plot (SVG); default: <stem>-responses.svg beside the rig,
    /// or in the working folder when the rig is in a folder anaglyph wrote.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Also write the sensing matrix C (rows × unknowns, f64) as .npy for `anaglyph demux`.
    #[arg(long)]
    pub export_c: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
pub struct SelectFiltersArgs {
    /// How many filters (cameras) to choose.
    #[arg(long, default_value_t = 8)]
    pub count: usize,
    /// Folder of candidate filter CSVs (default: the built-in modelled gel library).
    #[arg(long)]
    pub candidates: Option<PathBuf>,
    /// Sensor curve ("builtin:<name>" or CSV path).
    #[arg(long, default_value = "builtin:canon_eos_5d_mark_ii")]
    pub sensor: String,
    /// Illuminant ("builtin:<name>", CSV path, or "none").
    #[arg(long, default_value = "builtin:cie_a")]
    pub illuminant: String,
    #[arg(long, value_enum, default_value_t = SelectionCriterion::Condition)]
    pub criterion: SelectionCriterion,
    /// Smoothness weight λ of the solver the noise criterion assumes.
    #[arg(long, default_value_t = 0.01)]
    pub lambda: f64,
    /// Sensor full-well capacity (e⁻) of the noise criterion.
    #[arg(long, default_value_t = 10_000.0)]
    pub full_well: f64,
    /// Read noise (e⁻) of the noise criterion.
    #[arg(long, default_value_t = 5.0)]
    pub read_noise: f64,
    /// How many of the best subsets to print.
    #[arg(long, default_value_t = 5)]
    pub keep: usize,
    /// Search exhaustively up to this many subsets, otherwise greedy selection plus swaps.
    #[arg(long, default_value_t = anaglyph_core::filters::EXHAUSTIVE_LIMIT)]
    pub exhaustive_limit: u64,
    #[arg(long, value_enum, default_value_t = OutOfBand::Extend)]
    pub out_of_band: OutOfBand,
    /// Write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// Inner corners of the checkerboard, COLSxROWS (9x6 for a board of 10 × 7 squares);
    /// every camera must see every inner corner (the frame may cut the outer squares).
    #[arg(long)]
    pub checkerboard: BoardPattern,
    /// Folder of checkerboard captures named <camera>.png|tif (e.g. r0c1.png), one per camera.
    #[arg(long)]
    pub images: PathBuf,
    /// Rig file (TOML): which cameras there are.
    #[arg(long)]
    pub rig: PathBuf,
    /// Output folder: <camera>.json (OpenCV FileStorage `homography`), corners/,
    /// manifest.json with residuals; give it to `reconstruct --calibration`.
    #[arg(long)]
    pub out: PathBuf,
    /// The camera the array is registered to, by name [default: the rig's camera with
    /// `reference = true`, else its first camera].
    #[arg(long)]
    pub reference: Option<String>,
    /// Fit affine maps (6 parameters) instead of homographies (8).
    #[arg(long)]
    pub affine: bool,
    /// Replace the output folder even if anaglyph did not write it.
    #[arg(long)]
    pub force: bool,
}

#[derive(Debug, clap::Args)]
pub struct CalibrateFilterArgs {
    /// Spectrometer reading without the filter (CSV, one or more target columns).
    #[arg(long)]
    pub without: PathBuf,
    /// Reading of the same targets through the filter.
    #[arg(long = "with")]
    pub with_filter: PathBuf,
    /// Where to write the transmission CSV.
    #[arg(long)]
    pub out: PathBuf,
    /// The spectrometer's relative measurement error E (Eq. 7 bounds the result by 2E).
    #[arg(long, default_value_t = 0.01)]
    pub relative_error: f64,
}

/// Parses `START:STEP` (nm).
fn parse_wavelengths(text: &str) -> Result<(f64, f64), String> {
    let (a, b) = text
        .split_once(':')
        .ok_or("expected START:STEP, e.g. 450:8")?;
    let start: f64 = a
        .trim()
        .parse()
        .map_err(|_| format!("'{a}' is not a number"))?;
    let step: f64 = b
        .trim()
        .parse()
        .map_err(|_| format!("'{b}' is not a number"))?;
    if !(start.is_finite() && step.is_finite() && start > 0.0 && step > 0.0) {
        return Err(format!("START {start} and STEP {step} must be positive"));
    }
    Ok((start, step))
}

#[derive(Debug, clap::Args)]
pub struct DemuxArgs {
    /// Sensing matrix C, rows × N (.npy, or CSV of numbers without header).
    #[arg(long)]
    pub sensing: PathBuf,
    /// Measurements P: pixels × rows or H × W × rows (.npy, f32 or f64; NaN = missing).
    #[arg(long)]
    pub measurements: PathBuf,
    /// Output spectra S: .npy (same leading shape, N channels, same float type as P), or an
    /// ENVI cube when the name ends in .hdr (P must be H × W × rows; float32 + .img beside it).
    #[arg(long)]
    pub out: PathBuf,
    /// Band centres of C's columns for the ENVI header, as START:STEP in nm (e.g. 378:8).
    #[arg(long, value_parser = parse_wavelengths)]
    pub wavelengths: Option<(f64, f64)>,
    /// Smoothness weight λ (applied exactly).
    #[arg(long, default_value_t = 0.01)]
    pub lambda: f64,
    #[arg(long, value_enum, default_value_t = Solver::Exact)]
    pub solver: Solver,
    /// Boolean mask of P's shape (true = use the measurement).
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Relative tolerance of the iterative solvers, in (0, 1).
    #[arg(long, default_value_t = 1e-10, value_parser = parse_tolerance)]
    pub tolerance: f64,
}

/// Views of the array: `all` or a list of camera names like `r0c0,r1c2`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ViewList {
    All,
    Some(Vec<String>),
}

/// `--max-disp N|auto`: `0:N`.
fn parse_search_range(text: &str) -> Result<DisparitySearch, String> {
    if text.eq_ignore_ascii_case("auto") {
        return Ok(DisparitySearch::Auto);
    }
    match text.trim().parse::<i32>() {
        Ok(n) if (2..=4096).contains(&n) => {
            Ok(DisparitySearch::Fixed(DisparityRange { min: 0, max: n }))
        }
        _ => Err(format!(
            "'{text}' (expected auto or a number of disparities in 2..=4096)"
        )),
    }
}

/// `--disp-range MIN:MAX|auto`.
fn parse_signed_search_range(text: &str) -> Result<DisparitySearch, String> {
    if text.eq_ignore_ascii_case("auto") {
        return Ok(DisparitySearch::Auto);
    }
    parse_disparity_range(text).map(DisparitySearch::Fixed)
}

/// `--negatives NEAR:FAR`: 0 < NEAR <= FAR <= 64 px.
fn parse_negatives(text: &str) -> Result<(f32, f32), String> {
    let parsed = text
        .split_once(':')
        .and_then(|(a, b)| Some((a.trim().parse::<f32>().ok()?, b.trim().parse::<f32>().ok()?)));
    match parsed {
        Some((near, far)) if near > 0.0 && near <= far && far <= 64.0 => Ok((near, far)),
        _ => Err(format!(
            "'{text}' (expected NEAR:FAR in pixels with 0 < NEAR <= FAR <= 64, e.g. 4:10)"
        )),
    }
}

fn parse_disparity_range(text: &str) -> Result<DisparityRange, String> {
    text.parse::<DisparityRange>().map_err(|e| e.to_string())
}

fn parse_non_negative(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("'{text}' (expected a finite number >= 0)")),
    }
}

fn parse_disputed_tolerance(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if (v == 0.0 || v >= 1.0) && v.is_finite() => Ok(v),
        _ => Err(format!("'{text}' (expected 0, or a finite number >= 1)")),
    }
}

/// A relative tolerance: a solver asked for 0 or NaN would iterate to its cap on every pixel.
fn parse_tolerance(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v < 1.0 => Ok(v),
        _ => Err(format!("'{text}' (expected a number in (0, 1))")),
    }
}

fn parse_positive(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("'{text}' (expected a finite number > 0)")),
    }
}

fn parse_views(text: &str) -> Result<ViewList, String> {
    if text.trim().eq_ignore_ascii_case("all") {
        return Ok(ViewList::All);
    }
    text.split(',')
        .map(|item| match item.trim() {
            "" => Err(format!(
                "'{text}': expected camera names separated by commas, e.g. r0c1,r1c1"
            )),
            name => Ok(name.to_string()),
        })
        .collect::<Result<Vec<_>, String>>()
        .map(ViewList::Some)
}

/// Pixel positions (x, y) given as `x,y[,x,y...]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Probes(pub Vec<(usize, usize)>);

fn parse_frames(text: &str) -> Result<FrameRange, String> {
    text.parse()
        .map_err(|e: anaglyph_core::Error| e.to_string())
}

fn parse_probes(text: &str) -> Result<Probes, String> {
    let values: Vec<usize> = text
        .split(',')
        .map(|v| {
            v.trim()
                .parse()
                .map_err(|_| format!("'{v}' is not a pixel coordinate"))
        })
        .collect::<Result<_, _>>()?;
    if values.is_empty() || !values.len().is_multiple_of(2) {
        return Err("expected x,y pairs: x,y[,x,y...]".into());
    }
    Ok(Probes(
        values.chunks_exact(2).map(|p| (p[0], p[1])).collect(),
    ))
}

#[derive(Debug, clap::Args)]
pub struct ReconstructArgs {
    /// Rig file (TOML) naming each camera's filter, sensor, capture and white board.
    #[arg(long)]
    pub rig: PathBuf,
    /// Output folder (views/, disparity/, preview/, probes/, registered/, manifest.json), written
    /// whole at the end: a killed run leaves the previous folder as it was. A path ending in
    /// `.zarr` is a Zarr v3 store instead (frame by frame with --frames; a rerun completes it).
    #[arg(long)]
    pub out: PathBuf,
    /// Reconstruct a sequence: `all` the frames of --captures, frame numbers `A:B` (both
    /// included) or one frame number. --captures holds a folder per frame
    /// (<frame>/<camera>.png) or per camera (<camera>/<frame>.png); --out is a Zarr store.
    #[arg(long, value_parser = parse_frames, requires = "captures")]
    pub frames: Option<FrameRange>,
    /// How --captures holds the frames (default: camera-major when it has a folder per
    /// camera, else frame-major).
    #[arg(long, value_enum, requires = "frames")]
    pub layout: Option<FrameLayout>,
    /// Dark frames of the sequence's captures: a folder of <camera>.png|tif (one per
    /// camera for every frame), or of a dark per frame and camera laid out as the captures
    /// (frame-major or camera-major). The white boards keep the rig's `dark`.
    #[arg(long, requires = "frames")]
    pub darks: Option<PathBuf>,
    /// Reconstruct every frame of --frames alone, instead of starting each from what the
    /// previous frame learned (the search range narrowed to its disparities, its views'
    /// scene priors; a cut falls back to the full search by itself).
    #[arg(long, requires = "frames")]
    pub no_reuse: bool,
    /// Replace the output folder even if anaglyph did not write it (a folder anaglyph
    /// wrote is replaced whole without asking; one holding the inputs never is).
    #[arg(long)]
    pub force: bool,
    /// Folder of captures named <camera>.png|tif, e.g. r0c1.png (default: the rig's `image` paths).
    #[arg(long)]
    pub captures: Option<PathBuf>,
    /// Folder of white-board captures named <camera>.png|tif (default: the rig's `white`).
    #[arg(long)]
    pub white: Option<PathBuf>,
    /// Folder of calibrations named <camera>.json|yml|yaml|npy
    /// (default: the rig's `calibration` paths); with them the array is rectified first.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Views to reconstruct: `all` or a list like r0c0,r1c2.
    #[arg(long, default_value = "all", value_parser = parse_views)]
    pub views: ViewList,
    /// What each view gets: `cube` (reflectance, views/), `registered` (every camera's
    /// capture warped into the view, registered/: band names = cameras, NaN where a
    /// camera does not see the point) or `both`.
    #[arg(long, value_enum, default_value_t = Products::Cubes)]
    pub output: Products,
    /// Scene illuminant (CSV, builtin:<name>, or `none` for white boards only) folded into
    /// C instead of the rig's; needed with exposure metadata when there is no white board.
    #[arg(long)]
    pub illuminant: Option<String>,
    /// Disparities searched per column step, MIN ≤ d < MAX (signed: an array calibrated
    /// to a plane sees points beyond it at d < 0), or `auto` (the default) to choose both
    /// ends from a coarse registration of the captures (recorded in the manifest).
    #[arg(long, value_parser = parse_signed_search_range, allow_hyphen_values = true)]
    pub disp_range: Option<DisparitySearch>,
    /// Shorthand for `--disp-range 0:N` (or `auto`).
    #[arg(long, value_parser = parse_search_range, conflicts_with = "disp_range")]
    pub max_disp: Option<DisparitySearch>,
    /// The stages and tuning: `default` (every stage, the measured defaults), `fast`
    /// (a lighter scene prior: about 15 % quicker), `paper` (the paper's pipeline: Eq. 6
    /// on bilinearly warped measurements, no prior, no refinement). Tuning options
    /// override it.
    #[arg(long, value_enum, default_value_t = Preset::Default)]
    pub preset: Preset,
    /// Reflectance of the white board.
    #[arg(long, default_value_t = DEFAULT_WHITE_REFLECTANCE, allow_hyphen_values = true)]
    pub white_reflectance: f64,
    /// Capture values at or above this fraction of full scale are saturated (masked).
    #[arg(long, default_value_t = DEFAULT_SATURATION_LEVEL, allow_hyphen_values = true)]
    pub saturation: f32,
    /// Pixels whose spectra are plotted: x,y[,x,y...].
    #[arg(long, value_parser = parse_probes, allow_hyphen_values = true)]
    pub probe: Option<Probes>,
    /// A simulator output folder: its truth is drawn beside the probes.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Use this simulator output's true disparities instead of registration (the
    /// registration ceiling).
    #[arg(long)]
    pub true_disparity: Option<PathBuf>,
    #[command(flatten)]
    pub registration: RegistrationArgs,
    #[command(flatten)]
    pub tuning: TuningArgs,
}

impl ReconstructArgs {
    /// The search range asked for: `--disp-range`, else `--max-disp`, else `auto`.
    pub fn search_range(&self) -> DisparitySearch {
        self.disp_range
            .or(self.max_disp)
            .unwrap_or(DisparitySearch::Auto)
    }
}

/// How `reconstruct` registers the array.
#[derive(Debug, clap::Args)]
#[command(next_help_heading = "Registration")]
pub struct RegistrationArgs {
    #[arg(long, value_enum, default_value_t = RegistrationMode::MultiBaseline,
          conflicts_with = "true_disparity")]
    pub registration: RegistrationMode,
    /// Matching cost (multi-baseline registration needs mccnn).
    #[arg(long, value_enum, default_value_t = MatchMethod::Mccnn)]
    pub method: MatchMethod,
    /// Network weights (safetensors from `anaglyph train`); default: the built-in fast model.
    #[arg(long)]
    pub model: Option<PathBuf>,
}

/// The tuning knobs of `reconstruct`, each overriding the preset's value (shown as
/// "default" for the default preset).
#[derive(Debug, clap::Args)]
#[command(next_help_heading = "Tuning (each overrides --preset)")]
pub struct TuningArgs {
    /// What multi-baseline registration compares the views by [default: common-signals].
    #[arg(long, value_enum)]
    pub matching_image: Option<MatchingImage>,
    /// How the warp reads each camera at fractional positions [default: lanczos3].
    #[arg(long, value_enum)]
    pub warp_kernel: Option<WarpKernel>,
    /// Multi-baseline registration coarse to fine: the whole range at half the
    /// resolution, then a band around those disparities at full resolution.
    #[arg(long, value_enum, default_value_t = CoarseToFine::Auto)]
    pub coarse_to_fine: CoarseToFine,
    #[arg(long, value_enum, default_value_t = Solver::Exact)]
    pub solver: Solver,
    /// Admit the warped measurements a camera's own map disputes but the view's depth
    /// order allows, and keep them where a pixel's residual with them stays within T times
    /// its residual without them; 0: the cameras' maps decide visibility alone [default: 2].
    #[arg(long, value_name = "T", value_parser = parse_disputed_tolerance)]
    pub disputed_tolerance: Option<f64>,
    /// Pixels whose residual exceeds K times the median of the completely measured
    /// pixels' keep only their own camera's measurements, for the scene prior to estimate;
    /// 0: keep every measurement [default: 4].
    #[arg(long, value_name = "K", value_parser = parse_non_negative)]
    pub scene_prior_inconsistency: Option<f64>,
    /// Leave the pixels some cameras do not see to Eq. 6's smoothness alone (also switches
    /// off --scene-prior-inconsistency, whose pixels the prior estimates).
    #[arg(long)]
    pub no_scene_prior: bool,
    /// Scene prior: multiplies the measurement noise it assumes; larger leans more on the
    /// scene's mean spectrum [default: 0.5].
    #[arg(long, value_parser = parse_positive)]
    pub scene_prior_noise: Option<f64>,
    /// Scene prior: clusters per k-means run (the prior is a mixture of Gaussians over 2
    /// runs); 1: one Gaussian [default: 32].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub scene_prior_clusters: Option<u32>,
    /// Scene prior: rounds that add the materials the complete pixels lack [default: 2].
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=8))]
    pub scene_prior_rounds: Option<u32>,
    /// Leave each view's cube as demultiplexed instead of refining it with a guided
    /// filter whose guide is the view's own capture.
    #[arg(long)]
    pub no_refine: bool,
    /// Window half-width of the guided refinement, pixels [default: 4].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=64))]
    pub refine_radius: Option<u64>,
    /// Ridge weight ε of the guided refinement (squared reflectance) [default: 1e-4].
    #[arg(long, value_parser = parse_positive)]
    pub refine_epsilon: Option<f64>,
    /// Pixels weigh 1/(1+(ρ/σ)²) in the refinement, ρ their residual and σ this multiple
    /// of the view's median residual; 0: equal weights [default: 1.5].
    #[arg(long, value_parser = parse_non_negative)]
    pub refine_confidence: Option<f64>,
}

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Simulator output folder (rig.toml, truth/).
    #[arg(long)]
    pub truth: PathBuf,
    /// Reconstruction folder (views/).
    #[arg(long)]
    pub recon: PathBuf,
    /// Write the scores as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}
