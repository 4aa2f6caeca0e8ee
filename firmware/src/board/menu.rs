//! The settings menu, driven by the two buttons: the sound button (D12) and the mark
//! button (D6).
//!
//! - Outside the menu: a short press of the sound button mutes / unmutes (as before); a
//!   long press ([`LONG_PRESS_MS`]) opens the menu.
//! - In the menu: short press = next item (wrapping), long press = select (change the
//!   item's value, or start its procedure), mark button = leave the menu (the board saves
//!   the settings if they changed).
//!
//! Items: sound volume (0 = mute … 3), search mode (SOGs / classic), region (earth field),
//! step-length calibration walk, magnetometer calibration (rotation in place). The two
//! procedures are started by the board ([`MenuEvent::Start`]), which runs them
//! (`crate::calibration`) and stores the result in the settings' calibration record.

use crate::board::settings::{MAX_VOLUME, REGIONS, SearchMode, Settings};
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::{FONT_6X10, FONT_10X20};
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_graphics::text::{Baseline, Text};

/// Held at least this long (ms), a press is long.
pub const LONG_PRESS_MS: u64 = 800;

/// A press of a button, classified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Press {
    /// Released before [`LONG_PRESS_MS`].
    Short,
    /// Held [`LONG_PRESS_MS`] (reported once, while still held).
    Long,
}

/// Tells short from long presses of a debounced button level, sampled at the tick.
#[derive(Debug, Clone, Copy, Default)]
pub struct PressDetector {
    down_since_ms: Option<u64>,
    long_sent: bool,
}

impl PressDetector {
    /// A detector with the button released.
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds the debounced level (`pressed`) at `now_ms`; returns a press when one is
    /// complete (a short one at its release, a long one when the threshold is reached).
    pub fn update(&mut self, pressed: bool, now_ms: u64) -> Option<Press> {
        match (pressed, self.down_since_ms) {
            (true, None) => {
                self.down_since_ms = Some(now_ms);
                self.long_sent = false;
                None
            }
            (true, Some(t0)) if !self.long_sent && now_ms.saturating_sub(t0) >= LONG_PRESS_MS => {
                self.long_sent = true;
                Some(Press::Long)
            }
            (true, Some(_)) => None,
            (false, Some(_)) => {
                self.down_since_ms = None;
                (!self.long_sent).then_some(Press::Short)
            }
            (false, None) => None,
        }
    }
}

/// A menu item.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Item {
    /// Tone volume.
    Volume,
    /// Search mode.
    Mode,
    /// Region (earth field).
    Region,
    /// Step-length calibration walk.
    StepWalk,
    /// Magnetometer calibration.
    MagCalibration,
}

/// The items in display order.
pub const ITEMS: [Item; 5] = [
    Item::Volume,
    Item::Mode,
    Item::Region,
    Item::StepWalk,
    Item::MagCalibration,
];

/// A procedure the menu asks the board to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Procedure {
    /// Walk a known distance at normal pace: the step length.
    StepWalk,
    /// Turn the receiver through all orientations: hard and soft iron.
    MagCalibration,
}

/// What the board must do after an input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MenuEvent {
    /// Nothing beyond redrawing.
    None,
    /// Outside the menu: toggle mute.
    ToggleMute,
    /// The menu opened.
    Opened,
    /// A setting changed (already applied to the menu's copy).
    Changed,
    /// Run this procedure.
    Start(Procedure),
    /// The menu closed; `changed`: the settings differ from those at opening (save them).
    Closed {
        /// The settings changed while the menu was open.
        changed: bool,
    },
}

/// The menu's state: closed, or open at an item with the settings being edited.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Menu {
    open: Option<usize>,
    settings: Settings,
    at_open: Settings,
}

impl Menu {
    /// A closed menu over `settings`.
    pub fn new(settings: Settings) -> Self {
        Self {
            open: None,
            settings,
            at_open: settings,
        }
    }

    /// The settings as edited.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Replaces the settings (after a procedure stored its result).
    pub fn set_settings(&mut self, s: Settings) {
        self.settings = s;
    }

    /// The highlighted item, when open.
    pub fn item(&self) -> Option<Item> {
        self.open.and_then(|i| ITEMS.get(i).copied())
    }

    /// A press of the sound button.
    pub fn sound_button(&mut self, p: Press) -> MenuEvent {
        match (self.open, p) {
            (None, Press::Short) => MenuEvent::ToggleMute,
            (None, Press::Long) => {
                self.open = Some(0);
                self.at_open = self.settings;
                MenuEvent::Opened
            }
            (Some(i), Press::Short) => {
                self.open = Some((i + 1) % ITEMS.len());
                MenuEvent::None
            }
            (Some(_), Press::Long) => self.select(),
        }
    }

    /// A press of the mark button: leaves the menu (outside it the board marks a victim).
    pub fn mark_button(&mut self) -> Option<MenuEvent> {
        self.open.take().map(|_| MenuEvent::Closed {
            changed: self.settings != self.at_open,
        })
    }

    fn select(&mut self) -> MenuEvent {
        let item = self.item();
        let s = &mut self.settings;
        match item {
            Some(Item::Volume) => {
                s.volume = if s.volume >= MAX_VOLUME {
                    0
                } else {
                    s.volume + 1
                }
            }
            Some(Item::Mode) => {
                s.mode = match s.mode {
                    SearchMode::Sog => SearchMode::Classic,
                    SearchMode::Classic => SearchMode::Sog,
                }
            }
            Some(Item::Region) => {
                s.region = u8::try_from((usize::from(s.region) + 1) % REGIONS.len()).unwrap_or(0)
            }
            Some(Item::StepWalk) => return MenuEvent::Start(Procedure::StepWalk),
            Some(Item::MagCalibration) => return MenuEvent::Start(Procedure::MagCalibration),
            None => return MenuEvent::None,
        }
        MenuEvent::Changed
    }

