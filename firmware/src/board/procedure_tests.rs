//! The menu's procedures: a step walk and a magnetometer calibration from start to the
//! settings they change, and their failures.

use super::*;
use crate::Mat3;
use crate::board::menu::{Menu, MenuEvent, Press};
use crate::display::{Frame, lit};
use crate::frame::rotation_from_rpy;

#[test]
fn a_step_walk_sets_the_step_length_in_the_settings() {
    let r = match Running::start(Procedure::StepWalk, 120, 48.0) {
        Ok(r) => r,
        Err(e) => panic!("{e}"),
    };
    assert_eq!(r.procedure(), Procedure::StepWalk);
    assert_eq!(r.progress(140), 20);
    // 28 steps over 20 m.
    let out = r.finish(148);
    assert_eq!(
        out,
        Outcome::StepLength {
            length_m: WALK_DISTANCE_M / 28.0,
            steps: 28
        }
    );
    let mut s = Settings::DEFAULT;
    assert!(apply(&out, &mut s));
    assert_eq!(s.calibration.step_length_m, Some(20.0 / 28.0));
    assert_eq!(out.word(), "done");
}

#[test]
fn a_short_or_implausible_walk_changes_nothing() {
    let Ok(r) = Running::start(Procedure::StepWalk, 0, 48.0) else {
        panic!("start refused");
    };
    // 5 steps: too few; 100 steps over 20 m: 0.2 m, shorter than a step can be.
    for (steps, word) in [(5, "too few steps"), (100, "bad length")] {
        let out = r.finish(steps);
        assert_eq!(out.word(), word, "{out:?}");
        let mut s = Settings::DEFAULT;
        assert!(!apply(&out, &mut s));
        assert_eq!(s, Settings::DEFAULT);
    }
}

/// Raw readings of a unit with hard iron `b` and soft iron `d`, turned through a
/// figure-of-eight tumble in the field `earth`.
fn tumble(r: &mut Running, earth: &Vec3, b: &Vec3, d: &Mat3, n: usize) {
    for k in 0..n {
        let s = k as f32 / n as f32;
        let tau = 2.0 * core::f32::consts::PI;
        let rpy = Vec3::new(
            core::f32::consts::PI * libm::sinf(3.0 * tau * s),
            1.4 * libm::sinf(5.0 * tau * s + 0.3),
            2.0 * tau * s,
        );
        let m = rotation_from_rpy(&rpy).transpose() * earth;
        r.on_mag(&(d * m + b));
    }
}

#[test]
fn a_magnetometer_calibration_from_the_menu_lands_in_the_stored_settings() {
    // The menu: open, step to MAG CAL, start it.
    let mut menu = Menu::new(Settings::DEFAULT);
    assert_eq!(menu.sound_button(Press::Long), MenuEvent::Opened);
    for _ in 0..4 {
        menu.sound_button(Press::Short);
    }
    let MenuEvent::Start(p) = menu.sound_button(Press::Long) else {
        panic!("no procedure started");
    };
    let earth = menu.settings().earth_field();
    let Ok(mut r) = Running::start(p, 0, earth.norm()) else {
        panic!("start refused");
    };
    let b = Vec3::new(12.0, -7.0, 3.0);
    let d = Mat3::new(1.05, 0.02, 0.0, 0.02, 0.97, 0.01, 0.0, 0.01, 1.01);
    tumble(&mut r, &earth, &b, &d, 1500);
    r.on_mag(&Vec3::new(f32::NAN, 0.0, 0.0));
    assert_eq!(r.progress(0), 1500);
    let out = r.finish(0);
    let Outcome::Mag(fit) = out else {
        panic!("{out:?}");
    };
    assert!((fit.calibration.hard_iron - b).norm() < 0.05, "{fit:?}");
    let mut s = *menu.settings();
    assert!(apply(&out, &mut s));
    menu.set_settings(s);
    // Leaving the menu now reports a change: the board stores the settings.
    assert_eq!(
        menu.mark_button(),
        Some(MenuEvent::Closed { changed: true })
    );
    let stored = crate::board::settings::Settings::decode(&menu.settings().encode());
    assert_eq!(stored.map(|s| s.calibration.mag), Ok(Some(fit.calibration)));
}

#[test]
fn a_magnetometer_calibration_without_turning_fails_with_its_reason() {
    let earth = Vec3::new(21.8, 0.0, -42.8);
    let Ok(mut r) = Running::start(Procedure::MagCalibration, 0, earth.norm()) else {
        panic!("start refused");
    };
    assert_eq!(r.finish(0).word(), "too few");
    // Held still: 500 identical readings.
    for _ in 0..500 {
        r.on_mag(&earth);
    }
    let out = r.finish(0);
    assert!(matches!(out, Outcome::MagFailed(_)), "{out:?}");
    let mut s = Settings::DEFAULT;
    assert!(!apply(&out, &mut s));
    // A non-positive field cannot start it.
    assert!(Running::start(Procedure::MagCalibration, 0, 0.0).is_err());
}

#[test]
fn the_screens_show_progress_and_outcome() {
    let mut a = Frame::new();
    let mut b = Frame::new();
    assert_eq!(draw(Procedure::StepWalk, 3, &mut a), Ok(()));
    assert_eq!(draw(Procedure::StepWalk, 38, &mut b), Ok(()));
    // One more digit: more pixels.
    let (a, b) = (lit(&a).count(), lit(&b).count());
    assert!(a > 150 && b > a, "{a} {b}");
    let mut c = Frame::new();
    let out = Outcome::StepLength {
        length_m: 0.71,
        steps: 28,
    };
    assert_eq!(draw_outcome(&out, &mut c), Ok(()));
    assert!(lit(&c).count() > 150);
}
