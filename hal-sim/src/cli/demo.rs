//! `hal-sim demo`: one seeded closed-loop rescue ([`crate::sim::closed_loop`]) shown live in
//! the terminal — the receiver's 128×64 screen as drawn by `firmware::display`, rendered
//! with half-block characters — then a PNG plot of the search (trajectory, victim,
//! mixture components as 2σ ellipses at a few moments, estimate error and distance over
//! time) and a PNG of the final screen.
use crate::eval::plot::{self, ellipse, en, write_png};
use crate::sim::closed_loop::{self, ClosedLoopConfig, Outcome, PulseRow};
use anyhow::{Context, Result};
use embedded_graphics::image::GetPixel;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use firmware::app::Receiver;
use firmware::display::{self, Frame};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::io::{IsTerminal, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// Options of `hal-sim demo`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Scenario seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Only print the summary (no live screen).
    #[arg(long)]
    pub quiet: bool,
    /// Draw the screen every this many pulses.
    #[arg(long, default_value_t = 1)]
    pub every: usize,
    /// Output directory for `demo.png` and `display.png` (default `runs/demo-<seed>`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Several buried victims (2–4, see `multi-report`): the simulated rescuer presses
    /// the mark key ("M") at each "probe here" and moves on to the next victim.
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(2..=4))]
    pub victims: Option<usize>,
    /// Layout of the victims with `--victims`.
    #[arg(long, value_enum, default_value_t = crate::sim::multi::Layout::ClosePairOverlap)]
    pub layout: crate::sim::multi::Layout,
}

/// The screen as text: two pixel rows per line with half blocks (`▀ ▄ █`), framed.
pub fn ascii_frame(frame: &Frame) -> String {
    let w = display::WIDTH as i32;
    let h = display::HEIGHT as i32;
    let on = |x, y| frame.pixel(Point::new(x, y)) == Some(BinaryColor::On);
    let mut s = String::with_capacity(((w + 3) * (h / 2 + 2)) as usize * 3);
    s.push('+');
    s.push_str(&"-".repeat(w as usize));
    s.push_str("+\n");
    for y in (0..h).step_by(2) {
        s.push('|');
        for x in 0..w {
            s.push(match (on(x, y), on(x, y + 1)) {
                (true, true) => '█',
                (true, false) => '▀',
                (false, true) => '▄',
                (false, false) => ' ',
            });
        }
        s.push_str("|\n");
    }
    s.push('+');
    s.push_str(&"-".repeat(w as usize));
    s.push_str("+\n");
    s
}

/// Draws the receiver's current display into a frame.
pub fn render(rx: &Receiver) -> Frame {
    let mut f = Frame::new();
    // Drawing into a frame buffer cannot fail.
    let _ = display::draw(&rx.display_model(), &mut f);
    f
}

/// The multi-victim demo: live screen, mark key presses, the final screen as a PNG.
fn run_multi(args: &Args, victims: usize, dir: &Path, out: &mut impl Write) -> Result<()> {
    use crate::sim::multi::{Event, MultiConfig, run_with};
    let live = !args.quiet && std::io::stdout().is_terminal();
    let every = args.every.max(1);
    let mut n = 0usize;
    let mut io_err = None;
    let mut last_frame = Frame::new();
    let mut log = String::new();
    let cfg = MultiConfig::new(args.seed, victims, args.layout);
    let outcome = run_with(&cfg, &mut |ev: Event, rx: &Receiver| {
        last_frame = render(rx);
        let head = match ev {
            Event::Pulse(t) => {
                n += 1;
                if args.quiet || !(n - 1).is_multiple_of(every) {
                    return;
                }
                format!("t {t:6.1} s  pulse {n:4}")
            }
            Event::Mark(t, k) => {
                let line = format!("t {t:6.1} s  key M: victim {k} marked as found\n");
                log.push_str(&line);
                if args.quiet {
                    return;
                }
                line
            }
        };
        let d = rx.display_model();
        let list: Vec<String> = d
            .list
            .iter()
            .flatten()
            .map(|r| {
                format!(
                    "{}{}:{}{}",
                    if r.target { ">" } else { " " },
                    r.number,
                    r.distance_m.map_or("?".into(), |m| format!("{m:.1}m")),
                    if r.marked { " found" } else { "" }
                )
            })
            .collect();
        let text = format!(
            "{}{head}  [{}]  list {}\n{}",
            if live { "\x1b[H\x1b[2J" } else { "" },
            d.status.as_str(),
            list.join("  "),
            ascii_frame(&last_frame),
        );
        if let Err(e) = out.write_all(text.as_bytes())
            && io_err.is_none()
        {
            io_err = Some(e);
        }
    })?;
    if let Some(e) = io_err {
        return Err(e.into());
    }
    let screen = dir.join("display.png");
    write_frame_png(&last_frame, &screen, 4)?;
    write!(out, "{log}")?;
    for (i, v) in outcome.victims.iter().enumerate() {
        writeln!(
            out,
            "victim {} at ({:.1}, {:.1}, {:.1}) m: {}",
            i + 1,
            v.position[0],
            v.position[1],
            v.position[2],
            v.error_h_m.map_or_else(
                || "not found".into(),
                |e| format!("found, probe-point error {e:.2} m")
            ),
        )?;
    }
    writeln!(
        out,
        "{} wrong-victim marks; path {:.0} m; wrote {}",
        outcome.wrong_marks(),
        outcome.path_m,
        screen.display()
    )?;
    Ok(())
}