    /// The open menu's lines for the display: the item's name and its value (`None` when
    /// closed). The value of a procedure item says what a long press does.
    pub fn lines(&self) -> Option<(&'static str, &'static str)> {
        let s = &self.settings;
        Some(match self.item()? {
            Item::Volume => (
                "SOUND",
                ["MUTE", "LOW", "MID", "HIGH"]
                    .get(usize::from(s.volume))
                    .copied()
                    .unwrap_or("HIGH"),
            ),
            Item::Mode => (
                "MODE",
                match s.mode {
                    SearchMode::Sog => "SOGS",
                    SearchMode::Classic => "CLASSIC",
                },
            ),
            Item::Region => (
                "REGION",
                REGIONS.get(usize::from(s.region)).map_or("?", |r| r.name),
            ),
            Item::StepWalk => ("STEP WALK", "HOLD: START"),
            Item::MagCalibration => ("MAG CAL", "HOLD: START"),
        })
    }
}

/// Draws the open menu over a cleared `target`: the item's name, its value large, and
/// what the buttons do. Returns false (and draws nothing) when the menu is closed.
pub fn draw<D: DrawTarget<Color = BinaryColor>>(
    menu: &Menu,
    target: &mut D,
) -> Result<bool, D::Error> {
    let Some((name, value)) = menu.lines() else {
        return Ok(false);
    };
    let small = MonoTextStyle::new(&FONT_6X10, BinaryColor::On);
    let large = MonoTextStyle::new(&FONT_10X20, BinaryColor::On);
    Text::with_baseline(name, Point::new(0, 0), small, Baseline::Top).draw(target)?;
    Text::with_baseline(value, Point::new(0, 18), large, Baseline::Top).draw(target)?;
    Text::with_baseline(
        "D12 next/set  D6 exit",
        Point::new(0, 54),
        small,
        Baseline::Top,
    )
    .draw(target)?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::display::{Frame, lit};
    extern crate std;

    #[test]
    fn presses_are_short_or_long_once() {
        let mut d = PressDetector::new();
        let mut got = std::vec::Vec::new();
        // Short: down 0..300 ms; long: down 1000..2500 ms (reported at 1800 ms, once).
        for t in (0..3000u64).step_by(10) {
            let pressed = t < 300 || (1000..2500).contains(&t);
            if let Some(p) = d.update(pressed, t) {
                got.push((t, p));
            }
        }
        assert_eq!(got, [(300, Press::Short), (1800, Press::Long)]);
    }

    #[test]
    fn the_menu_walks_its_items_changes_values_and_reports_changes() {
        let mut m = Menu::new(Settings::DEFAULT);
        assert_eq!(m.sound_button(Press::Short), MenuEvent::ToggleMute);
        assert_eq!(m.lines(), None);
        assert_eq!(m.mark_button(), None);
        assert_eq!(m.sound_button(Press::Long), MenuEvent::Opened);
        assert_eq!(m.lines(), Some(("SOUND", "HIGH")));
        // Volume wraps to mute.
        assert_eq!(m.sound_button(Press::Long), MenuEvent::Changed);
        assert_eq!(m.lines(), Some(("SOUND", "MUTE")));
        m.sound_button(Press::Short);
        assert_eq!(m.sound_button(Press::Long), MenuEvent::Changed);
        assert_eq!(m.lines(), Some(("MODE", "CLASSIC")));
        m.sound_button(Press::Short);
        m.sound_button(Press::Long);
        assert_eq!(m.lines(), Some(("REGION", "ROCKIES")));
        m.sound_button(Press::Short);
        assert_eq!(
            m.sound_button(Press::Long),
            MenuEvent::Start(Procedure::StepWalk)
        );
        m.sound_button(Press::Short);
        assert_eq!(
            m.sound_button(Press::Long),
            MenuEvent::Start(Procedure::MagCalibration)
        );
        // Next wraps to the first item.
        m.sound_button(Press::Short);
        assert_eq!(m.item(), Some(Item::Volume));
        assert_eq!(m.mark_button(), Some(MenuEvent::Closed { changed: true }));
        let s = *m.settings();
        assert_eq!((s.volume, s.mode, s.region), (0, SearchMode::Classic, 1));
        // Open and close without a change.
        m.sound_button(Press::Long);
        assert_eq!(m.mark_button(), Some(MenuEvent::Closed { changed: false }));
    }

    #[test]
    fn every_item_has_a_label_that_fits_the_display() {
        let mut m = Menu::new(Settings::DEFAULT);
        m.sound_button(Press::Long);
        for _ in ITEMS {
            let (name, value) = m.lines().unwrap();
            // 21 characters of 6 px on the 128 px line.
            assert!(name.len() <= 21 && value.len() <= 21);
            m.sound_button(Press::Short);
        }
    }

    #[test]
    fn draws_only_when_open() {
        let mut m = Menu::new(Settings::DEFAULT);
        let mut closed = Frame::new();
        assert_eq!(draw(&m, &mut closed), Ok(false));
        assert_eq!(lit(&closed).count(), 0);
        assert_eq!(m.sound_button(Press::Long), MenuEvent::Opened);
        let mut open = Frame::new();
        assert_eq!(draw(&m, &mut open), Ok(true));
        // Name, value and the hint line: hundreds of pixels, the hint across the width.
        let (n, right) = (lit(&open).count(), lit(&open).map(|p| p.x).max());
        assert!(n > 200 && right > Some(100), "{n} px to x = {right:?}");
    }
}
