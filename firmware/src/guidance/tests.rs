//! Tests of the search control (`super`).

use super::*;
use crate::Mat3;
use crate::frame::wrap_pi;
use core::f32::consts::{FRAC_PI_2, PI};

fn est(p: Vec3, sigma: f32) -> VictimEstimate {
    VictimEstimate {
        p,
        cov: Mat3::from_diagonal(&Vec3::new(sigma * sigma, sigma * sigma, 0.04)),
        moment: Vec3::new(0.0, 0.0, 0.02),
        scale: 1.0,
        scale_sigma: 0.02,
        rpy: Vec3::zeros(),
        n_components: 1,
        max_weight: 1.0,
    }
}

fn input(h: Vec3, walked: f32, yaw: f32, e: Option<VictimEstimate>) -> GuidanceInput {
    GuidanceInput {
        h_g: Some(h),
        walked_m: walked,
        yaw,
        yaw_var: 0.0,
        estimate: e,
        reinitialized: false,
        signal_lost: false,
        height_m: None,
        lower_allowed: true,
    }
}

/// A fresh guidance localized from 30 m away (a concentrated belief there, so that a mean
/// near the receiver is trusted later).
fn localized(cfg: GuidanceConfig) -> Guidance {
    let mut g = Guidance::new(cfg);
    let far = est(Vec3::new(30.0, 0.0, -2.0), 2.0);
    let o = g.update(&input(Vec3::new(1e-4, 0.0, 0.0), 1.0, 0.0, Some(far)));
    assert_eq!(o.status, Status::Localized);
    g
}

#[test]
fn flux_sign_follows_the_heading_then_the_previous_direction() {
    let mut g = Guidance::new(GuidanceConfig::default());
    // Facing north, field along ±north: walk north whatever the pulse's sign.
    let o = g.update(&input(Vec3::new(-1e-6, 0.0, 3e-7), 0.0, 0.0, None));
    assert_eq!(o.status, Status::FluxLine);
    assert!(o.bearing.is_some_and(|b| b.abs() < 1e-5));
    // The next pulse with the opposite sign and slightly turned keeps going north-ish.
    let o = g.update(&input(Vec3::new(1.1e-6, -1e-7, 0.0), 1.0, 0.3, None));
    let b = o.bearing.unwrap_or(PI);
    assert!(b.abs() < 0.2, "bearing {b}");
    // Arrow relative to the device: yaw 0.3 rad, bearing ≈ -0.09 → to the right.
    assert!(
        o.arrow
            .is_some_and(|a| a < 0.0 && (a - (b - 0.3)).abs() < 1e-5)
    );
    // Facing south first picks the southern sign.
    let mut g = Guidance::new(GuidanceConfig::default());
    let o = g.update(&input(Vec3::new(1e-6, 0.0, 0.0), 0.0, PI, None));
    assert!(o.bearing.is_some_and(|b| (b.abs() - PI).abs() < 1e-5));
}

#[test]
fn flux_direction_flips_when_the_signal_falls_over_five_metres() {
    let mut g = Guidance::new(GuidanceConfig::default());
    let mut h = 1e-6;
    let mut bearing = 0.0;
    for _ in 0..7 {
        let o = g.update(&input(Vec3::new(h, 0.0, 0.0), 1.0, 0.0, None));
        bearing = o.bearing.unwrap_or(f32::NAN);
        h *= 0.9; // walking away: falling signal
    }
    assert!(
        (bearing.abs() - PI).abs() < 1e-5,
        "turned around: {bearing}"
    );
    // A growing signal never flips.
    let mut g = Guidance::new(GuidanceConfig::default());
    for k in 0..20 {
        let o = g.update(&input(
            Vec3::new(1e-7 * (1.0 + k as f32), 0.0, 0.0),
            1.0,
            0.0,
            None,
        ));
        assert!(o.bearing.is_some_and(|b| b.abs() < 1e-5));
    }
}

