//! `anaglyph calibrate --checkerboard`: one checkerboard capture per camera to each
//! camera's homography onto the reference camera, written as OpenCV FileStorage files that
//! `reconstruct --calibration` reads.

use super::{begin_output, format_seconds};
use crate::cli::CalibrateArgs;
use anaglyph_core::plane_calibration::{
    calibrate_to_plane, load_board_captures, write_plane_calibration, PlaneModel,
};
use anaglyph_core::rig::Rig;
use anyhow::Context;
use std::time::Instant;

pub fn run(args: CalibrateArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let rig = Rig::load(&args.rig)?;
    let reference = match &args.reference {
        Some(name) => {
            let index = rig
                .camera_index(name)
                .with_context(|| format!("--reference {name}: {}", args.rig.display()))?;
            rig.cameras[index].name.clone()
        }
        None => rig.cameras[rig.reference].name.clone(),
    };
    let folder = begin_output(&args.out, args.force, &[&args.images, &args.rig])?;
    let captures = load_board_captures(&rig, &args.images)?;
    let model = if args.affine {
        PlaneModel::Affine
    } else {
        PlaneModel::Homography
    };
    let calibration = calibrate_to_plane(&captures, args.checkerboard, &reference, model)?;
    let count = write_plane_calibration(&folder, &calibration, &captures)?;
    let out = folder.commit()?;
    println!(
        "{} cameras calibrated to the plane of a {} checkerboard (reference {reference}) in {}:",
        calibration.cameras.len(),
        calibration.pattern,
        format_seconds(calibration.seconds)
    );
    for fit in &calibration.cameras {
        println!(
            "  {}: residual {:.3} px RMS, {:.3} px largest",
            fit.name, fit.residual_rms_px, fit.residual_max_px
        );
    }
    for fit in calibration.cameras.iter().filter(|f| f.mounted_otherwise()) {
        let orientation = &fit.orientation;
        let alternatives = if orientation.alternatives.is_empty() {
            String::new()
        } else {
            format!(
                " (or {}: a {} board's colours cannot tell these apart)",
                orientation.alternatives.join(" or "),
                calibration.pattern
            )
        };
        eprintln!(
            "warning: camera {} sees the board {}{alternatives}: its map turns the image by {:.1}°, \
             and reconstruct registers its captures (taken the same way) through it",
            fit.name,
            orientation.seen,
            fit.rotation_deg,
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
