//! The detection section of `hal-sim sensing-report`: the DSP's false-alarm rate on
//! noise-only streams and its probability of detection against the field, measured through
//! the emulated chain ([`crate::bus::detection`]), compared with the matched-filter limit
//! at the measured false-alarm rate, and the reception range this gives for the standard's
//! weakest and strongest transmitters.
use crate::sensors::bus::detection::{
    Limit, MAX_OFFSET_HZ, PERIOD_S, PULSE_S, matched_filter_limit, probe_run, probe_train, range_m,
};
use crate::sensors::bus::if_signal::REFERENCE_PULSE_S;
use crate::sensors::bus::run::{UnitCalibration, scenario_calibration, scenario_unit};
use crate::sensors::bus::unit::Unit;
use anyhow::Result;
use firmware::board::REFERENCE;
use rayon::prelude::*;
use std::fmt::Write as _;

/// The environment's EMI, A/m per component of a 70 ms pulse (the `paper` preset's
/// `pulse_noise.sigma_bkg_A_per_m`).
pub const SIGMA_BKG: f64 = 2.59e-9;
/// The false-alarm requirement: one per 10 minutes.
pub const REQUIRED_RATE_PER_S: f64 = 1.0 / 600.0;
/// EN 300 718's field strength at 10 m (most favourable direction), weakest and strongest
/// transmitter, A/m.
pub const H10_WEAKEST: f64 = 0.5e-6;
/// See [`H10_WEAKEST`].
pub const H10_STRONGEST: f64 = 2.23e-6;
/// Field magnitudes probed, in σ_bkg.
pub const SNR_GRID: [f64; 12] = [
    4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 16.0,
];
/// Length of one noise-only run, s.
const NOISE_RUN_S: f64 = 3600.0;
/// Units (scenario seeds) the runs rotate through.
const UNITS: u64 = 4;

/// Options of the detection measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectionArgs {
    /// Hours of noise-only simulated time.
    pub noise_hours: u64,
    /// Pulses per point of the field grid.
    pub pulses: usize,
}

/// Pd at one field magnitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PdPoint {
    /// `|H|/σ_bkg`.
    pub snr: f64,
    /// Pulses emulated.
    pub n: usize,
    /// Pulses the DSP reported (any measurement).
    pub detected: usize,
    /// Pulses that gave a field vector.
    pub fields: usize,
    /// Reports that matched no pulse.
    pub false_alarms: usize,
}

/// The whole measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Options.
    pub args: DetectionArgs,
    /// Noise-only simulated time, s.
    pub noise_s: f64,
    /// Reports on noise: any measurement, and field vectors.
    pub noise_reports: usize,
    /// Of which field vectors.
    pub noise_fields: usize,
    /// Detections the DSP rejected as too short on noise.
    pub noise_rejected_short: u32,
    /// Per-component σ of a 70 ms amplitude including the ADC's own noise, in σ_bkg.
    pub sigma_tot: f64,
    /// The probed points.
    pub points: Vec<PdPoint>,
}

/// The unit of scenario seed `seed` and its bench calibration.
fn unit(seed: u64) -> Result<(Unit, firmware::frontend::Calibration)> {
    Ok((
        scenario_unit(seed),
        scenario_calibration(seed, UnitCalibration::Bench)?,
    ))
}

/// The noise the DSP faces per component of a 70 ms amplitude, in σ_bkg: the EMI and the
/// emulated ADC's input noise at the starting gain, through unit `u`'s coil gains.
fn sigma_tot(u: &Unit) -> f64 {
    let fs = f64::from(REFERENCE.sample_rate_hz());
    let v = f64::from(REFERENCE.adc.input_noise_v_rms[REFERENCE.start_range().gain as usize]);
    let per_sample: f64 = u
        .chain
        .gain_a_per_m_per_v
        .iter()
        .map(|g| (v * g).powi(2))
        .sum::<f64>()
        / 3.0;
    let adc = per_sample * 2.0 / (REFERENCE_PULSE_S * fs);
    (SIGMA_BKG * SIGMA_BKG + adc).sqrt() / SIGMA_BKG
}

