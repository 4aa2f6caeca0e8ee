//! Line plots of the baselines' reports (PNG) in the figures' common style
//! ([`crate::eval::plot`]: embedded font, named axes with units, ticks, legend), on linear or
//! logarithmic axes (errors that span decades are shown on a log axis).
use crate::eval::plot::{self, FONT, write_png};
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

/// Where the legend goes (the corner the curves leave free).
#[derive(Debug, Clone, Copy)]
pub(crate) enum Legend {
    /// Upper right corner.
    UpperRight,
    /// Lower right corner.
    LowerRight,
}

/// A tick label: integers plainly, small values with their significant digits.
fn tick(v: f64) -> String {
    if v.abs() >= 1.0 || v == 0.0 {
        format!("{}", (v * 100.0).round() / 100.0)
    } else {
        let digits = (-v.abs().log10()).ceil() as usize + 1;
        let s = format!("{v:.digits$}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// A line plot with a title, named axes with ticks and a legend at `legend`.
pub(crate) fn plot(
    path: &Path,
    title: &str,
    x: &Axis,
    y: &Axis,
    series: &[Series],
    legend: Legend,
) -> Result<()> {
    plot::fonts();
    let (w, h) = (1100u32, 620u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot::err)?;
        let root = root.titled(title, (FONT, 20)).map_err(plot::err)?;
        let (x0, x1, y0, y1) = (x.range.0, x.range.1, y.range.0, y.range.1);
        let p = Parts {
            x,
            y,
            series,
            legend,
        };
        match (x.log, y.log) {
            (false, false) => draw(&root, x0..x1, y0..y1, &p)?,
            (false, true) => draw(&root, x0..x1, (y0..y1).log_scale(), &p)?,
            (true, false) => draw(&root, (x0..x1).log_scale(), y0..y1, &p)?,
            (true, true) => draw(&root, (x0..x1).log_scale(), (y0..y1).log_scale(), &p)?,
        }
        root.present().map_err(plot::err)?;
    }
    write_png(path, w, h, &buf)
}

/// What [`draw`] draws.
struct Parts<'a> {
    x: &'a Axis,
    y: &'a Axis,
    series: &'a [Series],
    legend: Legend,
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
        let c = s.colour;
        chart
            .draw_series(LineSeries::new(pts, c.stroke_width(2)))
            .map_err(plot::err)?
            .label(s.name.as_str())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], c.stroke_width(3)));
    }
    let position = match p.legend {
        Legend::UpperRight => SeriesLabelPosition::UpperRight,
        Legend::LowerRight => SeriesLabelPosition::LowerRight,
    };
    plot::draw_legend_at(&mut chart, position)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick(0.01), "0.01");
        assert_eq!(tick(0.1), "0.1");
        assert_eq!(tick(1.0), "1");
        assert_eq!(tick(100.0), "100");
        assert_eq!(tick(0.5), "0.5");
        assert_eq!(tick(0.25), "0.25");
    }
}
