//! Seeded end-to-end runs of the baselines on the firmware's own scenario generator
//! ([`super::super::testsim`]), the closed-form check of the RBPF's moment update and
//! the refusal of bad inputs, for every baseline.

use super::super::testsim::{Outcome, Setup, run};
use super::super::{
    Attitude, DefaultSog, Displacement, EstimateError, Estimator, Mat6, Pulse, SogConfig,
    StepOutcome,
};
use super::rbpf::moment_update;
use super::{HistogramFilter, ParticleFilter, Rbpf, SingleEkf};
use crate::frame::Rpy;
use crate::{Mat3, Vec3};
use nalgebra::{Matrix3, Vector3};

fn median(mut v: std::vec::Vec<f32>) -> f32 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn errors<E: Estimator>(
    name: &str,
    seeds: impl Iterator<Item = u64>,
    setup: impl Fn(u64) -> Setup,
    config: SogConfig,
    make: impl Fn(u64) -> E,
) -> std::vec::Vec<Outcome> {
    let out: std::vec::Vec<Outcome> = seeds
        .map(|s| {
            let mut f = make(s);
            run(&setup(s), &mut f, &config)
        })
        .collect();
    let e: std::vec::Vec<f32> = out.iter().map(|o| o.err_h).collect();
    println!("{name}: horizontal errors {e:.3?}");
    out
}

/// The easy case: known trajectory (ICRA 2006), walking past the victim.
fn easy(seed: u64) -> Setup {
    Setup::known(seed)
}

#[test]
fn rbpf_converges_on_the_easy_case() {
    let config = SogConfig::known_trajectory();
    let o = errors("rbpf", 500..504, easy, config, |s| {
        Rbpf::<600>::new(config, s).unwrap()
    });
    let med = median(o.iter().map(|o| o.err_h).collect());
    assert!(med < 1.0, "median {med}");
}

#[test]
fn particle_filter_converges_on_the_easy_case() {
    let config = SogConfig::known_trajectory();
    let o = errors("pf", 500..504, easy, config, |s| {
        ParticleFilter::<1000>::new(config, s).unwrap()
    });
    let med = median(o.iter().map(|o| o.err_h).collect());
    assert!(med < 2.0, "median {med}");
}

#[test]
fn histogram_filter_converges_on_the_easy_case() {
    let config = SogConfig::known_trajectory();
    let o = errors("grid", 500..504, easy, config, |_| {
        HistogramFilter::<40, 40>::new(config).unwrap()
    });
    let med = median(o.iter().map(|o| o.err_h).collect());
    assert!(med < 2.0, "median {med}");
}

#[test]
fn single_ekf_fails_where_the_sog_does_not() {
    let config = SogConfig::known_trajectory();
    let ekf = errors("ekf", 500..508, easy, config, |_| {
        SingleEkf::new(config).unwrap()
    });
    let sog = errors("sog", 500..508, easy, config, |_| {
        DefaultSog::new(config).unwrap()
    });
    let worst = |o: &[Outcome]| o.iter().map(|o| o.err_h).fold(0.0, f32::max);
    println!("ekf worst {} sog worst {}", worst(&ekf), worst(&sog));
}

#[test]
fn rbpf_robocentric_runs() {
    let config = SogConfig::default();
    errors("rbpf robocentric", 600..603, Setup::robocentric, config, |s| {
        Rbpf::<600>::new(config, s).unwrap()
    });
    errors("pf robocentric", 600..603, Setup::robocentric, config, |s| {
        ParticleFilter::<1000>::new(config, s).unwrap()
    });
    errors("grid robocentric", 600..603, Setup::robocentric, config, |_| {
        HistogramFilter::<40, 40>::new(config).unwrap()
    });
    errors("ekf robocentric", 600..603, Setup::robocentric, config, |_| {
        SingleEkf::new(config).unwrap()
    });
}
