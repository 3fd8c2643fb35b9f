//! `anaglyph demux`: Eq. 6 for every pixel of a user's measurement array, with our solvers.

use super::format_seconds;
use crate::cli::DemuxArgs;
use crate::progress::spinner;
use anaglyph_core::demux::{demultiplex_as, DemuxOptions, DemuxReport, Sample};
use anaglyph_core::image::Image;
use anaglyph_core::io::{
    open_npy_rows, read_npy_bool, read_npy_f64, read_npy_float, write_envi, write_npy_f32,
    write_npy_f64, EnviCube, FloatArray,
};
use anaglyph_core::rig::{condition_from_singular_values, ILL_CONDITIONED_WARNING};
use anyhow::{bail, Context};
use std::path::Path;
use std::time::Instant;

/// Largest CSV sensing matrix read.
const MAX_MATRIX_CSV_BYTES: u64 = 16 << 20;

/// Reads C as (rows, cols, row-major values) from .npy or a numeric CSV.
fn read_sensing(path: &Path) -> anyhow::Result<(usize, usize, Vec<f64>)> {
    let is_npy = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    if is_npy {
        let a = read_npy_f64(path)?;
        if a.shape.len() != 2 {
            bail!(
                "{}: C has shape {:?} (expected 2-D rows × N)",
                path.display(),
                a.shape
            );
        }
        return Ok((a.shape[0], a.shape[1], a.data));
    }
    let size = std::fs::metadata(path)
        .with_context(|| format!("reading {}", path.display()))?
        .len();
    if size > MAX_MATRIX_CSV_BYTES {
        bail!(
            "{}: {size} bytes (limit {MAX_MATRIX_CSV_BYTES} for a CSV matrix)",
            path.display()
        );
    }
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut values = Vec::new();
    let mut cols = None;
    let mut rows = 0;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let row: Vec<f64> = line
            .split(',')
            .map(|f| f.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .with_context(|| format!("{}: line {}: not a row of numbers", path.display(), i + 1))?;
        if *cols.get_or_insert(row.len()) != row.len() {
            bail!(
                "{}: line {} has {} values (expected {})",
                path.display(),
                i + 1,
                row.len(),
                cols.unwrap_or(0)
            );
        }
        values.extend(row);
        rows += 1;
    }
    match cols {
        Some(c) if rows > 0 => Ok((rows, c, values)),
        _ => bail!("{}: no matrix rows", path.display()),
    }
}

/// Writes an H × W × N float32 cube as ENVI.
fn write_cube(args: &DemuxArgs, shape: &[usize], data: Vec<f32>) -> anyhow::Result<()> {
    let bands = shape[2];
    let cube = EnviCube {
        image: Image::new(shape[1], shape[0], bands, data)?,
        wavelengths: args
            .wavelengths
            .map(|(start, step)| (0..bands).map(|b| start + step * b as f64).collect()),
        band_names: None,
    };
    write_envi(&args.out, &cube, "anaglyph demux spectra")?;
    Ok(())
}

fn print_report(report: &DemuxReport) {
    println!(
        "{} pixels touch s >= 0, {} distinct measurement masks, {} pixels without measurements (NaN)",
        report.bounded_pixels, report.distinct_masks, report.unmeasured_pixels
    );
}

pub fn run(args: DemuxArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let data_file = args.out.with_extension("img");
    let envi_out = args
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("hdr"));
    let mut outputs = vec![("--out", args.out.as_path())];
    if envi_out {
        outputs.push(("--out (its ENVI data file)", data_file.as_path()));
    }
    let mut inputs = vec![
        ("--sensing", args.sensing.as_path()),
        ("--measurements", args.measurements.as_path()),
    ];
    inputs.extend(args.mask.as_deref().map(|p| ("--mask", p)));
    super::check_output_files(&outputs, &inputs)?;
    let (rows, n, c) = read_sensing(&args.sensing)?;
    if rows == 0 || n == 0 {
        bail!(
            "{}: C is {rows} × {n} (expected at least one row and one column)",
            args.sensing.display()
        );
    }
    let envi = args
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("hdr"));
    // Native .npy in and out streams bands through reader, solver and writer at once;
    // an ENVI output needs the whole array.
    let stream_reader = if envi {
        None
    } else {
        open_npy_rows(&args.measurements)?
    };
    let p = match stream_reader {
        Some(_) => None,
        None => Some(read_npy_float(&args.measurements)?),
    };
    let shape_in = match (&p, &stream_reader) {
        (Some(p), _) => p.shape().to_vec(),
        (None, Some(reader)) => reader.shape.clone(),
        (None, None) => Vec::new(),
    };
    check_measurement_shape(&args, &shape_in, rows, envi)?;
    let mask = read_mask(&args, &shape_in)?;
    let loaded = start.elapsed().as_secs_f64();
    warn_if_ill_conditioned(&c, rows, n, args.lambda);
    let options = DemuxOptions {
        lambda: args.lambda,
        solver: args.solver,
        tolerance: args.tolerance,
        ..DemuxOptions::default()
    };
    let pixels = shape_in.iter().product::<usize>() / rows;
    let mut shape = shape_in;
    if let Some(last) = shape.last_mut() {
        *last = n;
    }
    let problem = Problem {
        c: &c,
        rows,
        n,
        mask: mask.as_deref(),
        options: &options,
        pixels,
    };
    match p {
        None => run_streamed(&args, &problem),
        Some(p) => run_in_memory(&args, &problem, p, &shape, envi, loaded),
    }
}

