//! `anaglyph calibrate --checkerboard`: one checkerboard capture per camera to each
//! camera's homography onto the reference camera, written as OpenCV FileStorage files that
//! `reconstruct --calibration` reads.

use super::{begin_output, format_seconds};
use crate::cli::CalibrateArgs;
use anaglyph_core::plane_calibration::{
    calibrate_to_plane, load_board_captures, write_plane_calibration, PlaneModel,
};
use anaglyph_core::rig::Rig;
use std::time::Instant;

pub fn run(args: CalibrateArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let rig = Rig::load(&args.rig)?;
    let reference = args.reference;
    if !rig.cameras.iter().any(|c| (c.row, c.col) == reference) {
        anyhow::bail!(
            "--reference r{}c{}: not a camera of the rig {}",
            reference.0,
            reference.1,
            args.rig.display()
        );
    }
    let folder = begin_output(&args.out, args.force, &[&args.images, &args.rig])?;
    let captures = load_board_captures(&rig, &args.images)?;
    let model = if args.affine {
        PlaneModel::Affine
    } else {
        PlaneModel::Homography
    };
    let calibration = calibrate_to_plane(&captures, args.checkerboard, reference, model)?;
    let count = write_plane_calibration(&folder, &calibration, &captures)?;
    let out = folder.commit()?;
    println!(
        "{} cameras calibrated to the plane of a {} checkerboard (reference r{}c{}) in {}:",
        calibration.cameras.len(),
        calibration.pattern,
        reference.0,
        reference.1,
        format_seconds(calibration.seconds)
    );
    for fit in &calibration.cameras {
        println!(
            "  r{}c{}: residual {:.3} px RMS, {:.3} px largest",
            fit.row, fit.col, fit.residual_rms_px, fit.residual_max_px
        );
    }
    println!(
        "wrote {count} files under {} in {}; reconstruct with --calibration {}",
        out.display(),
        format_seconds(started.elapsed().as_secs_f64()),
        out.display()
    );
    Ok(())
}
