//! The 128×64 monochrome screen: draws a [`DisplayModel`] on any `embedded-graphics`
//! [`DrawTarget`] with `BinaryColor` (an SSD1306 on the board, a [`Frame`] buffer that
//! `hal-sim` turns into ASCII art or a PNG).
//!
//! Layout (pixels):
//! ```text
//!  0        60 64                    127
//!  +-------------------------------+  row 0..9: status word · overlap "!" · victims "V1"
//!  |   arrow in a  | 12.3m          |  rows 12..31: distance (10×20 font)
//!  |   64×52 box   | depth 1.2m     |  rows 35..44: depth (fine search)
//!  |   (forward=up)| ±0.4m [###   ] |  rows 52..61: uncertainty text and bar
//!  +-------------------------------+
//! ```
//! The arrow is relative to the device's heading: straight up means "ahead", positive
//! angles turn it to the left. "Probe here" replaces the arrow with a cross-hair.
//! Prompts take the status word's place: "LOWER TO SNOW" / "RAISE TO 1M" (the height
//! prompts of the fine search, [`DisplayModel::height_prompt`]), then "LIFT 40CM".
//!
//! Several victims: the top row's right end lists them by number (the target drawn
//! inverted, a found one as `+`) instead of "V1", and outside the fine search the depth
//! row names the nearest other unmarked victim: number, distance and a direction glyph
//! (`^` ahead, `<` left, `>` right, `v` behind). When every listed victim is marked the
//! status word reads "ALL MARKED".
//! Distances: 0.1 m resolution below 10 m, whole metres above.

use core::fmt::Write as _;

use embedded_graphics::framebuffer::{Framebuffer, buffer_size};
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::{FONT_6X10, FONT_10X20};
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::pixelcolor::raw::{BigEndian, RawU1};
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::{Circle, Line, PrimitiveStyle, Rectangle, Triangle};
use embedded_graphics::text::{Baseline, Text};

use crate::guidance::{HeightPrompt, Status};

mod model;
pub use model::{DisplayModel, VictimRow};

/// Screen width, pixels.
pub const WIDTH: u32 = 128;
/// Screen height, pixels.
pub const HEIGHT: u32 = 64;

/// A 128×64 one-bit frame buffer (1 KB, the SSD1306's own layout aside).
pub type Frame = Framebuffer<
    BinaryColor,
    RawU1,
    BigEndian,
    { WIDTH as usize },
    { HEIGHT as usize },
    { buffer_size::<BinaryColor>(WIDTH as usize, HEIGHT as usize) },
>;

/// The lit pixels of `frame`: what the tests measure of a screen.
#[cfg(test)]
pub(crate) fn lit(frame: &Frame) -> impl Iterator<Item = Point> + '_ {
    use embedded_graphics::image::GetPixel;
    frame
        .bounding_box()
        .points()
        .filter(|p| frame.pixel(*p) == Some(BinaryColor::On))
}

/// Centre of the arrow box.
pub const ARROW_CENTRE: Point = Point::new(31, 37);
/// Arrow half-length, pixels.
pub const ARROW_LEN: i32 = 22;
/// Top-left of the distance text.
pub const DISTANCE_AT: Point = Point::new(66, 12);
/// Top-left of the depth text.
pub const DEPTH_AT: Point = Point::new(66, 35);
/// Top-left of the uncertainty text.
pub const UNCERTAINTY_AT: Point = Point::new(66, 52);
/// The uncertainty bar's outline.
pub const UNCERTAINTY_BAR: Rectangle = Rectangle::new(Point::new(102, 53), Size::new(25, 8));

/// Left end of the victim list in the top row (four 6-pixel glyphs).
pub const LIST_AT: Point = Point::new(104, 0);
/// Status word when every listed victim is marked.
pub const ALL_MARKED_WORD: &str = "ALL MARKED";

/// Short text, formatted without a heap.
type Line16 = heapless::String<16>;

