//! `hal-sim demo`: one seeded closed-loop rescue ([`crate::closed_loop`]) shown live in
//! the terminal — the receiver's 128×64 screen as drawn by `firmware::display`, rendered
//! with half-block characters — then a PNG plot of the search (trajectory, victim,
//! mixture components as 2σ ellipses at a few moments, estimate error and distance over
//! time) and a PNG of the final screen.
use crate::closed_loop::{self, ClosedLoopConfig, Outcome, PulseRow};
use anyhow::{Context, Result};
use embedded_graphics::image::GetPixel;
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::{FONT_6X10, FONT_9X15};
use embedded_graphics::pixelcolor::{BinaryColor, Rgb888};
use embedded_graphics::prelude::*;
use embedded_graphics::text::{Baseline, Text};
use firmware::app::Receiver;
use firmware::display::{self, Frame};
use plotters::prelude::*;
use std::io::{IsTerminal, Write};
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
    #[arg(long, value_enum, default_value_t = crate::multi::Layout::ClosePairOverlap)]
    pub layout: crate::multi::Layout,
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
    use crate::multi::{Event, MultiConfig, run_with};
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
        "seed {}: victim {:.1} m away (depth {:.1} m); {} after {:.0} s, path {:.1} m = {:.2}x ideal; \
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

pub(crate) fn write_png(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header()?;
    writer.write_image_data(rgb)?;
    writer.finish()?;
    Ok(())
}

/// An RGB byte buffer as an `embedded-graphics` target (for text on plots).
pub(crate) struct Canvas<'a> {
    pub(crate) buf: &'a mut [u8],
    pub(crate) w: u32,
    pub(crate) h: u32,
}

impl OriginDimensions for Canvas<'_> {
    fn size(&self) -> Size {
        Size::new(self.w, self.h)
    }
}

impl DrawTarget for Canvas<'_> {
    type Color = Rgb888;
    type Error = core::convert::Infallible;

    fn draw_iter<I>(&mut self, pixels: I) -> Result<(), Self::Error>
    where
        I: IntoIterator<Item = embedded_graphics::Pixel<Self::Color>>,
    {
        for embedded_graphics::Pixel(p, c) in pixels {
            if p.x >= 0 && p.y >= 0 && (p.x as u32) < self.w && (p.y as u32) < self.h {
                let i = ((p.y as u32 * self.w + p.x as u32) * 3) as usize;
                if let Some(px) = self.buf.get_mut(i..i + 3) {
                    px.copy_from_slice(&[c.r(), c.g(), c.b()]);
                }
            }
        }
        Ok(())
    }
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

/// Map coordinates: x = east (−west), y = north.
pub(crate) fn en(p: [f64; 2]) -> (f64, f64) {
    (-p[1], p[0])
}

/// The 2σ ellipse of a horizontal covariance `[xx, xy, yy]` around `m` (north, west).
fn ellipse(m: [f64; 2], c: [f64; 3]) -> Vec<(f64, f64)> {
    ellipse_n(m, c, 32)
}

/// [`ellipse`] drawn with `n` segments.
pub(crate) fn ellipse_n(m: [f64; 2], c: [f64; 3], n: u32) -> Vec<(f64, f64)> {
    let (a, b, d) = (c[0], c[1], c[2]);
    let half = 0.5 * (a - d);
    let r = (half * half + b * b).sqrt();
    let (l1, l2) = ((0.5 * (a + d) + r).max(0.0), (0.5 * (a + d) - r).max(0.0));
    let th = 0.5 * (2.0 * b).atan2(a - d);
    let (s, co) = th.sin_cos();
    (0..=n)
        .map(|i| {
            let u = f64::from(i) / f64::from(n) * std::f64::consts::TAU;
            let (x, y) = (2.0 * l1.sqrt() * u.cos(), 2.0 * l2.sqrt() * u.sin());
            en([m[0] + co * x - s * y, m[1] + s * x + co * y])
        })
        .collect()
}