#[test]
fn a_weak_signal_lost_on_the_flux_line_turns_the_direction_back() {
    let cfg = GuidanceConfig::default();
    // Walking north along a flux line at the edge of reception (|H| ≈ 5 σ_bkg):
    // the pulses stop, the rescuer turns back on "no signal", the pulses return.
    let weak = 5.0 * cfg.sigma_bkg;
    let walk_out = |g: &mut Guidance| {
        for _ in 0..4 {
            let o = g.update(&input(Vec3::new(weak, 0.0, 0.0), 1.0, 0.0, None));
            assert!(o.bearing.is_some_and(|b| b.abs() < 1e-5));
        }
    };
    let back = |lost: bool, h: f32| GuidanceInput {
        signal_lost: lost,
        ..input(Vec3::new(h, 0.0, 0.0), 4.0, PI, None)
    };
    let mut g = Guidance::new(cfg);
    walk_out(&mut g);
    let o = g.update(&back(true, weak));
    assert!(
        o.bearing.is_some_and(|b| (b.abs() - PI).abs() < 1e-5),
        "sent back south: {:?}",
        o.bearing
    );
    // Without the loss the old direction holds (the 5 m rule has not fired).
    let mut g = Guidance::new(cfg);
    walk_out(&mut g);
    assert!(
        g.update(&back(false, weak))
            .bearing
            .is_some_and(|b| b.abs() < 1e-5)
    );
    // A strong signal is not lost by walking a few metres: the direction holds.
    let mut g = Guidance::new(cfg);
    for _ in 0..4 {
        let _ = g.update(&input(Vec3::new(1e-6, 0.0, 0.0), 1.0, 0.0, None));
    }
    assert!(
        g.update(&back(true, 1e-6))
            .bearing
            .is_some_and(|b| b.abs() < 1e-5)
    );
}

#[test]
fn a_vertical_field_keeps_the_heading_and_no_pulse_gives_no_signal() {
    let mut g = Guidance::new(GuidanceConfig::default());
    // No horizontal direction: straight on along the device's heading (yaw 0.3).
    let o = g.update(&input(Vec3::new(0.0, 0.0, 1e-6), 0.0, 0.3, None));
    assert_eq!(o.status, Status::FluxLine);
    assert!(o.arrow.is_some_and(|a| a.abs() < 1e-5), "{:?}", o.arrow);
    assert!(o.bearing.is_some_and(|b| (b - 0.3).abs() < 1e-5));
    let o = g.update(&GuidanceInput {
        h_g: None,
        walked_m: 0.0,
        yaw: 0.0,
        yaw_var: 0.0,
        estimate: None,
        reinitialized: false,
        signal_lost: false,
        height_m: None,
        lower_allowed: true,
    });
    assert_eq!(o, GuidanceOutput::default());
    // NaNs are ignored rather than propagated.
    let o = g.update(&input(
        Vec3::new(f32::NAN, 1.0, 0.0),
        f32::NAN,
        f32::NAN,
        None,
    ));
    assert_eq!(o.status, Status::NoSignal);
}

#[test]
fn a_horizontal_field_within_the_noise_does_not_steer_the_flux_line() {
    let cfg = GuidanceConfig::default();
    let sigma = cfg.sigma_bkg;
    let mut g = Guidance::new(cfg);
    // A clear horizontal field along x (20 σ) sets the direction.
    let o = g.update(&input(Vec3::new(20.0 * sigma, 0.0, 0.0), 1.0, 0.0, None));
    assert!(o.bearing.is_some_and(|b| b.abs() < 1e-3), "{:?}", o.bearing);
    // Then a near-vertical field of the same strength (no flip) whose horizontal part
    // (1.5 σ, along y) is below flux_min_snr × the reading σ (1.17 σ at 20 σ): the
    // direction is held, over many pulses.
    let vertical = |horizontal: f32| libm::sqrtf(400.0 - horizontal * horizontal) * sigma;
    let weak = Vec3::new(0.0, 1.5 * sigma, vertical(1.5));
    for _ in 0..10 {
        let o = g.update(&input(weak, 1.0, 0.0, None));
        assert_eq!(o.status, Status::FluxLine);
        assert!(o.bearing.is_some_and(|b| b.abs() < 1e-3), "{:?}", o.bearing);
    }
    // The same horizontal part at 4 σ steers again (toward ±y).
    let clear = Vec3::new(0.0, 4.0 * sigma, vertical(4.0));
    let mut b = 0.0;
    for _ in 0..10 {
        b = g
            .update(&input(clear, 1.0, 0.0, None))
            .bearing
            .unwrap_or(0.0);
    }
    assert!((b.abs() - FRAC_PI_2).abs() < 0.05, "{b}");
}

