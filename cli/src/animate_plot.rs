//! The per-frame plot of `vkrt bench animate`: build or refit ms and render ms of every
//! structure and update mode over the frames, one SVG with two panels.

use std::path::Path;

use plotters::prelude::*;

use vkrt::gpu::{write_atomically, GpuError};
use vkrt::render::animate::{AnimationReport, FrameRow};

/// Draws `reports` into an SVG at `path` (written atomically).
pub fn frames_svg(reports: &[AnimationReport], path: &Path) -> Result<(), GpuError> {
    let mut svg = String::new();
    draw(reports, &mut svg).map_err(|e| GpuError::Io {
        path: path.display().to_string(),
        reason: format!("plot: {e}"),
    })?;
    write_atomically(path, svg.as_bytes())
}

type Panel<'a> = (&'a str, fn(&FrameRow) -> f64);

fn draw(reports: &[AnimationReport], svg: &mut String) -> Result<(), Box<dyn std::error::Error>> {
    let root = SVGBackend::with_string(svg, (960, 720)).into_drawing_area();
    root.fill(&WHITE)?;
    let panels: [Panel; 2] = [
        ("build or refit ms per frame (GPU)", |f| f.update_ms),
        ("render ms per frame (GPU)", |f| f.render_ms),
    ];
    let frames = reports
        .iter()
        .map(|r| r.frames.len())
        .max()
        .unwrap_or(1)
        .max(2);
    for (area, (title, value)) in root.split_evenly((2, 1)).iter().zip(panels) {
        let top = reports
            .iter()
            .flat_map(|r| r.frames.iter().map(value))
            .fold(0.0f64, f64::max)
            .max(1e-3)
            * 1.1;
        let mut chart = ChartBuilder::on(area)
            .caption(title, ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(28)
            .y_label_area_size(48)
            .build_cartesian_2d(0f64..(frames - 1) as f64, 0f64..top)?;
        chart.configure_mesh().x_desc("frame").y_desc("ms").draw()?;
        for (i, r) in reports.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            let points = r.frames.iter().map(|f| (f.frame as f64, value(f)));
            chart
                .draw_series(LineSeries::new(points, color.stroke_width(2)))?
                .label(match r.levels {
                    2 => format!("{} {} (two levels)", r.accel, r.update.name()),
                    _ => format!("{} {}", r.accel, r.update.name()),
                })
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
    }
    root.present()?;
    Ok(())
}
