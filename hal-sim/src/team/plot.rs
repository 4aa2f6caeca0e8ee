//! The joint map as a PNG: covered strips (light), dead-reckoned tracks (thin, pale),
//! corrected tracks (rescuer colours), victims with 2σ ellipses and labels, and when the
//! truth is known the true victims (black crosses) and true tracks (grey).
use super::map::TeamMap;
use crate::demo::{Canvas, ellipse_n, en, write_png};
use anyhow::Result;
use embedded_graphics::mono_font::{MonoTextStyle, ascii::FONT_6X10};
use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::text::{Baseline, Text};
use plotters::prelude::*;
use std::path::Path;

/// What the simulator knows (for the report's picture).
#[derive(Debug, Clone, Default)]
pub struct TruthOverlay {
    /// True victim positions (north, west).
    pub victims: Vec<[f64; 2]>,
    /// True tracks (north, west).
    pub tracks: Vec<Vec<[f64; 2]>>,
}

const COLOURS: [RGBColor; 4] = [
    RGBColor(230, 110, 0),
    RGBColor(0, 110, 200),
    RGBColor(150, 0, 170),
    RGBColor(0, 150, 70),
];
const SIZE: u32 = 900;

fn e<E: std::fmt::Debug>(err: E) -> anyhow::Error {
    anyhow::anyhow!("{err:?}")
}

/// Draws `map` (and `truth`) to a PNG at `path`.
pub fn plot(map: &TeamMap, truth: Option<&TruthOverlay>, path: &Path) -> Result<()> {
    let mut buf = vec![255u8; (SIZE * SIZE * 3) as usize];
    let mut pts: Vec<(f64, f64)> = map
        .rescuers
        .iter()
        .flat_map(|r| r.track.iter().chain(&r.dr_track).map(|p| en([p[1], p[2]])))
        .collect();
    pts.extend(map.victims.iter().filter_map(|v| v.p.map(en)));
    let (x0, x1, y0, y1) = pts.iter().fold(
        (f64::MAX, f64::MIN, f64::MAX, f64::MIN),
        |(a, b, c, d), &(x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
    );
    let span = ((x1 - x0).max(y1 - y0).max(10.0) + 2.0 * map.options.strip_half_width_m) * 1.05;
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (xr, yr) = (
        cx - 0.5 * span..cx + 0.5 * span,
        cy - 0.5 * span..cy + 0.5 * span,
    );
    let mut labels: Vec<(String, (f64, f64), Rgb888)> = Vec::new();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (SIZE, SIZE)).into_drawing_area();
        root.fill(&WHITE).map_err(e)?;
        let mut chart = ChartBuilder::on(&root)
            .margin(20)
            .build_cartesian_2d(xr.clone(), yr.clone())
            .map_err(e)?;
        // Covered area: the union of the strips, 1 m cells in light grey.
        let cells = super::map::covered_cells(map);
        chart
            .draw_series(cells.iter().map(|(c, _)| {
                let (x, y) = en(*c);
                Rectangle::new(
                    [(x - 0.5, y - 0.5), (x + 0.5, y + 0.5)],
                    RGBColor(236, 238, 242).filled(),
                )
            }))
            .map_err(e)?;
        if let Some(t) = truth {
            for tr in &t.tracks {
                let line: Vec<(f64, f64)> = tr.iter().map(|p| en(*p)).collect();
                chart
                    .draw_series(LineSeries::new(
                        line,
                        RGBColor(120, 120, 120).stroke_width(1),
                    ))
                    .map_err(e)?;
            }
        }
        for (r, res) in map.rescuers.iter().enumerate() {
            let c = COLOURS[r % 4];
            let dr: Vec<(f64, f64)> = res.dr_track.iter().map(|p| en([p[1], p[2]])).collect();
            chart
                .draw_series(LineSeries::new(dr, c.mix(0.35).stroke_width(1)))
                .map_err(e)?;
            let line: Vec<(f64, f64)> = res.track.iter().map(|p| en([p[1], p[2]])).collect();
            if let Some(&s) = line.first() {
                labels.push((format!("R{r}"), s, Rgb888::new(c.0, c.1, c.2)));
            }
            chart
                .draw_series(LineSeries::new(line, c.stroke_width(2)))
                .map_err(e)?;
        }
        for v in &map.victims {
            let (Some(p), Some(c)) = (v.p, v.cov) else {
                continue;
            };
            chart
                .draw_series(std::iter::once(PathElement::new(
                    ellipse_n(p, c, 36),
                    RED.stroke_width(2),
                )))
                .map_err(e)?;
            chart
                .draw_series(std::iter::once(Circle::new(en(p), 4, RED.filled())))
                .map_err(e)?;
            // Each rescuer's own-map position: small circles in its colour.
            for s in &v.seen_by {
                if let Some(o) = s.own_p {
                    let c = COLOURS[s.rescuer % 4];
                    chart
                        .draw_series(std::iter::once(Circle::new(en(o), 3, c.stroke_width(2))))
                        .map_err(e)?;
                }
            }
            labels.push((format!("V{}", v.id), en(p), Rgb888::new(200, 0, 0)));
        }
        if let Some(t) = truth {
            for v in &t.victims {
                let (x, y) = en(*v);
                let d = 1.0;
                for seg in [
                    [(x - d, y - d), (x + d, y + d)],
                    [(x - d, y + d), (x + d, y - d)],
                ] {
                    chart
                        .draw_series(LineSeries::new(seg, BLACK.stroke_width(2)))
                        .map_err(e)?;
                }
            }
        }
        root.present().map_err(e)?;
    }
    let to_px = |(x, y): (f64, f64)| {
        let u = 20.0 + (x - xr.start) / span * f64::from(SIZE - 40);
        let v = 20.0 + (yr.end - y) / span * f64::from(SIZE - 40);
        Point::new(u as i32 + 6, v as i32 - 12)
    };
    let mut canvas = Canvas {
        buf: &mut buf,
        w: SIZE,
        h: SIZE,
    };
    let title = format!(
        "team map: {} victims, {} rescuers, covered {:.0} m2 (strip +-{:.0} m); north up",
        map.victims.iter().filter(|v| v.p.is_some()).count(),
        map.rescuers.len(),
        map.covered_area_m2,
        map.options.strip_half_width_m
    );
    let _ = Text::with_baseline(
        &title,
        Point::new(24, 4),
        MonoTextStyle::new(&FONT_6X10, Rgb888::BLACK),
        Baseline::Top,
    )
    .draw(&mut canvas);
    for (text, at, colour) in &labels {
        let _ = Text::with_baseline(
            text,
            to_px(*at),
            MonoTextStyle::new(&FONT_6X10, *colour),
            Baseline::Top,
        )
        .draw(&mut canvas);
    }
    write_png(path, SIZE, SIZE, &buf)
}
