//! One module per subcommand; `run` dispatches.

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
    if reference.eq_ignore_ascii_case("none") {
        return Ok(None);
    }
    Ok(Some(anaglyph_core::rig::resolve_curve(
        reference,
        std::path::Path::new("."),
    )?))
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
