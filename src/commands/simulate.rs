//! `anaglyph simulate`: a scene rendered through a rig into the simulator's file layout.

use super::{begin_output, format_seconds, rig_inputs};
use crate::cli::SimulateArgs;
use crate::progress::spinner;
use anaglyph_core::rig::Rig;
use anaglyph_core::scene::{MetamerVariation, Scene, SceneFile};
use anaglyph_core::simulate::{
    write_simulation, write_simulation_frames, DarkSignal, PoseJitter, Simulation,
    SimulationSettings,
};
use anyhow::Context;
use std::path::Path;
use std::time::Instant;

pub fn run(args: SimulateArgs) -> anyhow::Result<()> {
    let rig_path = Path::new(&args.rig);
    let rig = if rig_path.is_file() {
        Rig::load(rig_path)?
    } else {
        Rig::preset(&args.rig)
            .with_context(|| format!("--rig {}: no such file, and not a preset", args.rig))?
    };
    let (file, base) = SceneFile::named(&args.scene, args.seed)
        .with_context(|| format!("--scene {}", args.scene))?;
    let scene = Scene::resolve(file.clone(), &base)?;
    let mut inputs = rig_inputs(&rig);
    if rig_path.is_file() {
        inputs.push(rig_path.to_path_buf());
    }
    inputs.push(Path::new(&args.scene).to_path_buf());
    let folder = begin_output(&args.out, args.force, &inputs)?;
    let mut settings = SimulationSettings {
        width: args.size.0,
        height: args.size.1,
        supersampling: args.supersampling,
        seed: args.seed,
        vignetting: args.vignetting,
        dark: args
            .dark
            .map(|(level, pattern)| DarkSignal { level, pattern }),
        ..SimulationSettings::default()
    };
    if args.noise_free {
        settings.noise = None;
    }
    settings.metamers = args.metamers.map(|(amplitude, scale_mm)| MetamerVariation {
        amplitude,
        scale_mm,
    });
    settings.pose_jitter = args
        .pose_jitter
        .map(|(rotation_deg, offset_mm)| PoseJitter {
            rotation_deg,
            offset_mm,
        });
    let bar = spinner(format!(
        "rendering {} views of '{}' at {}×{}",
        rig.cameras.len(),
        file.name,
        settings.width,
        settings.height
    ));
    let start = Instant::now();
    if let Some(frames) = args.frames {
        if !file.moves() {
            eprintln!(
                "note: nothing in scene '{}' moves (give objects velocity_mm or spin_deg, or use \
                 tabletop-moving): the frames differ by their noise only",
                file.name
            );
        }
        let mut rendered = 0.0;
        let count = write_simulation_frames(
            &folder,
            &rig,
            &file,
            frames as usize,
            |k| {
                bar.set_message(format!("rendering frame {}/{frames}", k + 1));
                let at = Scene::resolve(file.at_frame(k), &base).map_err(|e| {
                    anaglyph_core::Error::scene(
                        format!("frame {k}"),
                        e.to_string(),
                        "a scene every frame can render (move objects less, or render fewer frames)",
                    )
                })?;
                Simulation::run(
                    &rig,
                    &at,
                    SimulationSettings {
                        frame: k,
                        ..settings.clone()
                    },
                )
            },
            &mut rendered,
        )?;
        let out = folder.commit()?;
        bar.finish_and_clear();
        println!(
            "scene '{}' through rig '{}': {frames} frames of {} views at {}×{} rendered in {}, written in {}",
            file.name,
            rig.file.name,
            rig.cameras.len(),
            settings.width,
            settings.height,
            format_seconds(rendered),
            format_seconds(start.elapsed().as_secs_f64() - rendered)
        );
        println!("wrote {count} files under {}", out.display());
        return Ok(());
    }
    let simulation = Simulation::run(&rig, &scene, settings)?;
    let rendered = start.elapsed().as_secs_f64();
    bar.set_message("writing files");
    let count = write_simulation(&folder, &rig, &file, &simulation, rendered)?;
    let out = folder.commit()?;
    bar.finish_and_clear();
    let saturated: usize = simulation.views.iter().map(|v| v.saturated).sum();
    let (dmin, dmax) = simulation
        .views
        .iter()
        .flat_map(|v| v.disparity.iter().filter(|d| d.is_finite()))
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &d| {
            (a.min(d), b.max(d))
        });
    println!(
        "scene '{}' ({} objects) through rig '{}': {} views at {}×{} rendered in {}, written in {}",
        file.name,
        scene.objects.len(),
        rig.file.name,
        simulation.views.len(),
        simulation.settings.width,
        simulation.settings.height,
        format_seconds(rendered),
        format_seconds(start.elapsed().as_secs_f64() - rendered)
    );
    println!(
        "disparity {dmin:.1}–{dmax:.1} px per column step; exposures {}; {saturated} saturated values",
        simulation.views.iter().map(|v| format!("{:.2}", v.exposure)).collect::<Vec<_>>().join(" ")
    );
    println!("wrote {count} files under {}", out.display());
    Ok(())
}
