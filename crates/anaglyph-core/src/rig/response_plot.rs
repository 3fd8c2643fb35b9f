//! An SVG chart of every camera channel's effective response (sensor × filter ×
//! illuminant, each camera normalised as in C) with the reconstruction range shaded, the
//! picture `anaglyph rig show` writes (the paper's Fig. 4b–d in one plot).

use super::{EffectiveResponses, SensingMatrix};
use crate::spectrum::SpectralShape;
use crate::{io::write_atomically, Error, Result};
use plotters::prelude::*;
use std::path::Path;

/// Channel colours by sensor channel name.
fn channel_colour(label: &str, camera: usize) -> RGBColor {
    let base = match label.rsplit(':').next() {
        Some("r") => (200, 40, 40),
        Some("g") => (30, 150, 60),
        Some("b") => (40, 70, 210),
        _ => (60, 60, 60),
    };
    let shade = (camera % 4) as i32 * 12;
    let c = |v: i32| (v - shade).clamp(0, 255) as u8;
    RGBColor(c(base.0), c(base.1), c(base.2))
}

/// Writes the chart as SVG to `path`.
pub fn plot_effective_responses(
    path: &Path,
    responses: &EffectiveResponses,
    sensing: &SensingMatrix,
    reported: &SpectralShape,
    title: &str,
) -> Result<()> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1000, 600)).into_drawing_area();
        let plot_err = |e: String| Error::output("response plot", e);
        root.fill(&WHITE).map_err(|e| plot_err(e.to_string()))?;
        let grid = &responses.grid;
        let peak = responses
            .rows
            .iter()
            .zip(&sensing.row_scale)
            .flat_map(|(row, s)| row.iter().map(move |v| v / s))
            .fold(0.0f64, f64::max)
            .max(1e-12);
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(grid.start..grid.end(), 0.0..peak * 1.05)
            .map_err(|e| plot_err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("wavelength (nm)")
            .y_desc("effective response (per camera exposure, 1/nm)")
            .draw()
            .map_err(|e| plot_err(e.to_string()))?;
        let lo = reported.start - 0.5 * reported.step;
        let hi = reported.end() + 0.5 * reported.step;
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(lo, 0.0), (hi, peak * 1.05)],
                RGBColor(235, 235, 245).filled(),
            )))
            .map_err(|e| plot_err(e.to_string()))?;
        for (r, row) in responses.rows.iter().enumerate() {
            let colour = channel_colour(&responses.labels[r], responses.camera_of_row[r]);
            let scale = sensing.row_scale[r];
            chart
                .draw_series(LineSeries::new(
                    row.iter()
                        .enumerate()
                        .map(|(t, v)| (grid.wavelength(t), v / scale)),
                    colour.stroke_width(2),
                ))
                .map_err(|e| plot_err(e.to_string()))?
                .label(responses.labels[r].clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 11))
            .draw()
            .map_err(|e| plot_err(e.to_string()))?;
        root.present().map_err(|e| plot_err(e.to_string()))?;
    }
    write_atomically(path, |w| w.write_all(svg.as_bytes()))
}