/// A distance in metres as the screen shows it: 0.1 m below 10 m, whole metres above.
pub fn format_metres(m: f32) -> Line16 {
    let mut s = Line16::new();
    let m = if m.is_finite() {
        m.clamp(0.0, 999.0)
    } else {
        999.0
    };
    // Rounding 9.96 to one decimal gives "10.0": switch to whole metres from 9.95.
    let _ = if m < 9.95 {
        write!(s, "{m:.1}m")
    } else {
        write!(s, "{}m", libm::roundf(m) as u32)
    };
    s
}

/// The top-row word of the lift prompt ([`DisplayModel::lift`]).
pub const LIFT_WORD: &str = "LIFT 40CM";

/// The top-row words of the height prompts ([`DisplayModel::height_prompt`]).
pub const LOWER_WORD: &str = "LOWER TO SNOW";
/// See [`LOWER_WORD`].
pub const RAISE_WORD: &str = "RAISE TO 1M";

/// The status word.
pub fn status_word(s: Status) -> &'static str {
    match s {
        Status::NoSignal => "NO SIGNAL",
        Status::FluxLine => "FLUX LINE",
        Status::Localized => "LOCALIZED",
        Status::Probe => "PROBE HERE",
    }
}

/// Uncertainty bar fill (pixels inside the outline) for a σ in metres: logarithmic,
/// empty at 0.1 m and below, full at 10 m and above.
pub fn uncertainty_fill(sigma_m: f32) -> u32 {
    let inner = UNCERTAINTY_BAR.size.width.saturating_sub(2);
    if sigma_m.is_nan() || sigma_m <= 0.1 {
        return 0;
    }
    let f = (libm::log10f(sigma_m) + 1.0) / 2.0; // 0.1 m → 0, 10 m → 1
    let f = if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        1.0
    };
    libm::roundf(f * inner as f32) as u32
}

/// The arrow's tip for an angle in degrees (positive left): screen x grows to the right,
/// y downward, "ahead" is up.
pub fn arrow_tip(centre: Point, len: i32, arrow_deg: f32) -> Point {
    // A pixel endpoint needs ≈ 1e-2 relative accuracy: micromath's polynomial sin/cos (error
    // ≈ 1e-3) costs a fraction of libm's on the M4F and the display redraws at every pulse.
    let (s, c) = micromath::F32Ext::sin_cos(arrow_deg.to_radians());
    Point::new(
        centre.x - libm::roundf(len as f32 * s) as i32,
        centre.y - libm::roundf(len as f32 * c) as i32,
    )
}

/// Draws an arrow from behind `centre` to its tip `len` ahead, turned by `arrow_deg`.
pub fn draw_arrow<D>(
    target: &mut D,
    centre: Point,
    len: i32,
    arrow_deg: f32,
) -> Result<(), D::Error>
where
    D: DrawTarget<Color = BinaryColor>,
{
    let tip = arrow_tip(centre, len, arrow_deg);
    let tail = arrow_tip(centre, len, arrow_deg + 180.0);
    let head = len / 2;
    let back = arrow_tip(tip, -head, arrow_deg);
    // Head corners: half a head-length to either side of its base.
    let left = arrow_tip(back, head / 2, arrow_deg + 90.0);
    let right = arrow_tip(back, head / 2, arrow_deg - 90.0);
    Line::new(tail, back)
        .into_styled(PrimitiveStyle::with_stroke(BinaryColor::On, 3))
        .draw(target)?;
    Triangle::new(tip, left, right)
        .into_styled(PrimitiveStyle::with_fill(BinaryColor::On))
        .draw(target)
}

/// Draws "probe here": a cross-hair in a circle.
fn draw_crosshair<D>(target: &mut D, centre: Point, r: i32) -> Result<(), D::Error>
where
    D: DrawTarget<Color = BinaryColor>,
{
    let stroke = PrimitiveStyle::with_stroke(BinaryColor::On, 1);
    Circle::with_center(centre, (2 * r) as u32)
        .into_styled(stroke)
        .draw(target)?;
    Circle::with_center(centre, (r / 2) as u32)
        .into_styled(PrimitiveStyle::with_fill(BinaryColor::On))
        .draw(target)?;
    Line::new(centre - Point::new(r + 4, 0), centre + Point::new(r + 4, 0))
        .into_styled(stroke)
        .draw(target)?;
    Line::new(centre - Point::new(0, r + 4), centre + Point::new(0, r + 4))
        .into_styled(stroke)
        .draw(target)
}