#[test]
fn switches_to_the_mean_when_far_in_mahalanobis_distance_and_latches() {
    let mut g = Guidance::new(GuidanceConfig::default());
    let h = Vec3::new(1e-6, 0.0, 0.0);
    // Broad belief around the receiver: keep following the flux line.
    let o = g.update(&input(
        h,
        1.0,
        0.0,
        Some(est(Vec3::new(5.0, 5.0, -2.0), 10.0)),
    ));
    assert_eq!(o.status, Status::FluxLine);
    assert!(o.distance_m.is_none() && o.sigma_h_m.is_some());
    // Concentrated and 3σ away: go to the mean (to the west = 90° left).
    let o = g.update(&input(
        h,
        1.0,
        0.0,
        Some(est(Vec3::new(0.0, 20.0, -2.0), 2.0)),
    ));
    assert_eq!(o.status, Status::Localized);
    assert!(o.arrow.is_some_and(|a| (a - FRAC_PI_2).abs() < 1e-5));
    assert!(
        o.distance_m
            .is_some_and(|d| (d - 404f32.sqrt()).abs() < 1e-3)
    );
    assert!(o.depth_m.is_none());
    // Latched while walking in (the receiver falls inside the ellipse).
    let o = g.update(&input(
        h,
        1.0,
        FRAC_PI_2,
        Some(est(Vec3::new(0.0, 2.5, -2.0), 1.0)),
    ));
    assert_eq!(o.status, Status::Localized);
    assert!(o.arrow.is_some_and(|a| a.abs() < 1e-5));
    assert!(o.depth_m.is_some_and(|d| (d - 1.0).abs() < 1e-5));
    // A re-initialized mixture drops back to the flux line.
    let mut i = input(h, 1.0, 0.0, Some(est(Vec3::new(0.0, 2.5, -2.0), 30.0)));
    i.reinitialized = true;
    assert_eq!(g.update(&i).status, Status::FluxLine);
}

#[test]
fn probe_needs_a_tight_belief_right_below_for_two_pulses() {
    let mut g = localized(GuidanceConfig::default());
    let h = Vec3::new(1e-4, 0.0, 0.0);
    // Close but 0.7 m off (beyond reach): not yet.
    let o = g.update(&input(
        h,
        1.0,
        0.0,
        Some(est(Vec3::new(0.7, 0.0, -2.0), 0.05)),
    ));
    assert_eq!(o.status, Status::Localized);
    // Within 0.3 m and 3σ = 0.15 m: first pulse confirms, the second probes.
    let e = Some(est(Vec3::new(0.2, 0.0, -2.2), 0.05));
    assert_eq!(g.update(&input(h, 0.5, 0.0, e)).status, Status::Localized);
    let o = g.update(&input(h, 0.0, 0.0, e));
    assert_eq!(o.status, Status::Probe);
    assert!(o.depth_m.is_some_and(|d| (d - 1.2).abs() < 1e-4));
    assert!(o.arrow.is_some_and(|a| a.abs() < 1e-5));
    // Latched.
    let e = Some(est(Vec3::new(0.35, 0.0, -2.2), 0.05));
    assert_eq!(g.update(&input(h, 0.0, 0.0, e)).status, Status::Probe);
}

#[test]
fn an_uncertain_depth_over_the_mean_asks_for_a_lift_before_probing() {
    let cfg = GuidanceConfig::default();
    let mut g = localized(cfg);
    let h = Vec3::new(1e-4, 0.0, 0.0);
    let mut wide = est(Vec3::new(0.1, 0.0, -2.2), 0.05);
    wide.cov[(2, 2)] = 0.3 * 0.3;
    // Far from the mean: no lift even with a wide depth.
    let mut far = wide;
    far.p.x = 2.0;
    assert!(!g.update(&input(h, 1.0, 0.0, Some(far))).lift);
    // Over it: lift (no probe meanwhile), at most `lift_max_pulses` times.
    for _ in 0..cfg.lift_max_pulses {
        let o = g.update(&input(h, 0.0, 0.0, Some(wide)));
        assert!(o.lift && o.status == Status::Localized);
    }
    let o = g.update(&input(h, 0.0, 0.0, Some(wide)));
    assert!(!o.lift && o.status == Status::Probe);
    // A pinned depth probes without a lift.
    let mut g = localized(cfg);
    let mut tight = wide;
    tight.cov[(2, 2)] = 0.1 * 0.1;
    assert!(!g.update(&input(h, 0.0, 0.0, Some(tight))).lift);
    assert_eq!(
        g.update(&input(h, 0.0, 0.0, Some(tight))).status,
        Status::Probe
    );
}

/// The probe thresholds the fine-search tests' σ values are placed against (radius
/// 0.3 m, plateau ceiling 0.15 m); the rules' logic does not depend on the values.
fn probe_rule_03() -> GuidanceConfig {
    GuidanceConfig {
        probe_radius_m: 0.3,
        probe_plateau_max_sigma_m: 0.15,
        ..GuidanceConfig::default()
    }
}