/// Plots a run: the map (trajectory, victim, mixture snapshots) above, errors below.
pub fn plot_outcome(o: &Outcome, path: &Path) -> Result<()> {
    let (w, h) = (PLOT_W, MAP_H + ERR_H);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let mut labels: Vec<(String, Point, Rgb888)> = Vec::new();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let (map, err) = root.split_vertically(MAP_H);
        // Equal-scale map around the track and the victim.
        let mut pts: Vec<(f64, f64)> = o.track.iter().map(|p| en(*p)).collect();
        pts.push(en([o.victim[0], o.victim[1]]));
        let (mut x0, mut x1, mut y0, mut y1) = pts.iter().fold(
            (f64::MAX, f64::MIN, f64::MAX, f64::MIN),
            |(a, b, c, d), &(x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
        );
        let span = (x1 - x0).max(y1 - y0).max(10.0) * 1.15;
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        let px_w = f64::from(PLOT_W - 60);
        let px_h = f64::from(MAP_H - 70);
        let (sx, sy) = if px_w >= px_h {
            (span * px_w / px_h, span)
        } else {
            (span, span * px_h / px_w)
        };
        (x0, x1, y0, y1) = (cx - sx / 2.0, cx + sx / 2.0, cy - sy / 2.0, cy + sy / 2.0);
        let mut chart = ChartBuilder::on(&map)
            .margin_top(40)
            .margin_bottom(30)
            .margin_left(30)
            .margin_right(30)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        // 10 m grid.
        let grid = RGBColor(230, 230, 230);
        let mut g = (x0 / 10.0).ceil() * 10.0;
        while g < x1 {
            chart
                .draw_series(LineSeries::new([(g, y0), (g, y1)], grid))
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            g += 10.0;
        }
        let mut g = (y0 / 10.0).ceil() * 10.0;
        while g < y1 {
            chart
                .draw_series(LineSeries::new([(x0, g), (x1, g)], grid))
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            g += 10.0;
        }
        for (i, s) in o.snapshots.iter().enumerate() {
            let colour = SNAPSHOT_COLOURS[i % SNAPSHOT_COLOURS.len()];
            let mut comps: Vec<_> = s.components.iter().filter(|c| c.0 >= 1e-3).collect();
            comps.sort_by(|a, b| b.0.total_cmp(&a.0));
            for c in comps.iter().take(150) {
                let style = colour
                    .mix(0.25 + 0.75 * c.0.clamp(0.0, 1.0))
                    .stroke_width(1);
                chart
                    .draw_series(std::iter::once(PathElement::new(ellipse(c.1, c.2), style)))
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            }
            chart
                .draw_series(std::iter::once(Circle::new(en(s.rx), 5, colour.filled())))
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            let (px, py) = chart.backend_coord(&en(s.rx));
            labels.push((
                format!("t={:.0}s {}", s.t, s.status),
                Point::new(px + 8, py - 4),
                Rgb888::new(colour.0, colour.1, colour.2),
            ));
        }
        chart
            .draw_series(LineSeries::new(
                o.track.iter().map(|p| en(*p)),
                BLACK.stroke_width(2),
            ))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let v = en([o.victim[0], o.victim[1]]);
        chart
            .draw_series([
                Cross::new(v, 8, RED.stroke_width(3)),
                Cross::new(en([o.start[0], o.start[1]]), 6, GREEN.stroke_width(3)),
            ])
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let (vx, vy) = chart.backend_coord(&v);
        labels.push(("victim".into(), Point::new(vx + 10, vy + 6), Rgb888::RED));
        let (sx, sy) = chart.backend_coord(&en([o.start[0], o.start[1]]));
        labels.push((
            "start".into(),
            Point::new(sx + 10, sy + 6),
            Rgb888::new(0, 128, 0),
        ));
        labels.push((
            format!(
                "10 m grid, north up; {}",
                "2-sigma ellipses of the mixture components"
            ),
            Point::new(30, 22),
            Rgb888::BLACK,
        ));

        // Errors over time, log scale.
        let t_max = o.rows.last().map_or(1.0, |r| r.t).max(1.0);
        let mut chart = ChartBuilder::on(&err)
            .margin_top(30)
            .margin_bottom(25)
            .margin_left(50)
            .margin_right(30)
            .build_cartesian_2d(0.0..t_max, (0.01f64..200.0).log_scale())
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        for decade in [0.01, 0.1, 1.0, 10.0, 100.0] {
            chart
                .draw_series(LineSeries::new([(0.0, decade), (t_max, decade)], grid))
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            let (_, py) = chart.backend_coord(&(0.0, decade));
            labels.push((format!("{decade}"), Point::new(4, py - 4), Rgb888::BLACK));
        }
        chart
            .draw_series(LineSeries::new(
                o.rows.iter().map(|r| (r.t, r.true_distance_m.max(0.01))),
                RGBColor(120, 120, 120).stroke_width(2),
            ))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        chart
            .draw_series(LineSeries::new(
                o.rows
                    .iter()
                    .filter_map(|r| r.error_h_m.map(|e| (r.t, e.clamp(0.01, 200.0)))),
                RED.stroke_width(2),
            ))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let (_, top) = chart.backend_coord(&(0.0, 200.0));
        labels.push((
            format!(
                "m vs time (0..{t_max:.0} s): grey true distance, red horizontal estimate error"
            ),
            Point::new(60, top - 16),
            Rgb888::BLACK,
        ));
        root.present().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    }
    let mut canvas = Canvas {
        buf: &mut buf,
        w,
        h,
    };
    let title = summary(o);
    let small = |c| MonoTextStyle::new(&FONT_6X10, c);
    let (head, rest) = title.split_once(';').unwrap_or((&title, ""));
    let _ = Text::with_baseline(
        head,
        Point::new(30, 4),
        MonoTextStyle::new(&FONT_9X15, Rgb888::BLACK),
        Baseline::Top,
    )
    .draw(&mut canvas);
    let rest = rest.trim();
    let _ = Text::with_baseline(
        rest,
        Point::new(30, MAP_H as i32 - 16),
        small(Rgb888::BLACK),
        Baseline::Top,
    )
    .draw(&mut canvas);
    for (text, at, colour) in &labels {
        let _ = Text::with_baseline(text, *at, small(*colour), Baseline::Top).draw(&mut canvas);
    }
    write_png(path, w, h, &buf)
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
