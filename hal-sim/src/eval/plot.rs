//! What every figure shares: a real font (DejaVu Sans, embedded, so a fresh machine needs no
//! font stack) for plotters' axes, ticks, captions and legends, and the error conversion.
use plotters::coord::ranged1d::ValueFormatter;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
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
}
