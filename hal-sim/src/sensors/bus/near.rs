//! The receiver lying on the snow over a shallow, strong beacon, at the bus level: the
//! fields that saturate a fixed-gain receiver, through the emulated ADS131M04 (PGA,
//! clipping, input noise) and IF range switch, the firmware's driver and its pulse DSP
//! with gain ranging (`firmware::frontend::ranging`).
//!
//! The transmitter is the standard's strongest the simulator draws (3e-2 A·m², see
//! [`crate::world::transmitter::TransmitterSpec`]) pulsing 70 ms every 0.95 s; the receiver is
//! still, at a fixed attitude, `depth` above it.
use super::ads131m04::F_CLKIN_HZ;
use super::antenna::Antenna;
use super::if_signal::{AnalogInput, IF_HZ, RangeSwitch, sample_sigma};
use super::unit::Unit;
use crate::world::physics::{M3, V3, dipole_field, rotation_from_rpy};
use anyhow::Result;
use firmware::board::REFERENCE;
use firmware::frontend::{Calibration, IfRange, Pulse, Range, RangeChange};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::f64::consts::TAU;

/// Magnetic moment of the strongest transmitter, A·m².
pub const STRONGEST_MOMENT: f64 = 3e-2;
/// Pulse period and on-time of the beacon, s.
const PERIOD_S: f64 = 0.95;
const ON_S: f64 = 0.070;
/// First pulse, s (after the DSP has seeded its floor).
const FIRST_S: f64 = 0.5;
/// Carrier offset of the beacon, Hz.
const OFFSET_HZ: f64 = 37.0;
/// Environment noise, A/m per component of a 70 ms pulse.
const SIGMA_BKG: f64 = 2.59e-9;

/// The coils' IF voltages of the still receiver over the beacon.
#[derive(Debug, Clone)]
struct NearSignal {
    unit: Unit,
    /// The beacon's field in the body frame, A/m.
    h: V3,
    sigma_sample: f64,
    noise: ChaCha8Rng,
    switch: RangeSwitch,
}

impl AnalogInput for NearSignal {
    fn volts(&mut self, t: f64) -> [f64; 4] {
        let k = ((t - FIRST_S) / PERIOD_S).floor();
        let on = k >= 0.0 && t - (FIRST_S + k * PERIOD_S) < ON_S;
        let arg = TAU * ((IF_HZ + OFFSET_HZ) * t).fract();
        let c = &self.unit.chain;
        let range = self.switch.get();
        let mut v = [0.0; 4];
        for (i, out) in v.iter_mut().take(3).enumerate() {
            let n: f64 = StandardNormal.sample(&mut self.noise);
            let s = if on {
                self.h[i] * (arg - c.lag(i, range)).cos()
            } else {
                0.0
            };
            *out = (s + self.sigma_sample * n) / c.gain(i, range) + c.offset_v[i];
        }
        v
    }
}

/// What the DSP made of the beacon.
#[derive(Debug, Clone)]
pub struct NearRun {
    /// The beacon's true field at the receiver, body frame, A/m.
    pub h_true: V3,
    /// Every pulse with the setting it was measured in.
    pub pulses: Vec<(Pulse, Range)>,
    /// The changes of setting.
    pub changes: Vec<RangeChange>,
}

/// The attitude the receiver lies at (roll, pitch, yaw, rad): tilted a little on uneven
/// snow so that every coil sees part of the field.
pub const LYING_RPY: [f64; 3] = [0.15, -0.1, 0.7];

