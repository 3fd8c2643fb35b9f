//! One module per subcommand; `run` dispatches.

mod calibrate;
mod calibrate_filter;
mod demo;
mod demo_light_field;
mod demo_report;
mod demux;
mod demux_stream;
mod eval;
mod match_pair;
mod reconstruct;
mod rig;
mod select_filters;
mod simulate;
mod train;

use crate::cli::Command;

/// Runs one parsed command.
pub fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Demo(args) => demo::run(args),
        Command::Rig(args) => rig::run(args),
        Command::SelectFilters(args) => select_filters::run(args),
        Command::Calibrate(args) => calibrate::run(args),
        Command::CalibrateFilter(args) => calibrate_filter::run(args),
        Command::Demux(args) => demux::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Train(args) => train::run(args),
        Command::Match(args) => match_pair::run(args),
        Command::Reconstruct(args) => reconstruct::run(*args),
        Command::Eval(args) => eval::run(args),
    }
}

/// Resolves a curve reference given on the command line ("none" for no curve).
pub fn optional_curve(
    reference: &str,
) -> anyhow::Result<Option<anaglyph_core::spectrum::ResponseCurve>> {
    Ok(anaglyph_core::rig::resolve_optional_curve(
        reference,
        std::path::Path::new("."),
    )?)
}

/// Opens the output folder `out` before any work (see `OutputFolder::begin`): `force`
/// allows replacing a folder anaglyph did not write; `inputs` may never lie inside it.
pub fn begin_output(
    out: &std::path::Path,
    force: bool,
    inputs: &[impl AsRef<std::path::Path>],
) -> anyhow::Result<anaglyph_core::io::OutputFolder> {
    use anaglyph_core::io::{OutputFolder, Replace};
    let replace = if force {
        Replace::Anything
    } else {
        Replace::OwnOutput
    };
    let inputs: Vec<&std::path::Path> = inputs.iter().map(AsRef::as_ref).collect();
    Ok(OutputFolder::begin(out, replace, &inputs)?)
}

/// Checks, before any work, that a file can be written at `path` (given as `option`):
/// not a folder, in a folder that exists and takes new files. Leaves nothing behind.
pub fn check_output_file(path: &std::path::Path, option: &str) -> anyhow::Result<()> {
    if path.is_dir() {
        anyhow::bail!(
            "{option} {}: is a folder (expected a file to write)",
            path.display()
        );
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => std::path::Path::new("."),
    };
    if !parent.is_dir() {
        anyhow::bail!(
            "{option} {}: the folder {} does not exist (expected an existing folder)",
            path.display(),
            parent.display()
        );
    }
    let probe = parent.join(format!(".anaglyph-write-check-{}", std::process::id()));
    std::fs::write(&probe, b"")
        .map_err(|e| anyhow::anyhow!("{option} {}: cannot write there: {e}", path.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// The file `path` names, as a canonical path: its own if it exists (links resolved),
/// else its folder's joined with its name.
fn file_identity(path: &std::path::Path) -> Option<std::path::PathBuf> {
    if let Ok(canonical) = path.canonicalize() {
        return Some(canonical);
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => std::path::Path::new("."),
    };
    Some(parent.canonicalize().ok()?.join(path.file_name()?))
}

/// Checks, before any work, every file a command writes (option, path): each can be
/// written ([`check_output_file`]), none is one of the command's `inputs` (option, path)
/// and no two name the same file (by canonical path, links resolved), so that no input
/// is overwritten and no output replaces another.
pub fn check_output_files(
    outputs: &[(&str, &std::path::Path)],
    inputs: &[(&str, &std::path::Path)],
) -> anyhow::Result<()> {
    for (option, path) in outputs {
        check_output_file(path, option)?;
    }
    let known = |list: &[(&str, &std::path::Path)]| -> Vec<(String, std::path::PathBuf, std::path::PathBuf)> {
        list.iter()
            .filter_map(|(o, p)| file_identity(p).map(|id| (o.to_string(), p.to_path_buf(), id)))
            .collect()
    };
    let (outs, ins) = (known(outputs), known(inputs));
    for (k, (option, path, id)) in outs.iter().enumerate() {
        if let Some((input, input_path, _)) = ins.iter().find(|(_, _, i)| i == id) {
            anyhow::bail!(
                "{option} {}: is the input {input} {} (expected a new file; writing it would \
                 overwrite the input)",
                path.display(),
                input_path.display()
            );
        }
        if let Some((other, other_path, _)) = outs[..k].iter().find(|(_, _, o)| o == id) {
            anyhow::bail!(
                "{option} {}: is also {other} {} (expected a different file for each output)",
                path.display(),
                other_path.display()
            );
        }
    }
    Ok(())
}

/// The CSV files among curve references given on the command line (relative to the
/// working folder): inputs a command's outputs must not overwrite.
pub fn curve_files(references: &[&str]) -> Vec<std::path::PathBuf> {
    let here = std::path::Path::new(".");
    references
        .iter()
        .filter_map(|r| anaglyph_core::rig::curve_file(r, here))
        .collect()
}

/// The curve files (CSV) a rig's sensor, illuminant and filters name.
pub fn rig_curve_files(rig: &anaglyph_core::rig::Rig) -> Vec<std::path::PathBuf> {
    let f = &rig.file;
    let references = std::iter::once(Some(&f.sensor))
        .chain(std::iter::once(f.illuminant.as_ref()))
        .chain(
            f.cameras
                .iter()
                .flat_map(|c| [c.filter.as_ref(), c.sensor.as_ref()]),
        );
    references
        .flatten()
        .filter_map(|r| anaglyph_core::rig::curve_file(r, &rig.base_dir))
        .collect()
}

/// Every file a rig names (captures, white boards, calibrations, dark frames), resolved:
/// inputs an output folder must not hold.
pub fn rig_inputs(rig: &anaglyph_core::rig::Rig) -> Vec<std::path::PathBuf> {
    rig.cameras
        .iter()
        .flat_map(|c| [&c.image, &c.white, &c.calibration, &c.dark])
        .flatten()
        .map(|p| rig.base_dir.join(p))
        .collect()
}

/// Formats a duration in the unit a reader expects.
pub fn format_seconds(seconds: f64) -> String {
    if seconds < 1e-3 {
        format!("{:.1} µs", seconds * 1e6)
    } else if seconds < 1.0 {
        format!("{:.1} ms", seconds * 1e3)
    } else {
        format!("{seconds:.2} s")
    }
}
