//! Guidance by tones: what the buzzer plays at each moment, from the display model.
//!
//! A rescuer searches with the eyes on the debris, so the receiver guides by ear the way
//! commercial digital receivers do: while there is a distance, beeps come faster and
//! higher as the victim gets closer; "probe here" is a distinct continuous two-tone
//! warble; a sensor fault is a low triple beep that overrides everything (a broken
//! receiver must not sound like an empty slope, nor like a victim). No signal is silence.
//!
//! [`tone_at`] is a pure function of what to say and the time, so the board only has to
//! call it at every tick (100 Hz: 10 ms edges) and set the PWM's frequency, or silence it.
//!
//! | situation | tone |
//! |---|---|
//! | distance d (m) | beeps every [`beep_period_ms`]`(d)` (≈ 0.2 s at 1 m, 1 s at 10 m, ≤ 1.5 s), [`BEEP_FRACTION`] of it on (50–150 ms), pitch [`beep_pitch_hz`]`(d)` (4 kHz at 0 m → 1.6 kHz far) |
//! | probe here | [`PROBE_HZ`] alternating every [`PROBE_SWAP_MS`], continuous |
//! | sensor fault | [`FAULT_HZ`]: three 100 ms beeps every 2 s |
//! | no signal, or muted | silence |
//!
//! Volume: the PWM duty ([`duty`]), 0 / −6 / −14 dB for the settings' steps 3 / 2 / 1.

use super::health::Fault;
use crate::guidance::Status;

/// The two pitches of "probe here", Hz.
pub const PROBE_HZ: [u32; 2] = [2000, 2600];
/// How long each pitch of "probe here" lasts, ms.
pub const PROBE_SWAP_MS: u64 = 125;
/// The fault tone, Hz (low: unlike any guidance tone).
pub const FAULT_HZ: u32 = 400;
/// The fault pattern's period, ms.
pub const FAULT_PERIOD_MS: u64 = 2000;
/// Part of a beep period the beep lasts.
pub const BEEP_FRACTION: f32 = 0.35;
/// The chirp that confirms "sound on" (unmuting in silence would otherwise give no sign),
/// Hz.
pub const CHIRP_HZ: u32 = 1000;
/// How long the chirp lasts, ms.
pub const CHIRP_MS: u64 = 100;

/// What the sound says.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SoundInput {
    /// The guidance status shown.
    pub status: Status,
    /// The distance shown, m.
    pub distance_m: Option<f32>,
    /// The sensor fault shown.
    pub fault: Option<Fault>,
    /// Sound off (a setting).
    pub muted: bool,
}

/// The beep period for a distance, ms: 120 ms + 90 ms per metre, within 150–1500 ms.
pub fn beep_period_ms(distance_m: f32) -> u64 {
    let d = if distance_m.is_finite() {
        distance_m.max(0.0)
    } else {
        f32::MAX
    };
    let ms = (120.0 + 90.0 * d.min(100.0)).clamp(150.0, 1500.0);
    ms as u64
}

/// The beep pitch for a distance, Hz: 1.5 kHz + 2.5 kHz / (1 + d / 2 m).
pub fn beep_pitch_hz(distance_m: f32) -> u32 {
    let d = if distance_m.is_finite() {
        distance_m.max(0.0)
    } else {
        f32::MAX
    };
    let hz = 1500.0 + 2500.0 / (1.0 + d.min(1e6) / 2.0);
    hz as u32
}

/// The tone to play at `t_ms` (any monotonic millisecond clock), Hz; `None`: silence.
pub fn tone_at(input: &SoundInput, t_ms: u64) -> Option<u32> {
    if input.muted {
        return None;
    }
    if input.fault.is_some() {
        let phase = t_ms % FAULT_PERIOD_MS;
        return (phase < 500 && (phase / 100).is_multiple_of(2)).then_some(FAULT_HZ);
    }
    match input.status {
        Status::NoSignal => None,
        Status::Probe => {
            let i = ((t_ms / PROBE_SWAP_MS) % 2) as usize;
            PROBE_HZ.get(i).copied()
        }
        Status::FluxLine | Status::Localized => {
            let d = input.distance_m.filter(|d| d.is_finite())?;
            let period = beep_period_ms(d);
            let on = ((period as f32 * BEEP_FRACTION) as u64).clamp(50, 150);
            (t_ms % period < on).then(|| beep_pitch_hz(d))
        }
    }
}

