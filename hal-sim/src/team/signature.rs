//! Transmitter signatures from a session log alone, and association of the tracks of
//! several logs by them.
//!
//! The session-log spec records, per pulse, only its time, field vector and the front
//! end's local `src` label: no period or carrier offset. A track's signature is therefore
//! derived from its pulse times: a transmitter pulses with a fixed period within
//! 1000 ± 300 ms (EN 300 718), so `t_k = φ + n_k P` and a least-squares line through the
//! pulse times gives `P` to a few µs over a minute of pulses (missed pulses only skip
//! `n_k`).
//!
//! Limits, stated plainly:
//! - The receivers' clocks are independent (no common epoch), so the phase `φ` is not
//!   comparable across logs; only the period is. Each receiver's crystal errs by up to
//!   tens of ppm, which scales its measured periods alike: two transmitters whose periods
//!   differ by less than about `2 × clock_ppm × P` (≈ 0.1 ms at 50 ppm) cannot be told
//!   apart (for periods uniform over 600 ms that is about 3 in 10 000 per pair).
//! - A track with fewer than 4 pulses (3 intervals of one period) gets no signature and
//!   stays a victim of its own log only.
//! - The estimated moment magnitude (field-strength consistency) is recorded per track as
//!   a second, weaker check; it is reported, not used to decide.
use serde::{Deserialize, Serialize};

/// The signature of one `src` track of one log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Signature {
    /// Pulse period, s (on the receiver's clock).
    pub period_s: f64,
    /// Its standard error from the fit, s.
    pub period_sigma_s: f64,
    /// Time of pulse 0 of the fit, s (the receiver's clock: not comparable across logs).
    pub phase_s: f64,
    /// Pulses used.
    pub pulses: usize,
    /// RMS residual of the pulse times about the fitted line, s.
    pub rms_s: f64,
}

/// Shortest and longest period a transmitter of the standard may have, s.
pub const PERIOD_RANGE_S: [f64; 2] = [0.7, 1.3];

/// Least-squares line `t = φ + n P` through `(n, t)` pairs: `(φ, P, rms, σ_P)`.
fn line_fit(n: &[f64], t: &[f64]) -> Option<(f64, f64, f64, f64)> {
    let k = n.len() as f64;
    let (mn, mt) = (n.iter().sum::<f64>() / k, t.iter().sum::<f64>() / k);
    let snn: f64 = n.iter().map(|v| (v - mn) * (v - mn)).sum();
    let snt: f64 = n.iter().zip(t).map(|(a, b)| (a - mn) * (b - mt)).sum();
    if snn <= 0.0 {
        return None;
    }
    let p = snt / snn;
    let phi = mt - p * mn;
    let ss: f64 = n
        .iter()
        .zip(t)
        .map(|(a, b)| (b - phi - p * a).powi(2))
        .sum();
    let rms = (ss / k).sqrt();
    // 1e-5 s floor: the log's time resolution is 1e-4 s (uniform rounding, σ ≈ 3e-5 s).
    let sigma_t = (ss / (k - 2.0).max(1.0)).sqrt().max(3e-5);
    Some((phi, p, rms, sigma_t / snn.sqrt()))
}

/// The signature of a track from its (sorted) pulse times; `None` with fewer than 4
/// pulses, fewer than 3 intervals of one period, non-finite times or no period within the
/// standard's range.
pub fn fit(times: &[f64]) -> Option<Signature> {
    if times.len() < 4 || times.iter().any(|t| !t.is_finite()) {
        return None;
    }
    let t0 = times.first()?;
    // Start from the median of the consecutive differences that can be one period.
    let mut d: Vec<f64> = times
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| (PERIOD_RANGE_S[0] * 0.98..=PERIOD_RANGE_S[1] * 1.02).contains(d))
        .collect();
    if d.len() < 3 {
        return None;
    }
    d.sort_by(f64::total_cmp);
    let mut p = d[d.len() / 2];
    let mut out = None;
    // Number the pulses with the current period and refit; twice is enough once the
    // period error times the longest gap is well under half a period.
    for _ in 0..3 {
        let n: Vec<f64> = times.iter().map(|t| ((t - t0) / p).round()).collect();
        let (phi, p_new, rms, sigma) = line_fit(&n, times)?;
        p = p_new;
        out = Some(Signature {
            period_s: p,
            period_sigma_s: sigma,
            phase_s: phi,
            pulses: times.len(),
            rms_s: rms,
        });
    }
    // A period that does not explain the times (residuals beyond a tenth of a period)
    // is not a transmitter's period.
    out.filter(|s| s.rms_s < 0.1 * s.period_s && s.period_s.is_finite())
}

/// Whether two signatures may be the same transmitter, allowing `clock_ppm` of clock error
/// in each receiver and 4σ of fit error.
pub fn compatible(a: &Signature, b: &Signature, clock_ppm: f64) -> bool {
    let tol = 4.0 * a.period_sigma_s.hypot(b.period_sigma_s)
        + 2.0 * clock_ppm * 1e-6 * a.period_s.max(b.period_s);
    (a.period_s - b.period_s).abs() <= tol
}

