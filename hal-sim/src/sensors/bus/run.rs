//! `simulate --bus`: world → emulated chips → the firmware's drivers → the firmware's
//! pulse DSP → session-log records, and the comparison with the measurement level.
//!
//! The scenario (world, receiver configuration, truth) is the measurement level's for the
//! same configuration; only the session log's records differ:
//! - `imu`: [`firmware::drivers::imu::Imu::read`] at the IMU rate on the emulated BMI160 and
//!   LSM303AGR (same noise draws as the measurement level, then the chips' quantization);
//! - `pulse`: the firmware's [`Frontend`] fed by [`firmware::drivers::ads131m04`] frames
//!   from the emulated ADC at 8 kSPS; one record per pulse with a field vector (overlapped,
//!   saturated or truncated pulses give none), `t` = the DSP's pulse centre, `src` = the
//!   DSP's transmitter tracker when the world has several transmitters. The DSP reports
//!   each vector with its largest component positive, so the log is always
//!   sign-ambiguous;
//! - `event` of kind `withheld`: a pulse the DSP finished without a vector (overlapped,
//!   saturated or truncated), written by the board's [`BoardLog::pulse`] when the DSP
//!   finished it, like the pulses;
//! - `event` of kind `gain`: each change of the analog setting the DSP asked for, applied
//!   by the board's [`firmware::board::gain::apply_change`] and written by the board's
//!   [`BoardLog::gain`] (the same text as on the card), among the records by its `t`.
use super::antenna::Antenna;
use super::if_signal::{IfSignal, RangeSwitch};
use super::imu::{ImuBus, ImuSampler};
use super::unit::Unit;
use super::{NoDelay, SimClock};
use crate::io::session::{Imu, Pulse, Session};
use crate::sensors::{ImuModel, quantize, round_significant};
use crate::world::physics::V3;
use crate::world::scenario::{ScenarioConfig, Simulation, merge, simulate};
use anyhow::{Context, Result, anyhow};
use firmware::board::REFERENCE;
use firmware::board::board_log::BoardLog;
use firmware::board::gain::GainEvent;
use firmware::board::sd_log::{RamCard, SdSink};
use firmware::frontend::{Calibration, FrontendStats, PulseMeasurement, RangeChange};
use firmware::timebase::Instant;

/// Seed stream of the measurement-level IMU noise (see `scenario::simulate`).
const IMU_STREAM: u64 = 2;
/// Mixed into the scenario seed for the antenna's noise (kept apart from the scenario's
/// own streams).
const ANTENNA_SEED: u64 = 0xA27E_77A0_5EED_0005;
/// Mixed into the scenario seed for the unit's drawn parameters.
const UNIT_SEED: u64 = 0x0B0A_2D00_5EED_0001;
/// Mixed into the scenario seed for the ADC's own input noise.
const ADC_NOISE_SEED: u64 = 0xADC0_4015_5EED_0003;
/// Mixed into the scenario seed for the unit's bench session.
const BENCH_SEED: u64 = 0xBE9C_4000_5EED_0002;

/// The unit the bus-level simulation of scenario seed `seed` runs: drawn about the
/// reference board's nominal values with its tolerances.
pub fn scenario_unit(seed: u64) -> Unit {
    Unit::draw(&REFERENCE, seed ^ UNIT_SEED)
}

/// What a unit's firmware knows of its own analog chain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UnitCalibration {
    /// The board profile's nominal calibration: a unit that has not been on the bench.
    Nominal,
    /// The unit's bench calibration (`docs/antenna-bench-calibration.md`), run on the
    /// emulated unit from the nominal one: a shipped unit.
    Bench,
}

/// The calibration the DSP of scenario seed `seed`'s unit holds.
pub fn scenario_calibration(seed: u64, mode: UnitCalibration) -> Result<Calibration> {
    let nominal = REFERENCE.analog.nominal;
    match mode {
        UnitCalibration::Nominal => Ok(nominal),
        UnitCalibration::Bench => {
            super::bench::bench_calibrate(&scenario_unit(seed), &nominal, seed ^ BENCH_SEED)
                .map(|fit| fit.calibration)
        }
    }
}

