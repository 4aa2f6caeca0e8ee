use super::*;
use crate::frame::rpy_from_rotation;

fn disp(t: [f32; 3], r: [f32; 3], st: f32, sr: f32) -> Displacement {
    Displacement::with_sigmas(Vec3::from(t), Rpy::from(r), st, sr)
}

/// f64 reference of the composed mean.
fn compose_mean_f64(a: &[f64; 6], b: &[f64; 6]) -> [f64; 6] {
    let ra = rot64(&[a[3], a[4], a[5]]);
    let rb = rot64(&[b[3], b[4], b[5]]);
    let t =
        nalgebra::Vector3::new(a[0], a[1], a[2]) + ra * nalgebra::Vector3::new(b[0], b[1], b[2]);
    let r = ra * rb;
    let pitch = (-r[(2, 0)]).asin();
    let roll = r[(2, 1)].atan2(r[(2, 2)]);
    let yaw = r[(1, 0)].atan2(r[(0, 0)]);
    [t.x, t.y, t.z, roll, pitch, yaw]
}

fn rot64(rpy: &[f64; 3]) -> nalgebra::Matrix3<f64> {
    let (sr, cr) = rpy[0].sin_cos();
    let (sp, cp) = rpy[1].sin_cos();
    let (sy, cy) = rpy[2].sin_cos();
    let rx = nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, cr, -sr, 0.0, sr, cr);
    let ry = nalgebra::Matrix3::new(cp, 0.0, sp, 0.0, 1.0, 0.0, -sp, 0.0, cp);
    let rz = nalgebra::Matrix3::new(cy, -sy, 0.0, sy, cy, 0.0, 0.0, 0.0, 1.0);
    rz * ry * rx
}

#[test]
fn composition_matches_f64_and_finite_difference_covariance() {
    let a = disp([1.2, -0.3, 0.05], [0.05, -0.08, 0.6], 0.1, 0.03);
    let b = disp([0.8, 0.4, -0.02], [-0.03, 0.1, -0.4], 0.2, 0.05);
    let c = compose(&a, &b).unwrap();
    let a64: [f64; 6] = core::array::from_fn(|i| {
        f64::from(if i < 3 {
            a.translation[i]
        } else {
            a.rotation[i - 3]
        })
    });
    let b64: [f64; 6] = core::array::from_fn(|i| {
        f64::from(if i < 3 {
            b.translation[i]
        } else {
            b.rotation[i - 3]
        })
    });
    let m = compose_mean_f64(&a64, &b64);
    for (i, want) in m.iter().enumerate() {
        let got = f64::from(if i < 3 {
            c.translation[i]
        } else {
            c.rotation[i - 3]
        });
        assert!((got - want).abs() < 1e-5, "mean {i}: {got} vs {want}");
    }
    // Covariance: finite-difference Jacobians of the f64 composition.
    let h = 1e-6;
    let mut ja = nalgebra::SMatrix::<f64, 6, 6>::zeros();
    let mut jb = nalgebra::SMatrix::<f64, 6, 6>::zeros();
    for k in 0..6 {
        let (mut ap, mut am, mut bp, mut bm) = (a64, a64, b64, b64);
        ap[k] += h;
        am[k] -= h;
        bp[k] += h;
        bm[k] -= h;
        let (fap, fam) = (compose_mean_f64(&ap, &b64), compose_mean_f64(&am, &b64));
        let (fbp, fbm) = (compose_mean_f64(&a64, &bp), compose_mean_f64(&a64, &bm));
        for r in 0..6 {
            ja[(r, k)] = (fap[r] - fam[r]) / (2.0 * h);
            jb[(r, k)] = (fbp[r] - fbm[r]) / (2.0 * h);
        }
    }
    let qa = a.cov.cast::<f64>();
    let qb = b.cov.cast::<f64>();
    let want = ja * qa * ja.transpose() + jb * qb * jb.transpose();
    for r in 0..6 {
        for k in 0..6 {
            let got = f64::from(c.cov[(r, k)]);
            assert!(
                (got - want[(r, k)]).abs() < 1e-5 + 1e-3 * want[(r, k)].abs(),
                "cov ({r},{k}): {got} vs {}",
                want[(r, k)]
            );
        }
    }
}

