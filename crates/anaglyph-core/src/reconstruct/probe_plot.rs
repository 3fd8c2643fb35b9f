//! Spectral curves at chosen pixels (the paper's Figs. 10–11) as an SVG chart: each probe's
//! reconstructed reflectance as a thick line, its truth (when known) as a thin line of the
//! same colour.

use crate::io::write_atomically;
use crate::{Error, Result};
use plotters::prelude::*;
use std::path::Path;

/// Line colours of successive probes.
const COLOURS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
];

/// One pixel's spectra.
#[derive(Debug, Clone)]
pub struct Probe {
    pub label: String,
    /// Reconstructed reflectance per band (NaN: not reconstructed).
    pub estimate: Vec<f64>,
    pub truth: Option<Vec<f64>>,
}

/// Writes the chart of `probes` over band centres `centres` to `path` (SVG).
pub fn plot_probe(path: &Path, title: &str, centres: &[f64], probes: &[Probe]) -> Result<()> {
    let (Some(&lo), Some(&hi)) = (centres.first(), centres.last()) else {
        return Err(Error::setting(
            "probe plot",
            "no bands",
            "at least one band",
        ));
    };
    let peak = probes
        .iter()
        .flat_map(|p| p.estimate.iter().chain(p.truth.iter().flatten()))
        .filter(|v| v.is_finite())
        .fold(0.0f64, |a, &b| a.max(b))
        .max(0.1);
    let plot_err = |e: String| Error::output("probe plot", e);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 540)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err(e.to_string()))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d(lo..hi, 0.0..peak * 1.1)
            .map_err(|e| plot_err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("wavelength (nm)")
            .y_desc("reflectance")
            .draw()
            .map_err(|e| plot_err(e.to_string()))?;
        for (k, probe) in probes.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let points = |values: &[f64]| -> Vec<(f64, f64)> {
                centres
                    .iter()
                    .zip(values)
                    .filter(|(_, v)| v.is_finite())
                    .map(|(&l, &v)| (l, v))
                    .collect()
            };
            chart
                .draw_series(LineSeries::new(
                    points(&probe.estimate),
                    colour.stroke_width(3),
                ))
                .map_err(|e| plot_err(e.to_string()))?
                .label(format!("{} reconstructed", probe.label))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(3))
                });
            if let Some(truth) = &probe.truth {
                chart
                    .draw_series(LineSeries::new(points(truth), colour.stroke_width(1)))
                    .map_err(|e| plot_err(e.to_string()))?
                    .label(format!("{} truth", probe.label))
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(1))
                    });
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 12))
            .draw()
            .map_err(|e| plot_err(e.to_string()))?;
        root.present().map_err(|e| plot_err(e.to_string()))?;
    }
    write_atomically(path, |w| w.write_all(svg.as_bytes()))
}

/// A generic line chart (SVG): one polyline per `(label, points)` series, for the
/// report's figures that are not spectra (PSNR against noise in C, Fig. 8a).
pub fn plot_series(
    path: &Path,
    title: &str,
    (x_label, y_label): (&str, &str),
    series: &[(String, Vec<(f64, f64)>)],
) -> Result<()> {
    let points = || {
        series
            .iter()
            .flat_map(|(_, p)| p.iter())
            .filter(|(x, y)| x.is_finite() && y.is_finite())
    };
    let (x_lo, x_hi) = points().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &(x, _)| {
        (a.min(x), b.max(x))
    });
    let (y_lo, y_hi) = points().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &(_, y)| {
        (a.min(y), b.max(y))
    });
    if !(x_hi > x_lo) || !(y_hi >= y_lo) {
        return Err(Error::setting(
            "chart",
            "fewer than two distinct finite x values",
            "at least two",
        ));
    }
    let pad = ((y_hi - y_lo) * 0.08).max(0.5);
    let plot_err = |e: String| Error::output("chart", e);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 540)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err(e.to_string()))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d(x_lo..x_hi, (y_lo - pad)..(y_hi + pad))
            .map_err(|e| plot_err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .draw()
            .map_err(|e| plot_err(e.to_string()))?;
        for (k, (label, pts)) in series.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            chart
                .draw_series(LineSeries::new(
                    pts.iter()
                        .copied()
                        .filter(|(x, y)| x.is_finite() && y.is_finite()),
                    colour.stroke_width(3),
                ))
                .map_err(|e| plot_err(e.to_string()))?
                .label(label.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(3))
                });
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 12))
            .draw()
            .map_err(|e| plot_err(e.to_string()))?;
        root.present().map_err(|e| plot_err(e.to_string()))?;
    }
    write_atomically(path, |w| w.write_all(svg.as_bytes()))
}