/// A bus-level simulation and what it is compared with.
#[derive(Debug, Clone)]
pub struct BusRun {
    /// The scenario with the bus-level session log (truth records at the bus-level pulse
    /// times).
    pub sim: Simulation,
    /// The measurement-level session log of the same scenario.
    pub measurement: Session,
    /// The DSP's counters.
    pub frontend: FrontendStats,
    /// ADC conversions read.
    pub adc_samples: u64,
    /// The DSP's changes of the analog setting (gain ranging), in order.
    pub range_changes: Vec<RangeChange>,
    /// The same changes as the board applied and logged them.
    pub gain_events: Vec<GainEvent>,
    /// Pulses the DSP finished without a vector, in order: what it measured instead.
    pub withheld: Vec<Withheld>,
    /// I2C transactions with the IMU chips.
    pub i2c_transactions: u64,
}

use crate::world::scenario::stream;

/// A pulse the DSP finished without a field vector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Withheld {
    /// The pulse's centre (the record's `t`), s.
    pub t: f64,
    /// When the DSP finished it (the board writes it then), s.
    pub written_t: f64,
    /// Why there is no vector (`Overlap`, `Saturated` or `Truncated`).
    pub m: PulseMeasurement,
    /// The DSP's track.
    pub src: Option<u8>,
}

/// Runs the scenario of `cfg` through the emulated chips of `unit` and the firmware's
/// drivers and DSP, the DSP holding the calibration `cal` (what the unit knows of itself).
pub fn simulate_bus(cfg: &ScenarioConfig, unit: &Unit, cal: &Calibration) -> Result<BusRun> {
    let mut sim = simulate(cfg);
    let measurement = sim.session.clone();
    let world = &sim.world;
    let duration = sim.draw.duration_s;
    let clock = SimClock::new();

    // Antenna: ADC, IF range switch, DSP with gain ranging.
    let adc_cfg = REFERENCE.adc.config;
    let fs = f64::from(adc_cfg.data_rate_hz(super::ads131m04::F_CLKIN_HZ as f32));
    let switch = RangeSwitch::new();
    let signal = IfSignal::new(
        world,
        unit.chain,
        cfg.sensors.pulse.sigma_bkg_a_per_m,
        cfg.sensors.pulse.k_sen,
        fs,
        cfg.seed ^ ANTENNA_SEED,
    )
    .with_switch(switch.clone());
    let mut antenna = Antenna::new(
        signal,
        switch,
        clock.clone(),
        &adc_cfg,
        REFERENCE.frontend_config(cal),
        cfg.seed ^ ADC_NOISE_SEED,
    )?;

    // IMU chips.
    let model = ImuModel::new(cfg.sensors.imu.clone(), stream(cfg.seed, IMU_STREAM));
    let bus = ImuBus::new(ImuSampler::new(world, model), clock.clone());
    let mut imu = firmware::drivers::imu::Imu::new(bus.clone(), bus.clone(), &mut NoDelay)
        .map_err(|e| anyhow!("IMU init: {:?}", e.error))?;

    let several = world.transmitters.len() > 1;
    let hz = cfg.sensors.imu.hz;
    let n_imu = (duration * hz).floor() as u64;
    let mut imu_records = Vec::with_capacity(n_imu as usize + 1);
    let mut pulses = Vec::new();
    // When the front end finished each pulse (the board writes it then).
    let mut written_t = Vec::new();
    let mut withheld = Vec::new();
    for k in 0..=n_imu {
        let t = k as f64 / hz;
        clock.set(t);
        antenna
            .drain(|p| {
                let t_pulse = quantize(f64::from(p.t_s), 1e4);
                if let Some(h) = p.field() {
                    written_t.push(t);
                    pulses.push(Pulse {
                        t: t_pulse,
                        h: [0, 1, 2].map(|i| round_significant(f64::from(h[i]), 5)),
                        src: if several { p.src.map(u32::from) } else { None },
                    });
                } else {
                    withheld.push(Withheld {
                        t: t_pulse,
                        written_t: t,
                        m: p.measurement,
                        src: p.src,
                    });
                }
            })
            .with_context(|| format!("antenna at t = {t} s"))?;
        let r = imu
            .read()
            .map_err(|e| anyhow!("IMU read at t = {t} s: {e:?}"))?;
        let v = |x: firmware::Vec3, inv: f64| [0, 1, 2].map(|i| quantize(f64::from(x[i]), inv));
        imu_records.push(Imu {
            t,
            acc: v(r.acc, 1e4),
            gyr: v(r.gyr, 1e5),
            mag: Some(v(r.mag, 1e3)),
        });
    }
    let i2c_transactions = bus.transactions();
    drop(imu);
    drop(bus);
    let frontend = antenna.frontend.stats();
    let adc_samples = antenna.samples;
    let range_changes = std::mem::take(&mut antenna.changes);
    let gain_events = std::mem::take(&mut antenna.gain_events);
    drop(antenna);

    let truth = world.truth_records(cfg.truth_hz, duration, pulses.iter().map(|p| p.t), |t| t);
    let mut header = sim.session.header.clone();
    header.sign_ambiguous = true;
    sim.session = Session::new(header.clone());
    sim.session.records = merge(imu_records, pulses);
    sim.pulse_written_t = Some(written_t);
    sim.device_events = device_lines(&gain_events, &withheld)?;
    sim.truth = Session::new(header);
    sim.truth.records = truth;
    sim.receiver.sign_ambiguous = true;
    Ok(BusRun {
        sim,
        measurement,
        frontend,
        adc_samples,
        range_changes,
        gain_events,
        withheld,
        i2c_transactions,
    })
}