/// Runs the demo.
pub fn run(args: &Args, out: &mut impl Write) -> Result<()> {
    let dir = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("runs/demo-{}", args.seed)));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    if let Some(v) = args.victims {
        return run_multi(args, v, &dir, out);
    }
    let live = !args.quiet && std::io::stdout().is_terminal();
    let every = args.every.max(1);
    let mut n = 0usize;
    let mut io_err = None;
    let mut last_frame = Frame::new();
    let outcome = closed_loop::run(
        &ClosedLoopConfig::new(args.seed),
        &mut |row: &PulseRow, rx: &Receiver| {
            n += 1;
            last_frame = render(rx);
            if args.quiet || !(n - 1).is_multiple_of(every) {
                return;
            }
            let text = format!(
                "{}t {:6.1} s  pulse {:4}  true distance {:5.1} m  estimate error {}  path {:5.1} m  [{}]\n{}",
                if live { "\x1b[H\x1b[2J" } else { "" },
                row.t,
                n,
                row.true_distance_m,
                row.error_h_m
                    .map_or_else(|| "  –  ".into(), |e| format!("{e:5.2} m")),
                row.path_m,
                row.status,
                ascii_frame(&last_frame),
            );
            if let Err(e) = out.write_all(text.as_bytes())
                && io_err.is_none()
            {
                io_err = Some(e);
            }
        },
    )?;
    if let Some(e) = io_err {
        return Err(e.into());
    }
    let plot = dir.join("demo.png");
    plot_outcome(&outcome, &plot)?;
    let screen = dir.join("display.png");
    write_frame_png(&last_frame, &screen, 4)?;
    writeln!(out, "{}", summary(&outcome))?;
    writeln!(out, "wrote {} and {}", plot.display(), screen.display())?;
    Ok(())
}

/// One-paragraph summary of a run.
pub fn summary(o: &Outcome) -> String {
    let fmt = |x: Option<f64>| x.map_or_else(|| "–".into(), |v| format!("{v:.2} m"));
    format!(
        "seed {}: victim {:.1} m away (depth {:.1} m); {} after {:.0} s, path {:.1} m = {:.2}× ideal; \
         estimate error {} horizontal, {} depth; receiver {:.2} m from the victim; {} pulses, {} re-initializations",
        o.seed,
        o.ideal_path_m,
        -o.victim[2],
        if o.probe_t.is_some() {
            "PROBE HERE"
        } else {
            "not found"
        },
        o.probe_t.unwrap_or(o.end_t),
        o.path_m,
        o.path_ratio(),
        fmt(o.error_h_m),
        fmt(o.error_z_m),
        o.miss_h_m,
        o.pulses,
        o.reinitializations,
    )
}