#[test]
fn over_a_wide_mean_the_arrow_brackets_it_then_times_out() {
    // A fixed 0.5 m offset (the range-scaled one has its own test).
    let cfg = GuidanceConfig {
        bracket_range_ratio: 0.0,
        ..probe_rule_03()
    };
    let mut g = localized(cfg);
    let h = Vec3::new(1e-4, 0.0, 0.0);
    // Over the mean (0.1 m) but σ = 0.4 m: bracket, no probe yet; the same side
    // until the receiver has reached it.
    let e = Some(est(Vec3::new(0.1, 0.0, -2.0), 0.4));
    let a = g.update(&input(h, 0.0, 0.0, e));
    let b = g.update(&input(h, 0.0, 0.0, e));
    assert_eq!(a.status, Status::Localized);
    let (ba, bb) = (a.bearing.unwrap_or(9.0), b.bearing.unwrap_or(9.0));
    assert!(wrap_pi(ba - bb).abs() < 1e-5, "{ba} {bb}");
    assert!(
        a.walk_m
            .is_some_and(|w| (w - 0.6).abs() < 1e-4 || (w - 0.4).abs() < 1e-4)
    );
    // At the bracketing point (0.5 m beyond the mean): back across the mean to the
    // other side.
    let side = [libm::cosf(ba), libm::sinf(ba)];
    let at = |k: f32| Some(est(Vec3::new(0.1 - k * side[0], -k * side[1], -2.0), 0.4));
    let c = g.update(&input(h, 0.5, 0.0, at(b.walk_m.unwrap_or(0.0))));
    let bc = c.bearing.unwrap_or(9.0);
    assert!((wrap_pi(bc - ba).abs() - PI).abs() < 0.05, "{ba} {bc}");
    let d = g.update(&input(h, 0.5, 0.0, e));
    let bd = d.bearing.unwrap_or(9.0);
    assert!((wrap_pi(bd - ba).abs() - PI).abs() < 1e-3, "{ba} {bd}");
    // Standing over the mean, it times out into "probe here".
    let mut n = 0;
    let mut last = d.status;
    while last != Status::Probe && n < 100 {
        last = g.update(&input(h, 0.0, 0.0, e)).status;
        n += 1;
    }
    assert_eq!(last, Status::Probe);
    // The pulses before the loop that were within reach of the mean count too (a, b
    // and d; c if the bracketing point lay within reach).
    let before = [a, b, c, d]
        .iter()
        .filter(|o| {
            o.horizontal_m
                .is_some_and(|h| h <= cfg.probe_reach_m.max(0.4))
        })
        .count();
    assert_eq!(n + before, usize::from(cfg.probe_timeout_pulses));
}

/// Pulses standing over a mean 0.2 m away until "probe here" (at most 40), with the
/// horizontal σ of pulse k given by `sigma(k)`.
fn pulses_to_probe(g: &mut Guidance, sigma: impl Fn(usize) -> f32) -> Option<usize> {
    let h = Vec3::new(1e-4, 0.0, 0.0);
    (0..40).find(|&k| {
        let e = est(Vec3::new(0.2, 0.0, -2.0), sigma(k));
        g.update(&input(h, 0.0, 0.0, Some(e))).status == Status::Probe
    })
}

#[test]
fn the_bracketing_offset_grows_with_the_range_between_one_and_two_steps() {
    let cfg = probe_rule_03();
    let h = Vec3::new(1e-4, 0.0, 0.0);
    // Over a wide mean (σ 0.4 m) 0.1 m ahead at depth z: the walk is the offset ± 0.1.
    let walk_over = |z: f32| {
        let mut g = Guidance::new(cfg);
        let far = est(Vec3::new(30.0, 0.0, z), 2.0);
        let _ = g.update(&input(h, 1.0, 0.0, Some(far)));
        let o = g.update(&input(h, 0.0, 0.0, Some(est(Vec3::new(0.1, 0.0, z), 0.4))));
        o.walk_m.unwrap_or(f32::NAN)
    };
    let near = |w: f32, b: f32| (w - b - 0.1).abs() < 1e-3 || (w - b + 0.1).abs() < 1e-3;
    // Shallow: the least offset; 2.5 m deep: 0.35 × 2.5 m; 5 m deep: capped at 1 m.
    let range = |z: f32| libm::sqrtf(0.01 + z * z);
    assert!(near(walk_over(-1.0), 0.5), "{}", walk_over(-1.0));
    let mid = cfg.bracket_range_ratio * range(-2.5);
    assert!(near(walk_over(-2.5), mid), "{} {mid}", walk_over(-2.5));
    assert!(near(walk_over(-5.0), 1.0), "{}", walk_over(-5.0));
    // A bad ratio falls back to the least offset instead of a NaN target.
    let mut g = Guidance::new(GuidanceConfig {
        bracket_range_ratio: f32::NAN,
        ..cfg
    });
    let far = est(Vec3::new(30.0, 0.0, -2.5), 2.0);
    let _ = g.update(&input(h, 1.0, 0.0, Some(far)));
    let o = g.update(&input(
        h,
        0.0,
        0.0,
        Some(est(Vec3::new(0.1, 0.0, -2.5), 0.4)),
    ));
    assert!(o.walk_m.is_some_and(|w| near(w, 0.5)), "{:?}", o.walk_m);
}