/// `seconds` of the receiver (unit `unit`, its DSP holding `cal`, the board profile's
/// ranging) lying `depth` m above a beacon of moment `moment` A·m² whose axis is tilted
/// `tilt` rad from the vertical; noise from `seed`.
pub fn near_run(
    unit: &Unit,
    cal: &Calibration,
    depth: f64,
    moment: f64,
    tilt: f64,
    seconds: f64,
    seed: u64,
) -> Result<NearRun> {
    let m = V3::new(tilt.sin(), 0.0, tilt.cos()) * moment;
    let h_world = dipole_field(&V3::new(0.0, 0.0, depth), &m);
    let rot: M3 = rotation_from_rpy(&V3::from(LYING_RPY));
    let h = rot.transpose() * h_world;
    let fs = f64::from(REFERENCE.adc.config.data_rate_hz(F_CLKIN_HZ as f32));
    let switch = RangeSwitch::new();
    let signal = NearSignal {
        unit: *unit,
        h,
        sigma_sample: sample_sigma(SIGMA_BKG, fs),
        noise: ChaCha8Rng::seed_from_u64(seed),
        switch: switch.clone(),
    };
    let (mut antenna, clock) =
        Antenna::on_reference_board(signal, switch, REFERENCE.frontend_config(cal), seed ^ 0xADC)?;
    let start = antenna.frontend.range();
    let mut pulses = Vec::new();
    for k in 0..=(seconds * 100.0) as u64 {
        clock.set(k as f64 / 100.0);
        antenna.drain(|p| pulses.push(p))?;
    }
    // The setting of a pulse: the last change before its centre (changes come only
    // between pulses).
    let changes = antenna.changes;
    let pulses = pulses
        .into_iter()
        .map(|p| {
            let r = changes
                .iter()
                .rfind(|c| c.t_s < p.t_s)
                .map_or(start, |c| c.to);
            (p, r)
        })
        .collect();
    Ok(NearRun {
        h_true: h,
        pulses,
        changes,
    })
}

/// The field a DSP holding `cal` reads for the true field `h` in IF range `range` of
/// `unit` without noise: each coil scaled by its calibration's error (the in-phase
/// projection of a few tenths of a degree of phase error is exact to 1e-5).
pub fn calibration_reading(unit: &Unit, cal: &Calibration, h: &V3, range: IfRange) -> V3 {
    let c = &unit.chain;
    V3::from_fn(|i, _| {
        let held = f64::from(cal.gain_a_per_m_per_v[i])
            * match range {
                IfRange::High => 1.0,
                IfRange::Low => f64::from(cal.low_range_ratio[i]),
            };
        h[i] * held / c.gain(i, range)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::bus::run::scenario_calibration;
    use crate::sensors::bus::run::{UnitCalibration, scenario_unit};
    use firmware::frontend::PulseMeasurement;

    fn aligned(a: &V3, b: &V3) -> V3 {
        if a.dot(b) >= 0.0 { *b } else { -b }
    }

    #[test]
    fn on_the_snow_over_the_strongest_beacon_pulses_are_measured_within_the_calibration() {
        let mut worst_excess = 0.0f64;
        let mut worst_cal = 0.0f64;
        for (seed, depth, tilt) in [(1, 0.4, 0.0), (2, 0.3, 0.5), (3, 0.5, 1.2), (4, 0.4, 0.3)] {
            let unit = scenario_unit(seed);
            let cal = scenario_calibration(seed, UnitCalibration::Bench).unwrap();
            let run = near_run(&unit, &cal, depth, STRONGEST_MOMENT, tilt, 12.0, seed).unwrap();
            let n = run.pulses.len();
            let saturated = run
                .pulses
                .iter()
                .filter(|(p, _)| p.measurement == PulseMeasurement::Saturated)
                .count();
            // Ranging from the most sensitive setting takes at most three clipped pulses.
            assert!(n >= 11, "{n} pulses");
            assert!(saturated <= 3, "seed {seed}: {saturated} saturated");
            let settled = &run.pulses[saturated..];
            for (p, range) in settled {
                let Some(h) = p.field() else {
                    panic!("seed {seed}: withheld after ranging: {p:?}");
                };
                let h = V3::new(f64::from(h.x), f64::from(h.y), f64::from(h.z));
                let want = calibration_reading(&unit, &cal, &run.h_true, range.if_range);
                let cal_err = (want - run.h_true).norm() / run.h_true.norm();
                let err = (aligned(&want, &h) - want).norm() / run.h_true.norm();
                worst_cal = worst_cal.max(cal_err);
                worst_excess = worst_excess.max(err);
                assert_eq!(range.if_range, IfRange::Low, "{range:?}");
            }
            println!(
                "seed {seed}, {depth} m, |H| = {:.3} A/m: {n} pulses, {saturated} saturated, \
                 settings {:?}",
                run.h_true.norm(),
                run.changes.iter().map(|c| c.to).collect::<Vec<_>>()
            );
        }
        println!(
            "worst calibration error {:.2} %, worst measured − calibration-predicted {:.3} %",
            100.0 * worst_cal,
            100.0 * worst_excess
        );
        // The measured field is what the unit's calibration predicts, to the noise.
        assert!(worst_excess < 2e-3, "{worst_excess}");
        assert!(worst_cal < 0.05, "{worst_cal}");
    }
}
