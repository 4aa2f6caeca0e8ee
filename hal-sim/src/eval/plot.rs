//! What every figure shares: a real font (DejaVu Sans, embedded, so a fresh machine needs no
//! font stack) for plotters' axes, ticks, captions and legends, and the error conversion.
use anyhow::Context as _;
use plotters::coord::combinators::WithKeyPoints;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
use std::ops::Range;
use std::path::Path;
use std::sync::Once;

/// The embedded font (license: `hal-sim/assets/LICENSE-DejaVu.txt`).
const SANS: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// The family name figures use in their text styles.
pub const FONT: &str = "sans-serif";

/// Registers the embedded font with plotters (once per process).
pub fn fonts() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // The bytes are a valid TrueType font (checked by the test below): ignoring the
        // error cannot hide a bad input at run time.
        let _ = register_font(FONT, FontStyle::Normal, SANS);
    });
}

/// Turns a plotters drawing error (which is not `Send + Sync`) into an `anyhow` error.
pub fn err(e: impl std::fmt::Debug) -> anyhow::Error {
    anyhow::anyhow!("drawing failed: {e:?}")
}

/// Draws a chart's axes in the figures' style: named, ticks in the embedded font formatted
/// by `x_fmt` / `y_fmt`, a pale grid.
pub fn draw_axes<'a, DB, X, Y>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
    (x_desc, y_desc): (&str, &str),
    x_fmt: &dyn Fn(&X::ValueType) -> String,
    y_fmt: &dyn Fn(&Y::ValueType) -> String,
) -> anyhow::Result<()>
where
    DB: DrawingBackend + 'a,
    X: Ranged + ValueFormatter<X::ValueType>,
    Y: Ranged + ValueFormatter<Y::ValueType>,
{
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_label_formatter(x_fmt)
        .y_label_formatter(y_fmt)
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 15))
        .light_line_style(RGBColor(240, 240, 240))
        .bold_line_style(RGBColor(215, 215, 215))
        .draw()
        .map_err(err)
}