/// The glyph of a direction relative to the heading (degrees, positive left).
pub fn direction_glyph(arrow_deg: f32) -> char {
    let a = libm::fabsf(arrow_deg);
    if a <= 30.0 {
        '^'
    } else if a >= 150.0 || !a.is_finite() {
        'v'
    } else if arrow_deg > 0.0 {
        '<'
    } else {
        '>'
    }
}

/// The nearest unmarked victim other than the target, as "3:23m <".
pub fn next_victim(model: &DisplayModel) -> Option<Line16> {
    let row = model
        .list
        .iter()
        .flatten()
        .filter(|r| !r.marked && !r.target)
        .filter_map(|r| r.distance_m.map(|d| (r, d)))
        .min_by(|a, b| a.1.total_cmp(&b.1))?
        .0;
    let mut s = Line16::new();
    let _ = write!(
        s,
        "{}:{} {}",
        row.number.min(9),
        format_metres(row.distance_m.unwrap_or(0.0)),
        row.arrow_deg.map_or('?', direction_glyph)
    );
    Some(s)
}

/// The victim list in the top row: the number of each victim, the target inverted, a
/// found victim as `+`.
fn draw_list<D>(target: &mut D, list: &[Option<VictimRow>]) -> Result<(), D::Error>
where
    D: DrawTarget<Color = BinaryColor>,
{
    for (k, row) in list.iter().enumerate() {
        let Some(row) = row else { continue };
        let at = LIST_AT + Point::new(6 * k as i32, 0);
        let mut glyph = heapless::String::<2>::new();
        let _ = if row.marked {
            glyph.push('+')
        } else {
            glyph.push(char::from(b'0' + row.number.min(9)))
        };
        let (fg, bg) = if row.target {
            (BinaryColor::Off, Some(BinaryColor::On))
        } else {
            (BinaryColor::On, None)
        };
        if let Some(bg) = bg {
            Rectangle::new(at, Size::new(6, 10))
                .into_styled(PrimitiveStyle::with_fill(bg))
                .draw(target)?;
        }
        Text::with_baseline(
            &glyph,
            at,
            MonoTextStyle::new(&FONT_6X10, fg),
            Baseline::Top,
        )
        .draw(target)?;
    }
    Ok(())
}

