//! The board's two buttons and what they drive, polled at the 100 Hz tick by the
//! processing task: the sound button (debounced, short and long presses: mute, the menu),
//! the mark button (mark a victim, or leave the menu / end a procedure / dismiss its
//! outcome), the menu's procedures ([`crate::board::procedure`]), and the tone of the
//! moment with its volume. The board binary only reads the pins and carries out the
//! [`Response`]s (log records, the flash save, the receiver's rebuild, a victim marked).

use crate::Vec3;
use crate::app::DisplayModel;
use crate::board::health::Fault;
use crate::board::menu::{Menu, MenuEvent, Press, PressDetector, Procedure};
use crate::board::procedure::{self, Outcome, Running};
use crate::board::settings::Settings;
use crate::board::sound::{self, SoundInput};

/// Polls in a row a button must read pressed (30 ms at 100 Hz: past a switch's bounce).
pub const DEBOUNCE_POLLS: u8 = 3;

/// The menu closed with changed settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Closed {
    /// The settings to apply and store.
    pub settings: Settings,
    /// The mode, region or step length changed: the receiver must be rebuilt (a new
    /// search; the board calls [`Controls::rebuilt`] when it was).
    pub rebuild: bool,
}

/// What the board must do after a button poll.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Response {
    /// The screen changed.
    pub redraw: bool,
    /// A `calibration` event: `step_walk` / `mag_cal`, `start` / `cancelled` / the
    /// outcome's word, the value (step length m or residual µT).
    pub calibration: Option<(&'static str, &'static str, Option<f32>)>,
    /// The menu closed with changed settings.
    pub closed: Option<Closed>,
    /// The mark button marks the victim being guided to (outside the menu).
    pub mark_victim: bool,
    /// Sound toggled by the button: `Some(muted)`.
    pub muted: Option<bool>,
}

/// The buttons' state.
#[derive(Debug, Clone)]
pub struct Controls {
    low_polls: u8,
    press: PressDetector,
    menu: Menu,
    muted: bool,
    chirp_until_ms: u64,
    procedure: Option<Running>,
    outcome: Option<Outcome>,
    applied: Settings,
}

/// The log's word for a menu procedure.
pub fn procedure_word(p: Procedure) -> &'static str {
    match p {
        Procedure::StepWalk => "step_walk",
        Procedure::MagCalibration => "mag_cal",
    }
}

impl Controls {
    /// Buttons released, the menu closed over `settings` (those the receiver was built
    /// with); sound on unless `sound_on` is false or the volume is 0.
    pub fn new(settings: Settings, sound_on: bool) -> Self {
        Self {
            low_polls: 0,
            press: PressDetector::new(),
            menu: Menu::new(settings),
            muted: !sound_on || settings.volume == 0,
            chirp_until_ms: 0,
            procedure: None,
            outcome: None,
            applied: settings,
        }
    }

    /// The menu (open or not).
    pub fn menu(&self) -> &Menu {
        &self.menu
    }

    /// The menu when open, for the screen.
    pub fn open_menu(&self) -> Option<Menu> {
        self.menu.item().map(|_| self.menu)
    }

    /// The running procedure and its progress at `total_steps`, for the screen.
    pub fn procedure(&self, total_steps: u32) -> Option<(Procedure, u32)> {
        self.procedure
            .as_ref()
            .map(|r| (r.procedure(), r.progress(total_steps)))
    }

    /// The last procedure's outcome, until the next press.
    pub fn outcome(&self) -> Option<Outcome> {
        self.outcome
    }

    /// Whether the sound is off.
    pub fn muted(&self) -> bool {
        self.muted
    }

    /// The board rebuilt the receiver for `s`.
    pub fn rebuilt(&mut self, s: &Settings) {
        self.applied = *s;
    }

    /// A raw magnetometer reading (the calibration, when it runs).
    pub fn on_mag(&mut self, raw: &Vec3) {
        if let Some(p) = self.procedure.as_mut() {
            p.on_mag(raw);
        }
    }