#[test]
fn a_levelled_off_sigma_probes_before_the_timeout() {
    let cfg = GuidanceConfig {
        probe_timeout_pulses: 30,
        ..probe_rule_03()
    };
    let n = usize::from(cfg.probe_plateau_pulses);
    // σ stuck at 0.12 m (3σ > the 0.3 m probe radius, below the plateau bound):
    // "probe here" once it has not shrunk for `probe_plateau_pulses` pulses — the
    // first pulse sets the best σ, so the probe comes on pulse index n.
    let mut g = localized(cfg);
    assert_eq!(pulses_to_probe(&mut g, |_| 0.12), Some(n));
    // Shrinking by 15 % every second pulse until pulse 4, then level at 0.101 m: the
    // plateau counts from pulse 4.
    let mut g = localized(cfg);
    let shrinking = |k: usize| 0.14 * libm::powf(0.85, (k / 2) as f32).max(0.101 / 0.14);
    let k = pulses_to_probe(&mut g, shrinking).unwrap_or(usize::MAX);
    assert_eq!(k, 4 + n, "the last progress on pulse 4");
    // A wide belief that stopped shrinking is not trusted: only the timeout probes.
    let mut g = localized(cfg);
    assert_eq!(
        pulses_to_probe(&mut g, |_| 0.2),
        Some(usize::from(cfg.probe_timeout_pulses) - 1)
    );
    // Disabled: the timeout again.
    let mut g = localized(GuidanceConfig {
        probe_plateau_pulses: 0,
        ..cfg
    });
    assert_eq!(
        pulses_to_probe(&mut g, |_| 0.12),
        Some(usize::from(cfg.probe_timeout_pulses) - 1)
    );
}

#[test]
fn one_jump_of_the_estimate_does_not_restart_the_timeout() {
    let cfg = probe_rule_03();
    let timeout = usize::from(cfg.probe_timeout_pulses);
    // A wide belief (no plateau probe) 0.2 m away, except on the pulses in `jumps`,
    // where it is 3 m away (beyond the bracketing span): the pulse of the probe.
    let run = |jumps: &[usize]| {
        let mut g = localized(cfg);
        let h = Vec3::new(1e-4, 0.0, 0.0);
        (0..60).find(|k| {
            let x = if jumps.contains(k) { 3.0 } else { 0.2 };
            let e = est(Vec3::new(x, 0.0, -2.0), 0.2);
            g.update(&input(h, 0.0, 0.0, Some(e))).status == Status::Probe
        })
    };
    assert_eq!(run(&[]), Some(timeout - 1));
    // One jump: that pulse is not over the mean, the count goes on.
    assert_eq!(run(&[5]), Some(timeout));
    // Two in a row: the rescuer left, the count starts again after them.
    assert_eq!(run(&[5, 6]), Some(7 + timeout - 1));
}

#[test]
fn an_inconclusive_signal_does_not_flip_the_flux_line() {
    // At the edge of reception: |H| ≈ 5 σ_bkg, fluctuating by ±σ_bkg (never a
    // significant decrease), over 40 m: keep the direction.
    let cfg = GuidanceConfig::default();
    let mut g = Guidance::new(cfg);
    for k in 0..40 {
        let wiggle = if k % 3 == 0 { 1.0 } else { -0.6 };
        let h = cfg.sigma_bkg * (5.0 + wiggle);
        let o = g.update(&input(Vec3::new(h, 0.0, 0.0), 1.0, 0.0, None));
        assert!(o.bearing.is_some_and(|b| b.abs() < 1e-5), "pulse {k}");
    }
    // A significant fall (walking away: |H| ∝ r⁻³) still flips it within 5 m + a few.
    let mut h = 5.0 * cfg.sigma_bkg;
    let mut flipped = false;
    for _ in 0..12 {
        h *= 0.85;
        let o = g.update(&input(Vec3::new(h, 0.0, 0.0), 1.0, 0.0, None));
        flipped |= o.bearing.is_some_and(|b| (b.abs() - PI).abs() < 1e-5);
    }
    assert!(flipped);
}

