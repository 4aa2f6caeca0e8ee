//! The buttons as a user presses them: debouncing, mute, the menu, a procedure from its
//! start to the settings it changes, and the tone's volume.

use super::*;
use crate::board::settings::SearchMode;
use crate::guidance::Status;
extern crate std;
use std::vec::Vec;

/// Drives the sound button: held for `held_ms` from `*now`, then released for 100 ms,
/// polled every 10 ms; returns the responses that did something.
fn hold(c: &mut Controls, now: &mut u64, held_ms: u64, steps: u32) -> Vec<Response> {
    let mut out = Vec::new();
    let end = *now + held_ms;
    while *now < end + 100 {
        let r = c.sound_button(*now < end, *now, steps);
        if r != Response::default() {
            out.push(r);
        }
        *now += 10;
    }
    out
}

fn short(c: &mut Controls, now: &mut u64) -> Vec<Response> {
    hold(c, now, 200, 0)
}

fn long(c: &mut Controls, now: &mut u64) -> Vec<Response> {
    hold(c, now, 1000, 0)
}

#[test]
fn a_bounce_is_no_press_and_a_short_press_mutes_with_a_chirp_on_unmute() {
    let mut c = Controls::new(Settings::DEFAULT, true);
    let mut now = 0;
    // 20 ms of contact: below the debounce.
    assert!(hold(&mut c, &mut now, 20, 0).is_empty());
    assert!(!c.muted());
    let r = short(&mut c, &mut now);
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].muted, Some(true));
    let model = DisplayModel {
        status: Status::Localized,
        distance_m: Some(5.0),
        ..DisplayModel::default()
    };
    assert_eq!(c.tone(&model, None, now), None);
    let r = short(&mut c, &mut now);
    assert_eq!(r[0].muted, Some(false));
    // The chirp right after the release that unmuted (within CHIRP_MS).
    let released = now - 100 + 10;
    assert_eq!(
        c.tone(&model, None, released),
        Some((sound::CHIRP_HZ, Settings::DEFAULT.volume))
    );
}

#[test]
fn the_menu_changes_volume_and_mode_and_closing_asks_for_a_rebuild_only_when_needed() {
    let mut c = Controls::new(Settings::DEFAULT, true);
    let mut now = 0;
    assert!(long(&mut c, &mut now)[0].redraw);
    assert!(c.open_menu().is_some());
    // SOUND: HIGH → MUTE → LOW.
    long(&mut c, &mut now);
    long(&mut c, &mut now);
    assert_eq!(c.menu().settings().volume, 1);
    // A tone plays at the volume being chosen.
    let model = DisplayModel {
        status: Status::Localized,
        distance_m: Some(1.0),
        ..DisplayModel::default()
    };
    let playing = (0..2000)
        .step_by(10)
        .find_map(|t| c.tone(&model, None, now + t));
    assert_eq!(playing.map(|p| p.1), Some(1));
    // Leave: volume only, no rebuild.
    let r = c.mark_button(0);
    assert_eq!(
        r.closed,
        Some(Closed {
            settings: Settings {
                volume: 1,
                ..Settings::DEFAULT
            },
            rebuild: false
        })
    );
    // Again: MODE → CLASSIC, leave: rebuild.
    long(&mut c, &mut now);
    short(&mut c, &mut now);
    long(&mut c, &mut now);
    let r = c.mark_button(0);
    let closed = r.closed.unwrap_or_else(|| panic!("{r:?}"));
    assert_eq!(closed.settings.mode, SearchMode::Classic);
    assert!(closed.rebuild);
    c.rebuilt(&closed.settings);
    // Open and close without a change: nothing to store.
    long(&mut c, &mut now);
    assert_eq!(c.mark_button(0).closed, None);
    // Outside the menu the mark button marks a victim.
    assert!(c.mark_button(0).mark_victim);
}

#[test]
fn a_step_walk_from_the_menu_ends_in_the_settings_to_store() {
    let mut c = Controls::new(Settings::DEFAULT, true);
    let mut now = 0;
    long(&mut c, &mut now);
    for _ in 0..3 {
        short(&mut c, &mut now);
    }
    // STEP WALK, started at 100 steps.
    let r = hold(&mut c, &mut now, 1000, 100);
    assert_eq!(r[0].calibration, Some(("step_walk", "start", None)));
    assert_eq!(c.procedure(125), Some((Procedure::StepWalk, 25)));
    // The mark button at 128 steps: 28 steps over 20 m.
    let r = c.mark_button(128);
    let len = procedure::WALK_DISTANCE_M / 28.0;
    assert_eq!(r.calibration, Some(("step_walk", "done", Some(len))));
    assert!(matches!(c.outcome(), Some(Outcome::StepLength { .. })));
    assert!(!r.mark_victim && r.closed.is_none());
    // Dismiss the outcome, then leave: the new step length rebuilds and is stored.
    assert!(c.mark_button(128).closed.is_none());
    assert_eq!(c.outcome(), None);
    let closed = c
        .mark_button(128)
        .closed
        .unwrap_or_else(|| panic!("not closed"));
    assert_eq!(closed.settings.calibration.step_length_m, Some(len));
    assert!(closed.rebuild);
}

#[test]
fn a_procedure_is_cancelled_by_a_short_press_and_changes_nothing() {
    let mut c = Controls::new(Settings::DEFAULT, true);
    let mut now = 0;
    long(&mut c, &mut now);
    for _ in 0..4 {
        short(&mut c, &mut now);
    }
    let r = long(&mut c, &mut now);
    assert_eq!(r[0].calibration, Some(("mag_cal", "start", None)));
    // A long press while it runs does nothing; a short one cancels.
    assert!(
        long(&mut c, &mut now)
            .iter()
            .all(|r| r.calibration.is_none())
    );
    let r = short(&mut c, &mut now);
    assert_eq!(r[0].calibration, Some(("mag_cal", "cancelled", None)));
    assert_eq!(c.procedure(0), None);
    assert_eq!(c.mark_button(0).closed, None);
}