    /// The sound button's level at a tick (`low`: pressed), at `now_ms`, with
    /// `total_steps` steps counted so far (a step walk starts from it; the magnetometer
    /// calibration takes the menu's region's field as its scale).
    pub fn sound_button(&mut self, low: bool, now_ms: u64, total_steps: u32) -> Response {
        self.low_polls = if low {
            self.low_polls.saturating_add(1)
        } else {
            0
        };
        let mut r = Response::default();
        let Some(press) = self.press.update(self.low_polls >= DEBOUNCE_POLLS, now_ms) else {
            return r;
        };
        r.redraw = true;
        // An outcome on screen: any press takes it away. A procedure running: a short
        // press cancels it.
        if self.outcome.take().is_some() {
            return r;
        }
        if let Some(p) = self.procedure.as_ref() {
            if press == Press::Short {
                r.calibration = Some((procedure_word(p.procedure()), "cancelled", None));
                self.procedure = None;
            }
            return r;
        }
        match self.menu.sound_button(press) {
            MenuEvent::ToggleMute => {
                self.muted = !self.muted;
                if !self.muted {
                    self.chirp_until_ms = now_ms + sound::CHIRP_MS;
                }
                r.muted = Some(self.muted);
                r.redraw = false;
            }
            MenuEvent::Start(p) => {
                let field = self.menu.settings().earth_field().norm();
                // Refused only for a field that is not positive: no region has one.
                if let Ok(run) = Running::start(p, total_steps, field) {
                    self.procedure = Some(run);
                    r.calibration = Some((procedure_word(p), "start", None));
                }
            }
            MenuEvent::Closed { changed } => r.closed = self.closed(changed),
            MenuEvent::Opened | MenuEvent::Changed | MenuEvent::None => {}
        }
        r
    }

    /// A press of the mark button, with `total_steps` steps counted so far.
    pub fn mark_button(&mut self, total_steps: u32) -> Response {
        let mut r = Response {
            redraw: true,
            ..Response::default()
        };
        if self.outcome.take().is_some() {
            // The outcome was read: back to the menu.
        } else if let Some(p) = self.procedure.take() {
            let out = p.finish(total_steps);
            let mut s = *self.menu.settings();
            if procedure::apply(&out, &mut s) {
                self.menu.set_settings(s);
            }
            let value = match out {
                Outcome::StepLength { length_m, .. } => Some(length_m),
                Outcome::Mag(fit) => Some(fit.residual_rms_ut),
                Outcome::WalkFailed(_) | Outcome::MagFailed(_) => None,
            };
            r.calibration = Some((procedure_word(p.procedure()), out.word(), value));
            self.outcome = Some(out);
        } else if let Some(MenuEvent::Closed { changed }) = self.menu.mark_button() {
            r.closed = self.closed(changed);
        } else {
            r.mark_victim = true;
        }
        r
    }

    /// The menu closed: changed settings apply (volume 0 mutes) and are handed on.
    fn closed(&mut self, changed: bool) -> Option<Closed> {
        if !changed {
            return None;
        }
        let s = *self.menu.settings();
        self.muted = s.volume == 0;
        let a = &self.applied;
        let rebuild = (s.mode, s.region, s.calibration.step_length_m)
            != (a.mode, a.region, a.calibration.step_length_m);
        Some(Closed {
            settings: s,
            rebuild,
        })
    }

    /// The tone of the moment for the screen's `model` and `fault` at `now_ms`, with the
    /// volume step to play it at (the menu's: a change is heard while it is chosen; the
    /// sound button's "on" plays at least the lowest step).
    pub fn tone(
        &self,
        model: &DisplayModel,
        fault: Option<Fault>,
        now_ms: u64,
    ) -> Option<(u32, u8)> {
        let hz = if now_ms < self.chirp_until_ms {
            Some(sound::CHIRP_HZ)
        } else {
            sound::tone_at(
                &SoundInput {
                    status: model.status,
                    distance_m: model.distance_m,
                    fault,
                    muted: self.muted,
                },
                now_ms,
            )
        };
        hz.map(|hz| (hz, self.menu.settings().volume.max(1)))
    }
}

#[cfg(test)]
#[path = "controls_tests.rs"]
mod tests;