#[test]
fn angles_and_helpers() {
    assert!((to_degrees_wrapped(-PI) - 180.0).abs() < 1e-4);
    assert!((to_degrees_wrapped(FRAC_PI_2) - 90.0).abs() < 1e-4);
    assert!((relative_arrow(0.1, 2.0 * PI + 0.2) + 0.1).abs() < 1e-5);
    let e = est(Vec3::new(3.0, 4.0, 0.0), 1.0);
    assert!((horizontal_mahalanobis2(&e) - 25.0).abs() < 1e-3);
    let mut c = Mat3::zeros();
    c[(0, 0)] = 1.0;
    c[(1, 1)] = 1.0;
    c[(0, 1)] = 0.5;
    c[(1, 0)] = 0.5;
    let (axis, s) = horizontal_axis(&c);
    assert!((s - 1.5f32.sqrt()).abs() < 1e-5);
    assert!((axis[0] - axis[1]).abs() < 1e-5);
    assert!(flux_direction(&Vec3::new(0.0, 0.0, 1.0), &[1.0, 0.0]).is_none());
}

#[test]
fn without_a_heading_the_belief_is_not_walked_to() {
    // The bound: 9 · a(σψ²) = 1 at σψ = 0.680 rad (39.0°) for go_to_mean_d2 = 9.
    assert!(heading_supports(2f32.to_radians().powi(2), 9.0));
    assert!(heading_supports(0.67f32.powi(2), 9.0));
    assert!(!heading_supports(0.69f32.powi(2), 9.0));
    assert!(!heading_supports(PI * PI, 9.0));
    assert!(!heading_supports(f32::NAN, 9.0));
    assert!(!heading_supports(f32::INFINITY, 9.0));
    assert!(heading_supports(-1.0, 9.0));
    let cfg = GuidanceConfig::default();
    let h = Vec3::new(1e-4, 0.0, 0.0);
    let far = Some(est(Vec3::new(30.0, 0.0, -2.0), 2.0));
    let unknown = |e: Option<VictimEstimate>| GuidanceInput {
        yaw_var: PI * PI,
        ..input(h, 1.0, 0.0, e)
    };
    // A concentrated belief 30 m away (localized with a heading, see `localized`): the
    // flux line without one, no distance shown.
    let mut g = Guidance::new(cfg);
    let o = g.update(&unknown(far));
    assert_eq!(o.status, Status::FluxLine);
    assert!(o.distance_m.is_none() && !g.is_localized());
    // Localized, then the heading lost: back to the flux line, and localized again once
    // the heading is back.
    let mut g = localized(cfg);
    assert_eq!(g.update(&unknown(far)).status, Status::FluxLine);
    assert!(!g.is_localized());
    assert_eq!(g.update(&input(h, 1.0, 0.0, far)).status, Status::Localized);
    // A probe under way stays: at the mean the heading moves nothing.
    let mut g = localized(cfg);
    let over = Some(est(Vec3::new(0.05, 0.0, -3.0), 0.05));
    let _ = g.update(&input(h, 0.0, 0.0, over));
    assert_eq!(g.update(&input(h, 0.0, 0.0, over)).status, Status::Probe);
    assert_eq!(g.update(&unknown(over)).status, Status::Probe);
}

#[test]
fn without_a_heading_probe_here_shows_on_the_strict_rule() {
    let cfg = GuidanceConfig::default();
    let h = Vec3::new(1e-4, 0.0, 0.0);
    let unknown = |e: VictimEstimate, yaw: f32| GuidanceInput {
        yaw_var: PI * PI,
        ..input(h, 0.0, yaw, Some(e))
    };
    // Over a concentrated belief, whatever the (unknown) yaw: the flux line on the first
    // pulse, "probe here" once confirmed, with distances but no arrow.
    let over = est(Vec3::new(0.2, -0.1, -1.8), 0.1);
    for yaw in [0.0, 2.0, -2.9] {
        let mut g = Guidance::new(cfg);
        for _ in 1..cfg.probe_confirm_pulses {
            assert_eq!(g.update(&unknown(over, yaw)).status, Status::FluxLine);
        }
        let o = g.update(&unknown(over, yaw));
        assert_eq!(o.status, Status::Probe);
        assert!(o.bearing.is_none() && o.arrow.is_none() && !g.is_localized());
        assert_eq!(o.walk_m, Some(0.0));
        assert!(
            o.horizontal_m
                .is_some_and(|d| (d - 0.05f32.sqrt()).abs() < 1e-5)
        );
        assert!(o.depth_m.is_some_and(|d| (d - 0.8).abs() < 1e-5));
        // Latched, like any probe.
        let away = est(Vec3::new(5.0, 0.0, -1.8), 0.1);
        assert_eq!(g.update(&unknown(away, yaw)).status, Status::Probe);
    }
    // Not over it, not concentrated, or not confirmed: the flux line.
    for (e, why) in [
        (est(Vec3::new(0.8, 0.0, -1.8), 0.1), "beyond reach"),
        (
            est(Vec3::new(0.1, 0.0, -1.8), 0.2),
            "3σ beyond the probe radius",
        ),
    ] {
        let mut g = Guidance::new(cfg);
        for _ in 0..5 {
            assert_eq!(g.update(&unknown(e, 0.0)).status, Status::FluxLine, "{why}");
        }
    }
    let mut g = Guidance::new(cfg);
    let _ = g.update(&unknown(over, 0.0));
    let _ = g.update(&unknown(est(Vec3::new(0.8, 0.0, -1.8), 0.1), 0.0));
    assert_eq!(g.update(&unknown(over, 0.0)).status, Status::FluxLine);
}