/// A bank whose first victim (source 1) was walked past: 0.5 m per pulse along
/// north at 3 m west of a dipole 1.5 m deep; returns the receiver's position and time.
fn walked_bank(tx: &Vec3, m: &Vec3) -> (Box<VictimBank>, Vec3, f32) {
    let cfg = crate::app::AppConfig::new(Vec3::new(21.0, 0.0, -42.0), Some(0.56)).sog;
    let mut bank = Box::new(VictimBank::new(cfg).unwrap());
    let att = Attitude::with_sigmas(Rpy::zeros(), 0.01, 0.02);
    let mut r = Vec3::new(-10.0, -3.0, 0.0);
    let mut t = 0.0;
    for k in 0..40 {
        let step = if k == 0 {
            Vec3::zeros()
        } else {
            Vec3::new(0.5, 0.0, 0.0)
        };
        r += step;
        t += 1.0;
        let h = crate::dipole::field(&(tx - r), m).unwrap();
        let i = bank.slot_for(Some(1), t).unwrap();
        bank.step(i, Some(1), &cut(step), &att, &Pulse { h, t })
            .unwrap();
    }
    (bank, r, t)
}

fn cut(step: Vec3) -> MotionCut {
    MotionCut {
        cut: Displacement::with_sigmas(step, Rpy::zeros(), 0.03, 0.005),
        partial: Displacement::zero(),
        back: Displacement::zero(),
        distance_m: step.norm(),
        partial_m: 0.0,
        steps: 1,
        standing: false,
        floors: None,
    }
}

#[test]
fn the_position_is_carried_over_the_walk_since_the_last_pulse() {
    let (tx, m) = (Vec3::new(0.0, 0.0, -1.5), Vec3::new(0.02, 0.0, 0.0));
    let (bank, _, _) = walked_bank(&tx, &m);
    let v = bank.get(0).unwrap();
    let now = v.position_now().unwrap();
    assert_eq!(v.position_after(&Displacement::zero()), Some(now));
    // Level receiver, no motion pending: 3 m north and 0.4 m measured down (absolute)
    // move the victim 3 m south (times the estimated scale) and 0.4 m up.
    let scale = v.filter().estimate().unwrap().scale;
    let mut more = Displacement::zero();
    more.translation = Vec3::new(3.0, 0.0, 0.0);
    more.absolute = Vec3::new(0.0, 0.0, -0.4);
    let after = v.position_after(&more).unwrap();
    let want = now - Vec3::new(3.0 * scale, 0.0, -0.4);
    assert!((after - want).norm() < 1e-5, "{after:?} vs {want:?}");
    more.translation.x = f32::NAN;
    assert_eq!(v.position_after(&more), None);
}