/// The PWM duty for volume step `volume` (0 = silent … [`crate::board::settings::MAX_VOLUME`]) on a timer whose
/// full duty is `max_duty`. A passive piezo driven by a rectangular wave of duty `d` gets
/// a fundamental of amplitude `(2/π)·sin(π d)`: duties 1/2, 1/6 and 1/16 give 0, −6 and
/// −14 dB, steps a rescuer hears apart without a quiet step that vanishes in the wind.
pub fn duty(max_duty: u16, volume: u8) -> u16 {
    let div = match volume {
        0 => return 0,
        1 => 16,
        2 => 6,
        _ => 2,
    };
    max_duty / div
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn volume_steps_are_quieter_duties_and_zero_is_silent() {
        let max = 4000;
        let duties: [u16; 4] = [0, 1, 2, 3].map(|v| duty(max, v));
        assert_eq!(duties, [0, 250, 666, 2000]);
        assert_eq!(duty(max, 200), 2000);
        // Fundamental level relative to the loudest step, dB: 0 > −6 > −14.
        let db = |d: u16| {
            let x = f32::from(d) / f32::from(max);
            20.0 * libm::log10f(libm::sinf(core::f32::consts::PI * x))
        };
        assert!((db(duties[2]) + 6.0).abs() < 0.1, "{}", db(duties[2]));
        assert!((db(duties[1]) + 14.2).abs() < 0.2, "{}", db(duties[1]));
        // A timer with a tiny range still sounds at every step but 0.
        assert!(duty(16, 1) > 0);
    }

    fn input(status: Status, d: Option<f32>) -> SoundInput {
        SoundInput {
            status,
            distance_m: d,
            fault: None,
            muted: false,
        }
    }

    /// Beep onsets and the pitches heard over `ms` milliseconds at 10 ms ticks.
    fn listen(i: &SoundInput, ms: u64) -> (Vec<u64>, Vec<u32>) {
        let (mut onsets, mut pitches) = (vec![], vec![]);
        let mut was_on = false;
        for t in (0..ms).step_by(10) {
            let tone = tone_at(i, t);
            if let Some(f) = tone {
                if !was_on {
                    onsets.push(t);
                }
                if !pitches.contains(&f) {
                    pitches.push(f);
                }
            }
            was_on = tone.is_some();
        }
        (onsets, pitches)
    }

    #[test]
    fn closer_beeps_faster_and_higher() {
        let mut last = (0usize, 0u32);
        for d in [40.0, 20.0, 10.0, 5.0, 2.0, 1.0, 0.3] {
            let (onsets, pitches) = listen(&input(Status::Localized, Some(d)), 10_000);
            assert_eq!(pitches.len(), 1, "one pitch per distance");
            assert!(onsets.len() >= last.0, "d = {d}: {} beeps", onsets.len());
            assert!(pitches[0] > last.1, "d = {d}: {} Hz", pitches[0]);
            last = (onsets.len(), pitches[0]);
        }
        // One beep per period: 1.02 s at 10 m, the 1.5 s ceiling at 20 m, the 150 ms floor
        // at 0.3 m.
        for (d, period) in [(10.0, 1020u64), (20.0, 1500), (0.3, 150)] {
            assert_eq!(beep_period_ms(d), period);
            let beeps = listen(&input(Status::FluxLine, Some(d)), 10_000).0.len() as u64;
            assert_eq!(beeps, 10_000u64.div_ceil(period), "d = {d}");
        }
        assert_eq!(beep_period_ms(10.0), 1020);
        assert_eq!(beep_pitch_hz(0.0), 4000);
        assert_eq!(beep_pitch_hz(2.0), 2750);
    }

    #[test]
    fn probe_here_is_a_continuous_warble() {
        let i = input(Status::Probe, Some(0.2));
        let heard: Vec<Option<u32>> = (0..100).map(|k| tone_at(&i, k * 10)).collect();
        assert!(heard.iter().all(Option::is_some), "never silent");
        let (_, pitches) = listen(&i, 1000);
        assert_eq!(pitches, PROBE_HZ);
        // Unlike any distance beep: two pitches, no gap.
        let (onsets, p) = listen(&input(Status::Localized, Some(0.2)), 1000);
        assert!(onsets.len() > 1 && p.len() == 1);
    }

    #[test]
    fn a_fault_overrides_everything_and_no_signal_or_mute_is_silent() {
        for status in [
            Status::NoSignal,
            Status::FluxLine,
            Status::Localized,
            Status::Probe,
        ] {
            let i = SoundInput {
                fault: Some(Fault::Adc),
                ..input(status, Some(3.0))
            };
            let (onsets, pitches) = listen(&i, 4000);
            assert_eq!(pitches, [FAULT_HZ]);
            assert_eq!(onsets, [0, 200, 400, 2000, 2200, 2400]);
        }
        assert_eq!(listen(&input(Status::NoSignal, None), 5000).0.len(), 0);
        assert_eq!(listen(&input(Status::Localized, None), 5000).0.len(), 0);
        assert_eq!(
            listen(&input(Status::Localized, Some(f32::NAN)), 5000)
                .0
                .len(),
            0
        );
        let muted = SoundInput {
            muted: true,
            fault: Some(Fault::Imu),
            ..input(Status::Probe, Some(0.1))
        };
        assert_eq!(listen(&muted, 5000).0.len(), 0);
    }

    #[test]
    fn extreme_distances_stay_in_range() {
        for d in [-5.0, 0.0, 1e-9, 1e9, f32::INFINITY, f32::NAN, f32::MAX] {
            let p = beep_period_ms(d);
            let f = beep_pitch_hz(d);
            assert!((150..=1500).contains(&p), "{d}: {p} ms");
            assert!((1500..=4000).contains(&f), "{d}: {f} Hz");
        }
    }
}