/// Groups tracks of several logs into transmitters: `tracks[log][k]` is the signature of
/// track `k` of `log` (`None`: no signature, it stays alone). Returns a global id per
/// track, the ids numbered 0.. in order of period. Greedy in order of period: a track
/// joins the current group when it is compatible with the group's first member and the
/// group has no track of the same log yet (one log's front end already separated its
/// transmitters).
pub fn associate(tracks: &[Vec<Option<Signature>>], clock_ppm: f64) -> Vec<Vec<usize>> {
    let mut order: Vec<(usize, usize, f64)> = Vec::new();
    for (l, ts) in tracks.iter().enumerate() {
        for (k, s) in ts.iter().enumerate() {
            order.push((l, k, s.as_ref().map_or(f64::INFINITY, |s| s.period_s)));
        }
    }
    order.sort_by(|a, b| a.2.total_cmp(&b.2).then(a.0.cmp(&b.0)).then(a.1.cmp(&b.1)));
    let mut out: Vec<Vec<usize>> = tracks.iter().map(|ts| vec![0; ts.len()]).collect();
    let mut groups: Vec<(Signature, Vec<usize>)> = Vec::new();
    let mut next = 0;
    for (l, k, _) in order {
        let sig = tracks.get(l).and_then(|ts| ts.get(k)).cloned().flatten();
        let joined = sig.as_ref().and_then(|s| {
            groups
                .iter_mut()
                .enumerate()
                .rev()
                .take(3)
                .find(|(_, (g, logs))| !logs.contains(&l) && compatible(g, s, clock_ppm))
                .map(|(i, (_, logs))| {
                    logs.push(l);
                    i
                })
        });
        let id = match joined {
            Some(i) => i,
            None => {
                if let Some(s) = sig {
                    groups.push((s, vec![l]));
                } else {
                    // No signature: a group of its own that nothing can join.
                    let never = Signature {
                        period_s: f64::NAN,
                        period_sigma_s: 0.0,
                        phase_s: 0.0,
                        pulses: 0,
                        rms_s: 0.0,
                    };
                    groups.push((never, vec![l]));
                }
                next += 1;
                next - 1
            }
        };
        if let Some(slot) = out.get_mut(l).and_then(|v| v.get_mut(k)) {
            *slot = id;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn pulses(period: f64, phase: f64, n: usize, drop: f64, seed: u64) -> Vec<f64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .filter(|_| rng.random::<f64>() >= drop)
            .map(|k| ((phase + k as f64 * period) * 1e4).round() / 1e4)
            .collect()
    }

    #[test]
    fn period_is_recovered_with_missed_pulses() {
        let t = pulses(1.0873, 12.3, 120, 0.4, 1);
        let s = fit(&t).unwrap();
        assert!(
            (s.period_s - 1.0873).abs() < 4.0 * s.period_sigma_s + 1e-9,
            "{s:?}"
        );
        assert!(s.period_sigma_s < 2e-6);
    }

    #[test]
    fn too_short_or_bad_tracks_have_no_signature() {
        assert!(fit(&[0.0, 1.0, 2.0]).is_none());
        assert!(fit(&[0.0, 1.0, 2.0, 3.0]).is_some());
        assert!(fit(&[0.0, 1.0, 2.0, 3.0, f64::NAN, 5.0]).is_none());
        // Two intervals of a period and a long gap: too little to fit.
        assert!(fit(&[0.0, 1.0, 2.0, 9.0]).is_none());
        // Times with no period in the standard's range.
        assert!(fit(&[0.0, 0.1, 0.2, 0.3, 0.4, 6.0]).is_none());
    }

    #[test]
    fn tracks_group_across_logs_by_period() {
        // Three transmitters, two logs with their own labels and clock errors (±20 ppm).
        let periods = [0.9512, 1.2033, 0.9517];
        let sig =
            |p: f64, clock: f64, seed| fit(&pulses(p * clock, 3.0 * seed as f64, 90, 0.2, seed));
        let log_a = vec![
            sig(periods[2], 1.0 + 2e-5, 1),
            sig(periods[0], 1.0 + 2e-5, 2),
        ];
        let log_b = vec![
            sig(periods[0], 1.0 - 2e-5, 3),
            sig(periods[1], 1.0 - 2e-5, 4),
            sig(periods[2], 1.0 - 2e-5, 5),
            None,
        ];
        let ids = associate(&[log_a, log_b], 50.0);
        assert_eq!(ids[0][0], ids[1][2]);
        assert_eq!(ids[0][1], ids[1][0]);
        assert_ne!(ids[0][0], ids[0][1]);
        let mut all: Vec<usize> = ids.concat();
        all.sort();
        all.dedup();
        // 3 transmitters + the track without a signature.
        assert_eq!(all.len(), 4);
    }
}
