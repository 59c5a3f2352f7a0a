//! The plot of one group in the report: time × error, the Pareto front as a staircase,
//! every point labelled with its setting.

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;

use super::escape;
use crate::accuracy::pareto::{self, fmt_num};
use crate::accuracy::KnobGroup;

const PLOT_SIZE: (u32, u32) = (900, 420);
/// Times spread wider than this ratio get a log10 axis.
const LOG_RATIO: f64 = 20.0;

/// The group's points on time × error as an SVG: the front as a step line with filled
/// markers, the other points hollow, each labelled with its setting. Non-finite points are
/// left out; an empty group gives empty axes.
pub fn plot_svg(group: &KnobGroup) -> String {
    let pts: Vec<(usize, f64, f64)> = (group.points.iter().enumerate())
        .filter(|(_, p)| p.time_ms.is_finite() && p.error.is_finite())
        .map(|(i, p)| (i, p.time_ms, p.error))
        .collect();
    let (t_lo, t_hi) = min_max(pts.iter().map(|p| p.1));
    let (e_lo, e_hi) = min_max(pts.iter().map(|p| p.2));
    let y = pad(e_lo.min(0.0), e_hi, 0.1);
    // A little below the lowest error, so that points at error 0 sit above the axis.
    let y = (y.start - 0.04 * (y.end - y.start))..y.end;
    let mut svg = String::new();
    let drawn = if t_lo > 0.0 && t_hi / t_lo > LOG_RATIO {
        let (lo, hi) = (t_lo / 1.5, t_hi * 1.5);
        let x = (lo..hi).log_scale().with_key_points(log_ticks(lo, hi));
        draw(&mut svg, group, &pts, x, y, " (log scale)")
    } else {
        draw(&mut svg, group, &pts, pad(t_lo, t_hi, 0.08), y, "")
    };
    if let Err(e) = drawn {
        svg = format!("<p>plot failed: {}</p>", escape(&e.to_string()));
    }
    svg
}

/// 1, 2, 5 times the powers of ten in `lo..=hi`: plotters' own log ticks crowd one decade.
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let decades = lo.log10().floor() as i32..=hi.log10().ceil() as i32;
    (decades.flat_map(|k| [1.0, 2.0, 5.0].map(|m| m * 10f64.powi(k))))
        .filter(|v| (lo..=hi).contains(v))
        .collect()
}

/// The smallest and largest values; (0, 0) when there are none.
fn min_max(v: impl Iterator<Item = f64>) -> (f64, f64) {
    v.fold(None, |acc: Option<(f64, f64)>, x| match acc {
        None => Some((x, x)),
        Some((lo, hi)) => Some((lo.min(x), hi.max(x))),
    })
    .unwrap_or((0.0, 0.0))
}

/// `lo..hi` widened by `frac` of its span each side, not below 0 when `lo` is not; an empty
/// span becomes one around its value (0..1 around 0).
fn pad(lo: f64, hi: f64, frac: f64) -> std::ops::Range<f64> {
    let w = if hi > lo {
        (hi - lo) * frac
    } else if hi == 0.0 {
        return 0.0..1.0;
    } else {
        hi.abs() * 0.5
    };
    let floor = if lo >= 0.0 { 0.0 } else { f64::NEG_INFINITY };
    (lo - w).max(floor)..(hi + w)
}

type PlotResult = Result<(), Box<dyn std::error::Error>>;

fn draw<X>(
    svg: &mut String,
    g: &KnobGroup,
    pts: &[(usize, f64, f64)],
    x: X,
    y: std::ops::Range<f64>,
    x_note: &str,
) -> PlotResult
where
    X: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
{
    let root = SVGBackend::with_string(svg, PLOT_SIZE).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .margin(12)
        .margin_right(24)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(x, y)?;
    chart
        .configure_mesh()
        .x_desc(format!("{}{x_note}", g.time_axis))
        .y_desc(g.error_axis.as_str())
        .x_label_formatter(&|v| fmt_num(*v))
        .y_label_formatter(&|v| fmt_num(*v))
        .light_line_style(WHITE.mix(0.0))
        .bold_line_style(BLACK.mix(0.08))
        .axis_desc_style(("sans-serif", 15))
        .label_style(("sans-serif", 13))
        .draw()?;
    let front = pareto::front(&g.points);
    let blue = RGBColor(31, 101, 196);
    let grey = RGBColor(120, 120, 120);
    // The front as a staircase: what is attainable at each time budget.
    let mut steps = Vec::new();
    for (k, &i) in front.iter().enumerate() {
        let p = &g.points[i];
        if k > 0 {
            steps.push((p.time_ms, g.points[front[k - 1]].error));
        }
        steps.push((p.time_ms, p.error));
    }
    chart.draw_series(LineSeries::new(steps, blue.stroke_width(2)))?;
    chart.draw_series(pts.iter().map(|&(i, t, e)| {
        let style = if front.contains(&i) {
            blue.filled()
        } else {
            grey.stroke_width(2)
        };
        Circle::new((t, e), 5, style)
    }))?;
    // Labels in pixels, each at the first spot beside its point that overlaps no earlier label
    // or marker.
    let font = ("sans-serif", 13).into_font();
    let area = chart.plotting_area().get_pixel_range();
    let mut taken: Vec<Rect> = (pts.iter())
        .map(|&(_, t, e)| {
            let (px, py) = chart.backend_coord(&(t, e));
            Rect {
                x0: px - 6,
                y0: py - 6,
                x1: px + 6,
                y1: py + 6,
            }
        })
        .collect();
    let mut order: Vec<&(usize, f64, f64)> = pts.iter().collect();
    order.sort_by_key(|&&(i, _, _)| !front.contains(&i));
    for &&(i, t, e) in &order {
        let text = &g.points[i].setting;
        let (px, py) = chart.backend_coord(&(t, e));
        let w = 7 * text.chars().count() as i32 + 2;
        let spots = [
            (8, -16),
            (8, 2),
            (-8 - w, -16),
            (-8 - w, 2),
            (8, -30),
            (8, 16),
            (-w / 2, -30),
            (-w / 2, 10),
        ];
        let rect = |(dx, dy): (i32, i32)| Rect {
            x0: px + dx,
            y0: py + dy,
            x1: px + dx + w,
            y1: py + dy + 15,
        };
        let inside = |r: &Rect| {
            r.x0 >= area.0.start && r.x1 <= area.0.end && r.y0 >= area.1.start && r.y1 <= area.1.end
        };
        let best = (spots.iter().map(|&s| rect(s)))
            .find(|r| inside(r) && !taken.iter().any(|o| o.overlaps(r)))
            .or_else(|| spots.iter().map(|&s| rect(s)).find(inside))
            .unwrap_or_else(|| rect(spots[0]));
        let color = if front.contains(&i) { blue } else { grey };
        root.draw(&Text::new(
            text.clone(),
            (best.x0, best.y0),
            font.clone().color(&color),
        ))?;
        taken.push(best);
    }
    root.present()?;
    Ok(())
}

/// A label's or marker's box in pixels.
struct Rect {
    x0: i32,
    y0: i32,
    x1: i32,
    y1: i32,
}

impl Rect {
    fn overlaps(&self, o: &Rect) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }
}