/// Writes `frame` as a PNG, `scale`× enlarged, in the look of a blue OLED.
pub fn write_frame_png(frame: &Frame, path: &Path, scale: u32) -> Result<()> {
    let scale = scale.max(1);
    let (w, h) = (display::WIDTH * scale, display::HEIGHT * scale);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    for y in 0..h {
        for x in 0..w {
            let on = frame.pixel(Point::new((x / scale) as i32, (y / scale) as i32))
                == Some(BinaryColor::On);
            let c: [u8; 3] = if on { [200, 230, 255] } else { [8, 16, 36] };
            let i = ((y * w + x) * 3) as usize;
            buf[i..i + 3].copy_from_slice(&c);
        }
    }
    write_png(path, w, h, &buf)
}

const PLOT_W: u32 = 900;
const MAP_H: u32 = 820;
const ERR_H: u32 = 300;
const SNAPSHOT_COLOURS: [RGBColor; 6] = [
    RGBColor(230, 120, 0),
    RGBColor(0, 130, 200),
    RGBColor(150, 0, 180),
    RGBColor(0, 160, 80),
    RGBColor(200, 0, 90),
    RGBColor(90, 90, 90),
];

/// Plots a run: the map (trajectory, victim, mixture snapshots) above, errors below.
pub fn plot_outcome(o: &Outcome, path: &Path) -> Result<()> {
    crate::eval::plot::fonts();
    let (w, h) = (PLOT_W, MAP_H + ERR_H);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot::err)?;
        let (head, rest) = summary_lines(o);
        let root = root.titled(&head, (plot::FONT, 20)).map_err(plot::err)?;
        let (map, err) = root.split_vertically(MAP_H - 30);
        let (note, map) = map.split_vertically(60);
        let style = (plot::FONT, 14).into_text_style(&note);
        for (i, line) in rest.iter().enumerate() {
            let y = 2 + 18 * i as i32;
            note.draw_text(line, &style, (70, y)).map_err(plot::err)?;
        }
        draw_map(o, &map)?;
        draw_errors(o, &err)?;
        root.present().map_err(plot::err)?;
    }
    write_png(path, w, h, &buf)
}

/// The summary split for a figure: a title, then lines short enough for the width.
fn summary_lines(o: &Outcome) -> (String, Vec<String>) {
    let s = summary(o);
    let mut parts = s.split(';').map(str::trim);
    let head = parts.next().unwrap_or_default().to_string();
    let mut lines = vec![String::new()];
    for part in parts {
        let last = lines.len() - 1;
        if !lines[last].is_empty() && lines[last].len() + part.len() > 90 {
            lines.push(String::new());
        }
        let last = lines.len() - 1;
        if !lines[last].is_empty() {
            lines[last].push_str("; ");
        }
        lines[last].push_str(part);
    }
    lines.push("ellipses: 2σ of each mixture component at the pulse marked in its colour".into());
    (head, lines)
}

/// Square metres on both axes around the track and the victim, as ranges for the chart.
fn map_ranges(o: &Outcome, aspect: f64) -> (Range<f64>, Range<f64>) {
    let mut pts: Vec<(f64, f64)> = o.track.iter().map(|p| en(*p)).collect();
    pts.push(en([o.victim[0], o.victim[1]]));
    plot::map_view(&pts, 0.0, 1.15, aspect)
}