/// The device's event records as the board writes them: `gain` ([`BoardLog::gain`]) at
/// the change's `t`, `withheld` ([`BoardLog::pulse`]) when the DSP finished the pulse.
/// Each comes with the time it is written (s, in order) and without its `seq` (the
/// session log numbers every record in file order, `seq` first:
/// [`crate::io::session::write_as_written`]); the rest of the line is the board's text.
fn device_lines(gains: &[GainEvent], withheld: &[Withheld]) -> Result<Vec<(f64, String)>> {
    enum Item<'a> {
        Gain(&'a GainEvent),
        Withheld(&'a Withheld),
    }
    let mut items: Vec<(f64, Item)> = gains
        .iter()
        .map(|e| (Instant::from_micros(e.t_us).secs_f64(), Item::Gain(e)))
        .chain(withheld.iter().map(|w| (w.written_t, Item::Withheld(w))))
        .collect();
    // Stable: a gain change and a pulse finished on the same tick keep the DSP's order.
    items.sort_by(|a, b| a.0.total_cmp(&b.0));
    // No card: the UART stream alone carries the records.
    let mut log: BoardLog<RamCard<'static>, String> =
        BoardLog::new(SdSink::new(None), Some(String::new()));
    for (_, item) in &items {
        match item {
            Item::Gain(e) => log.gain(e),
            Item::Withheld(w) => log.pulse(w.t, &w.m, w.src),
        }
    }
    let text = log.uart().cloned().unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    if lines.len() != items.len() {
        return Err(anyhow!(
            "the board's log wrote {} lines for {} events",
            lines.len(),
            items.len()
        ));
    }
    lines
        .iter()
        .zip(&items)
        .enumerate()
        .map(|(k, (l, (at, _)))| {
            // The board's writer puts `seq` last.
            let rest = l
                .strip_suffix(&format!(",\"seq\":{k}}}"))
                .ok_or_else(|| anyhow!("event line without seq {k}: {l}"))?;
            Ok((*at, format!("{rest}}}")))
        })
        .collect()
}

/// One measurement-level pulse and the bus-level pulse matched to it.
#[derive(Debug, Clone, PartialEq)]
pub struct PulsePair {
    /// Measurement-level pulse time, s.
    pub t: f64,
    /// Bus-level minus measurement-level time, s.
    pub dt: f64,
    /// True |H| at the receiver, A/m.
    pub h_true: f64,
    /// Relative difference of the magnitudes, `(|h_bus| − |h_meas|) / |h_meas|`.
    pub rel_norm: f64,
    /// Angle between the two vectors' lines (sign flip allowed), degrees.
    pub angle_deg: f64,
    /// Squared difference (sign-aligned) per component over twice the model variance
    /// `σ_bkg² + (k_sen·|H|)²`: ≈1 on average when both levels follow the model.
    pub nees: f64,
}

/// How the bus level's pulses compare with the measurement level's.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PulseComparison {
    /// Measurement-level pulses.
    pub measurement: usize,
    /// Bus-level pulses.
    pub bus: usize,
    /// Measurement-level pulses whose true |H| is at least [`STRONG_FACTOR`] × σ_bkg.
    pub strong: usize,
    /// How many of those have a bus-level match.
    pub strong_matched: usize,
    /// Matched pairs (each bus pulse used once, within 30 ms).
    pub pairs: Vec<PulsePair>,
}

/// |H| / σ_bkg above which the DSP is expected to report every pulse. The DSP's detector
/// (window energy above 1.8× the floor of a 2 ms block's three-coil noise) starts at about
/// 9 σ_bkg; the measurement level emits pulses from 3 σ_bkg on.
pub const STRONG_FACTOR: f64 = 12.0;

