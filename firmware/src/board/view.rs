//! What the board's display task draws: the newest [`View`] the processing task handed
//! over (the newest wins), drawn over a cleared screen by [`draw`] — a procedure's
//! outcome, else the running procedure, else the open menu, else the search screen with
//! the health overlay (fault box, battery gauge, SD mark).

use crate::app::DisplayModel;
use crate::board::health::{self, BatteryState, Fault};
use crate::board::menu::{self, Menu, Procedure};
use crate::board::procedure::{self, Outcome};
use crate::display;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;

/// One screen's content.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// The search screen's model.
    pub model: DisplayModel,
    /// The sensor fault shown over the status word.
    pub fault: Option<Fault>,
    /// The battery gauge.
    pub battery: Option<BatteryState>,
    /// The menu, when open (drawn instead of the search screen).
    pub menu: Option<Menu>,
    /// A procedure running, with its progress (drawn instead of the menu).
    pub procedure: Option<(Procedure, u32)>,
    /// How the last procedure ended, until the next press (drawn instead of all else).
    pub outcome: Option<Outcome>,
}

/// Draws `view` on a cleared `target`; `sd` is the SD card's word for the bottom line
/// (`NO SD`, `SD ERR`; `None` while it logs).
pub fn draw<D: DrawTarget<Color = BinaryColor>>(
    view: &View,
    sd: Option<&str>,
    target: &mut D,
) -> Result<(), D::Error> {
    if let Some(o) = &view.outcome {
        return procedure::draw_outcome(o, target);
    }
    if let Some((p, progress)) = view.procedure {
        return procedure::draw(p, progress, target);
    }
    if let Some(m) = &view.menu {
        return menu::draw(m, target).map(|_| ());
    }
    display::draw(&view.model, target)?;
    health::draw_overlay(view.fault, view.battery, target)?;
    health::draw_sd_mark(sd, target)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::menu::{MenuEvent, Press};
    use crate::board::settings::Settings;
    use crate::display::{Frame, lit};

    fn frame(view: &View, sd: Option<&str>) -> Frame {
        let mut f = Frame::new();
        assert_eq!(draw(view, sd, &mut f), Ok(()));
        f
    }

    #[test]
    fn the_outcome_then_the_procedure_then_the_menu_then_the_search_screen() {
        let mut m = Menu::new(Settings::DEFAULT);
        assert_eq!(m.sound_button(Press::Long), MenuEvent::Opened);
        let out = Outcome::StepLength {
            length_m: 0.7,
            steps: 29,
        };
        let search = View {
            model: DisplayModel::default(),
            fault: None,
            battery: None,
            menu: None,
            procedure: None,
            outcome: None,
        };
        let with_menu = View {
            menu: Some(m),
            ..search
        };
        let with_procedure = View {
            procedure: Some((Procedure::StepWalk, 12)),
            ..with_menu
        };
        let with_outcome = View {
            outcome: Some(out),
            ..with_procedure
        };
        // Each screen is exactly what its own drawing gives.
        let mut want = Frame::new();
        assert_eq!(procedure::draw_outcome(&out, &mut want), Ok(()));
        assert!(frame(&with_outcome, None) == want);
        let mut want = Frame::new();
        assert_eq!(procedure::draw(Procedure::StepWalk, 12, &mut want), Ok(()));
        assert!(frame(&with_procedure, None) == want);
        let mut want = Frame::new();
        assert_eq!(menu::draw(&m, &mut want), Ok(true));
        assert!(frame(&with_menu, None) == want);
        // The search screen carries the SD mark; the menu does not.
        let plain = frame(&search, None);
        let marked = frame(&search, Some("NO SD"));
        assert!(lit(&marked).count() > lit(&plain).count());
        assert!(frame(&with_menu, Some("NO SD")) == frame(&with_menu, None));
    }
}