/// Clears `target` and draws `model` on it (128×64 layout of the module docs).
pub fn draw<D>(model: &DisplayModel, target: &mut D) -> Result<(), D::Error>
where
    D: DrawTarget<Color = BinaryColor>,
{
    target.clear(BinaryColor::Off)?;
    let small = MonoTextStyle::new(&FONT_6X10, BinaryColor::On);
    let big = MonoTextStyle::new(&FONT_10X20, BinaryColor::On);

    // Top row: status (or the height or lift prompt), overlap flag, victims heard.
    let all_marked = model.victims > 0 && model.found >= model.victims;
    let word = if model.height_prompt == HeightPrompt::Lower {
        LOWER_WORD
    } else if model.height_prompt == HeightPrompt::Raise {
        RAISE_WORD
    } else if model.lift {
        LIFT_WORD
    } else if all_marked && model.target.is_none() {
        ALL_MARKED_WORD
    } else {
        status_word(model.status)
    };
    Text::with_baseline(word, Point::zero(), small, Baseline::Top).draw(target)?;
    if model.overlap {
        Text::with_baseline("!", Point::new(98, 0), small, Baseline::Top).draw(target)?;
    }
    if model.list.iter().flatten().count() > 1 || model.found > 0 {
        draw_list(target, &model.list)?;
    } else {
        let mut v = Line16::new();
        let _ = write!(v, "V{}", model.victims.min(9));
        Text::with_baseline(&v, Point::new(WIDTH as i32 - 12, 0), small, Baseline::Top)
            .draw(target)?;
    }
    Line::new(Point::new(0, 10), Point::new(WIDTH as i32 - 1, 10))
        .into_styled(PrimitiveStyle::with_stroke(BinaryColor::On, 1))
        .draw(target)?;

    // Left: the arrow (or the cross-hair).
    match (model.status, model.arrow_deg) {
        (Status::Probe, _) => draw_crosshair(target, ARROW_CENTRE, 14)?,
        (_, Some(a)) if a.is_finite() => draw_arrow(target, ARROW_CENTRE, ARROW_LEN, a)?,
        _ => {
            Text::with_baseline("?", ARROW_CENTRE - Point::new(5, 10), big, Baseline::Top)
                .draw(target)?;
        }
    }

    // Right: distance, depth, uncertainty.
    if let Some(d) = model.distance_m {
        Text::with_baseline(&format_metres(d), DISTANCE_AT, big, Baseline::Top).draw(target)?;
    }
    if let Some(depth) = model.depth_m {
        let mut s = Line16::new();
        let _ = write!(s, "dep {}", format_metres(depth));
        Text::with_baseline(&s, DEPTH_AT, small, Baseline::Top).draw(target)?;
    } else if let Some(next) = next_victim(model) {
        Text::with_baseline(&next, DEPTH_AT, small, Baseline::Top).draw(target)?;
    }
    if let Some(sigma) = model.uncertainty_m {
        let mut s = Line16::new();
        let _ = if sigma < 9.95 {
            write!(s, "+-{:.1}", sigma.max(0.0))
        } else {
            write!(s, "+-{}", libm::roundf(sigma.min(99.0)) as u32)
        };
        Text::with_baseline(&s, UNCERTAINTY_AT, small, Baseline::Top).draw(target)?;
        UNCERTAINTY_BAR
            .into_styled(PrimitiveStyle::with_stroke(BinaryColor::On, 1))
            .draw(target)?;
        let fill = uncertainty_fill(sigma);
        if fill > 0 {
            Rectangle::new(
                UNCERTAINTY_BAR.top_left + Point::new(1, 1),
                Size::new(fill, UNCERTAINTY_BAR.size.height - 2),
            )
            .into_styled(PrimitiveStyle::with_fill(BinaryColor::On))
            .draw(target)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_graphics::image::GetPixel;
    use embedded_graphics::mock_display::MockDisplay;

    fn model() -> DisplayModel {
        DisplayModel {
            status: Status::Localized,
            arrow_deg: Some(0.0),
            distance_m: Some(12.34),
            horizontal_m: Some(12.0),
            depth_m: Some(1.24),
            walk_m: Some(12.0),
            uncertainty_m: Some(0.4),
            victims: 1,
            overlap: false,
            pulses: 5,
            t_s: 5.0,
            lift: false,
            ..DisplayModel::default()
        }
    }

    fn lit(f: &Frame, x: i32, y: i32) -> bool {
        f.pixel(Point::new(x, y)) == Some(BinaryColor::On)
    }

    /// Whether the rectangle `at`+`size` of `a` equals the same text drawn alone.
    fn shows_text(
        f: &Frame,
        text: &str,
        at: Point,
        font: &embedded_graphics::mono_font::MonoFont,
    ) -> bool {
        let mut alone = Frame::new();
        let style = MonoTextStyle::new(font, BinaryColor::On);
        let t = Text::with_baseline(text, at, style, Baseline::Top);
        let _ = t.draw(&mut alone);
        let bb = t.bounding_box();
        bb.points().all(|p| f.pixel(p) == alone.pixel(p))
            && bb.points().any(|p| alone.pixel(p) == Some(BinaryColor::On))
    }

    #[test]
    fn metres_have_the_promised_resolution() {
        assert_eq!(format_metres(0.04).as_str(), "0.0m");
        assert_eq!(format_metres(9.94).as_str(), "9.9m");
        assert_eq!(format_metres(9.96).as_str(), "10m");
        assert_eq!(format_metres(42.6).as_str(), "43m");
        assert_eq!(format_metres(f32::NAN).as_str(), "999m");
        assert_eq!(format_metres(-3.0).as_str(), "0.0m");
    }

    #[test]
    fn arrow_points_ahead_left_and_right() {
        // Ahead: a tall, narrow shape above and below the centre.
        let mut d = MockDisplay::new();
        d.set_allow_overdraw(true);
        draw_arrow(&mut d, Point::new(32, 32), 20, 0.0).unwrap();
        let bb = d.affected_area();
        assert!(bb.size.height > 38 && bb.size.width < 14, "{bb:?}");
        assert_eq!(d.get_pixel(Point::new(32, 12)), Some(BinaryColor::On));
        // 90° left: the tip is at the left edge.
        let mut d = MockDisplay::new();
        d.set_allow_overdraw(true);
        draw_arrow(&mut d, Point::new(32, 32), 20, 90.0).unwrap();
        let bb = d.affected_area();
        assert!(bb.size.width > 38 && bb.size.height < 14, "{bb:?}");
        assert_eq!(d.get_pixel(Point::new(12, 32)), Some(BinaryColor::On));
        assert_eq!(bb.top_left.x, 12);
        // 90° right: the tip is at the right edge.
        let mut d = MockDisplay::new();
        d.set_allow_overdraw(true);
        draw_arrow(&mut d, Point::new(32, 32), 20, -90.0).unwrap();
        assert_eq!(d.affected_area().bottom_right().map(|p| p.x), Some(52));
        // Tip helper: behind is down on the screen.
        assert_eq!(arrow_tip(Point::new(0, 0), 10, 180.0), Point::new(0, 10));
    }

    #[test]
    fn full_frame_shows_every_field() {
        let mut f = Frame::new();
        draw(&model(), &mut f).unwrap();
        assert!(shows_text(&f, "LOCALIZED", Point::zero(), &FONT_6X10));
        assert!(shows_text(&f, "V1", Point::new(116, 0), &FONT_6X10));
        assert!(shows_text(&f, "12m", DISTANCE_AT, &FONT_10X20));
        assert!(shows_text(&f, "dep 1.2m", DEPTH_AT, &FONT_6X10));
        assert!(shows_text(&f, "+-0.4", UNCERTAINTY_AT, &FONT_6X10));
        // Arrow straight up from the centre; nothing to its sides.
        assert!(lit(&f, ARROW_CENTRE.x, ARROW_CENTRE.y - ARROW_LEN + 1));
        assert!(lit(&f, ARROW_CENTRE.x, ARROW_CENTRE.y + ARROW_LEN - 1));
        assert!(!lit(&f, ARROW_CENTRE.x - 20, ARROW_CENTRE.y));
        // The bar: outline and a partial fill (0.4 m → 30 %).
        let fill = uncertainty_fill(0.4);
        assert!(fill > 5 && fill < 12, "{fill}");
        let y = UNCERTAINTY_BAR.top_left.y + 4;
        let x0 = UNCERTAINTY_BAR.top_left.x;
        assert!(lit(&f, x0 + 1, y) && lit(&f, x0 + fill as i32, y));
        assert!(!lit(&f, x0 + fill as i32 + 2, y));
    }

    #[test]
    fn height_prompts_take_the_top_row_and_keep_the_numbers() {
        for (prompt, word) in [
            (HeightPrompt::Lower, LOWER_WORD),
            (HeightPrompt::Raise, RAISE_WORD),
        ] {
            let mut f = Frame::new();
            let m = DisplayModel {
                height_prompt: prompt,
                lift: true,
                ..model()
            };
            draw(&m, &mut f).unwrap();
            // The prompt wins over the lift word and the status; it fits before the
            // overlap flag at x = 98.
            assert!(shows_text(&f, word, Point::zero(), &FONT_6X10), "{word}");
            assert!(word.len() * 6 < 98);
            assert!(!shows_text(&f, LIFT_WORD, Point::zero(), &FONT_6X10));
            assert!(shows_text(&f, "12m", DISTANCE_AT, &FONT_10X20));
            assert!(shows_text(&f, "dep 1.2m", DEPTH_AT, &FONT_6X10));
        }
        // Without a prompt the status word is back.
        let mut f = Frame::new();
        draw(&model(), &mut f).unwrap();
        assert!(!shows_text(&f, LOWER_WORD, Point::zero(), &FONT_6X10));
        assert!(shows_text(&f, "LOCALIZED", Point::zero(), &FONT_6X10));
    }

    #[test]
    fn probe_and_no_signal_screens() {
        let mut f = Frame::new();
        let mut m = model();
        m.status = Status::Probe;
        m.distance_m = Some(1.3);
        m.overlap = true;
        draw(&m, &mut f).unwrap();
        assert!(shows_text(&f, "PROBE HERE", Point::zero(), &FONT_6X10));
        assert!(shows_text(&f, "1.3m", DISTANCE_AT, &FONT_10X20));
        assert!(shows_text(&f, "!", Point::new(98, 0), &FONT_6X10));
        assert!(lit(&f, ARROW_CENTRE.x, ARROW_CENTRE.y)); // cross-hair centre dot
        assert!(lit(&f, ARROW_CENTRE.x - 18, ARROW_CENTRE.y)); // horizontal hair
        // No signal: "?" in the arrow box and no numbers.
        let mut f = Frame::new();
        let m = DisplayModel::default();
        draw(&m, &mut f).unwrap();
        assert!(shows_text(&f, "NO SIGNAL", Point::zero(), &FONT_6X10));
        assert!(shows_text(
            &f,
            "?",
            ARROW_CENTRE - Point::new(5, 10),
            &FONT_10X20
        ));
        assert!((DISTANCE_AT.y..64).all(|y| (DISTANCE_AT.x..128).all(|x| !lit(&f, x, y))));
    }

    #[test]
    fn victim_list_target_inverted_found_as_plus_and_next_victim() {
        let mut m = model();
        m.depth_m = None;
        m.victims = 3;
        m.found = 1;
        m.target = Some(2);
        let row = |number, d: f32, a: f32, marked, target| VictimRow {
            number,
            distance_m: Some(d),
            arrow_deg: Some(a),
            marked,
            target,
        };
        m.list = [
            Some(row(1, 3.0, 0.0, true, false)),
            Some(row(2, 12.3, 0.0, false, true)),
            Some(row(3, 23.4, 100.0, false, false)),
            None,
        ];
        let mut f = Frame::new();
        draw(&m, &mut f).unwrap();
        assert!(shows_text(&f, "+", LIST_AT, &FONT_6X10));
        assert!(shows_text(&f, "3", LIST_AT + Point::new(12, 0), &FONT_6X10));
        // The target's cell is inverted: its corner is lit.
        assert!(lit(&f, LIST_AT.x + 6, 0) && lit(&f, LIST_AT.x + 11, 9));
        assert!(!lit(&f, LIST_AT.x + 18, 9));
        assert!(shows_text(&f, "3:23m <", DEPTH_AT, &FONT_6X10));
        assert_eq!(next_victim(&m).unwrap().as_str(), "3:23m <");
        // Every listed victim marked, no target: "ALL MARKED".
        m.found = 3;
        m.target = None;
        for r in m.list.iter_mut().flatten() {
            r.marked = true;
            r.target = false;
        }
        let mut f = Frame::new();
        draw(&m, &mut f).unwrap();
        assert!(shows_text(&f, ALL_MARKED_WORD, Point::zero(), &FONT_6X10));
        assert!(next_victim(&m).is_none());
        assert_eq!(direction_glyph(-90.0), '>');
        assert_eq!(direction_glyph(170.0), 'v');
        assert_eq!(direction_glyph(f32::NAN), 'v');
    }

    #[test]
    fn uncertainty_bar_is_logarithmic_and_bounded() {
        assert_eq!(uncertainty_fill(0.05), 0);
        assert_eq!(uncertainty_fill(f32::NAN), 0);
        assert_eq!(uncertainty_fill(1e9), UNCERTAINTY_BAR.size.width - 2);
        assert!(uncertainty_fill(1.0) > uncertainty_fill(0.5));
    }
}