impl PulseComparison {
    /// Median of `f` over the pairs (NaN when there are none).
    pub fn median(&self, f: impl Fn(&PulsePair) -> f64) -> f64 {
        self.quantile(0.5, f)
    }

    /// The `q` quantile (0…1, nearest rank) of `f` over the pairs (NaN when there are none).
    pub fn quantile(&self, q: f64, f: impl Fn(&PulsePair) -> f64) -> f64 {
        let mut v: Vec<f64> = self.pairs.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        let i = ((v.len() as f64 - 1.0) * q).round().max(0.0) as usize;
        v.get(i).copied().unwrap_or(f64::NAN)
    }

    /// Mean of [`PulsePair::nees`] (NaN without pairs).
    pub fn mean_nees(&self) -> f64 {
        self.pairs.iter().map(|p| p.nees).sum::<f64>() / self.pairs.len() as f64
    }

    /// Adds another comparison's counts and pairs to this one.
    pub fn extend(&mut self, other: PulseComparison) {
        self.measurement += other.measurement;
        self.bus += other.bus;
        self.strong += other.strong;
        self.strong_matched += other.strong_matched;
        self.pairs.extend(other.pairs);
    }
}

/// Matches measurement-level pulses of `run` with bus-level pulses (nearest in time within
/// 30 ms, each bus pulse at most once, closest pairs first) and compares the vectors;
/// `sigma_bkg`, `k_sen` give the noise model.
pub fn compare_pulses(run: &BusRun, sigma_bkg: f64, k_sen: f64) -> PulseComparison {
    let bus: Vec<&Pulse> = run.sim.session.pulses().collect();
    let meas: Vec<&Pulse> = run.measurement.pulses().collect();
    let h_true = |m: &Pulse| {
        let i = m.src.unwrap_or(0) as usize;
        run.sim
            .world
            .field_body(i, m.t)
            .map_or(V3::from(m.h).norm(), |h| h.norm())
    };
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (i, m) in meas.iter().enumerate() {
        for (j, b) in bus.iter().enumerate() {
            let dt = (b.t - m.t).abs();
            if dt < 0.03 {
                candidates.push((dt, i, j));
            }
        }
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut used_m, mut used_b) = (vec![false; meas.len()], vec![false; bus.len()]);
    let mut pairs = Vec::new();
    let mut strong_matched = 0;
    for (_, i, j) in candidates {
        if used_m[i] || used_b[j] {
            continue;
        }
        used_m[i] = true;
        used_b[j] = true;
        let (m, b) = (meas[i], bus[j]);
        let (hm, hb) = (V3::from(m.h), V3::from(b.h));
        let hb = if hb.dot(&hm) < 0.0 { -hb } else { hb };
        let cos = (hb.dot(&hm) / (hb.norm() * hm.norm())).clamp(-1.0, 1.0);
        let h_true = h_true(m);
        if h_true >= STRONG_FACTOR * sigma_bkg {
            strong_matched += 1;
        }
        let var = sigma_bkg * sigma_bkg + (k_sen * h_true).powi(2);
        pairs.push(PulsePair {
            t: m.t,
            dt: b.t - m.t,
            h_true,
            rel_norm: (hb.norm() - hm.norm()) / hm.norm(),
            angle_deg: cos.acos().to_degrees(),
            nees: (hb - hm).norm_squared() / (3.0 * 2.0 * var),
        });
    }
    pairs.sort_by(|a, b| a.t.total_cmp(&b.t));
    PulseComparison {
        measurement: meas.len(),
        bus: bus.len(),
        strong: meas
            .iter()
            .filter(|m| h_true(m) >= STRONG_FACTOR * sigma_bkg)
            .count(),
        strong_matched,
        pairs,
    }
}

/// The bus-level simulation of `cfg` on the scenario's drawn unit ([`scenario_unit`])
/// with its bench calibration (a shipped unit), with context on error.
pub fn simulate_bus_default(cfg: &ScenarioConfig) -> Result<BusRun> {
    simulate_bus_with(cfg, UnitCalibration::Bench)
}

/// The bus-level simulation of `cfg` on the scenario's drawn unit holding the calibration
/// `mode` says, with context on error.
pub fn simulate_bus_with(cfg: &ScenarioConfig, mode: UnitCalibration) -> Result<BusRun> {
    let cal = scenario_calibration(cfg.seed, mode)?;
    simulate_bus(cfg, &scenario_unit(cfg.seed), &cal)
        .with_context(|| format!("bus-level simulation of {:?} seed {}", cfg.preset, cfg.seed))
}