/// A tick label: integers plainly, small values with their significant digits, below a
/// thousandth as a power of ten.
pub fn tick(v: f64) -> String {
    if v.abs() >= 1.0 || v == 0.0 {
        format!("{}", (v * 100.0).round() / 100.0)
    } else if v.abs() < 1e-3 {
        format!("1e{}", v.abs().log10().round())
    } else {
        let digits = (-v.abs().log10()).ceil() as usize + 1;
        let s = format!("{v:.digits$}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// Every power of ten from `lo` to `hi`: a log axis' labelled ticks (plotters' own choice
/// skips decades), and the 2…9 multiples between them for its light grid lines.
pub fn decades(lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
    let (a, b) = (lo.log10().ceil() as i32, hi.log10().floor() as i32);
    let bold: Vec<f64> = (a..=b).map(|e| 10f64.powi(e)).collect();
    let light = (a - 1..=b)
        .flat_map(|e| (2..10).map(move |m| f64::from(m) * 10f64.powi(e)))
        .filter(|v| (lo..=hi).contains(v))
        .collect();
    (bold, light)
}

/// A log axis from `lo` to `hi` with a labelled tick at every decade ([`decades`]).
pub fn log_axis(lo: f64, hi: f64) -> WithKeyPoints<LogCoord<f64>> {
    let (bold, light) = decades(lo, hi);
    (lo..hi)
        .log_scale()
        .with_key_points(bold)
        .with_light_points(light)
}

/// A map's chart: metres east and north on equal scales.
pub type MapChart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Map coordinates of a `[north, west]` point: x = east (−west), y = north.
pub fn en(p: [f64; 2]) -> (f64, f64) {
    (-p[1], p[0])
}

/// The 2σ ellipse of a horizontal covariance `[xx, xy, yy]` around `m` (north, west), in
/// map coordinates, drawn with `n` segments.
pub fn ellipse(m: [f64; 2], c: [f64; 3], n: u32) -> Vec<(f64, f64)> {
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

/// The view of a map around `points` (map coordinates): the larger side of their bounding
/// box (at least 10 m) plus `pad_m`, times `scale`, widened to `aspect` (width / height)
/// so that a metre is as long on both axes.
pub fn map_view(
    points: &[(f64, f64)],
    pad_m: f64,
    scale: f64,
    aspect: f64,
) -> (Range<f64>, Range<f64>) {
    let (x0, x1, y0, y1) = points.iter().fold(
        (f64::MAX, f64::MIN, f64::MAX, f64::MIN),
        |(a, b, c, d), &(x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
    );
    let span = ((x1 - x0).max(y1 - y0).max(10.0) + pad_m) * scale;
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (sx, sy) = if aspect >= 1.0 {
        (span * aspect, span)
    } else {
        (span, span / aspect)
    };
    (cx - sx / 2.0..cx + sx / 2.0, cy - sy / 2.0..cy + sy / 2.0)
}

/// A map's chart on `area` over `view` (see [`map_view`]), its axes drawn: `margin` px
/// around, `y_label_px` for the north axis' labels.
pub fn map_chart<'a, 'b>(
    area: &'a DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    view: (Range<f64>, Range<f64>),
    margin: u32,
    y_label_px: u32,
) -> anyhow::Result<MapChart<'a, 'b>> {
    let mut chart = ChartBuilder::on(area)
        .margin(margin)
        .x_label_area_size(40)
        .y_label_area_size(y_label_px)
        .build_cartesian_2d(view.0, view.1)
        .map_err(err)?;
    draw_axes(
        &mut chart,
        ("east (m)", "north (m)"),
        &|v| format!("{v:.0}"),
        &|v| format!("{v:.0}"),
    )?;
    Ok(chart)
}

/// The scale bar's length for a map `width_m` wide: the largest 1, 2 or 5 × 10ⁿ m not
/// longer than a fifth of it.
pub fn scale_length(width_m: f64) -> f64 {
    let target = (width_m / 5.0).max(1e-9);
    let decade = 10f64.powf(target.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * decade)
        .find(|l| *l <= target)
        .unwrap_or(decade)
}

/// Draws a map's scale bar in its lower left corner: [`scale_length`] metres with end
/// ticks, labelled above.
pub fn scale_bar(chart: &mut MapChart<'_, '_>) -> anyhow::Result<()> {
    let (xr, yr) = (chart.x_range(), chart.y_range());
    let width = xr.end - xr.start;
    let len = scale_length(width);
    let (x0, y0) = (
        xr.start + 0.04 * width,
        yr.start + 0.04 * (yr.end - yr.start),
    );
    let style = BLACK.stroke_width(3);
    chart
        .draw_series(std::iter::once(PathElement::new(
            [(x0, y0), (x0 + len, y0)],
            style,
        )))
        .map_err(err)?;
    let tick = |x: f64| EmptyElement::at((x, y0)) + PathElement::new([(0, -6), (0, 6)], style);
    chart.draw_series([tick(x0), tick(x0 + len)]).map_err(err)?;
    let label = Text::new(format!("{len} m"), (0, -26), (FONT, 15).into_font());
    chart
        .draw_series(std::iter::once(EmptyElement::at((x0, y0)) + label))
        .map_err(err)?;
    Ok(())
}

/// Writes an 8-bit RGB buffer of `w` × `h` pixels as a PNG (creating the directory).
pub fn write_png(path: &Path, w: u32, h: u32, rgb: &[u8]) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
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

/// Draws the legend of a chart's labelled series in its upper right corner.
pub fn draw_legend<'a, DB, CT>(chart: &mut ChartContext<'a, DB, CT>) -> anyhow::Result<()>
where
    DB: DrawingBackend + 'a,
    CT: CoordTranslate,
{
    draw_legend_at(chart, SeriesLabelPosition::UpperRight)
}

/// As [`draw_legend`], at `position` (for figures whose curves fill the upper right).
pub fn draw_legend_at<'a, DB, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> anyhow::Result<()>
where
    DB: DrawingBackend + 'a,
    CT: CoordTranslate,
{
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(160, 160, 160))
        .label_font((FONT, 13))
        .draw()
        .map_err(err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_font_draws_text_with_non_ascii_signs() {
        fonts();
        assert!(register_font("check", FontStyle::Normal, SANS).is_ok());
        let mut buf = vec![255u8; 200 * 40 * 3];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (200, 40)).into_drawing_area();
            root.draw_text("2σ × 10 m", &(FONT, 20).into_text_style(&root), (5, 5))
                .expect("text draws");
            root.present().expect("present");
        }
        let inked = buf.chunks(3).filter(|p| p[0] < 128).count();
        assert!(inked > 100, "only {inked} dark pixels: no glyphs drawn");
    }

    #[test]
    fn the_scale_bar_is_a_round_fifth_of_the_map_or_less() {
        for (width, len) in [
            (120.0, 20.0),
            (100.0, 20.0),
            (60.0, 10.0),
            (30.0, 5.0),
            (4.0, 0.5),
        ] {
            assert_eq!(scale_length(width), len, "{width} m wide");
        }
    }

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick(0.01), "0.01");
        assert_eq!(tick(0.1), "0.1");
        assert_eq!(tick(1.0), "1");
        assert_eq!(tick(100.0), "100");
        assert_eq!(tick(0.5), "0.5");
        assert_eq!(tick(0.25), "0.25");
        assert_eq!(tick(1e-4), "1e-4");
    }

    #[test]
    fn a_log_axis_labels_every_decade() {
        let (bold, light) = decades(0.01, 300.0);
        assert_eq!(bold.len(), 5);
        for (b, want) in bold.iter().zip([0.01, 0.1, 1.0, 10.0, 100.0]) {
            assert!((b / want - 1.0).abs() < 1e-12, "{bold:?}");
        }
        // 2…9 × each decade inside the range: 8 × 4 below 100, then 200 and 300.
        assert_eq!(light.len(), 34, "{light:?}");
        assert!(light.iter().all(|v| (0.01..=300.0).contains(v)));
    }
}
