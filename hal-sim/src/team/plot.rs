//! The joint map as a PNG: covered strips (light), dead-reckoned tracks (thin, pale),
//! corrected tracks (rescuer colours), victims with 2σ ellipses and labels, and when the
//! truth is known the true victims (black crosses) and true tracks (grey).
use super::map::TeamMap;
use crate::eval::plot::{self, FONT, MapChart, ellipse, en, write_png};
use anyhow::Result;
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

/// Draws `map` (and `truth`) to a PNG at `path`.
pub fn plot(map: &TeamMap, truth: Option<&TruthOverlay>, path: &Path) -> Result<()> {
    plot::fonts();
    let mut buf = vec![255u8; (SIZE * SIZE * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (SIZE, SIZE)).into_drawing_area();
        root.fill(&WHITE).map_err(plot::err)?;
        let title = format!(
            "team map: {} victims, {} rescuers, {:.0} m² covered (strips ±{:.0} m)",
            map.victims.iter().filter(|v| v.p.is_some()).count(),
            map.rescuers.len(),
            map.covered_area_m2,
            map.options.strip_half_width_m
        );
        let root = root.titled(&title, (FONT, 20)).map_err(plot::err)?;
        let mut chart = plot::map_chart(&root, view(map), 12, 55)?;
        draw_coverage(map, &mut chart)?;
        if let Some(t) = truth {
            draw_true_tracks(t, &mut chart)?;
        }
        draw_tracks(map, &mut chart)?;
        draw_victims(map, &mut chart)?;
        if let Some(t) = truth {
            draw_true_victims(t, &mut chart)?;
        }
        plot::scale_bar(&mut chart)?;
        plot::draw_legend(&mut chart)?;
        root.present().map_err(plot::err)?;
    }
    write_png(path, SIZE, SIZE, &buf)
}

/// A square view around every track and victim with room for the strips.
fn view(map: &TeamMap) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let mut pts: Vec<(f64, f64)> = map
        .rescuers
        .iter()
        .flat_map(|r| r.track.iter().chain(&r.dr_track).map(|p| en([p[1], p[2]])))
        .collect();
    pts.extend(map.victims.iter().filter_map(|v| v.p.map(en)));
    plot::map_view(&pts, 2.0 * map.options.strip_half_width_m, 1.05, 1.0)
}

/// The covered area: the union of the strips, 1 m cells in light grey.
fn draw_coverage(map: &TeamMap, chart: &mut MapChart<'_, '_>) -> Result<()> {
    let cells = super::map::covered_cells(map);
    let fill = RGBColor(226, 230, 238);
    chart
        .draw_series(cells.iter().map(|(c, _)| {
            let (x, y) = en(*c);
            Rectangle::new([(x - 0.5, y - 0.5), (x + 0.5, y + 0.5)], fill.filled())
        }))
        .map_err(plot::err)?
        .label("area covered by the strips")
        .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 20, y + 5)], fill.filled()));
    Ok(())
}

/// The simulator's true tracks, thin grey.
fn draw_true_tracks(t: &TruthOverlay, chart: &mut MapChart<'_, '_>) -> Result<()> {
    let grey = RGBColor(120, 120, 120);
    for (i, tr) in t.tracks.iter().enumerate() {
        let drawn = chart
            .draw_series(LineSeries::new(
                tr.iter().map(|p| en(*p)),
                grey.stroke_width(1),
            ))
            .map_err(plot::err)?;
        if i == 0 {
            drawn
                .label("true tracks")
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], grey));
        }
    }
    Ok(())
}

/// Each rescuer's dead-reckoned track (pale) and corrected track (its colour, labelled).
fn draw_tracks(map: &TeamMap, chart: &mut MapChart<'_, '_>) -> Result<()> {
    for (r, res) in map.rescuers.iter().enumerate() {
        let c = COLOURS[r % COLOURS.len()];
        let dr = res.dr_track.iter().map(|p| en([p[1], p[2]]));
        let pale = chart
            .draw_series(LineSeries::new(dr, c.mix(0.35).stroke_width(1)))
            .map_err(plot::err)?;
        if r == 0 {
            pale.label("dead-reckoned tracks (pale)")
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], c.mix(0.35).stroke_width(1))
                });
        }
        let line: Vec<(f64, f64)> = res.track.iter().map(|p| en([p[1], p[2]])).collect();
        if let Some(&start) = line.first() {
            chart
                .draw_series(std::iter::once(Text::new(
                    format!("R{r}"),
                    start,
                    (FONT, 15).into_font().color(&c),
                )))
                .map_err(plot::err)?;
        }
        chart
            .draw_series(LineSeries::new(line, c.stroke_width(2)))
            .map_err(plot::err)?
            .label(format!("R{r}: track corrected by the joint map"))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], c.stroke_width(2)));
    }
    Ok(())
}

/// The joint map's victims (2σ ellipse, labelled) and each rescuer's own-map position.
fn draw_victims(map: &TeamMap, chart: &mut MapChart<'_, '_>) -> Result<()> {
    let (mut ring_in_legend, mut own_in_legend) = (false, false);
    for v in &map.victims {
        let (Some(p), Some(c)) = (v.p, v.cov) else {
            continue;
        };
        let ring = PathElement::new(ellipse(p, c, 36), RED.stroke_width(2));
        let ring = chart
            .draw_series(std::iter::once(ring))
            .map_err(plot::err)?;
        if !ring_in_legend {
            ring.label("victim in the joint map, 2σ")
                .legend(|(x, y)| Circle::new((x + 10, y), 5, RED.stroke_width(2)));
            ring_in_legend = true;
        }
        chart
            .draw_series(std::iter::once(Circle::new(en(p), 4, RED.filled())))
            .map_err(plot::err)?;
        // The name just outside the ellipse's upper right corner, clear of the markers
        // and tracks that meet at the victim.
        let (right, top) = ellipse(p, c, 36)
            .iter()
            .fold((f64::MIN, f64::MIN), |(x, y), q| (x.max(q.0), y.max(q.1)));
        let name = Text::new(
            format!("V{}", v.id),
            (0, -16),
            (FONT, 15).into_font().color(&RED),
        );
        chart
            .draw_series(std::iter::once(EmptyElement::at((right, top)) + name))
            .map_err(plot::err)?;
        for s in &v.seen_by {
            let Some(o) = s.own_p else { continue };
            let c = COLOURS[s.rescuer % COLOURS.len()];
            let own = chart
                .draw_series(std::iter::once(Circle::new(en(o), 3, c.stroke_width(2))))
                .map_err(plot::err)?;
            if !own_in_legend {
                own.label("victim in one rescuer's own map")
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, c.stroke_width(2)));
                own_in_legend = true;
            }
        }
    }
    Ok(())
}

/// The true victims as black crosses.
fn draw_true_victims(t: &TruthOverlay, chart: &mut MapChart<'_, '_>) -> Result<()> {
    let crosses = t
        .victims
        .iter()
        .map(|v| Cross::new(en(*v), 7, BLACK.stroke_width(2)));
    chart
        .draw_series(crosses)
        .map_err(plot::err)?
        .label("true victims")
        .legend(|(x, y)| Cross::new((x + 10, y), 5, BLACK.stroke_width(2)));
    Ok(())
}
