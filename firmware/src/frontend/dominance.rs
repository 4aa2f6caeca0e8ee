//! Overlapped pulses where one transmitter dominates (issue 9).
//!
//! The field falls as r⁻³, so near the victim being searched its pulse is typically
//! 20–60 dB above the other beacons'. A pulse overlapped by a much weaker one carries a
//! vector error of at most the interferer's amplitude `ρ·|H|` (ρ = interferer / dominant
//! amplitude). The pulse noise model (ICRA eq. 10) is `σ = σ_bkg + k_sen·|H|` with
//! `k_sen = 0.03`: an interferer below [`DOMINANCE_RATIO`] = 1 % of the dominant
//! amplitude adds less than a third of that relative noise (0.01 < 0.03 / 3 ≈ 0.01,
//! and in quadrature √(0.03² + 0.01²) = 1.054 · 0.03, a 5 % inflation). Such a pulse is
//! passed on with its σ inflated by the bound; a comparable overlap is withheld.

/// Largest interferer/dominant amplitude ratio for which an overlapped pulse is kept
/// (measured: `docs/decisions/overlap-thresholds.md`).
pub const DOMINANCE_RATIO: f32 = 0.01;

/// What to do with an overlapped pulse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OverlapVerdict {
    /// One transmitter dominates: keep the pulse; `ratio` bounds the interferer's
    /// amplitude relative to the pulse's.
    Dominant {
        /// Interferer / dominant amplitude (0 ≤ ratio ≤ [`DOMINANCE_RATIO`]).
        ratio: f32,
    },
    /// The transmitters are comparable: withhold the pulse as before.
    Withheld,
}

/// Why an overlap could not be judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DominanceError {
    /// An amplitude was NaN, infinite or negative.
    #[error("an amplitude was NaN, infinite or negative")]
    BadAmplitude,
}

/// Judge a pulse of amplitude `own` (A/m) overlapped by one of amplitude `interferer`.
/// A zero `own` amplitude is never dominant.
pub fn overlap_verdict(own: f32, interferer: f32) -> Result<OverlapVerdict, DominanceError> {
    let ok = |a: f32| a.is_finite() && a >= 0.0;
    if !ok(own) || !ok(interferer) {
        return Err(DominanceError::BadAmplitude);
    }
    // Written as a product so that own = 0 can never pass.
    if own > 0.0 && interferer <= DOMINANCE_RATIO * own {
        Ok(OverlapVerdict::Dominant {
            ratio: interferer / own,
        })
    } else {
        Ok(OverlapVerdict::Withheld)
    }
}

impl OverlapVerdict {
    /// Per-component σ (A/m) of a kept pulse of amplitude `h_norm` whose noise without
    /// the interferer is `sigma`: the interferer's worst-case error `ratio·|H|` added in
    /// quadrature. `None` for a withheld pulse.
    pub fn inflated_sigma(&self, sigma: f32, h_norm: f32) -> Option<f32> {
        match *self {
            OverlapVerdict::Dominant { ratio } => Some(libm::hypotf(sigma, ratio * h_norm)),
            OverlapVerdict::Withheld => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dominant_overlap_is_kept_with_inflated_sigma() {
        let v = overlap_verdict(2.0, 0.01).unwrap();
        assert_eq!(v, OverlapVerdict::Dominant { ratio: 0.005 });
        // Against f64: hypot(σ, ρ|H|).
        let s = v.inflated_sigma(0.06, 2.0).unwrap();
        let want = (0.06f64).hypot(0.005 * 2.0);
        assert!((f64::from(s) - want).abs() < 1e-6, "{s} vs {want}");
        assert!(s > 0.06);
    }

    #[test]
    fn comparable_overlap_is_withheld() {
        for (own, int) in [(1.0, 0.5), (1.0, 1.0), (0.3, 1.0), (1.0, 0.0101)] {
            let v = overlap_verdict(own, int).unwrap();
            assert_eq!(v, OverlapVerdict::Withheld, "{own} {int}");
            assert_eq!(v.inflated_sigma(0.1, own), None);
        }
        // The weaker of a dominant pair is withheld, the stronger kept.
        assert_eq!(overlap_verdict(0.001, 1.0), Ok(OverlapVerdict::Withheld));
        assert!(matches!(
            overlap_verdict(1.0, 0.001),
            Ok(OverlapVerdict::Dominant { .. })
        ));
    }

    #[test]
    fn bad_amplitudes_are_errors() {
        for (own, int) in [
            (f32::NAN, 0.0),
            (1.0, f32::NAN),
            (f32::INFINITY, 0.0),
            (1.0, -0.1),
            (-1.0, 0.0),
        ] {
            assert_eq!(
                overlap_verdict(own, int),
                Err(DominanceError::BadAmplitude),
                "{own} {int}"
            );
        }
        // Nothing heard on either: not dominant.
        assert_eq!(overlap_verdict(0.0, 0.0), Ok(OverlapVerdict::Withheld));
    }
}