/// The map: walked track, start, victim, and the mixture's 2σ ellipses at a few pulses.
fn draw_map(o: &Outcome, area: &DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()> {
    let (pw, ph) = area.dim_in_pixel();
    // Axes take ≈ 70 px left and 50 px below: keep one metre the same on both axes.
    let aspect = f64::from(pw.saturating_sub(100)) / f64::from(ph.saturating_sub(60)).max(1.0);
    let mut chart = plot::map_chart(area, map_ranges(o, aspect), 10, 60)?;
    for (i, s) in o.snapshots.iter().enumerate() {
        let colour = SNAPSHOT_COLOURS[i % SNAPSHOT_COLOURS.len()];
        let mut comps: Vec<_> = s.components.iter().filter(|c| c.0 >= 1e-3).collect();
        comps.sort_by(|a, b| b.0.total_cmp(&a.0));
        for c in comps.iter().take(150) {
            let style = colour
                .mix(0.25 + 0.75 * c.0.clamp(0.0, 1.0))
                .stroke_width(1);
            chart
                .draw_series(std::iter::once(PathElement::new(
                    ellipse(c.1, c.2, 32),
                    style,
                )))
                .map_err(plot::err)?;
        }
        chart
            .draw_series(std::iter::once(Circle::new(en(s.rx), 5, colour.filled())))
            .map_err(plot::err)?
            .label(format!("receiver at t = {:.0} s ({})", s.t, s.status))
            .legend(move |(x, y)| Circle::new((x + 10, y), 5, colour.filled()));
    }
    chart
        .draw_series(LineSeries::new(
            o.track.iter().map(|p| en(*p)),
            BLACK.stroke_width(2),
        ))
        .map_err(plot::err)?
        .label("rescuer's walk")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK.stroke_width(2)));
    let start = en([o.start[0], o.start[1]]);
    chart
        .draw_series(std::iter::once(Cross::new(start, 6, GREEN.stroke_width(3))))
        .map_err(plot::err)?
        .label("start")
        .legend(|(x, y)| Cross::new((x + 10, y), 5, GREEN.stroke_width(3)));
    let victim = en([o.victim[0], o.victim[1]]);
    chart
        .draw_series(std::iter::once(Cross::new(victim, 8, RED.stroke_width(3))))
        .map_err(plot::err)?
        .label(format!("victim ({:.1} m deep)", -o.victim[2]))
        .legend(|(x, y)| Cross::new((x + 10, y), 6, RED.stroke_width(3)));
    plot::scale_bar(&mut chart)?;
    plot::draw_legend(&mut chart)
}

/// True distance and the estimate's horizontal error against time, log scale.
fn draw_errors(o: &Outcome, area: &DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()> {
    let t_max = o.rows.last().map_or(1.0, |r| r.t).max(1.0);
    let mut chart = ChartBuilder::on(area)
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_max, plot::log_axis(0.01, 200.0))
        .map_err(plot::err)?;
    plot::draw_axes(
        &mut chart,
        ("time since the start (s)", "distance, error (m, log scale)"),
        &|v| format!("{v:.0}"),
        &|v| plot::tick(*v),
    )?;
    let grey = RGBColor(120, 120, 120);
    chart
        .draw_series(LineSeries::new(
            o.rows.iter().map(|r| (r.t, r.true_distance_m.max(0.01))),
            grey.stroke_width(2),
        ))
        .map_err(plot::err)?
        .label("true distance to the victim")
        .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], grey.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(
            o.rows
                .iter()
                .filter_map(|r| r.error_h_m.map(|e| (r.t, e.clamp(0.01, 200.0)))),
            RED.stroke_width(2),
        ))
        .map_err(plot::err)?
        .label("horizontal error of the estimate")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED.stroke_width(2)));
    plot::draw_legend(&mut chart)
}

#[cfg(test)]
mod tests {
    use super::*;
    use firmware::app::DisplayModel;
    use firmware::guidance::Status;

    #[test]
    fn ascii_frame_has_the_screen_size_and_shows_the_status() {
        let mut f = Frame::new();
        let m = DisplayModel {
            status: Status::FluxLine,
            arrow_deg: Some(30.0),
            ..DisplayModel::default()
        };
        display::draw(&m, &mut f).unwrap();
        let s = ascii_frame(&f);
        let lines: Vec<&str> = s.lines().collect();
        assert_eq!(lines.len(), 34);
        assert!(lines.iter().all(|l| l.chars().count() == 130));
        assert!(s.contains('█') && s.contains('▀'));
        // Golden: the frame round-trips through PNG.
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.png");
        write_frame_png(&f, &p, 2).unwrap();
        let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&p).unwrap()));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (256, 128));
        // Pixel (0,0) of the status text "FLUX LINE" vs an empty corner.
        let lit = (0..128 * 64)
            .filter(|i| buf[(i * 2 % 256 + (i / 128) * 2 * 256) * 3] > 100)
            .count();
        let frame_lit = f
            .data()
            .iter()
            .map(|b| b.count_ones() as usize)
            .sum::<usize>();
        assert_eq!(lit, frame_lit);
    }
}