/// Runs the measurement (parallel over hours and grid points).
pub fn measure(args: DetectionArgs) -> Result<Detection> {
    let units: Vec<_> = (1..=UNITS).map(unit).collect::<Result<_>>()?;
    use indicatif::ParallelProgressIterator as _;
    let noise: Vec<_> = (0..args.noise_hours)
        .into_par_iter()
        .progress_with(crate::cli::progress::bar(
            args.noise_hours,
            "noise-only hours",
        ))
        .map(|h| {
            let (u, c) = &units[(h % UNITS) as usize];
            probe_run(
                u,
                REFERENCE.frontend_config(c),
                SIGMA_BKG,
                Vec::new(),
                NOISE_RUN_S,
                0xFA15_0000 + h,
            )
        })
        .collect::<Result<_>>()?;
    let points: Vec<PdPoint> = SNR_GRID
        .par_iter()
        .enumerate()
        .progress_with(crate::cli::progress::bar(
            SNR_GRID.len() as u64,
            "field magnitudes",
        ))
        .map(|(k, &snr)| {
            let (u, c) = &units[k % UNITS as usize];
            let truth = probe_train(args.pulses, snr * SIGMA_BKG, 0xD37E_0000 + k as u64);
            let secs = 1.0 + args.pulses as f64 * PERIOD_S + 1.0;
            let run = probe_run(
                u,
                REFERENCE.frontend_config(c),
                SIGMA_BKG,
                truth,
                secs,
                0x9D00_0000 + k as u64,
            )?;
            let d = run.detections();
            Ok(PdPoint {
                snr,
                n: d.len(),
                detected: d.iter().filter(|x| x.0).count(),
                fields: d.iter().filter(|x| x.1).count(),
                false_alarms: run.false_alarms().len(),
            })
        })
        .collect::<Result<_>>()?;
    let sigma = units.iter().map(|(u, _)| sigma_tot(u)).sum::<f64>() / units.len() as f64;
    Ok(Detection {
        args,
        noise_s: noise.iter().map(|r| r.seconds).sum(),
        noise_reports: noise.iter().map(|r| r.reported.len()).sum(),
        noise_fields: noise
            .iter()
            .map(|r| r.reported.iter().filter(|p| p.field().is_some()).count())
            .sum(),
        noise_rejected_short: noise.iter().map(|r| r.stats.rejected_short).sum(),
        sigma_tot: sigma,
        points,
    })
}

/// `|H|/σ_bkg` where the fraction `f(point)` first reaches `p` (linear between grid
/// points), if it does.
pub fn crossing(points: &[PdPoint], p: f64, f: impl Fn(&PdPoint) -> usize) -> Option<f64> {
    let frac = |q: &PdPoint| f(q) as f64 / q.n.max(1) as f64;
    let mut prev: Option<&PdPoint> = None;
    for q in points {
        if frac(q) >= p {
            return Some(match prev {
                Some(a) if frac(a) < p => {
                    let (fa, fq) = (frac(a), frac(q));
                    a.snr + (p - fa) / (fq - fa) * (q.snr - a.snr)
                }
                _ => q.snr,
            });
        }
        prev = Some(q);
    }
    None
}

impl Detection {
    /// False alarms per second (field vectors from noise), and the one-sided 95 % upper
    /// bound (Poisson; 3/T when none).
    pub fn rate(&self) -> (f64, f64) {
        let n = self.noise_fields as f64;
        // Upper 95 % Poisson bound ≈ (√n + 1.645/2 … ): the exact values for small n.
        let upper = match self.noise_fields {
            0 => 3.0,
            1 => 4.74,
            2 => 6.30,
            3 => 7.75,
            4 => 9.15,
            5 => 10.51,
            _ => n + 1.645 * n.sqrt() + 1.0,
        };
        (n / self.noise_s, upper / self.noise_s)
    }

    /// The limit at the measured false-alarm rate (its upper bound when none was seen).
    pub fn limit(&self) -> Limit {
        let (r, up) = self.rate();
        matched_filter_limit(if self.noise_fields == 0 { up } else { r }, 0.9)
    }

