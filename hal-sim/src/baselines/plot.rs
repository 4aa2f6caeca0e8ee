//! Line plots of the baselines' reports (PNG): plotters draws the lines on a bitmap, the
//! text is drawn with embedded-graphics' mono fonts (no font stack on the host).
use crate::demo::{Canvas, write_png};
use anyhow::Result;
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::{FONT_6X10, FONT_9X15};
use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::text::{Baseline, Text};
use plotters::prelude::*;
use std::path::Path;

pub(crate) const COLOURS: [RGBColor; 8] = [
    RGBColor(0, 90, 200),
    RGBColor(230, 120, 0),
    RGBColor(0, 150, 70),
    RGBColor(150, 0, 180),
    RGBColor(200, 0, 60),
    RGBColor(90, 90, 90),
    RGBColor(0, 170, 200),
    RGBColor(160, 120, 0),
];

/// A named polyline.
pub(crate) struct Series {
    /// Legend text (ASCII).
    pub name: String,
    /// Line colour.
    pub colour: RGBColor,
    /// Points `(x, y)` in axis units (clipped to the axes' ranges).
    pub points: Vec<(f64, f64)>,
}

/// An axis: range, ticks `(value, label)` and title.
pub(crate) struct Axis {
    /// Lowest and highest value shown.
    pub range: (f64, f64),
    /// Grid lines `(value, label)`.
    pub ticks: Vec<(f64, String)>,
    /// Axis title.
    pub title: &'static str,
}

/// Ticks at the powers of ten `10^lo … 10^hi` of a log10 axis.
pub(crate) fn log_ticks(lo: i32, hi: i32) -> Vec<(f64, String)> {
    (lo..=hi)
        .map(|e| (f64::from(e), format!("{}", 10f64.powi(e))))
        .collect()
}

fn pe(e: impl std::fmt::Debug) -> anyhow::Error {
    anyhow::anyhow!("{e:?}")
}

/// A line plot on linear axes, text drawn with embedded-graphics' mono fonts.
pub(crate) fn plot(path: &Path, title: &str, x: &Axis, y: &Axis, series: &[Series]) -> Result<()> {
    let (w, h) = (1100u32, 560u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let black = Rgb888::BLACK;
    let mut labels: Vec<(String, Point, Rgb888)> = Vec::new();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let mut chart = ChartBuilder::on(&root)
            .margin_top(40)
            .margin_bottom(50)
            .margin_left(70)
            .margin_right(360)
            .build_cartesian_2d(x.range.0..x.range.1, y.range.0..y.range.1)
            .map_err(pe)?;
        let grid = RGBColor(225, 225, 225);
        let (x0, x1, y0, y1) = (x.range.0, x.range.1, y.range.0, y.range.1);
        for (v, l) in &x.ticks {
            chart
                .draw_series(LineSeries::new([(*v, y0), (*v, y1)], grid))
                .map_err(pe)?;
            let (px, py) = chart.backend_coord(&(*v, y0));
            labels.push((
                l.clone(),
                Point::new(px - 3 * l.len() as i32, py + 6),
                black,
            ));
        }
        for (v, l) in &y.ticks {
            chart
                .draw_series(LineSeries::new([(x0, *v), (x1, *v)], grid))
                .map_err(pe)?;
            let (px, py) = chart.backend_coord(&(x0, *v));
            labels.push((
                l.clone(),
                Point::new(px - 8 - 6 * l.len() as i32, py - 5),
                black,
            ));
        }
        chart
            .draw_series(LineSeries::new(
                [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)],
                BLACK,
            ))
            .map_err(pe)?;
        for (i, s) in series.iter().enumerate() {
            let clipped: Vec<(f64, f64)> = s
                .points
                .iter()
                .map(|&(a, b)| (a.clamp(x0, x1), b.clamp(y0, y1)))
                .collect();
            chart
                .draw_series(LineSeries::new(clipped, s.colour.stroke_width(2)))
                .map_err(pe)?;
            let ly = 50 + 22 * i as i32;
            let lx = w as i32 - 350;
            root.draw(&PathElement::new(
                vec![(lx, ly + 5), (lx + 24, ly + 5)],
                s.colour.stroke_width(3),
            ))
            .map_err(pe)?;
            let c = s.colour;
            labels.push((
                s.name.clone(),
                Point::new(lx + 30, ly),
                Rgb888::new(c.0, c.1, c.2),
            ));
        }
        let (px, py) = chart.backend_coord(&(0.5 * (x0 + x1), y0));
        labels.push((
            x.title.to_string(),
            Point::new(px - 3 * x.title.len() as i32, py + 24),
            black,
        ));
        let (px, py) = chart.backend_coord(&(x0, y1));
        labels.push((y.title.to_string(), Point::new(px - 60, py - 16), black));
    }
    let mut canvas = Canvas {
        buf: &mut buf,
        w,
        h,
    };
    let _ = Text::with_baseline(
        title,
        Point::new(70, 8),
        MonoTextStyle::new(&FONT_9X15, black),
        Baseline::Top,
    )
    .draw(&mut canvas);
    for (text, p, c) in labels {
        let _ = Text::with_baseline(&text, p, MonoTextStyle::new(&FONT_6X10, c), Baseline::Top)
            .draw(&mut canvas);
    }
    write_png(path, w, h, &buf)
}

/// ASCII label for the plots (the mono font has no “–”).
pub(crate) fn ascii(name: &str) -> String {
    name.replace('–', "-")
}
