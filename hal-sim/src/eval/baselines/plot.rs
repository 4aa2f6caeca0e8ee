//! Line plots of the baselines' reports (PNG) in the figures' common style
//! ([`crate::eval::plot`]: embedded font, named axes with units, ticks, legend), on linear or
//! logarithmic axes (errors that span decades are shown on a log axis, every decade
//! labelled); the legend stands in a column beside the chart.
use crate::eval::plot::{self, FONT, log_axis, tick, write_png};
use anyhow::Result;
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;
use std::path::Path;

/// Series colours, in order.
pub(crate) const COLOURS: [RGBColor; 10] = [
    RGBColor(0, 90, 200),
    RGBColor(230, 120, 0),
    RGBColor(0, 150, 70),
    RGBColor(150, 0, 180),
    RGBColor(200, 0, 60),
    RGBColor(90, 90, 90),
    RGBColor(0, 170, 200),
    RGBColor(160, 120, 0),
    RGBColor(0, 0, 0),
    RGBColor(240, 110, 170),
];

/// A named polyline.
pub(crate) struct Series {
    /// Legend text.
    pub name: String,
    /// Line colour.
    pub colour: RGBColor,
    /// Points `(x, y)` in axis units (clamped to the axes' ranges; non-finite dropped).
    pub points: Vec<(f64, f64)>,
}

/// An axis: range, scale and name with its unit.
pub(crate) struct Axis {
    /// Lowest and highest value shown (both > 0 on a log axis).
    pub range: (f64, f64),
    /// Logarithmic scale.
    pub log: bool,
    /// Axis name with its unit, e.g. "final error (m)".
    pub title: &'static str,
}

/// Width of the legend column beside the chart: the longest series name, a line sample
/// and margins.
fn legend_width(root: &DrawingArea<BitMapBackend<'_>, Shift>, series: &[Series]) -> u32 {
    let font = (FONT, LEGEND_PX).into_text_style(root);
    let text = series
        .iter()
        .filter_map(|s| root.estimate_text_size(&s.name, &font).ok())
        .map(|(w, _)| w)
        .max()
        .unwrap_or(0);
    text + 60
}

/// Legend text size, px.
const LEGEND_PX: u32 = 14;

/// A line plot with a title, named axes with ticks (every decade on a log axis) and a
/// legend in a column of its own to the right, so that it never hides a curve.
pub(crate) fn plot(path: &Path, title: &str, x: &Axis, y: &Axis, series: &[Series]) -> Result<()> {
    plot::fonts();
    let (chart_w, h) = (1100u32, 620u32);
    let w = {
        let mut probe = vec![255u8; 3];
        let area = BitMapBackend::with_buffer(&mut probe, (1, 1)).into_drawing_area();
        chart_w + legend_width(&area, series)
    };
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot::err)?;
        let root = root.titled(title, (FONT, 20)).map_err(plot::err)?;
        let (chart_area, legend_area) = root.split_horizontally(chart_w);
        let (x0, x1, y0, y1) = (x.range.0, x.range.1, y.range.0, y.range.1);
        let p = Parts { x, y, series };
        match (x.log, y.log) {
            (false, false) => draw(&chart_area, x0..x1, y0..y1, &p)?,
            (false, true) => draw(&chart_area, x0..x1, log_axis(y0, y1), &p)?,
            (true, false) => draw(&chart_area, log_axis(x0, x1), y0..y1, &p)?,
            (true, true) => draw(&chart_area, log_axis(x0, x1), log_axis(y0, y1), &p)?,
        }
        draw_legend(&legend_area, series)?;
        root.present().map_err(plot::err)?;
    }
    write_png(path, w, h, &buf)
}

/// The legend: one line sample and name per series, from the top of its column.
fn draw_legend(area: &DrawingArea<BitMapBackend<'_>, Shift>, series: &[Series]) -> Result<()> {
    let font = (FONT, LEGEND_PX).into_font();
    for (i, s) in series.iter().enumerate() {
        let y = 40 + 24 * i as i32;
        area.draw(&PathElement::new(
            [(8, y), (36, y)],
            s.colour.stroke_width(3),
        ))
        .map_err(plot::err)?;
        area.draw(&Text::new(
            s.name.as_str(),
            (44, y - LEGEND_PX as i32 / 2 - 1),
            font.clone(),
        ))
        .map_err(plot::err)?;
    }
    Ok(())
}

/// What [`draw`] draws.
struct Parts<'a> {
    x: &'a Axis,
    y: &'a Axis,
    series: &'a [Series],
}

fn draw<X, Y>(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    xr: X,
    yr: Y,
    p: &Parts<'_>,
) -> Result<()>
where
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let mut chart = ChartBuilder::on(root)
        .margin(15)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(xr, yr)
        .map_err(plot::err)?;
    plot::draw_axes(&mut chart, (p.x.title, p.y.title), &|v| tick(*v), &|v| {
        tick(*v)
    })?;
    let clamp = |v: f64, (lo, hi): (f64, f64)| v.clamp(lo, hi);
    for s in p.series {
        let pts: Vec<(f64, f64)> = s
            .points
            .iter()
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .map(|&(a, b)| (clamp(a, p.x.range), clamp(b, p.y.range)))
            .collect();
        chart
            .draw_series(LineSeries::new(pts, s.colour.stroke_width(2)))
            .map_err(plot::err)?;
    }
    Ok(())
}