/// C, the mask and the solve of a `demux` run.
struct Problem<'a> {
    c: &'a [f64],
    rows: usize,
    n: usize,
    mask: Option<&'a [bool]>,
    options: &'a DemuxOptions,
    pixels: usize,
}

/// Checks P's shape against C and the output format.
fn check_measurement_shape(
    args: &DemuxArgs,
    shape_in: &[usize],
    rows: usize,
    envi: bool,
) -> anyhow::Result<()> {
    let Some(&last) = shape_in.last() else {
        bail!(
            "{}: a 0-d array holds no measurements",
            args.measurements.display()
        );
    };
    if last != rows {
        bail!(
            "{}: last axis has {last} channels but C has {rows} rows (shape {:?})",
            args.measurements.display(),
            shape_in
        );
    }
    if envi && shape_in.len() != 3 {
        bail!(
            "an ENVI output needs P of shape H × W × {rows}, got {:?}",
            shape_in
        );
    }
    if args.wavelengths.is_some() && !envi {
        bail!("--wavelengths only applies to an ENVI (.hdr) output");
    }
    Ok(())
}

/// The `--mask`, checked against P's shape.
fn read_mask(args: &DemuxArgs, shape_in: &[usize]) -> anyhow::Result<Option<Vec<bool>>> {
    let Some(path) = args.mask.as_deref() else {
        return Ok(None);
    };
    let m = read_npy_bool(path)?;
    if m.shape != shape_in {
        bail!(
            "{}: mask shape {:?} differs from P's {:?}",
            path.display(),
            m.shape,
            shape_in
        );
    }
    Ok(Some(m.data))
}

fn warn_if_ill_conditioned(c: &[f64], rows: usize, n: usize, lambda: f64) {
    let sv = faer::MatRef::from_row_major_slice(c, rows, n)
        .singular_values()
        .ok();
    if let Some(cond) = sv.as_deref().map(condition_from_singular_values) {
        if cond > ILL_CONDITIONED_WARNING {
            eprintln!(
                "warning: cond(C) = {cond:.3e}; the smoothness prior (λ = {lambda}) keeps the solve stable"
            );
        }
    }
}

/// .npy in and out, band after band through reader, solver and writer.
fn run_streamed(args: &DemuxArgs, problem: &Problem<'_>) -> anyhow::Result<()> {
    let Some(reader) = open_npy_rows(&args.measurements)? else {
        bail!("{}: changed while reading", args.measurements.display());
    };
    let Problem {
        c,
        rows,
        n,
        mask,
        options,
        pixels,
    } = *problem;
    let bar = spinner(format!("demultiplexing {pixels} pixels (streamed)"));
    let streamed = Instant::now();
    let report = if reader.stored_as_f32 {
        super::demux_stream::stream::<f32>(reader, c, rows, n, mask, options, &args.out, "<f4")?
    } else {
        super::demux_stream::stream::<f64>(reader, c, rows, n, mask, options, &args.out, "<f8")?
    };
    bar.finish_and_clear();
    let seconds = streamed.elapsed().as_secs_f64();
    println!(
        "{pixels} pixels × {rows} measurements -> {n} channels ({:?}, λ = {}): read, solve and write overlapped in {} ({:.1} Mpixel/s)",
        args.solver,
        args.lambda,
        format_seconds(seconds),
        pixels as f64 / seconds / 1e6
    );
    print_report(&report);
    Ok(())
}

/// The whole array in memory, solved and saved in its own float type.
fn run_in_memory(
    args: &DemuxArgs,
    problem: &Problem<'_>,
    p: FloatArray,
    shape: &[usize],
    envi: bool,
    loaded: f64,
) -> anyhow::Result<()> {
    let Problem {
        rows, n, pixels, ..
    } = *problem;
    let bar = spinner(format!("demultiplexing {pixels} pixels"));
    fn solve<T: Sample>(
        problem: &Problem<'_>,
        data: &[T],
    ) -> anyhow::Result<(Vec<T>, DemuxReport, f64)> {
        let start = Instant::now();
        let (s, report) = demultiplex_as::<T, T>(
            problem.c,
            problem.rows,
            data,
            problem.mask,
            0..problem.n,
            problem.options,
        )?;
        Ok((s, report, start.elapsed().as_secs_f64()))
    }
    let (report, solved, save_start) = match p {
        FloatArray::F32(a) => {
            let (s, report, solved) = solve(problem, &a.data)?;
            drop(a);
            bar.finish_and_clear();
            let save_start = Instant::now();
            if envi {
                write_cube(args, shape, s)?;
            } else {
                write_npy_f32(&args.out, shape, s)?;
            }
            (report, solved, save_start)
        }
        FloatArray::F64(a) => {
            let (s, report, solved) = solve(problem, &a.data)?;
            drop(a);
            bar.finish_and_clear();
            let save_start = Instant::now();
            if envi {
                write_cube(args, shape, s.iter().map(|&v| v as f32).collect())?;
            } else {
                write_npy_f64(&args.out, shape, s)?;
            }
            (report, solved, save_start)
        }
    };
    let saved = save_start.elapsed().as_secs_f64();
    println!(
        "{pixels} pixels × {rows} measurements -> {n} channels ({:?}, λ = {}): load {}, solve {} ({:.1} Mpixel/s), save {}",
        args.solver,
        args.lambda,
        format_seconds(loaded),
        format_seconds(solved),
        pixels as f64 / solved / 1e6,
        format_seconds(saved)
    );
    print_report(&report);
    Ok(())
}