#[test]
fn the_walk_since_the_last_cut_is_taken_in_the_axes_after_the_pending_turn() {
    // Another transmitter's pulse cuts victim 1's motion after a 90° turn to the
    // left (yaw, counter-clockwise seen from above): a step "ahead" after it goes west
    // (+y) in the axes of victim 1's last pulse (IROS eq. 5: t_a + R(Ψ_a) t_b).
    let (tx, m) = (Vec3::new(0.0, 0.0, -1.5), Vec3::new(0.02, 0.0, 0.0));
    let (mut bank, r, t) = walked_bank(&tx, &m);
    let before = bank.get(0).unwrap().position_now().unwrap();
    let mut turn = cut(Vec3::zeros());
    turn.cut = Displacement::with_sigmas(
        Vec3::zeros(),
        Rpy::new(0.0, 0.0, core::f32::consts::FRAC_PI_2),
        0.03,
        0.005,
    );
    let att = Attitude::with_sigmas(Rpy::zeros(), 0.01, 0.02);
    let other = crate::dipole::field(&(Vec3::new(-20.0, 15.0, -1.0) - r), &m).unwrap();
    let i = bank.slot_for(Some(2), t + 0.5).unwrap();
    assert_ne!(i, 0);
    bank.step(
        i,
        Some(2),
        &turn,
        &att,
        &Pulse {
            h: other,
            t: t + 0.5,
        },
    )
    .unwrap();
    let v = bank.get(0).unwrap();
    assert_eq!(
        v.position_now(),
        Some(before),
        "a turn on the spot moves nothing"
    );
    let scale = v.filter().estimate().unwrap().scale;
    let mut ahead = Displacement::zero();
    ahead.translation = Vec3::new(1.0, 0.0, 0.0);
    let after = v.position_after(&ahead).unwrap();
    let want = before - Vec3::new(0.0, scale, 0.0);
    assert!((after - want).norm() < 1e-4, "{after:?} vs {want:?}");
}

#[test]
fn a_new_track_goes_to_the_silent_victim_whose_mixture_explains_it() {
    let (tx, m) = (Vec3::new(0.0, 0.0, -1.5), Vec3::new(0.02, 0.0, 0.0));
    let (mut bank, r, t) = walked_bank(&tx, &m);
    let v = bank.get(0).unwrap();
    assert!(v.localized(), "{:?}", v.filter().estimate());
    let att = Attitude::with_sigmas(Rpy::zeros(), 0.01, 0.02);
    let still = cut(Vec3::zeros());
    // Another transmitter 5 m away, moment across: not this victim's pulse.
    let other =
        crate::dipole::field(&(Vec3::new(2.0, 5.0, -1.0) - r), &Vec3::new(0.0, 0.02, 0.0)).unwrap();
    let t2 = t + 2.0;
    assert_eq!(
        v.filter()
            .explains(&still.cut, &att, &Pulse { h: other, t: t2 }),
        Some(false)
    );
    assert_eq!(
        bank.reassociate(Some(7), &still, &att, &Pulse { h: other, t: t2 }),
        None
    );
    // Its own transmitter under a new track id after 2 s of silence: re-associated.
    let own = crate::dipole::field(&(tx - r), &m).unwrap();
    // Not while it is still heard (silent < REASSOCIATE_SILENT_S).
    let early = Pulse { h: own, t: t + 1.0 };
    assert_eq!(bank.reassociate(Some(7), &still, &att, &early), None);
    let p = Pulse { h: own, t: t2 };
    assert_eq!(bank.reassociate(Some(7), &still, &att, &p), Some(0));
    assert_eq!(bank.get(0).unwrap().src(), Some(7));
    assert_eq!(bank.slot_for(Some(7), t2), Some(0));
    // Non-finite input: no re-association, nothing changed.
    let nan = Pulse {
        h: Vec3::new(f32::NAN, 0.0, 0.0),
        t: t2 + 2.0,
    };
    assert_eq!(bank.reassociate(Some(8), &still, &att, &nan), None);
    assert_eq!(bank.get(0).unwrap().src(), Some(7));
}