fn at_height(e: VictimEstimate, height: Option<f32>) -> GuidanceInput {
    GuidanceInput {
        height_m: height,
        ..input(Vec3::new(1e-4, 0.0, 0.0), 0.0, 0.0, Some(e))
    }
}

#[test]
fn a_rescuer_who_ignores_the_lowering_is_asked_a_few_times_then_left_alone() {
    let cfg = GuidanceConfig::default();
    let mut g = localized(cfg);
    // 1.5 m from the mean, 1.2 m deep below the snow, the receiver at 1 m.
    let near = est(Vec3::new(1.5, 0.0, -2.2), 0.3);
    // Farther than `lower_within_m`: not yet.
    let o = g.update(&at_height(est(Vec3::new(2.5, 0.0, -2.2), 0.3), Some(1.0)));
    assert_eq!(o.height_prompt, HeightPrompt::None);
    // Shown first, then through `height_prompt_pulses` intervals of standing.
    for _ in 0..=cfg.height_prompt_pulses {
        let o = g.update(&at_height(near, Some(1.0)));
        assert_eq!(o.height_prompt, HeightPrompt::Lower);
        assert_eq!(o.status, Status::Localized);
        assert!(!o.lift);
        // The depth below the snow from the current height.
        assert!(o.depth_m.is_some_and(|d| (d - 1.2).abs() < 1e-5));
    }
    // Ignored: not asked again in this search, even over the mean; the search goes on.
    for _ in 0..20 {
        let o = g.update(&at_height(near, Some(1.0)));
        assert_eq!(o.height_prompt, HeightPrompt::None);
    }
    let o = g.update(&at_height(est(Vec3::new(0.1, 0.0, -2.2), 0.05), Some(1.0)));
    assert_eq!(o.height_prompt, HeightPrompt::None);
    assert!(o.depth_m.is_some_and(|d| (d - 1.2).abs() < 1e-5));
}

#[test]
fn the_lowering_prompt_waits_for_a_walking_rescuer_to_stand_within_a_limit() {
    let cfg = GuidanceConfig::default();
    let near = est(Vec3::new(1.5, 0.0, -2.2), 0.3);
    let walking = |walked: f32| GuidanceInput {
        walked_m: walked,
        ..at_height(near, Some(1.0))
    };
    // Steps still under way on the first pulses: the prompt stays on, then runs for
    // the standing intervals.
    let mut g = localized(cfg);
    for _ in 0..3 {
        assert_eq!(g.update(&walking(0.6)).height_prompt, HeightPrompt::Lower);
    }
    for _ in 0..cfg.height_prompt_pulses {
        assert_eq!(g.update(&walking(0.0)).height_prompt, HeightPrompt::Lower);
    }
    assert_eq!(g.update(&walking(0.0)).height_prompt, HeightPrompt::None);
    // A rescuer who walks on regardless is asked on a bounded number of pulses.
    let mut g = localized(cfg);
    let most = usize::from(cfg.height_prompt_pulses) * usize::from(PROMPT_SHOWN_FACTOR);
    let shown = (0..100)
        .filter(|_| g.update(&walking(0.6)).height_prompt == HeightPrompt::Lower)
        .count();
    assert_eq!(shown, most);
}

#[test]
fn probe_here_is_confirmed_by_pulses_after_the_lowering() {
    let cfg = GuidanceConfig::default();
    let mut g = localized(cfg);
    // Right over a tight mean at 1 m: "probe here" would need two pulses, but the
    // lowering comes first, as often as it is shown.
    let over = est(Vec3::new(0.05, 0.0, -2.2), 0.05);
    for _ in 0..3 {
        let o = g.update(&at_height(over, Some(1.0)));
        assert_eq!(o.height_prompt, HeightPrompt::Lower);
        assert_eq!(o.status, Status::Localized);
    }
    // Lowered: the pulses from 1 m up confirm nothing; two at the snow do.
    let low = est(Vec3::new(0.05, 0.0, -1.4), 0.05);
    let o = g.update(&at_height(low, Some(0.2)));
    assert_eq!(
        (o.height_prompt, o.status),
        (HeightPrompt::None, Status::Localized)
    );
    assert_eq!(g.update(&at_height(low, Some(0.2))).status, Status::Probe);
}