    /// Renders the section.
    pub fn render(&self) -> String {
        let mut s = String::new();
        let (rate, upper) = self.rate();
        let lim = self.limit();
        let req = matched_filter_limit(REQUIRED_RATE_PER_S, 0.9);
        let h90 = crossing(&self.points, 0.9, |q| q.fields);
        let d90 = crossing(&self.points, 0.9, |q| q.detected);
        let lim_h = lim.h_over_sigma * self.sigma_tot;
        let req_h = req.h_over_sigma * self.sigma_tot;
        let fmt = |x: Option<f64>| x.map_or("> grid".to_string(), |v| format!("{v:.1} σ_bkg"));
        let ratio = |x: Option<f64>, l: f64| {
            x.map_or("–".to_string(), |v| {
                format!("{:.2}× ({:.1} dB)", v / l, 20.0 * (v / l).log10())
            })
        };
        let _ = writeln!(
            s,
            "## Detection near the physical limit\n\n| quantity | value |\n|---|---|\n| false alarms (field vectors from noise) | {} in {:.1} h: {:.2} per 10 min (95 % upper bound {:.2}) |\n| field vectors with probability 0.9 at | {} |\n| matched-filter limit at that rate (Pd 0.9) | {:.2} σ_tot = {:.2} σ_bkg (threshold {:.1} on χ²₆, {:.1e} per cell) |\n| DSP / limit | {} |\n| limit at the requirement (1 per 10 min) | {:.2} σ_bkg (threshold {:.1}); DSP / it {} |\n| reception range (DSP's 90 % point), weakest / strongest transmitter | {} / {} |\n| reception range (limit at 1 per 10 min) | {:.0} m / {:.0} m |\n",
            self.noise_fields,
            self.noise_s / 3600.0,
            rate * 600.0,
            upper * 600.0,
            fmt(h90),
            lim.h_over_sigma,
            lim_h,
            lim.threshold,
            lim.p_cell,
            ratio(h90, lim_h),
            req_h,
            req.threshold,
            ratio(h90, req_h),
            h90.map_or("–".into(), |h| format!(
                "{:.0} m",
                range_m(H10_WEAKEST, h * SIGMA_BKG)
            )),
            h90.map_or("–".into(), |h| format!(
                "{:.0} m",
                range_m(H10_STRONGEST, h * SIGMA_BKG)
            )),
            range_m(H10_WEAKEST, req_h * SIGMA_BKG),
            range_m(H10_STRONGEST, req_h * SIGMA_BKG),
        );
        let _ = writeln!(
            s,
            "Protocol (`hal_sim::eval::detection_report`, `hal_sim::sensors::bus::detection`): a still receiver, {UNITS} drawn units (scenario seeds 1..={UNITS}) each with its bench calibration, the board profile's front-end configuration (`REFERENCE.frontend_config`, gain ranging on, starting at PGA 128), the emulated ADS131M04 with its input noise, the firmware's driver and DSP. Noise: white EMI of σ_bkg = {SIGMA_BKG:.2e} A/m per component of a 70 ms amplitude (the `paper` preset's); with the ADC's own noise the DSP faces σ_tot = {:.3} σ_bkg, the σ the limit is stated in. False alarms: {} noise-only runs of {:.0} s; a false alarm is a field vector reported (the DSP also reported {} withheld pulses and dropped {} detections as too short). Detection: per field magnitude {} pulses of {:.0} ms, one per {PERIOD_S:.0} s, direction uniform on the sphere, carrier uniform in ±{MAX_OFFSET_HZ:.0} Hz, carrier phase uniform, start uniform within a 2 ms block; a pulse is detected when a report's centre is within 35 ms of its centre. Limit: the coherent energy of the three coils over one 70 ms pulse, Σ|c_i|²/σ² (χ²₆ on noise, non-central with λ = |H|²/σ² on a pulse), over 2·80 Hz·70 ms = {:.1} frequency bins × one position per 70 ms = {:.0} independent cells per second. Range: field ∝ r⁻³ from EN 300 718's 0.5 / 2.23 µA/m at 10 m (most favourable direction; commercial receivers state 50–70 m).\n",
            self.sigma_tot,
            self.args.noise_hours,
            NOISE_RUN_S,
            self.noise_reports - self.noise_fields,
            self.noise_rejected_short,
            self.args.pulses,
            PULSE_S * 1e3,
            2.0 * MAX_OFFSET_HZ * PULSE_S,
            lim.cells_per_s,
        );
        let _ = writeln!(
            s,
            "| \\|H\\|/σ_bkg | pulses | reported | field vectors | false alarms in the run |\n|---|---|---|---|---|"
        );
        for q in &self.points {
            let _ = writeln!(
                s,
                "| {:.0} | {} | {:.1} % | {:.1} % | {} |",
                q.snr,
                q.n,
                100.0 * q.detected as f64 / q.n.max(1) as f64,
                100.0 * q.fields as f64 / q.n.max(1) as f64,
                q.false_alarms
            );
        }
        let _ = writeln!(
            s,
            "\nAny report (field, overlap, saturated) with probability 0.9 at {}.\n",
            fmt(d90)
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crossing_interpolates_between_grid_points() {
        let p = |snr, fields| PdPoint {
            snr,
            n: 10,
            detected: fields,
            fields,
            false_alarms: 0,
        };
        let pts = [p(5.0, 2), p(6.0, 8), p(7.0, 10)];
        let x = crossing(&pts, 0.9, |q| q.fields).unwrap();
        assert!((x - 6.5).abs() < 1e-9, "{x}");
        assert_eq!(crossing(&pts[..2], 0.9, |q| q.fields), None);
    }
}