#[test]
fn a_full_list_evicts_a_marked_silent_victim_first_and_keeps_overlapped_ones() {
    let (tx, m) = (Vec3::new(0.0, 0.0, -1.5), Vec3::new(0.02, 0.0, 0.0));
    let (mut bank, r, mut t) = walked_bank(&tx, &m);
    let att = Attitude::with_sigmas(Rpy::zeros(), 0.01, 0.02);
    let h = crate::dipole::field(&(tx - r), &m).unwrap();
    let pulse = |bank: &mut VictimBank, src: u8, t: f32| {
        let i = bank.slot_for(Some(src), t)?;
        bank.step(i, Some(src), &cut(Vec3::zeros()), &att, &Pulse { h, t })
            .ok()?;
        Some(i)
    };
    for src in 2..=4 {
        t += 0.3;
        assert!(pulse(&mut bank, src, t).is_some());
    }
    assert!(bank.mark(0));
    // Full, nobody silent long enough: the new source finds no slot.
    t += 1.0;
    assert_eq!(bank.slot_for(Some(9), t), None);
    // Sources 2–4 keep pulsing; after EVICT_SILENT_S the marked victim 1 gives way.
    while t < 40.0 + EVICT_SILENT_S + 1.0 {
        t += 1.0;
        for src in 2..=4 {
            pulse(&mut bank, src, t + 0.1 * f32::from(src));
        }
    }
    t += 1.0;
    assert_eq!(bank.slot_for(Some(9), t), Some(0));
    // Source 9 takes the slot; later the marked victim's transmitter (source 1, its
    // id kept by the front end) is heard again and takes a slot back: it is the
    // victim already found, listed as marked, not one to search for again.
    assert!(bank.was_marked(Some(1)) && !bank.was_marked(Some(9)));
    assert_eq!(pulse(&mut bank, 9, t), Some(0));
    assert!(!bank.get(0).unwrap().marked());
    t += EVICT_SILENT_S + 1.0;
    for src in 2..=4 {
        pulse(&mut bank, src, t + 0.1 * f32::from(src));
    }
    let back = pulse(&mut bank, 1, t + 0.5).unwrap();
    assert_eq!(back, 0);
    assert_eq!(bank.get(0).unwrap().src(), Some(1));
    assert!(bank.get(0).unwrap().marked());
    assert_eq!(bank.nearest_unmarked().map(|n| n.0 != 0), Some(true));
    // An established unmarked victim silent beyond LOST_S stays listed while pulses
    // are being withheld as overlaps, and is dropped once they stop.
    let late = t + LOST_S + 1.0;
    bank.note_withheld(late - 1.0);
    assert_eq!(bank.drop_lost(late), 0);
    assert_eq!(bank.drop_lost(late + OVERLAP_HOLD_S + 1.0), 3);
}

#[test]
fn zero_is_the_identity_and_absolute_parts_rotate() {
    let mut a = disp(
        [1.0, 2.0, 0.0],
        [0.0, 0.0, core::f32::consts::FRAC_PI_2],
        0.1,
        0.02,
    );
    a.absolute = Vec3::new(0.0, 0.0, 0.3);
    let z = Displacement::zero();
    let left = compose(&z, &a).unwrap();
    let right = compose(&a, &z).unwrap();
    for c in [left, right] {
        assert!((c.translation - a.translation).norm() < 1e-6);
        assert!((c.rotation - a.rotation).norm() < 1e-6);
        assert!((c.cov - a.cov).norm() < 1e-6);
    }
    // b's absolute part along its x axis is along a's y axis after a 90° yaw.
    let mut b = Displacement::zero();
    b.absolute = Vec3::new(0.5, 0.0, 0.0);
    let c = compose(&a, &b).unwrap();
    assert!((c.absolute - Vec3::new(0.0, 0.5, 0.3)).norm() < 1e-6);
    let nan = disp([f32::NAN, 0.0, 0.0], [0.0; 3], 0.1, 0.1);
    assert!(compose(&a, &nan).is_none());
    // Composing many small motions equals their f32 sum of rotations about z.
    let step = disp([0.5, 0.0, 0.0], [0.0, 0.0, 0.1], 0.0, 0.0);
    let mut p = Pending::zero();
    for _ in 0..10 {
        p = p.then(&step, 0.5).unwrap();
    }
    assert!((p.d.rotation.z - 1.0).abs() < 1e-5);
    assert!((p.distance_m - 5.0).abs() < 1e-5);
    let r = rpy_from_rotation(&rotation_from_rpy(&p.d.rotation));
    assert!((r - p.d.rotation).norm() < 1e-5);
}