#[test]
fn a_lowered_receiver_ends_the_prompt_and_the_depth_follows_the_height() {
    let cfg = GuidanceConfig::default();
    let mut g = localized(cfg);
    let o = g.update(&at_height(est(Vec3::new(1.5, 0.0, -2.2), 0.3), Some(1.0)));
    assert_eq!(o.height_prompt, HeightPrompt::Lower);
    // Lowered by 0.8 m: the victim is 0.8 m less below the receiver, the depth below
    // the snow is the same.
    let o = g.update(&at_height(est(Vec3::new(1.5, 0.0, -1.4), 0.3), Some(0.2)));
    assert_eq!(o.height_prompt, HeightPrompt::None);
    assert!(o.depth_m.is_some_and(|d| (d - 1.2).abs() < 1e-5));
    // Lowered, a wide depth asks for no lift (the lowering pinned the range).
    let mut wide = est(Vec3::new(0.1, 0.0, -1.4), 0.05);
    wide.cov[(2, 2)] = 0.3 * 0.3;
    let o = g.update(&at_height(wide, Some(0.2)));
    assert!(!o.lift && o.height_prompt == HeightPrompt::None);
}

#[test]
fn a_shallow_victim_is_lowered_to_but_an_untracked_height_is_not() {
    let cfg = GuidanceConfig::default();
    // 0.5 m deep: lowered to 0.2 m it is 0.7 m below the receiver, and the estimator's
    // initialization prior follows the tracked height (`set_receiver_height`).
    let mut g = localized(cfg);
    let o = g.update(&at_height(est(Vec3::new(1.0, 0.0, -1.5), 0.3), Some(1.0)));
    assert_eq!(o.height_prompt, HeightPrompt::Lower);
    // Deep, but the caller tracks no height.
    let mut g = localized(cfg);
    let o = g.update(&at_height(est(Vec3::new(1.0, 0.0, -3.0), 0.3), None));
    assert_eq!(o.height_prompt, HeightPrompt::None);
    assert!(o.depth_m.is_some_and(|d| (d - 2.0).abs() < 1e-5));
    // Switched off.
    let mut g = localized(GuidanceConfig {
        lower_within_m: 0.0,
        ..cfg
    });
    let o = g.update(&at_height(est(Vec3::new(1.0, 0.0, -3.0), 0.3), Some(1.0)));
    assert_eq!(o.height_prompt, HeightPrompt::None);
    // Withheld by the caller (several victims): no prompt, and "probe here" is not
    // held back by one.
    let mut g = localized(cfg);
    let withheld = |e: VictimEstimate| GuidanceInput {
        lower_allowed: false,
        ..at_height(e, Some(1.0))
    };
    let o = g.update(&withheld(est(Vec3::new(1.0, 0.0, -3.0), 0.3)));
    assert_eq!(o.height_prompt, HeightPrompt::None);
    let over = est(Vec3::new(0.05, 0.0, -3.0), 0.05);
    let _ = g.update(&withheld(over));
    assert_eq!(g.update(&withheld(over)).status, Status::Probe);
}

#[test]
fn a_lowered_receiver_far_from_the_mean_is_asked_to_be_raised() {
    let cfg = GuidanceConfig::default();
    let mut g = localized(cfg);
    let near = est(Vec3::new(1.0, 0.0, -1.4), 0.3);
    assert_eq!(
        g.update(&at_height(near, Some(0.2))).height_prompt,
        HeightPrompt::None
    );
    // The mean moved 10 m away (e.g. the next victim): raise, a few pulses at most.
    let far = est(Vec3::new(10.0, 0.0, -1.4), 0.5);
    for _ in 0..=cfg.height_prompt_pulses {
        assert_eq!(
            g.update(&at_height(far, Some(0.2))).height_prompt,
            HeightPrompt::Raise
        );
    }
    assert_eq!(
        g.update(&at_height(far, Some(0.2))).height_prompt,
        HeightPrompt::None
    );
    // Raised: nothing more to ask; no lowering asked again this far away.
    assert_eq!(
        g.update(&at_height(far, Some(1.0))).height_prompt,
        HeightPrompt::None
    );
}
